"""The pose groups a graph is made of: SE(2) for a planar graph, SE(3) for a 3D one.

A :class:`Group` carries everything that differs between the two, so that the extraction,
the translation step, the relaxation, the initializers, the ranking and the robust path are
written once: the tangent and translation dimensions, GTSAM's pose and factor types, the g2o
tags, the information rule's bounds, the relaxation's lowest rank, the chi-square bounds of
an edge's residual, and the group operations on arrays.

Poses are arrays with one pose per row: planar ``(k, 3)`` rows ``(x, y, theta)``, spatial
``(k, 3, 4)`` ``[R | t]``. The operations (compose, inverse, between, Logmap, adjoint, in
GTSAM's tangent order) are :mod:`rlpgo_gtsam.se2`'s and :mod:`rlpgo_gtsam.se3`'s, only
repacked here. Rotations are the planar angles ``(n,)`` or the spatial matrices
``(n, 3, 3)``. :func:`group_of` reads a pose graph's group, :func:`graph_group` a GTSAM
graph's.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import gtsam
import numpy as np

import rlpgo_gtsam.se2 as se2
import rlpgo_gtsam.se3 as se3
from rlpgo_gtsam.se3 import pose_matrices

# A pose graph's extraction (:data:`rlpgo_gtsam.graph.PoseGraph`, which imports this module).
PoseGraph = Any

__all__ = ["Group", "SE2", "SE3", "GROUPS", "group_of", "graph_group", "pose3_arrays",
           "key_text"]


class Group:
    """SE(d): what a pose graph of this group needs; see the module docstring.

    Attributes:
        name: ``"SE2"`` or ``"SE3"``.
        dimension: 2 or 3, the pose graphs' ``dimension``.
        dof: tangent dimension (3 planar, 6 spatial): an edge's information size and its
            chi2's degrees of freedom.
        d: translation dimension (2 or 3): the translation step's residual dof.
        kind: how messages name the graph (``"planar"``, ``"3D"``).
        pose_type, between_factor, prior_factor: GTSAM's classes.
        measurement_factors: GTSAM's classes of measurements from a pose that tell the group
            (bearing-range, pose-to-point and pose-to-pose range).
        vertex_tag, edge_tag: the g2o tags the writer prints.
        g2o_tags: tag prefixes that mark a g2o line as this group's.
        max_condition: the largest condition number of an edge's information the
            extraction takes as given (:mod:`rlpgo_gtsam.information`).
        lowest_rank: the certified relaxation's lowest staircase rank (the planar complex
            form's 1, SE(3)'s 3).
        suspicion_chi2: an edge's chi2 that Gaussian noise exceeds with probability 0.001
            (chi-square with ``dof`` degrees of freedom).
        rotation_axes: the rotation's components in GTSAM's tangent order: planar
            ``(x, y, theta)`` (2,), Pose3 ``(rotation, translation)`` (0, 1, 2).
        rotation_volume: the volume of SO(d) in exponential coordinates (Haar measure that
            is Lebesgue at the identity): 2 pi, 8 pi^2.
    """

    name: str
    dimension: int
    dof: int
    d: int
    kind: str
    pose_type: type
    between_factor: type
    prior_factor: type
    measurement_factors: tuple[type, ...]
    vertex_tag: str
    edge_tag: str
    g2o_tags: tuple[str, ...]
    max_condition: float
    lowest_rank: int
    suspicion_chi2: float
    rotation_axes: tuple[int, ...]
    rotation_volume: float

    def __repr__(self) -> str:
        return self.name

    def compose(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def inverse(self, a: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def between(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Row-wise ``a^-1 b``."""
        raise NotImplementedError

    def logmap(self, a: np.ndarray) -> np.ndarray:
        """(k, dof) GTSAM's Logmap."""
        raise NotImplementedError

    def adjoint(self, a: np.ndarray) -> np.ndarray:
        """(k, dof, dof) GTSAM's adjoint maps: ``X Exp(d) X^-1 = Exp(Ad(X) d)``."""
        raise NotImplementedError

    def identity(self, n: int) -> np.ndarray:
        raise NotImplementedError

    def translations(self, poses: np.ndarray) -> np.ndarray:
        """(k, d) the poses' positions."""
        raise NotImplementedError

    def rotations(self, poses: np.ndarray) -> np.ndarray:
        """The poses' rotations: angles (k,) or matrices (k, 3, 3)."""
        raise NotImplementedError

    def rotation_matrices(self, rotations: np.ndarray) -> np.ndarray:
        """(n, d, d) matrices of rotations in the group's form (angles or matrices)."""
        return se2.rotation_matrices(rotations) if self.d == 2 else np.asarray(rotations)

    def with_positions(self, rotations: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Poses of the given rotations and (k, d) positions."""
        raise NotImplementedError

    def measured(self, g: PoseGraph) -> np.ndarray:
        """The edges' measured relative poses, one row per edge."""
        raise NotImplementedError

    def gtsam_pose(self, pose: np.ndarray) -> Any:
        """GTSAM's pose (``Pose2`` or ``Pose3``) of one pose row."""
        raise NotImplementedError

    def pose_arrays(self, poses: list[Any]) -> np.ndarray:
        """The rows of GTSAM poses."""
        raise NotImplementedError

    def pose_at(self, values: gtsam.Values, key: int) -> Any:
        """GTSAM's pose at ``key`` of ``values``."""
        raise NotImplementedError

    def anchored_graph(self, g: PoseGraph, keys: np.ndarray, poses: np.ndarray,
                       edges: np.ndarray, measured: np.ndarray,
                       information: np.ndarray) -> PoseGraph:
        """A pose graph like ``g`` of these poses (group form) and edges whose pose 0 is its
        anchor, held at ``poses[0]``: no other held pose, no prior, no GTSAM graph."""
        raise NotImplementedError

    def subgraph(self, g: PoseGraph, kept: np.ndarray) -> PoseGraph:
        """``g`` with only the edges in ``kept`` (poses, anchor and priors unchanged)."""
        raise NotImplementedError

    def edge_errors(self, g: PoseGraph, poses: np.ndarray) -> np.ndarray:
        """(m, dof) each edge's error at ``poses``, GTSAM's between factor's:
        ``e = Logmap(measured^-1 (X_i^-1 X_j))``."""
        relative = self.between(poses[g.edges[:, 0]], poses[g.edges[:, 1]])
        return self.logmap(self.between(self.measured(g), relative))

    def edge_chi2(self, g: PoseGraph, poses: np.ndarray) -> np.ndarray:
        """(m,) each edge's chi2 at ``poses``, as GTSAM's between factor charges it:
        ``e^T Lambda e`` with ``e`` from :meth:`edge_errors`."""
        error = self.edge_errors(g, poses)
        return np.einsum("ea,eab,eb->e", error, g.information, error)

    def poses_of(self, g: PoseGraph, values: gtsam.Values) -> np.ndarray:
        """``values``' poses in ``g``'s order."""
        return g.poses_of(values)

    def to_values(self, g: PoseGraph, poses: np.ndarray) -> gtsam.Values:
        """GTSAM values of ``poses`` under ``g``'s keys."""
        return g.to_values(poses)

    def agreement_chance(self, bar: float, volume: np.ndarray, side: float) -> np.ndarray:
        """The chance that a random relative pose lands within a cycle's agreement bar: the
        ellipsoid ``{x: x^T C^-1 x <= bar}`` (``volume = sqrt(det C)``) over the volume of
        the relative poses a wrong closure spreads over (positions in a cube of side
        ``2 side``, rotations anywhere)."""
        ball = math.pi ** (self.dof / 2) / math.gamma(self.dof / 2 + 1)
        return ball * bar ** (self.dof / 2) * volume / (
            np.float64(2.0 * side) ** self.d * self.rotation_volume)


class _SE2(Group):
    name, dimension, dof, d, kind = "SE2", 2, 3, 2, "planar"
    pose_type, between_factor, prior_factor = (gtsam.Pose2, gtsam.BetweenFactorPose2,
                                               gtsam.PriorFactorPose2)
    measurement_factors = (gtsam.BearingRangeFactor2D, gtsam.RangeFactor2D,
                           gtsam.RangeFactorPose2)
    vertex_tag, edge_tag = "VERTEX_SE2", "EDGE_SE2"
    g2o_tags = ("VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2")
    # eigenvalues from 1e-20 to 1e20 and a condition number up to 1e9 were certified and
    # refined on generated graphs; at 1e10 GTSAM's linear solves find the system indeterminate
    max_condition = 1e9
    lowest_rank, suspicion_chi2 = 1, 16.266
    rotation_axes, rotation_volume = (2,), 2.0 * math.pi

    def compose(self, a, b):
        return se2.compose(a, b)

    def inverse(self, a):
        return se2.inverse(a)

    def between(self, a, b):
        return se2.between(a, b)

    def logmap(self, a):
        return se2.logmap(a)

    def adjoint(self, a):
        return se2.adjoint(a)

    def identity(self, n):
        return np.zeros((n, 3))

    def translations(self, poses):
        return poses[:, :2]

    def rotations(self, poses):
        return poses[:, 2]

    def with_positions(self, rotations, positions):
        return np.column_stack([positions, rotations])

    def measured(self, g):
        return g.measured

    def gtsam_pose(self, pose):
        return gtsam.Pose2(*pose)

    def pose_arrays(self, poses):
        return np.array([[p.x(), p.y(), p.theta()] for p in poses]).reshape(-1, 3)

    def pose_at(self, values, key):
        return values.atPose2(key)

    def subgraph(self, g, kept):
        return replace(g, edges=g.edges[kept], measured=g.measured[kept],
                       information=g.information[kept])

    def anchored_graph(self, g, keys, poses, edges, measured, information):
        return replace(g, keys=keys, poses=poses, edges=edges, measured=measured,
                       information=information, anchor=0, fixed=np.zeros(0, np.int64),
                       fixed_poses=np.zeros((0, 3)), anchor_pose=poses[0], **_NO_PRIORS)


class _SE3(Group):
    name, dimension, dof, d, kind = "SE3", 3, 6, 3, "3D"
    pose_type, between_factor, prior_factor = (gtsam.Pose3, gtsam.BetweenFactorPose3,
                                               gtsam.PriorFactorPose3)
    measurement_factors = (gtsam.BearingRangeFactor3D, gtsam.RangeFactor3D,
                           gtsam.RangeFactorPose3)
    vertex_tag, edge_tag = "VERTEX_SE3:QUAT", "EDGE_SE3:QUAT"
    g2o_tags = ("VERTEX_SE3", "EDGE_SE3", "VERTEX3", "EDGE3", "VERTEX_TRACKXYZ", "EDGE_SE3_")
    # SE-Sync's parking-garage has 3 edges above the planar 1e9 (the worst 2.67e9); on
    # smallGrid3D GTSAM LM reached the same chi2 with one weak axis up to 1e16, and 1e12
    # keeps 4 of double's 16 digits for the Cholesky factor GTSAM whitens with
    max_condition = 1e12
    lowest_rank, suspicion_chi2 = 3, 22.458
    rotation_axes, rotation_volume = (0, 1, 2), 8.0 * math.pi ** 2

    def compose(self, a, b):
        return pose_matrices(*se3.compose(a[:, :, :3], a[:, :, 3], b[:, :, :3], b[:, :, 3]))

    def inverse(self, a):
        return pose_matrices(*se3.inverse(a[:, :, :3], a[:, :, 3]))

    def between(self, a, b):
        return pose_matrices(*se3.between(a[:, :, :3], a[:, :, 3], b[:, :, :3], b[:, :, 3]))

    def logmap(self, a):
        return se3.logmap(a[:, :, :3], a[:, :, 3])

    def adjoint(self, a):
        return se3.adjoint(a[:, :, :3], a[:, :, 3])

    def identity(self, n):
        return pose_matrices(np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))

    def translations(self, poses):
        return poses[:, :, 3]

    def rotations(self, poses):
        return poses[:, :, :3]

    def with_positions(self, rotations, positions):
        return pose_matrices(rotations, positions)

    def measured(self, g):
        return pose_matrices(g.measured_rotations, g.measured_translations)

    def gtsam_pose(self, pose):
        return gtsam.Pose3(gtsam.Rot3(pose[:, :3]), pose[:, 3])

    def pose_arrays(self, poses):
        return pose_matrices(*pose3_arrays(poses))

    def pose_at(self, values, key):
        return values.atPose3(key)

    def subgraph(self, g, kept):
        return replace(g, edges=g.edges[kept], measured_rotations=g.measured_rotations[kept],
                       measured_translations=g.measured_translations[kept],
                       information=g.information[kept])

    def anchored_graph(self, g, keys, poses, edges, measured, information):
        # the printed matrices stay keyed by content: an edge carried over unchanged keeps
        # its weights, one whose information was transformed is weighed by its own
        return replace(g, keys=keys, rotations=poses[:, :, :3], translations=poses[:, :, 3],
                       edges=edges, measured_rotations=measured[:, :, :3],
                       measured_translations=measured[:, :, 3], information=information,
                       anchor=0, fixed=np.zeros(0, np.int64), fixed_rotations=np.zeros((0, 3, 3)),
                       fixed_translations=np.zeros((0, 3)), anchor_rotation=poses[0, :, :3],
                       anchor_translation=poses[0, :, 3], **_NO_PRIORS)

    def edge_errors(self, g, poses):
        # the between of the edges' poses, then of the measurement, on the split arrays
        # (the packed form's concatenations cost a tenth of the 3D edge cost)
        i, j = g.edges[:, 0], g.edges[:, 1]
        r, t = poses[:, :, :3], poses[:, :, 3]
        r_rel, t_rel = se3.between(r[i], t[i], r[j], t[j])
        r_err, t_err = se3.between(g.measured_rotations, g.measured_translations, r_rel, t_rel)
        return se3.logmap(r_err, t_err)


