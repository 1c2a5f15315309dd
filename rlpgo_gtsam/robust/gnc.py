"""Graduated non-convexity with truncated least squares (Yang et al. 2020): ours on a linear
least-squares problem (the translation step), and GTSAM's GNC-LM, the robust path's last step.

:func:`gnc_tls` takes any weighted solve and residual function; :func:`robust_positions`
runs it on the translation step with fixed rotations, planar or 3D: the group's whitened
system and weighted solve (:func:`~rlpgo_gtsam.translations.translation_system`).
:func:`gnc_lm` runs GTSAM's ``GncLMOptimizer`` on the edges the robust path kept.
"""

from __future__ import annotations

import math
from typing import Any, cast

import gtsam
import numpy as np

from rlpgo_gtsam.errors import SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph, component_labels
from rlpgo_gtsam.linear import WEIGHT_FLOOR
from rlpgo_gtsam.numerics import eliminating_call
from rlpgo_gtsam.robust.problem import Problem
from rlpgo_gtsam.solvers import gauge_prior, solver_params
from rlpgo_gtsam.translations import translation_system

__all__ = ["gnc_tls", "tls_weights", "robust_positions", "gnc_lm"]

_MU_STEP = 1.4  # the control parameter's growth per iteration (GTSAM's GncParams muStep)
_MU_MIN = 1e-6  # its first value at least: a huge first residual must not make it zero
_WEIGHTS_TOL = 1e-4  # weights this close to 0 or 1 have converged (GTSAM's weightsTol)
# The weight of an edge out that places a pose no edge in weight joins to a held pose: far
# below any weight in (its pull on the rest is a millionth of an inlier's), far above the
# weighted solve's WEIGHT_FLOOR.
_PLACING = 1e-6


def robust_positions(g: PoseGraph, rotations: np.ndarray, known: np.ndarray,
                      excluded: np.ndarray, threshold: float,
                      iterations: int) -> tuple[np.ndarray, np.ndarray, int]:
    """GNC-TLS on the translation step with ``rotations`` fixed (planar angles (n,) or 3D
    matrices (n, 3, 3)): positions, weights, solves.

    The residuals are the translation step's, whitened (d dof:
    :meth:`~rlpgo_gtsam.translations.TranslationStep.whitened`); known edges keep
    weight 1, excluded edges 0.
    """
    i, j = g.edges[:, 0], g.edges[:, 1]
    a_j, b, solve = translation_system(g, rotations)

    def residuals(t: np.ndarray) -> np.ndarray:
        r = np.einsum("eab,eb->ea", a_j, t[j] - t[i]) - b
        return np.einsum("ea,ea->e", r, r)

    return gnc_tls(lambda weights: solve(_placing(g, weights)), residuals, known, excluded,
                   threshold, iterations)


def _placing(g: PoseGraph, weights: np.ndarray) -> np.ndarray:
    """``weights``, except that where the edges in weight leave poses joined to no held pose
    (untrusted odometry on both sides of a pose misfits), the edges out at those poses get
    :data:`_PLACING`: they place them and move nothing else."""
    live = weights > WEIGHT_FLOOR
    if live.all():
        return weights
    labels = component_labels(g.num_poses, g.edges[live])
    loose = ~np.isin(labels, labels[g.held[0]])
    if not loose.any():
        return weights
    lifted = ~live & (loose[g.edges[:, 0]] | loose[g.edges[:, 1]])
    return np.where(lifted, _PLACING, weights)


