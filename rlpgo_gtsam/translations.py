"""The translation step: positions that minimize GTSAM's cost of the edges for fixed rotations.

With the rotations fixed, an edge's error ``e = Logmap(measured^-1 X_i^-1 X_j)`` has a fixed
rotation part ``e_R`` and a translation part linear in the positions: planar
``e_t = R~^T (R_i^T (t_j - t_i) - t~)``, spatial ``e_t = V(e_R)^-1 R~^T (R_i^T (t_j - t_i) -
t~)`` (GTSAM's Pose3 Logmap). So ``e^T Lambda e = ||W (e_t + Lambda_tt^-1 Lambda_tR e_R)||^2
+ const`` (``W^T W = Lambda_tt``) is minimized exactly by one sparse linear solve: the full
information is kept, rotation-translation correlations included. Held poses (the anchor,
FIXed poses) keep their positions; soft priors are not used (refinement honours them).

Rotations are the group's: planar angles (n,), spatial matrices (n, 3, 3). The same names
serve both: :func:`poses_with_rotations`, :func:`solve_translations` and
:class:`TranslationStep` (``TranslationStep(pose_graph)`` makes the step of the graph's
group).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.graph import PoseGraph, PoseGraph2D, PoseGraph3D, edge_chi2
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.linear import PairwiseSystem, solve_block_pairwise, solve_isotropic
from rlpgo_gtsam.se2 import rotation_matrices, wrap
from rlpgo_gtsam.se3 import inverse_left_jacobians, log_so3

__all__ = ["solve_translations", "poses_with_rotations", "poses_and_points",
           "translation_system", "TranslationStep", "SystemParts", "TranslationSystem"]

# The translation step at fixed rotations: (m, d, d) blocks A_e and (m, d) b_e of the whitened
# residuals A_e (t_j - t_i) - b_e, and solve(weights) -> (n, d) positions.
TranslationSystem = tuple[np.ndarray, np.ndarray, Callable[[np.ndarray | None], np.ndarray]]


def poses_with_rotations(pose_graph: PoseGraph, rotations: np.ndarray) -> np.ndarray:
    """Poses ((n, 3) or (n, 3, 4)): ``rotations`` in the anchor's gauge, positions solved.

    The rotations are turned as a whole so that the anchor gets its rotation; every held pose
    (the anchor, FIXed poses) keeps its rotation and position; the others get positions from
    :func:`solve_translations`.
    """
    step = TranslationStep.shared(pose_graph)
    aligned = step.aligned(np.asarray(rotations, dtype=float))
    return pose_graph.group.with_positions(aligned, step.positions(aligned, gauge=False))


def poses_and_points(pose_graph: PoseGraph, rotations: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`poses_with_rotations`, and on a graph with landmarks or ranges the points'
    positions solved with the poses' (:meth:`TranslationStep.solve_with_points`; None
    without). ``rotations``: the poses', then on a graph with ranges each range's direction
    (planar angles; in 3D a rotation whose first column is the direction)."""
    g = pose_graph
    if g.points is None and g.ranges is None:
        return poses_with_rotations(g, rotations), None
    n = g.num_poses
    rotations = np.asarray(rotations, dtype=float)
    step = TranslationStep.shared(g)
    aligned = step.aligned(rotations[:n])
    directions = None
    if g.ranges is not None:  # each range's direction turned as the poses are
        turned = step.in_gauge(rotations[:n])[0]
        if g.group.d == 2:  # angles: the turn is one angle
            angles = rotations[n:] + (turned - rotations[0])
            directions = np.column_stack([np.cos(angles), np.sin(angles)])
        else:  # the first column of each range's rotation
            directions = (turned @ rotations[0].T @ rotations[n:])[:, :, 0]
    positions, points = step.solve_with_points(aligned, directions)
    return g.group.with_positions(aligned, positions), points


def solve_translations(pose_graph: PoseGraph, rotations: np.ndarray) -> np.ndarray:
    """Positions (n, d) minimizing the edges' cost with ``rotations`` fixed (used as given).

    The graph's :meth:`TranslationStep.shared` step solves it: a second call on the same
    graph (another initializer of a comparison) reuses its system, and in 2D its
    factorization where the translation information is isotropic.
    """
    return TranslationStep.shared(pose_graph).positions(np.asarray(rotations, dtype=float),
                                                        gauge=False)


