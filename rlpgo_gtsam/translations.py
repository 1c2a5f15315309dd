"""The LAGO-style translation step: positions that best fit the edges, orientations fixed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D, edge_chi2
from rlpgo_gtsam.linear import PairwiseSystem
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

    The graph's :meth:`TranslationStep.shared` step solves it: a second call on the same
    graph (another initializer of a comparison) reuses its system, and its factorization
    where the translation information is isotropic.
    """
    return TranslationStep.shared(pose_graph).positions(np.asarray(theta, dtype=float),
                                                         gauge=False)


@dataclass(frozen=True, eq=False)
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

    A training reward on the real cost solves it at every step: this class keeps what does
    not depend on the orientations (whitening factors, the
    :class:`~rlpgo_gtsam.linear.PairwiseSystem` with its sparsity pattern and ordering).
    :meth:`chi2` is the chi2 of the graph's edges at the solved positions, which is GTSAM's
    chi2 of ``poses_with_orientations(theta)`` on a graph without soft priors (a soft prior
    on the anchor adds nothing either: the anchor sits at its value), summed by
    :func:`~rlpgo_gtsam.graph.edge_chi2`.
    """

    def __init__(self, pose_graph: PoseGraph2D, parts: SystemParts | None = None,
                 system: PairwiseSystem | None = None) -> None:
        self.pose_graph = pose_graph
        self.parts = parts if parts is not None else SystemParts.of(pose_graph)
        held, held_poses = pose_graph.held
        self.held, self.held_xy = held, held_poses[:, :2]
        self.system = system if system is not None else PairwiseSystem(
            pose_graph.num_poses, pose_graph.edges, held)

    @classmethod
    def shared(cls, pose_graph: PoseGraph2D) -> TranslationStep:
        """The step whose parts and system the graph keeps (``pose_graph.cache``) for every
        translation step on it. Where each edge's translation information is a multiple of
        the identity (M3500, City10K, generated graphs), the normal matrix does not depend
        on the orientations, and its first factorization serves every later solve
        (``PairwiseSystem(fixed_matrix=True)``): a comparison's lago, chordal, Shonan and
        certified rows factorize once between them."""
        cached = pose_graph.cache.get("translation_step")
        if cached is None:
            info = pose_graph.information
            isotropic = bool((info[:, 0, 0] == info[:, 1, 1]).all()
                             and (info[:, 0, 1] == 0).all() and (info[:, 1, 0] == 0).all())
            cached = (SystemParts.of(pose_graph),
                      PairwiseSystem(pose_graph.num_poses, pose_graph.edges,
                                     pose_graph.held[0], fixed_matrix=isotropic))
            pose_graph.cache["translation_step"] = cached
        return cls(pose_graph, *cached)

    def positions(self, theta: np.ndarray, gauge: bool = True) -> np.ndarray:
        """(n, 2) positions of least cost for the orientations ``theta``; ``gauge``: rotate
        ``theta`` as a whole so that the anchor gets its angle first (as :meth:`solve`)."""
        if gauge:
            theta = self._in_gauge(theta)
        a, b, _ = whitened_system(self.pose_graph, theta, self.parts)
        return self.system.solve(-a, a, b, self.held_xy)

    def chi2(self, theta: np.ndarray) -> float:
        """The edges' chi2 at the positions of least cost for ``theta``."""
        return self.solve(theta)[1]

    def solve(self, theta: np.ndarray) -> tuple[np.ndarray, float]:
        """Both at once: (n, 2) positions of least cost and the edges' chi2 there."""
        theta = self._in_gauge(theta)
        xy = self.positions(theta, gauge=False)
        return xy, float(edge_chi2(self.pose_graph, np.column_stack([xy, theta])).sum())

    def _in_gauge(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        return theta - theta[self.held[0]] + self.pose_graph.held[1][0, 2]  # the anchor's angle
