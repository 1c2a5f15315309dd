"""SE(2) maths on arrays: poses are rows ``(x, y, theta)``, tangent vectors ``(x, y, theta)``
in GTSAM's order, and every function works row-wise on ``(k, 3)`` arrays.

The one home of the planar group operations (compose, inverse, between, adjoint, Logmap,
chains of relative steps) and of the rotation costs built on them (angle residuals, the
chordal edge cost, the orientation cost). Nothing here imports GTSAM; the conventions are
GTSAM's (``gtsam.Pose2``).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "wrap",
    "rotation_matrices",
    "compose",
    "inverse",
    "between",
    "adjoint",
    "logmap",
    "chain",
    "angle_residuals",
    "CHORDAL_SCALE",
    "CHORDAL_ROOT",
    "chordal_edge_costs",
    "orientation_cost",
]

# ||R_i R~_ij - R_j||_F^2 = CHORDAL_SCALE sin^2(r / 2) for the angle residual r; its square
# root, the chordal distance, is CHORDAL_ROOT |sin(r / 2)| (plain floats: the agent's hot loop
# uses them one edge at a time).
CHORDAL_SCALE = 8.0
CHORDAL_ROOT = math.sqrt(CHORDAL_SCALE)

_LOGMAP_SMALL = 1e-10  # below this |theta|, GTSAM's Pose2 Logmap returns the translation as is


def wrap(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def rotation_matrices(theta: np.ndarray) -> np.ndarray:
    """(k, 2, 2) rotation matrices of the angles ``theta``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a * b`` of (k, 3) poses (angle wrapped)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1],
                            a[:, 1] + s * b[:, 0] + c * b[:, 1], wrap(a[:, 2] + b[:, 2])])


def inverse(a: np.ndarray) -> np.ndarray:
    """Row-wise inverse of (k, 3) poses (angle negated, not wrapped)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]])


def between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a^-1 * b`` of (k, 3) poses: ``(R_a^T (t_b - t_a), wrap(theta_b - theta_a))``."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, wrap(b[:, 2] - a[:, 2])])


def adjoint(poses: np.ndarray) -> np.ndarray:
    """(k, 3, 3) GTSAM's Pose2 adjoint maps of (k, 3) poses (tangent order x, y, theta)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    result = np.zeros((len(poses), 3, 3))
    result[:, 0, 0], result[:, 0, 1], result[:, 0, 2] = c, -s, poses[:, 1]
    result[:, 1, 0], result[:, 1, 1], result[:, 1, 2] = s, c, -poses[:, 0]
    result[:, 2, 2] = 1.0
    return result


def logmap(poses: np.ndarray) -> np.ndarray:
    """(k, 3) GTSAM's Pose2 Logmap of (k, 3) poses whose angles lie in [-pi, pi].

    The angle is kept; the translation ``t`` becomes ``theta / det * J (R^T t - t)`` with
    ``det = (cos theta - 1)^2 + sin^2 theta`` and ``J`` the rotation by +90 degrees, or ``t``
    itself where ``|theta| < 1e-10``.
    """
    result = np.array(poses, dtype=float, copy=True)
    theta = result[:, 2]
    big = np.abs(theta) >= _LOGMAP_SMALL
    c_1, s = np.cos(theta[big]) - 1.0, np.sin(theta[big])
    det = c_1 * c_1 + s * s
    tx, ty = result[big, 0], result[big, 1]
    ux = c_1 * tx + s * ty  # R^T t - t
    uy = -s * tx + c_1 * ty
    scale = theta[big] / det
    result[big, 0] = -uy * scale
    result[big, 1] = ux * scale
    return result


def chain(steps: np.ndarray) -> np.ndarray:
    """(n, 3) poses of a chain of relative steps (n - 1, 3), starting at the origin:
    pose ``k + 1`` is pose ``k`` composed with ``steps[k]``."""
    theta = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    moves = np.column_stack([c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]])
    return np.column_stack([np.vstack([[0.0, 0.0], np.cumsum(moves, axis=0)]), wrap(theta)])


def angle_residuals(theta: np.ndarray, edges: np.ndarray, measured_theta: np.ndarray) -> np.ndarray:
    """Log(R~_ij^T R_i^T R_j) of every edge: wrap(theta_j - theta_i - theta~_ij), shape (m,)."""
    return wrap(theta[edges[:, 1]] - theta[edges[:, 0]] - measured_theta)


def chordal_edge_costs(residuals: np.ndarray) -> np.ndarray:
    """||R_i R~_ij - R_j||_F^2 per edge, from angle residuals: 8 sin^2(r / 2)."""
    return CHORDAL_SCALE * np.sin(0.5 * residuals) ** 2


def orientation_cost(theta: np.ndarray, edges: np.ndarray, measured_theta: np.ndarray) -> float:
    """The paper's OC: sqrt of the summed, unweighted chordal costs over all edges."""
    return float(np.sqrt(chordal_edge_costs(angle_residuals(theta, edges, measured_theta)).sum()))
