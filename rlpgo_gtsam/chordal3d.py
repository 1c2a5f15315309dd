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
from rlpgo_gtsam.translations3d import solve_block_pairwise

__all__ = ["chordal_rotations"]


def chordal_rotations(pose_graph: PoseGraph3D) -> np.ndarray:
    """Rotations (n, 3, 3) from the chordal relaxation (:func:`chordal_blocks`, three
    right-hand sides); held poses keep theirs.

    Raises:
        SolverError: the rotation terms leave a pose undetermined (it is named).
    """
    g = pose_graph
    a_i, a_j = chordal_blocks(rotation_weights(g), np.transpose(g.measured_rotations, (0, 2, 1)))
    held, held_r, _ = g.held
    # unknown k holds the rows of R_k as columns: x[k][:, c] = row c of R_k
    x = solve_block_pairwise(g.num_poses, g.edges, a_i, a_j, np.zeros((g.num_edges, 3, 3)),
                             held, np.transpose(held_r, (0, 2, 1)))
    rotations = project_to_so3(np.transpose(x, (0, 2, 1)))
    rotations[held] = held_r
    return rotations
