"""The chordal estimate of the rotations: the rotation terms alone, relaxed and projected.

It minimizes ``sum_e w_e ||R_j - R_i R~_ij||_F^2`` over unconstrained matrices with the held
poses' rotations fixed (``w_e``: :func:`~rlpgo_gtsam.graph.rotation_weights`), one sparse
linear solve, and projects each result back onto the rotations. Planar: each rotation is a
complex number z (a 2-vector) and the cost ``sum_e w_e |z_j - z_i exp(i theta~_ij)|^2``
(:class:`~rlpgo_gtsam.linear.PairwiseSystem`); 3D: row by row, ``R_j - R_i R~`` is
``r_j - R~^T r_i`` for the rows ``r`` of ``R``, so the 9 unknowns of a pose are three
3-vector problems with the same blocks: one factorization, three right-hand sides
(:func:`~rlpgo_gtsam.linear.solve_block_pairwise`). It starts the certified relaxation and is
the ``chordal`` initializer's rotation step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from rlpgo_gtsam.graph import PoseGraph, PoseGraph2D, PoseGraph3D, rotation_weights
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.linear import DenseCholesky, dense_cholesky, solve_block_pairwise, solve_pairwise
from rlpgo_gtsam.se2 import angle_residuals, chordal_edge_costs, rotation_matrices
from rlpgo_gtsam.se3 import project_to_so3

__all__ = ["chordal_rotations", "chordal_blocks", "chordal_cost"]


def chordal_rotations(pose_graph: PoseGraph, connection: np.ndarray | None = None) -> np.ndarray:
    """Rotations from the chordal relaxation, planar angles (n,) or matrices (n, 3, 3); held
    poses keep theirs.

    The graph keeps the result (``pose_graph.cache``): the certified relaxation starts from
    it, after a comparison's chordal row has computed it. A copy is returned.

    ``connection`` (3D): the graph's dense (3n, 3n) connection Laplacian with these weights
    (blocks ``kappa I`` at (i, i) and (j, j), ``-kappa R~`` at (i, j)), where the caller
    has it (the certified relaxation's small graphs): the cost is ``tr(X^T L X)`` with
    ``X_k = R_k^T``, minimized by one dense Cholesky solve of its free rows instead of the
    normal equations built again; a factor that fails hands over to the pairwise solve,
    which names the undetermined pose. (CPU ms, min of 300 / 40 runs: tinyGrid3D 0.69 ->
    0.32, smallGrid3D 5.4 -> 3.4; the same rotations to 1e-15.)

    Raises:
        SolverError: the rotation terms leave a pose undetermined (it is named).
    """
    g = pose_graph
    estimate = _ESTIMATES[g.group]
    if connection is not None:
        return estimate(g, connection)
    cached = g.cache.get("chordal_rotations")
    if cached is None:
        cached = g.cache["chordal_rotations"] = estimate(g, None)
    return cached.copy()


def chordal_cost(pose_graph: PoseGraph, rotations: np.ndarray) -> float:
    """``sum_e w_e ||R_i R~_ij - R_j||_F^2`` at ``rotations`` (angles or matrices): the
    weighted rotation cost the chordal estimate relaxes."""
    return float(rotation_weights(pose_graph) @ _EDGE_COSTS[pose_graph.group](pose_graph,
                                                                            rotations))


def chordal_blocks(weights: np.ndarray, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The blocks of the chordal rotation residuals ``sqrt(w_e) (x_j - M_e x_i)``, one per
    edge, as :func:`~rlpgo_gtsam.linear.solve_pairwise` takes them: ``a_i = -sqrt(w) M``,
    ``a_j = sqrt(w) I`` for (m,) ``weights`` and (m, d, d) ``rotations`` ``M`` (in 2D
    ``R(theta~)`` acting on ``z``; in 3D ``R~^T`` acting on a row of ``R``)."""
    root = np.sqrt(weights)[:, None, None]
    a_i = -root * rotations
    return a_i, root * np.broadcast_to(np.eye(rotations.shape[-1]), a_i.shape)


def _planar(g: PoseGraph2D, connection: None) -> np.ndarray:
    a_i, a_j = chordal_blocks(rotation_weights(g), rotation_matrices(g.measured[:, 2]))
    held, held_poses = g.held
    held_z = np.column_stack([np.cos(held_poses[:, 2]), np.sin(held_poses[:, 2])])
    z = solve_pairwise(g.num_poses, g.edges, a_i, a_j, np.zeros((g.num_edges, 2)), held, held_z)
    return np.arctan2(z[:, 1], z[:, 0])


def _spatial(g: PoseGraph3D, connection: np.ndarray | None) -> np.ndarray:
    held, held_poses = g.held
    held_r = np.ascontiguousarray(held_poses[:, :, :3])
    x = None if connection is None else _dense_chordal(connection, held, held_r)
    if x is None:
        a_i, a_j = chordal_blocks(rotation_weights(g),
                                  np.transpose(g.measured_rotations, (0, 2, 1)))
        # unknown k holds the rows of R_k as columns: x[k][:, c] = row c of R_k
        x = solve_block_pairwise(g.num_poses, g.edges, a_i, a_j,
                                 np.zeros((g.num_edges, 3, 3)), held,
                                 np.transpose(held_r, (0, 2, 1)))
    rotations = project_to_so3(np.transpose(x, (0, 2, 1)))
    rotations[held] = held_r
    return rotations


def _dense_chordal(connection: np.ndarray, held: np.ndarray,
                   held_r: np.ndarray) -> np.ndarray | None:
    """(n, 3, 3) blocks ``X_k`` minimizing ``tr(X^T L X)`` with the held ones at ``R^T``:
    ``L_ff X_f = -L_fh X_h`` by a dense Cholesky factor; None where it fails or a pivot
    falls below :data:`~rlpgo_gtsam.linear.PIVOT_FLOOR` of its diagonal
    (:func:`~rlpgo_gtsam.linear.dense_cholesky`)."""
    n = connection.shape[0] // 3
    is_held = np.zeros(n, bool)
    is_held[held] = True
    rows = np.arange(3 * n).reshape(n, 3)
    free, fixed = rows[~is_held].ravel(), rows[held].ravel()
    x = np.zeros((n, 3, 3))
    x[held] = np.transpose(held_r, (0, 2, 1))
    # factored in place: the transpose of the symmetric block is the same matrix in Fortran
    # order (dpotrf copied it again: smallGrid3D's chordal estimate 4.4 -> 3.3 ms CPU)
    lower = dense_cholesky(connection[np.ix_(free, free)].T, overwrite=True)
    if lower is None:
        return None
    solution = DenseCholesky(lower).solve(-connection[np.ix_(free, fixed)]
                                          @ x[held].reshape(-1, 3))
    if not np.isfinite(solution).all():
        return None
    x[~is_held] = solution.reshape(-1, 3, 3)
    return x


def _planar_costs(g: PoseGraph2D, theta: np.ndarray) -> np.ndarray:
    return chordal_edge_costs(angle_residuals(theta, g.edges, g.measured[:, 2]))


def _spatial_costs(g: PoseGraph3D, rotations: np.ndarray) -> np.ndarray:
    difference = rotations[g.edges[:, 0]] @ g.measured_rotations - rotations[g.edges[:, 1]]
    return np.einsum("eab,eab->e", difference, difference)


# each group's estimate (a connection is 3D's dense path) and per-edge chordal costs
_ESTIMATES: dict[Group, Callable[[Any, Any], np.ndarray]] = {SE2: _planar, SE3: _spatial}
_EDGE_COSTS: dict[Group, Callable[[Any, np.ndarray], np.ndarray]] = {
    SE2: _planar_costs, SE3: _spatial_costs}