def gnc_tls(solve, residuals, known: np.ndarray, excluded: np.ndarray, threshold: float,
             iterations: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Graduated non-convexity, TLS loss (Yang et al. 2020), GTSAM's super-linear schedule.

    ``solve(weights) -> x`` minimizes the weighted squares; ``residuals(x) -> (m,)`` squared
    whitened residuals, compared with ``threshold``. Known edges keep weight 1, excluded
    ones 0. Returns x, the weights it was solved with and the number of solves.
    """
    weights = np.where(excluded, 0.0, 1.0)
    x = solve(weights)
    unknown = ~known & ~excluded
    r2 = residuals(x)
    worst = float(r2[unknown].max(initial=0.0))
    if 2.0 * worst <= threshold:
        return x, weights, 1
    mu = max(threshold / (2.0 * worst - threshold), _MU_MIN)
    count = 1
    while count <= iterations:
        count += 1
        weights = tls_weights(r2, threshold, mu)
        weights[known] = 1.0
        weights[excluded] = 0.0
        x = solve(weights)
        if np.all(np.minimum(weights, 1.0 - weights) <= _WEIGHTS_TOL):
            break
        r2 = residuals(x)
        mu = math.sqrt(mu) * _MU_STEP if mu < 1.0 else mu * _MU_STEP
    return x, weights, count


def tls_weights(r2: np.ndarray, threshold: float, mu: float) -> np.ndarray:
    """The GNC-TLS weights (Yang et al. 2020, eq. 14) of squared residuals ``r2``."""
    with np.errstate(divide="ignore"):
        weights = np.sqrt(threshold * mu * (mu + 1.0) / r2) - mu
    weights[r2 <= mu / (mu + 1.0) * threshold] = 1.0
    weights[r2 >= (mu + 1.0) / mu * threshold] = 0.0
    return np.clip(weights, 0.0, 1.0)


def gnc_lm(problem: Problem, start: gtsam.Values, kept: np.ndarray,
           known: np.ndarray) -> tuple[gtsam.Values, np.ndarray]:
    """GTSAM's GNC-LM (TLS, super-linear schedule, the project's LM settings) from ``start`` on
    the ``kept`` edges, the ``known`` ones (and the gauge prior) as known inliers; returns its
    values, every held pose exactly where it is held, and the weight of every edge (0 for
    edges not kept).

    Edges rejected before are left out of its graph: kept in, their residuals set GNC's first
    control parameter near zero, and it spends dozens of outer iterations re-deriving what
    the steps before found. A FIXed pose is held by a prior as tight as the gauge's: GNC
    reweighs every factor through its information, which a constrained model does not have
    (kept as it is, GNC moved MIT's FIXed pose 400 by 110 m)."""
    settings = problem.settings
    optimized = problem.kept_graph(kept)
    if len(problem.g.fixed):
        optimized = _softly_held(optimized, problem, settings.anchor_sigma)
    optimized.add(gauge_prior(problem.g, start, settings.anchor_sigma))
    judged = set(problem.factor_of_edge[~known].tolist())
    inliers = [k for k in range(optimized.size())
               if optimized.at(k) is not None and k not in judged]
    lm = cast(gtsam.LevenbergMarquardtParams, solver_params("lm", settings.lm_iterations))
    params = gtsam.GncLMParams(lm)
    params.setLossType(gtsam.GncLossType.TLS)
    params.setScheduler(gtsam.GncScheduler.SuperLinear)
    params.maxIterations = settings.gnc_iterations  # the setter prints a warning to stdout
    params.setKnownInliers(inliers)
    try:
        optimizer = gtsam.GncLMOptimizer(optimized, start, params)
        optimizer.setInlierCostThresholdsAtProbability(settings.inlier_probability)
        result = eliminating_call(start.size(), optimizer.optimize, optimized.size())
    except RuntimeError as error:
        raise SolverError(f"GNC-LM failed: {one_line(error)}") from None
    weights = np.asarray(optimizer.getWeights(), dtype=float).ravel()[problem.factor_of_edge]
    return problem.holding(result), np.where(kept, weights, 0.0)


def _softly_held(graph: gtsam.NonlinearFactorGraph, problem: Problem,
                 sigma: float) -> gtsam.NonlinearFactorGraph:
    """``graph`` with each constrained prior replaced by a prior of isotropic ``sigma`` at the
    pose the graph holds it at (its slot left empty, the new prior appended)."""
    softened = gtsam.NonlinearFactorGraph(graph)
    prior: Any = problem.group.prior_factor
    tight = gtsam.noiseModel.Isotropic.Sigma(problem.group.dof, sigma)
    for k in range(graph.size()):
        factor: Any = graph.at(k)  # GTSAM's stubs type it as the base class
        if isinstance(factor, prior) and isinstance(factor.noiseModel(),
                                                    gtsam.noiseModel.Constrained):
            softened.remove(k)
            softened.add(prior(factor.keys()[0], factor.prior(), tight))
    return softened