def translation_system(pose_graph: PoseGraph, rotations: np.ndarray) -> TranslationSystem:
    """The translation step's whitened residuals at ``rotations`` and their weighted solve
    (:meth:`TranslationStep.solve_weighted`; held poses keep their positions), from a step
    of its own (the robust path's GNC weighs the residuals anew at each iteration)."""
    step = TranslationStep(pose_graph)
    a_j, b = step.whitened(rotations)
    return a_j, b, lambda weights: step.solve_weighted(a_j, b, weights)


class TranslationStep:
    """The translation step for many rotations of one graph: positions and their chi2.

    ``TranslationStep(pose_graph)`` makes the step of the graph's group. It keeps what does
    not depend on the rotations (whitening factors, the planar
    :class:`~rlpgo_gtsam.linear.PairwiseSystem` with its sparsity pattern and ordering): a
    training reward on the real cost solves it at every step. :meth:`chi2` is the chi2 of the
    graph's edges at the solved positions, which is GTSAM's chi2 of
    ``poses_with_rotations(rotations)`` on a graph without soft priors (a soft prior on the
    anchor adds nothing either: the anchor sits at its value), summed by
    :func:`~rlpgo_gtsam.graph.edge_chi2`.
    """

    pose_graph: Any
    held: np.ndarray
    held_rotations: np.ndarray
    held_positions: np.ndarray

    def __new__(cls, pose_graph: PoseGraph, *args: Any, **kwargs: Any) -> TranslationStep:
        if cls is TranslationStep:
            cls = _STEPS[pose_graph.group]
        return super().__new__(cls)

    def __init__(self, pose_graph: PoseGraph) -> None:
        self.pose_graph = pose_graph
        self.held, held_poses = pose_graph.held
        self.held_rotations = np.ascontiguousarray(pose_graph.group.rotations(held_poses))
        self.held_positions = np.ascontiguousarray(pose_graph.group.translations(held_poses))

    @classmethod
    def shared(cls, pose_graph: PoseGraph) -> TranslationStep:
        """The step the graph keeps (``pose_graph.cache``) for every translation step on it."""
        step = pose_graph.cache.get("translation_step")
        if step is None:
            step = pose_graph.cache["translation_step"] = _STEPS[pose_graph.group].of(pose_graph)
        return step

    @classmethod
    def of(cls, pose_graph: Any) -> TranslationStep:
        """The step :meth:`shared` keeps (the planar one may reuse its factorization)."""
        return cls(pose_graph)

    def with_points(self, rotations: np.ndarray) -> np.ndarray:
        """(n, d) positions of least cost for ``rotations`` (used as given) where the graph
        has landmarks: the poses' and the measured points' positions solved together
        (:meth:`solve_with_points`), the points left out of the result
        (:meth:`PoseGraph2D.to_values` places them again, at the same positions, as they
        depend on the poses alone)."""
        return self.solve_with_points(rotations)[0]

    def solve_with_points(self, rotations: np.ndarray, directions: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray | None]:
        """Positions of least cost for ``rotations`` (used as given) with the landmarks: each
        landmark measurement a whitened residual ``W R_i^T (l - t_i) - W z`` (``W^T W`` its
        information), and, given the ranges' ``directions`` (unit vectors (k, d)), each range
        the residual ``(t_b - t_a - r u) / sigma`` (CORA's, linear once the direction ``u`` is
        fixed). Returns (n, d) pose positions and (p, d) point positions (a point that
        nothing here measures keeps its value), None without landmarks."""
        g = self.pose_graph
        points, ranges, n = g.points, g.ranges, g.num_poses
        a_j, b = self.whitened(rotations)
        a, rhs, edges = [a_j], [b], [g.edges]
        d = g.group.d
        if points is not None and len(points.edges):
            turned = np.transpose(g.group.rotation_matrices(rotations)[points.edges[:, 0]],
                                  (0, 2, 1))
            try:
                w = np.transpose(np.linalg.cholesky(points.information), (0, 2, 1))
            except np.linalg.LinAlgError:
                raise SolverError("a landmark measurement's information is not positive "
                                  "definite") from None
            a.append(w @ turned)
            rhs.append(np.einsum("kab,kb->ka", w, points.measured))
            edges.append(np.column_stack([points.edges[:, 0], n + points.edges[:, 1]]))
        if ranges is not None and directions is not None:
            root = np.sqrt(ranges.weights)
            a.append(root[:, None, None] * np.eye(d))
            rhs.append((root * ranges.measured)[:, None] * directions)
            edges.append(ranges.nodes)
        pairs = np.concatenate(edges).astype(np.int64)
        blocks, rhs_all = np.concatenate(a), np.concatenate(rhs)
        if points is None:
            return solve_block_pairwise(n, pairs, -blocks, blocks, rhs_all, self.held,
                                        self.held_positions), None
        # the points some residual measures, numbered after the poses
        measured = np.unique(pairs[pairs >= n]) - n
        node = np.arange(n + points.count)
        node[n + measured] = n + np.arange(len(measured))
        solved = solve_block_pairwise(n + len(measured), node[pairs], -blocks, blocks,
                                      rhs_all, self.held, self.held_positions)
        placed = points.values.copy()
        placed[measured] = solved[n:]
        return solved[:n], placed

    def whitened(self, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals ``A_e (t_j - t_i) - b_e`` at ``rotations`` (whitened, d dof:
        ``W (e_t + Lambda_tt^-1 Lambda_tR e_R)``): (m, d, d) blocks ``A_e``, (m, d) ``b_e``."""
        raise NotImplementedError

    def positions(self, rotations: np.ndarray, gauge: bool = True) -> np.ndarray:
        """(n, d) positions of least cost for ``rotations``; ``gauge``: turn the rotations
        as a whole so that the anchor gets its rotation first (as :meth:`solve`)."""
        raise NotImplementedError

    def solve_weighted(self, a_j: np.ndarray, b: np.ndarray,
                       weights: np.ndarray | None) -> np.ndarray:
        """(n, d) positions of least weighted cost of the residuals :meth:`whitened` gave
        (held poses keep theirs; edges weighted at or below
        :data:`~rlpgo_gtsam.linear.WEIGHT_FLOOR` are left out)."""
        raise NotImplementedError

    def in_gauge(self, rotations: np.ndarray) -> np.ndarray:
        """``rotations`` turned as a whole so that the anchor gets its rotation."""
        raise NotImplementedError

    def aligned(self, rotations: np.ndarray) -> np.ndarray:
        """:meth:`in_gauge`, every held pose at its own rotation."""
        raise NotImplementedError

    def chi2(self, rotations: np.ndarray) -> float:
        """The edges' chi2 at the positions of least cost for ``rotations``."""
        return self.solve(rotations)[1]

    def solve(self, rotations: np.ndarray) -> tuple[np.ndarray, float]:
        """Both at once: (n, d) positions of least cost for ``rotations`` (in the anchor's
        gauge) and the edges' chi2 there."""
        rotations = self.in_gauge(rotations)
        positions = self.positions(rotations, gauge=False)
        poses = self.pose_graph.group.with_positions(rotations, positions)
        return positions, float(edge_chi2(self.pose_graph, poses).sum())


@dataclass(frozen=True, eq=False)
class SystemParts:
    """What the planar translation step's whitened system takes from the edges alone, not
    from the orientations.

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


class _PlanarStep(TranslationStep):
    """The step of a planar graph: angles (n,), one sparse solve of 2-vectors."""

    def __init__(self, pose_graph: PoseGraph2D, parts: SystemParts | None = None,
                 system: PairwiseSystem | None = None) -> None:
        super().__init__(pose_graph)
        self.parts = parts if parts is not None else SystemParts.of(pose_graph)
        self.system = system if system is not None else PairwiseSystem(
            pose_graph.num_poses, pose_graph.edges, self.held)

    @classmethod
    def of(cls, pose_graph: Any) -> TranslationStep:
        """Where each edge's translation information is a multiple of the identity (M3500,
        City10K, generated graphs), the normal matrix does not depend on the orientations,
        and its first factorization serves every later solve
        (``PairwiseSystem(fixed_matrix=True)``): a comparison's lago, chordal, Shonan and
        certified rows factorize once between them."""
        info = pose_graph.information
        isotropic = bool((info[:, 0, 0] == info[:, 1, 1]).all()
                         and (info[:, 0, 1] == 0).all() and (info[:, 1, 0] == 0).all())
        return cls(pose_graph, SystemParts.of(pose_graph),
                   PairwiseSystem(pose_graph.num_poses, pose_graph.edges, pose_graph.held[0],
                                  fixed_matrix=isotropic))

    def whitened(self, rotations):
        g, parts, theta = self.pose_graph, self.parts, rotations
        i, j = g.edges[:, 0], g.edges[:, 1]
        e_theta = wrap(theta[j] - theta[i] - g.measured[:, 2])
        a_j = parts.w @ (parts.r_meas_t @ np.transpose(rotation_matrices(theta[i]), (0, 2, 1)))
        b = np.einsum("eab,eb->ea", parts.w,
                      parts.t_meas - parts.shift_per_rad * e_theta[:, None])
        return a_j, b

    def positions(self, rotations, gauge=True):
        if gauge:
            rotations = self.in_gauge(rotations)
        if self.pose_graph.points is not None:
            return self.with_points(rotations)
        a, b = self.whitened(rotations)
        return self.system.solve(-a, a, b, self.held_positions)

    def solve_weighted(self, a_j, b, weights):
        return self.system.solve(-a_j, a_j, b, self.held_positions, weights)

    def in_gauge(self, rotations):
        theta = np.asarray(rotations, dtype=float)
        return theta - theta[self.held[0]] + self.held_rotations[0]

    def aligned(self, rotations):
        theta = wrap(rotations - rotations[self.held[0]] + self.held_rotations[0])
        theta[self.held] = self.held_rotations
        return theta


class _SpatialStep(TranslationStep):
    """The step of a 3D graph: rotations (n, 3, 3), by conjugate gradients where the edges'
    weights are nearly isotropic (:func:`~rlpgo_gtsam.linear.solve_isotropic`), else one
    sparse (or, small, dense) solve of 3-vectors."""

    def __init__(self, pose_graph: PoseGraph3D) -> None:
        super().__init__(pose_graph)
        info = pose_graph.information
        try:
            lower = np.linalg.cholesky(info[:, 3:, 3:])
        except np.linalg.LinAlgError:
            raise SolverError("an edge's translational information is not positive "
                              "definite") from None
        self.w = np.transpose(lower, (0, 2, 1))  # W^T W = Lambda_tt
        self.shift = np.linalg.solve(info[:, 3:, 3:], info[:, 3:, :3])  # Lambda_tt^-1 Lambda_tR
        self.measured_t = np.transpose(pose_graph.measured_rotations, (0, 2, 1))  # R~^T

    def whitened(self, rotations):
        g = self.pose_graph
        i, j = g.edges[:, 0], g.edges[:, 1]
        turned_i = np.transpose(rotations[i], (0, 2, 1))  # R_i^T
        error_r = log_so3(self.measured_t @ turned_i @ rotations[j])
        v_inv = inverse_left_jacobians(error_r)
        a_j = self.w @ v_inv @ self.measured_t @ turned_i
        b = np.einsum("eab,eb->ea", self.w,
                      np.einsum("eab,eb->ea", v_inv @ self.measured_t, g.measured_translations)
                      - np.einsum("eab,eb->ea", self.shift, error_r))
        return a_j, b

    def positions(self, rotations, gauge=True):
        if gauge:
            rotations = self.in_gauge(rotations)
        g = self.pose_graph
        if g.points is not None:
            return self.with_points(rotations)
        a_j, b = self.whitened(rotations)
        positions = solve_isotropic(g.num_poses, g.edges, a_j, b, self.held,
                                    self.held_positions)
        if positions is None:
            positions = self.solve_weighted(a_j, b, None)
        return positions

    def solve_weighted(self, a_j, b, weights):
        g = self.pose_graph
        return solve_block_pairwise(g.num_poses, g.edges, -a_j, a_j, b, self.held,
                                    self.held_positions, weights)

    def in_gauge(self, rotations):
        rotations = np.asarray(rotations, dtype=float)
        return self.held_rotations[0] @ rotations[self.held[0]].T @ rotations

    def aligned(self, rotations):
        turned = self.in_gauge(rotations)
        turned[self.held] = self.held_rotations
        return turned


_STEPS: dict[Group, type[TranslationStep]] = {SE2: _PlanarStep, SE3: _SpatialStep}
