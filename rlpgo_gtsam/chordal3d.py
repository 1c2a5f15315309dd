"""The chordal estimate of 3D rotations: the rotation terms alone, relaxed and projected.

Minimizes ``sum_e kappa_e ||R_j - R_i R~_ij||_F^2`` over 3x3 matrices with the held poses'
rotations fixed (``kappa``: :func:`~rlpgo_gtsam.graph3d.rotation_weights`, SE-Sync's). Row
by row, ``R_j - R_i R~`` is ``r_j - R~^T r_i`` for the rows ``r`` of ``R``, so the 9 unknowns
of a pose are three 3-vector problems with the same blocks: one sparse factorization, three
right-hand sides (:func:`~rlpgo_gtsam.translations3d.solve_block_pairwise`). Each result is
projected onto SO(3). It starts the certified relaxation and is the ``chordal`` 3D
initializer's rotation step.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.chordal import chordal_blocks
from rlpgo_gtsam.graph3d import PoseGraph3D, rotation_weights
from rlpgo_gtsam.se3 import project_to_so3
from rlpgo_gtsam.translations3d import DenseCholesky, dense_cholesky, solve_block_pairwise

__all__ = ["chordal_rotations"]


def chordal_rotations(pose_graph: PoseGraph3D,
                      connection: np.ndarray | None = None) -> np.ndarray:
    """Rotations (n, 3, 3) from the chordal relaxation (:func:`chordal_blocks`, three
    right-hand sides); held poses keep theirs.

    ``connection``: the graph's dense (3n, 3n) connection Laplacian with these weights
    (blocks ``kappa I`` at (i, i) and (j, j), ``-kappa R~`` at (i, j)), where the caller
    has it (the certified relaxation's small graphs): the cost is ``tr(X^T L X)`` with
    ``X_k = R_k^T``, minimized by one dense Cholesky solve of its free rows instead of the
    normal equations built again; a factor that fails hands over to the pairwise solve,
    which names the undetermined pose. chordal_rotations (CPU ms, min of 300 / 40 runs):
    tinyGrid3D 0.69 -> 0.32, smallGrid3D 5.4 -> 3.4; the same rotations to 1e-15.

    Raises:
        SolverError: the rotation terms leave a pose undetermined (it is named).
    """
    g = pose_graph
    held, held_r, _ = g.held
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
    falls below :data:`~rlpgo_gtsam.translations3d.PIVOT_FLOOR` of its diagonal
    (:func:`~rlpgo_gtsam.translations3d.dense_cholesky`)."""
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
