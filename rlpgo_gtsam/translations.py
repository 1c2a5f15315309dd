"""The LAGO-style translation step: positions that best fit the edges, orientations fixed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D, edge_chi2
from rlpgo_gtsam.linear import solve_pairwise
from rlpgo_gtsam.se2 import rotation_matrices, wrap

__all__ = ["solve_translations", "poses_with_orientations", "whitened_system", "SystemParts",
           "TranslationStep"]


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
    a_j, b, _ = whitened_system(pose_graph, theta)
    held, held_poses = pose_graph.held
    return solve_pairwise(pose_graph.num_poses, pose_graph.edges, -a_j, a_j, b, held,
                          held_poses[:, :2])


@dataclass(frozen=True)
class SystemParts:
    """What the translation step's whitened system takes from the edges alone, not from the
    orientations (see :func:`whitened_system`).

    Attributes:
        w: (m, 2, 2) upper factors, ``W^T W = Lambda_tt``.
        shift_per_rad: (m, 2) ``Lambda_tt^-1 Lambda_t,theta``, the translation shift per
            radian of angle error.
        r_meas_t: (m, 2, 2) the measured rotations, transposed.
        t_meas: (m, 2) ``R~^T t~``.
    """

    w: np.ndarray
    shift_per_rad: np.ndarray
    r_meas_t: np.ndarray
    t_meas: np.ndarray

    @classmethod
    def of(cls, pose_graph: PoseGraph2D) -> SystemParts:
        info = pose_graph.information
        info_tt = info[:, :2, :2]
        r_meas_t = np.transpose(rotation_matrices(pose_graph.measured[:, 2]), (0, 2, 1))
        return cls(w=np.transpose(np.linalg.cholesky(info_tt), (0, 2, 1)),
                   shift_per_rad=np.linalg.solve(info_tt, info[:, :2, 2:3])[..., 0],
                   r_meas_t=r_meas_t,
                   t_meas=np.einsum("eab,eb->ea", r_meas_t, pose_graph.measured[:, :2]))


def whitened_system(pose_graph: PoseGraph2D, theta: np.ndarray,
                    parts: SystemParts | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The translation step's residuals ``A_e (t_j - t_i) - b_e`` at the orientations
    ``theta`` (see :func:`solve_translations`): (m, 2, 2) blocks ``A_e``, (m, 2) ``b_e`` and
    (m,) the angle errors. ``parts`` (:meth:`SystemParts.of`) saves recomputing what does
    not depend on ``theta``."""
    g = pose_graph
    parts = parts if parts is not None else SystemParts.of(g)
    i, j = g.edges[:, 0], g.edges[:, 1]
    e_theta = wrap(theta[j] - theta[i] - g.measured[:, 2])
    a_j = parts.w @ (parts.r_meas_t @ np.transpose(rotation_matrices(theta[i]), (0, 2, 1)))
    b = np.einsum("eab,eb->ea", parts.w, parts.t_meas - parts.shift_per_rad * e_theta[:, None])
    return a_j, b, e_theta


class TranslationStep:
    """The translation step for many orientations of one graph: positions and their chi2.

    :func:`poses_with_orientations` solves through GTSAM, which costs milliseconds a call;
    a training reward on the real cost calls it at every step. This class keeps what does
    not depend on the orientations (whitening factors, the sparsity pattern of the normal
    equations) and solves them with scipy. :meth:`chi2` is the chi2 of the graph's edges at
    the solved positions, which is GTSAM's chi2 of ``poses_with_orientations(theta)`` on a
    graph without soft priors (a soft prior on the anchor adds nothing either: the anchor
    sits at its value), summed by :func:`~rlpgo_gtsam.graph.edge_chi2`.
    """

    def __init__(self, pose_graph: PoseGraph2D) -> None:
        from scipy import sparse

        g = self.pose_graph = pose_graph
        self.parts = SystemParts.of(g)
        held, held_poses = g.held
        self.held, self.held_xy = held, held_poses[:, :2]
        free = np.ones(g.num_poses, bool)
        free[held] = False
        self.column = np.full(g.num_poses, -1)
        self.column[free] = np.arange(int(free.sum()))
        self.unknowns = 2 * int(free.sum())
        i, j = g.edges[:, 0], g.edges[:, 1]
        # Normal-equation blocks: (i,i) and (j,j) get +A^T A, (i,j) and (j,i) get -A^T A.
        rows, cols, self._slots = [], [], []
        for a, b, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            keep = (self.column[a] >= 0) & (self.column[b] >= 0)
            for r in range(2):
                for c in range(2):
                    rows.append(2 * self.column[a][keep] + r)
                    cols.append(2 * self.column[b][keep] + c)
                    self._slots.append((keep, r, c, sign))
        self._rows, self._cols = np.concatenate(rows), np.concatenate(cols)
        self._sparse = sparse

    def positions(self, theta: np.ndarray) -> np.ndarray:
        """(n, 2) positions of least cost for the orientations ``theta``."""
        return self.solve(theta)[0]

    def chi2(self, theta: np.ndarray) -> float:
        """The edges' chi2 at the positions of least cost for ``theta``."""
        return self.solve(theta)[1]

    def solve(self, theta: np.ndarray) -> tuple[np.ndarray, float]:
        """Both at once: (n, 2) positions of least cost and the edges' chi2 there."""
        from scipy.sparse.linalg import spsolve

        g = self.pose_graph
        theta = np.asarray(theta, dtype=float)
        theta = theta - theta[self.held[0]] + g.held[1][0, 2]  # the anchor's angle
        a, b, _ = whitened_system(g, theta, self.parts)
        ata = np.einsum("eka,ekb->eab", a, a)
        data = np.concatenate([sign * ata[keep, r, c] for keep, r, c, sign in self._slots])
        normal = self._sparse.csc_matrix((data, (self._rows, self._cols)),
                                         shape=(self.unknowns, self.unknowns))
        # Residual A (x_j - x_i) - b with held positions moved to the right-hand side.
        xy = np.zeros((g.num_poses, 2))
        xy[self.held] = self.held_xy
        i, j = g.edges[:, 0], g.edges[:, 1]
        rhs_edge = b - np.einsum("eab,eb->ea", a, xy[j] - xy[i])  # zero for free poses
        atb = np.einsum("eka,ek->ea", a, rhs_edge)
        rhs = np.zeros(self.unknowns)
        for index, sign in ((j, 1.0), (i, -1.0)):
            free = self.column[index] >= 0
            np.add.at(rhs, 2 * self.column[index][free], sign * atb[free, 0])
            np.add.at(rhs, 2 * self.column[index][free] + 1, sign * atb[free, 1])
        solution = spsolve(normal, rhs) if self.unknowns else np.zeros(0)
        free = self.column >= 0
        xy[free] = solution.reshape(-1, 2)
        return xy, float(edge_chi2(g, np.column_stack([xy, theta])).sum())
