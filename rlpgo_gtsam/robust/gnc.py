"""Graduated non-convexity with truncated least squares (Yang et al. 2020) on a linear
least-squares problem, and its use on the translation step.

:func:`gnc_tls` takes any weighted solve and residual function; :func:`robust_positions`
runs it on the translation step with fixed rotations, planar or 3D: the group's whitened
system and weighted solve (:meth:`~rlpgo_gtsam.robust.groups.Group.translation_system`).
"""

from __future__ import annotations

import math

import numpy as np

from rlpgo_gtsam.robust.groups import PoseGraph, group_of

__all__ = ["gnc_tls", "tls_weights", "robust_positions"]

_MU_STEP = 1.4
_MU_MIN = 1e-6
_WEIGHTS_TOL = 1e-4


def robust_positions(g: PoseGraph, rotations: np.ndarray, known: np.ndarray,
                      excluded: np.ndarray, threshold: float,
                      iterations: int) -> tuple[np.ndarray, np.ndarray, int]:
    """GNC-TLS on the translation step with ``rotations`` fixed (planar angles (n,) or 3D
    matrices (n, 3, 3)): positions, weights, solves.

    The residuals are the translation step's, whitened (2 dof planar:
    :func:`~rlpgo_gtsam.translations.whitened_system`; 3 dof in 3D:
    :meth:`~rlpgo_gtsam.translations3d.TranslationStep3D.whitened`); known edges keep
    weight 1, excluded edges 0.
    """
    i, j = g.edges[:, 0], g.edges[:, 1]
    a_j, b, solve = group_of(g).translation_system(g, rotations)

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
