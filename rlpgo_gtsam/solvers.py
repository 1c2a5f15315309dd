"""GTSAM Gauss-Newton and Levenberg-Marquardt on the whole graph (planar or 3D), with a chi2
trace."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import gtsam

from rlpgo_gtsam.errors import SolverError, one_line
from rlpgo_gtsam.graph import chi2, extract_pose_graph
from rlpgo_gtsam.groups import GROUPS
from rlpgo_gtsam.numerics import eliminating_call

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph

__all__ = ["RefineResult", "refine", "solver_params", "gauge_prior", "SOLVERS"]

SOLVERS = ("lm", "gn")
# A gauge prior this tight holds the anchor without changing the chi2 of the other factors.
_ANCHOR_SIGMA = 1e-8
_TOLERANCE = 1e-10
_LM_LAMBDA_MAX = 1e5

Params = gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams


@dataclass(eq=False)
class RefineResult:
    """What :func:`refine` returns.

    Attributes:
        values: the refined poses (the last iterate GTSAM reached if it failed).
        chi2: g2o chi2 of ``values`` (2 x GTSAM error of the user's graph).
        iterations: solver iterations run.
        chi2_trace: chi2 before the first iteration and after each one.
        failure: why the solver stopped with an unusable result, or None.
    """

    values: gtsam.Values
    chi2: float
    iterations: int
    chi2_trace: list[float] = field(default_factory=list)
    failure: str | None = None


def solver_params(solver: str = "lm", iters: int = 30, tolerance: float = _TOLERANCE) -> Params:
    """GTSAM parameters of the project's GN / LM: ``iters`` at most, relative and absolute
    error tolerances ``tolerance`` (by default 1e-10).

    LM also stops once its damping exceeds 1e5 (no step that lowers the error is left).
    """
    if solver not in SOLVERS:
        raise SolverError(f"unknown solver '{solver}'; choose one of {', '.join(SOLVERS)}")
    if iters < 0:
        raise SolverError(f"iteration cap must be >= 0, got {iters}")
    params: Params
    if solver == "gn":
        params = gtsam.GaussNewtonParams()
    else:
        params = gtsam.LevenbergMarquardtParams()
        params.setlambdaUpperBound(_LM_LAMBDA_MAX)
    params.setMaxIterations(iters)
    params.setRelativeErrorTol(tolerance)
    params.setAbsoluteErrorTol(tolerance)
    return params


def refine(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    solver: str | Params = "lm",
    iters: int = 30,
    pose_graph: PoseGraph | None = None,
    on_iteration: Callable[[int, float], None] | None = None,
    *,
    tolerance: float = _TOLERANCE,
    has_prior: bool | None = None,
) -> RefineResult:
    """Run GTSAM's GN or LM on ``graph`` (Pose2 or Pose3) from ``values``.

    The graph is optimized as it is, every prior included. If it has no prior, the gauge
    is fixed by a tight prior on the anchor pose (the first key), which adds nothing to the
    reported chi2.

    Args:
        solver: "lm", "gn", or a ``gtsam.LevenbergMarquardtParams`` /
            ``gtsam.GaussNewtonParams`` run by GTSAM's own ``optimize()`` as given
            (``iters`` is then ignored). "gn" differs from GTSAM's own Gauss-Newton in one
            way, g2o's: GTSAM's GN declares convergence at the first step that raises the
            error and returns that worse iterate, so from a poor start it stops after one
            step; "gn" keeps iterating (GTSAM's ``iterate()``) until the error changes by
            less than 1e-10 (relative or absolute) or ``iters`` steps ran.
        iters: iteration cap of "lm" / "gn".
        pose_graph: the graph's extraction, if the caller has it (saves a second one).
        on_iteration: called once after each iteration with its number (from 1) and chi2
            (for progress lines); None: nothing.
        tolerance: "lm" / "gn" stop once an iteration changes the error by less than this,
            relative or absolute.
        has_prior: whether ``graph`` holds a Pose2 or Pose3 prior, where the caller knows;
            None: found out by a walk over its factors (MIT: 3 ms a call).

    A failure of the linear solver (an indeterminate system) or a non-finite error ends the
    run with ``failure`` set instead of raising. The solver runs on a thread whose stack
    holds GTSAM's elimination of the whole graph however deep its tree
    (:func:`~rlpgo_gtsam.numerics.eliminating_call`).

    Raises:
        SolverError: an unknown solver name or a negative iteration cap.
        GraphError: a graph the package cannot work on (see
            :func:`~rlpgo_gtsam.graph.extract_pose_graph`).
    """
    params = solver if isinstance(solver, Params) else solver_params(solver, iters, tolerance)
    name = "GN" if isinstance(params, gtsam.GaussNewtonParams) else "LM"
    g = pose_graph if pose_graph is not None else extract_pose_graph(graph, values)
    start_chi2 = chi2(graph, values)
    if params.getMaxIterations() == 0:
        return RefineResult(gtsam.Values(values), start_chi2, 0, [start_chi2])
    optimized = graph
    if not (_has_prior(graph, g) if has_prior is None else has_prior):
        optimized = gtsam.NonlinearFactorGraph(graph)
        optimized.add(gauge_prior(g, values, _ANCHOR_SIGMA))
    after_iteration: dict[int, float] = {}  # GTSAM's LM may report an iteration twice

    def record(k: int, value: float) -> None:
        if on_iteration is not None and k not in after_iteration:
            on_iteration(k, value)
        after_iteration[k] = value

    caller_hook = params.iterationHook  # the caller's params get their own hook back
    params.iterationHook = lambda k, _before, after: record(int(k), 2.0 * float(after))
    failure: str | None = None
    optimizer: gtsam.GaussNewtonOptimizer | gtsam.LevenbergMarquardtOptimizer | None = None
    try:
        if isinstance(params, gtsam.GaussNewtonParams):
            optimizer = gtsam.GaussNewtonOptimizer(optimized, values, params)
        else:
            optimizer = gtsam.LevenbergMarquardtOptimizer(optimized, values, params)
        run: Callable[[], object] = optimizer.optimize
        if solver == "gn":
            run = functools.partial(_iterate_through_increases, optimizer,
                                    params.getMaxIterations(), tolerance, record)
        eliminating_call(values.size(), run, optimized.size())
    except RuntimeError as error:
        failure = f"{name} failed: {one_line(error)}"
    finally:
        params.iterationHook = caller_hook
    result = gtsam.Values(values if optimizer is None else optimizer.values())
    final = chi2(graph, result)
    if failure is None and not math.isfinite(final):
        failure = f"{name} diverged (non-finite error)"
    iterations = 0 if optimizer is None else optimizer.iterations()
    trace = [start_chi2] + [after_iteration[k] for k in sorted(after_iteration)]
    return RefineResult(result, final, iterations, trace, failure)


def _iterate_through_increases(optimizer, iters: int, tolerance: float,
                               record: Callable[[int, float], None]) -> None:
    """g2o's Gauss-Newton loop over GTSAM's ``iterate()``: an error increase does not stop it;
    a change below ``tolerance`` (relative or absolute) does. ``record`` gets each
    iteration's number and chi2."""
    previous = optimizer.error()
    for k in range(1, iters + 1):
        optimizer.iterate()
        current = optimizer.error()
        record(k, 2.0 * current)
        if not math.isfinite(current):
            return
        decrease = abs(previous - current)
        if decrease <= tolerance or decrease <= tolerance * previous:
            return
        previous = current


def gauge_prior(pose_graph: PoseGraph, values: gtsam.Values,
                sigma: float) -> gtsam.NonlinearFactor:
    """A prior holding the anchor at its pose in ``values``, isotropic ``sigma``: the graph's
    group's prior factor (``PriorFactorPose2`` or ``PriorFactorPose3``)."""
    key = int(pose_graph.keys[pose_graph.anchor])
    group = pose_graph.group
    return group.prior_factor(key, group.pose_at(values, key),
                              gtsam.noiseModel.Isotropic.Sigma(group.dof, sigma))


def _has_prior(graph: gtsam.NonlinearFactorGraph, pose_graph: PoseGraph) -> bool:
    """Whether ``graph`` holds a Pose2 or Pose3 prior. Where ``pose_graph`` is the extraction
    of this very graph and found as many edges as the graph has factors, every factor is an
    edge and the answer needs no walk over the factors (0.04-0.06 s on City10K, once per
    refinement: six times in a comparison)."""
    if pose_graph.graph is graph and graph.size() == pose_graph.num_edges:
        return False
    priors = tuple(group.prior_factor for group in GROUPS)
    return any(isinstance(graph.at(i), priors) for i in range(graph.size()))

