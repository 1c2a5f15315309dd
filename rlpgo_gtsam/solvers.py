"""GTSAM Gauss-Newton and Levenberg-Marquardt with iteration caps and a per-iteration trace."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam

from rlpgo_gtsam.errors import SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph2D, between_factors

__all__ = ["RefineResult", "refine", "SOLVERS"]

SOLVERS = ("lm", "gn")
# An anchor prior this tight fixes the gauge without changing the chi2 of the other factors.
_ANCHOR_SIGMA = 1e-8
_TOLERANCE = 1e-10


@dataclass
class RefineResult:
    """What :func:`refine` returns.

    Attributes:
        values: the refined poses (the start, if the solver failed at once).
        chi2: g2o chi2 of ``values`` (2 x GTSAM error of the between factors).
        iterations: solver iterations run.
        chi2_trace: chi2 before the first iteration and after each one.
        failure: why the solver stopped early with an unusable result, or None.
    """

    values: gtsam.Values
    chi2: float
    iterations: int
    chi2_trace: list[float] = field(default_factory=list)
    failure: str | None = None


def refine(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    solver: str = "lm",
    iters: int = 30,
) -> RefineResult:
    """Run GTSAM's GN or LM from ``values`` for at most ``iters`` iterations.

    The anchor pose (the prior-marked one, else the first key) is held by a tight prior.
    Iterations stop early once the error's relative or absolute decrease falls below 1e-10,
    as GTSAM's own convergence test does. A failure of the linear solver (an indeterminate
    system) or a non-finite error ends the run with ``failure`` set instead of raising.

    Raises:
        SolverError: an unknown solver name or a negative iteration cap.
    """
    if solver not in SOLVERS:
        raise SolverError(f"unknown solver '{solver}'; choose one of {', '.join(SOLVERS)}")
    if iters < 0:
        raise SolverError(f"iteration cap must be >= 0, got {iters}")
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    objective = between_factors(graph)
    anchored = between_factors(graph)
    anchor_key = int(pose_graph.keys[pose_graph.anchor])
    anchor_noise = gtsam.noiseModel.Isotropic.Sigma(3, _ANCHOR_SIGMA)
    anchored.add(gtsam.PriorFactorPose2(anchor_key, values.atPose2(anchor_key), anchor_noise))
    trace = [2.0 * objective.error(values)]
    if iters == 0:
        return RefineResult(gtsam.Values(values), trace[0], 0, trace)
    optimizer = _make_optimizer(anchored, values, solver, iters)
    failure = None
    for _ in range(iters):
        try:
            optimizer.iterate()
        except RuntimeError as error:
            failure = f"{solver.upper()} failed: {one_line(error)}"
            break
        current = 2.0 * objective.error(optimizer.values())
        if not math.isfinite(current):
            failure = f"{solver.upper()} diverged (non-finite error)"
            break
        previous = trace[-1]
        trace.append(current)
        decrease = previous - current
        if abs(decrease) <= _TOLERANCE or abs(decrease) <= _TOLERANCE * previous:
            break
        if solver == "lm" and optimizer.lambda_() >= _LM_LAMBDA_MAX:
            break
    result = gtsam.Values(optimizer.values())
    return RefineResult(result, trace[-1], len(trace) - 1, trace, failure)


_LM_LAMBDA_MAX = 1e5


def _make_optimizer(graph, values, solver, iters):
    if solver == "gn":
        params = gtsam.GaussNewtonParams()
        params.setMaxIterations(iters)
        params.setRelativeErrorTol(_TOLERANCE)
        params.setAbsoluteErrorTol(_TOLERANCE)
        return gtsam.GaussNewtonOptimizer(graph, values, params)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iters)
    params.setRelativeErrorTol(_TOLERANCE)
    params.setAbsoluteErrorTol(_TOLERANCE)
    params.setlambdaUpperBound(_LM_LAMBDA_MAX)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params)