# the fields of a one-anchor problem's graph: its pose 0 the world frame, no prior
_NO_PRIORS: dict[str, Any] = {"priors": np.zeros(0, np.int64), "prior_poses": None,
                              "prior_information": None, "graph": None, "world_frame": True}

SE2: Group = _SE2()
SE3: Group = _SE3()
GROUPS: tuple[Group, ...] = (SE2, SE3)


def pose3_arrays(poses: list[gtsam.Pose3]) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (k, 3, 3) and translations (k, 3) of GTSAM ``Pose3`` objects."""
    return (np.array([p.rotation().matrix() for p in poses]).reshape(-1, 3, 3),
            np.array([p.translation() for p in poses]).reshape(-1, 3))


def group_of(pose_graph: Any) -> Group:
    """The group of a pose graph's extraction (its ``group``)."""
    return pose_graph.group


def key_text(key: int) -> str:
    """A key as GTSAM prints it (``x2`` for a symbol, ``12`` for a plain integer)."""
    return str(gtsam.DefaultKeyFormatter(int(key)))


def graph_group(graph: gtsam.NonlinearFactorGraph) -> Group:
    """SE3 if the first pose factor of ``graph`` is a Pose3 one (between or prior, or a
    bearing-range or range measurement from a pose), else SE2 (a graph of neither kind: the
    planar extraction names what it holds)."""
    kinds = {group: (group.between_factor, group.prior_factor, *group.measurement_factors)
             for group in GROUPS}
    for position in range(graph.size()):
        factor = graph.at(position)
        for group, types in kinds.items():
            if isinstance(factor, types):
                return group
    return SE2
