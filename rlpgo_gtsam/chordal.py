"""The chordal estimate of the orientations: the rotation terms alone, relaxed and projected.

Each rotation is a complex number z (a 2-vector); the relaxation minimizes
``sum_e w_e |z_j - z_i exp(i theta~_ij)|^2`` with ``w_e`` the edge's rotation weight
(:func:`~rlpgo_gtsam.graph.rotation_weights`) and the held poses' z fixed, one sparse linear
solve (:class:`~rlpgo_gtsam.linear.PairwiseSystem`). Each z is then projected onto the unit
circle. It starts the certified relaxation and is the ``chordal`` initializer's orientation
step.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D, rotation_weights
from rlpgo_gtsam.linear import solve_pairwise
from rlpgo_gtsam.se2 import rotation_matrices

__all__ = ["chordal_orientations", "chordal_blocks"]


def chordal_orientations(pose_graph: PoseGraph2D) -> np.ndarray:
    """Orientations (n,) from the chordal relaxation; held poses keep their angles.

    The graph keeps the result (``pose_graph.cache``): the certified relaxation starts from
    it, after a comparison's chordal row has computed it. A copy is returned.

    Raises:
        SolverError: the rotation terms leave a pose undetermined (it is named).
    """
    g = pose_graph
    cached = g.cache.get("chordal_orientations")
    if cached is None:
        cached = g.cache["chordal_orientations"] = _chordal_orientations(g)
    return cached.copy()


def _chordal_orientations(g: PoseGraph2D) -> np.ndarray:
    a_i, a_j = chordal_blocks(rotation_weights(g), rotation_matrices(g.measured[:, 2]))
    held, held_poses = g.held
    held_z = np.column_stack([np.cos(held_poses[:, 2]), np.sin(held_poses[:, 2])])
    z = solve_pairwise(g.num_poses, g.edges, a_i, a_j, np.zeros((g.num_edges, 2)), held, held_z)
    return np.arctan2(z[:, 1], z[:, 0])


def chordal_blocks(weights: np.ndarray, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The blocks of the chordal rotation residuals ``sqrt(w_e) (x_j - M_e x_i)``, one per
    edge, as :func:`~rlpgo_gtsam.linear.solve_pairwise` takes them: ``a_i = -sqrt(w) M``,
    ``a_j = sqrt(w) I`` for (m,) ``weights`` and (m, d, d) ``rotations`` ``M`` (in 2D
    ``R(theta~)`` acting on ``z``; in 3D ``R~^T`` acting on a row of ``R``)."""
    root = np.sqrt(weights)[:, None, None]
    a_i = -root * rotations
    return a_i, root * np.broadcast_to(np.eye(rotations.shape[-1]), a_i.shape)
