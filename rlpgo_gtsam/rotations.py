"""SO(2) maths on arrays of angles: wrapping, residuals and the orientation cost."""

from __future__ import annotations

import numpy as np

__all__ = [
    "wrap", "angle_residuals", "orientation_cost", "chordal_edge_costs", "rotation_matrices"
]


def wrap(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def angle_residuals(theta: np.ndarray, edges: np.ndarray, measured_theta: np.ndarray) -> np.ndarray:
    """Log(R~_ij^T R_i^T R_j) of every edge: wrap(theta_j - theta_i - theta~_ij), shape (m,)."""
    return wrap(theta[edges[:, 1]] - theta[edges[:, 0]] - measured_theta)


def chordal_edge_costs(residuals: np.ndarray) -> np.ndarray:
    """||R_i R~_ij - R_j||_F^2 per edge, from angle residuals: 8 sin^2(r / 2)."""
    return 8.0 * np.sin(0.5 * residuals) ** 2


def orientation_cost(theta: np.ndarray, edges: np.ndarray, measured_theta: np.ndarray) -> float:
    """The paper's OC: sqrt of the summed, unweighted chordal costs over all edges."""
    return float(np.sqrt(chordal_edge_costs(angle_residuals(theta, edges, measured_theta)).sum()))


def rotation_matrices(theta: np.ndarray) -> np.ndarray:
    """(k, 2, 2) rotation matrices of the angles ``theta``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
