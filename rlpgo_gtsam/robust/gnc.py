"""Graduated non-convexity with truncated least squares (Yang et al. 2020): ours on a linear
least-squares problem (the translation step), and GTSAM's GNC-LM, the robust path's last step.

:func:`gnc_tls` takes any weighted solve and residual function; :func:`robust_positions`
runs it on the translation step with fixed rotations, planar or 3D: the group's whitened
system and weighted solve (:func:`~rlpgo_gtsam.translations.translation_system`).
:func:`gnc_lm` runs GTSAM's ``GncLMOptimizer`` on the edges the robust path kept.
"""

from __future__ import annotations

import math
from typing import cast

import gtsam
import numpy as np

from rlpgo_gtsam.errors import SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph
from rlpgo_gtsam.robust.problem import Problem
from rlpgo_gtsam.solvers import gauge_prior, solver_params
from rlpgo_gtsam.translations import translation_system

__all__ = ["gnc_tls", "tls_weights", "robust_positions", "gnc_lm"]

_MU_STEP = 1.4  # the control parameter's growth per iteration (GTSAM's GncParams muStep)
_MU_MIN = 1e-6  # its first value at least: a huge first residual must not make it zero
_WEIGHTS_TOL = 1e-4  # weights this close to 0 or 1 have converged (GTSAM's weightsTol)


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

    return gnc_tls(solve, residuals, known, excluded, threshold, iterations)


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
    values and the weight of every edge (0 for edges not kept).

    Edges rejected before are left out of its graph: kept in, their residuals set GNC's first
    control parameter near zero, and it spends dozens of outer iterations re-deriving what
    the steps before found."""
    settings = problem.settings
    optimized = problem.kept_graph(kept)
    inliers = [k for k in range(optimized.size()) if optimized.at(k) is not None]
    inliers = sorted(set(inliers) - set(problem.factor_of_edge[~known].tolist()))
    optimized.add(gauge_prior(problem.g, start, settings.anchor_sigma))
    lm = cast(gtsam.LevenbergMarquardtParams, solver_params("lm", settings.lm_iterations))
    params = gtsam.GncLMParams(lm)
    params.setLossType(gtsam.GncLossType.TLS)
    params.setScheduler(gtsam.GncScheduler.SuperLinear)
    params.maxIterations = settings.gnc_iterations  # the setter prints a warning to stdout
    params.setKnownInliers(inliers + [optimized.size() - 1])
    try:
        optimizer = gtsam.GncLMOptimizer(optimized, start, params)
        optimizer.setInlierCostThresholdsAtProbability(settings.inlier_probability)
        result = optimizer.optimize()
    except RuntimeError as error:
        raise SolverError(f"GNC-LM failed: {one_line(error)}") from None
    weights = np.asarray(optimizer.getWeights(), dtype=float).ravel()[problem.factor_of_edge]
    return result, np.where(kept, weights, 0.0)
