"""The LAGO-style translation step: positions that best fit the edges, orientations fixed."""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.linear import solve_pairwise
from rlpgo_gtsam.rotations import rotation_matrices, wrap

__all__ = ["solve_translations", "poses_with_orientations"]


def poses_with_orientations(pose_graph: PoseGraph2D, theta: np.ndarray) -> np.ndarray:
    """Poses (n, 3): the orientations ``theta`` in the anchor's gauge, positions solved.

    ``theta`` is rotated as a whole so that the anchor gets its angle; every held pose (the
    anchor, FIXed poses) keeps its angle and position; the others get positions from
    :func:`solve_translations`.
    """
    held, held_poses = pose_graph.held
    theta = np.asarray(theta, dtype=float)
    theta = wrap(theta - theta[held[0]] + held_poses[0, 2])
    theta[held] = held_poses[:, 2]
    positions = solve_translations(pose_graph, theta)
    return np.column_stack([positions, theta])


def solve_translations(pose_graph: PoseGraph2D, theta: np.ndarray) -> np.ndarray:
    """Positions (n, 2) minimizing the edges' cost with the orientations ``theta`` fixed.

    Each edge contributes its error in the measurement's frame,
    ``e_t = R~_ij^T (R_i^T (t_j - t_i) - t~_ij)``, weighted by its full information:
    with the angle error ``e_theta`` fixed, ``[e_t, e_theta]^T Lambda [e_t, e_theta]`` is
    ``||W (e_t + Lambda_tt^-1 Lambda_t,theta e_theta)||^2 + const`` with ``W^T W = Lambda_tt``,
    so xy and x/y-theta correlations are both kept. Held poses (the anchor, FIXed poses)
    keep their positions; soft priors are not used (refinement honours them).
    """
    g = pose_graph
    i, j = g.edges[:, 0], g.edges[:, 1]
    info = g.information
    info_tt = info[:, :2, :2]
    w = np.transpose(np.linalg.cholesky(info_tt), (0, 2, 1))  # upper factor: W^T W = info_tt
    e_theta = wrap(theta[j] - theta[i] - g.measured[:, 2])
    shift = np.linalg.solve(info_tt, (info[:, :2, 2] * e_theta[:, None])[..., None])[..., 0]
    r_meas_t = np.transpose(rotation_matrices(g.measured[:, 2]), (0, 2, 1))
    m = r_meas_t @ np.transpose(rotation_matrices(theta[i]), (0, 2, 1))
    a_j = w @ m
    target = np.einsum("eab,eb->ea", r_meas_t, g.measured[:, :2]) - shift
    b = np.einsum("eab,eb->ea", w, target)
    held, held_poses = g.held
    return solve_pairwise(g.num_poses, g.edges, -a_j, a_j, b, held, held_poses[:, :2])
