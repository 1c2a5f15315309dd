"""Numpy arrays of a pose graph, extracted once from GTSAM's graph and values.

This is the one module that turns GTSAM factors into arrays. Everything downstream (rotation
maths, the rollout, the initializers) works on a :class:`PoseGraph2D` or a
:class:`PoseGraph3D` and hands results back as :class:`gtsam.Values`. Both carry their group
(:mod:`rlpgo_gtsam.groups`: ``SE2``, ``SE3``), which says what differs between them;
:func:`extract_pose_graph` extracts either, by what the graph holds.

What the arrays keep of GTSAM's meaning:

- every between factor (``BetweenFactorPose2`` / ``BetweenFactorPose3``) with a Gaussian
  noise model (unit, isotropic, diagonal or full) becomes an edge with its full information
  (3x3, or 6x6 in GTSAM's tangent order: rotation first);
- a prior factor with a constrained noise model (a g2o ``FIX`` line) holds its pose:
  every initializer leaves that pose at the prior's value;
- a prior factor with a Gaussian noise model is a soft prior: the initializers use it
  for the gauge only, while :func:`chi2` and :func:`~rlpgo_gtsam.solvers.refine` evaluate it
  as GTSAM does;
- anything else (robust noise models, other factor types, keys without a pose value of the
  graph's group) is a :class:`~rlpgo_gtsam.errors.GraphError` that names it.

Poses are arrays, one per row: planar ``(n, 3)`` ``(x, y, theta)``, 3D ``(n, 3, 4)``
``[R | t]``; :func:`edge_chi2` and :func:`edge_errors` take either. The information rules
are :mod:`rlpgo_gtsam.information`'s.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, ClassVar

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.groups import SE2, SE3, Group, graph_group, key_text, pose3_arrays
from rlpgo_gtsam.information import Factors, printed_of, sort_factors
from rlpgo_gtsam.landmarks import Carried, Points, Ranges, place_points, split_graph
from rlpgo_gtsam.se3 import pose_matrices

__all__ = [
    "PoseGraph",
    "PoseGraph2D",
    "PoseGraph3D",
    "extract_pose_graph",
    "chi2",
    "edge_chi2",
    "edge_errors",
    "rotation_weights",
    "translation_weights",
    "odometry_edges",
    "disconnection",
    "component_labels",
    "format_ranges",
    "find_root",
    "check_reach",
    "FARTHEST_M",
    "PoseArrays",
    "poses_of_values",
    "pose2_inserter",
]


@dataclass(frozen=True, eq=False, kw_only=True)
class PoseArrays:
    """What every pose graph's arrays hold, whatever its group; poses indexed 0..n-1.

    Attributes:
        keys: (n,) GTSAM keys of the poses, sorted; index ``k`` is pose ``keys[k]``.
        edges: (m, 2) pose indices (i, j) of each between factor, in graph order.
        information: (m, dof, dof) information matrix of each measurement, in GTSAM's
            tangent order (planar x, y, theta; 3D rotation first).
        anchor: index of the pose that fixes the gauge: the first hard prior's pose, else the
            first soft prior's, else index 0.
        fixed: (k,) indices of the poses held by hard (constrained) priors.
        priors: (p,) indices of the poses that soft (Gaussian) priors pull on, in graph order.
        prior_poses: (p, ...) the poses those priors measure, in the group's form (planar
            (p, 3), 3D (p, 3, 4)); None where there are none.
        prior_information: (p, dof, dof) their information matrices; None where there are
            none.
        world_frame: pose 0 is the world frame of a one-anchor problem
            (:mod:`rlpgo_gtsam.anchoring`): its weights are the FIX lines' and priors', which
            do not set the scale of the relaxation's tolerances.
        graph: the GTSAM graph the arrays came from (costs are evaluated on it).
        cache: what the numeric steps derive from these arrays alone and keep for the next
            call on the same graph (the chordal rotations, the translation step's system);
            the arrays are never changed in place, and a graph made from another
            (``dataclasses.replace``) starts with an empty one.
        group: the pose group (the class's: :data:`~rlpgo_gtsam.groups.SE2` or
            :data:`~rlpgo_gtsam.groups.SE3`); ``dimension`` is its.
    """

    group: ClassVar[Group]
    keys: np.ndarray
    edges: np.ndarray
    information: np.ndarray
    anchor: int
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    priors: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    prior_poses: np.ndarray | None = None
    prior_information: np.ndarray | None = None
    world_frame: bool = False
    points: Points | None = field(default=None, repr=False, compare=False)
    ranges: Ranges | None = field(default=None, repr=False, compare=False)
    carried: tuple[Carried, ...] = ()
    carried_values: gtsam.Values | None = field(default=None, repr=False, compare=False)
    graph: gtsam.NonlinearFactorGraph | None = field(default=None, repr=False, compare=False)
    cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def dimension(self) -> int:
        """2 or 3: the group's."""
        return self.group.dimension

    @property
    def factor_graph(self) -> gtsam.NonlinearFactorGraph:
        """``graph``, which costs are evaluated on.

        Raises:
            GraphError: arrays made without a GTSAM graph.
        """
        if self.graph is None:
            raise GraphError("the pose graph's arrays were made without a GTSAM graph")
        return self.graph

    @property
    def num_poses(self) -> int:
        return len(self.keys)

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    @property
    def whole(self) -> bool:
        """Whether the graph holds more than poses: landmarks, carried factors or other
        variables (their values complete :meth:`to_values`)."""
        return self.points is not None or self.carried_values is not None

    def sizes(self) -> str:
        """What the graph holds, in words: ``"300 poses, 519 edges, 75 landmarks (3923
        measurements), 12 ranges, 3 carried factors"`` (the parts it has)."""
        parts = [f"{self.num_poses} poses", f"{self.num_edges} edges"]
        if self.points is not None:
            parts.append(f"{self.points.count} landmarks ({len(self.points.edges)} "
                         "measurements)")
        if self.ranges is not None:
            parts.append(f"{self.ranges.count} ranges")
        if self.carried:
            parts.append(f"{len(self.carried)} carried factors")
        return ", ".join(parts)

    def with_others(self, values: gtsam.Values, poses: np.ndarray,
                    points: np.ndarray | None = None) -> gtsam.Values:
        """``values`` (the poses) completed with the other variables: the landmarks at
        ``points`` (p, d), or by default placed given ``poses``
        (:func:`~rlpgo_gtsam.landmarks.place_points`), every other variable at its value in
        the user's values."""
        if self.points is not None:
            group = self.group
            if points is not None:
                placed = points
            else:
                rotations = group.rotation_matrices(group.rotations(poses))
                placed = place_points(self.points, rotations, group.translations(poses))
            point = gtsam.Point2 if self.points.dimension == 2 else gtsam.Point3
            for key, position in zip(self.points.keys.tolist(), placed, strict=True):
                values.insert(key, point(*position))
        if self.carried_values is not None and self.carried_values.size():
            values.insert(self.carried_values)
        return values

    def check_connected(self) -> None:
        """Raise :class:`GraphError` naming the components if the graph is not connected.

        The edges already index the poses: their components are labelled directly (City10K:
        0.6 ms, where converting keys and edges to lists for :func:`disconnection` took 15
        ms), and :func:`disconnection` words the message only for a graph in pieces.
        """
        labels = component_labels(self.num_poses, self.edges)
        if np.count_nonzero(labels == np.arange(len(labels))) > 1:
            raise GraphError(disconnection(self.keys, self.keys[self.edges]))


@dataclass(frozen=True, eq=False, kw_only=True)
class PoseGraph2D(PoseArrays):
    """The measurements of a planar pose graph as arrays (with :class:`PoseArrays`'
    ``keys``, ``edges``, ``information`` (m, 3, 3), ``anchor``, ``fixed``, ``graph``,
    ``cache``).

    Attributes:
        poses: (n, 3) x, y, theta of each pose in the values the graph came with.
        measured: (m, 3) dx, dy, dtheta of each measurement (pose j in the frame of pose i).
        fixed_poses: (k, 3) the poses the hard priors hold.
        anchor_pose: (3,) where the initializers put the anchor: its prior's value if it has
            one, else its pose in ``values``.
    """

    group: ClassVar[Group] = SE2
    poses: np.ndarray
    measured: np.ndarray
    fixed_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    anchor_pose: np.ndarray | None = None

    @property
    def held(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices and poses the initializers keep: the anchor and every hard-prior pose."""
        anchor_pose = self.poses[self.anchor] if self.anchor_pose is None else self.anchor_pose
        mask = self.fixed != self.anchor
        return (np.concatenate([[self.anchor], self.fixed[mask]]).astype(np.int64),
                np.vstack([anchor_pose[None], self.fixed_poses[mask]]))

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> PoseGraph2D:
        """Extract the arrays; the graph must be connected and made of Pose2 factors only.

        Raises:
            GraphError: a factor other than BetweenFactorPose2 / PriorFactorPose2, a noise
                model that is not Gaussian (robust models), a key without a Pose2 value, or
                a graph that is not connected.
        """
        keys = np.array(sorted(values.keys()), dtype=np.uint64)
        index = {int(key): k for k, key in enumerate(keys)}
        try:
            poses = poses_of_values(values, keys.tolist())
        except RuntimeError as error:
            raise GraphError(f"values hold something other than Pose2: {error}") from None
        factors = sort_factors(graph, index, SE2, _pose_array)
        hard = factors.hard
        anchor, anchor_pose = factors.anchor
        result = cls(
            keys=keys,
            poses=poses.reshape(-1, 3),
            edges=np.array(factors.edges, dtype=np.int64),
            measured=np.array(factors.measured),
            information=np.array(factors.information),
            anchor=anchor,
            fixed=np.array([k for k, _ in hard], dtype=np.int64),
            fixed_poses=np.array([p for _, p in hard]).reshape(-1, 3),
            anchor_pose=poses[anchor] if anchor_pose is None else np.array(anchor_pose),
            **_soft_priors(factors, lambda rows: np.array(rows).reshape(-1, 3)),
            graph=graph,
        )
        result.check_connected()
        return result

    def rotation_weights(self) -> np.ndarray:
        """The weight of each edge's rotation error, the one convention of every initializer.

        It is the conditional rotational information ``information[2, 2]``: the precision of
        the angle with the translation error held at zero (what the g2o/GTSAM cost charges
        for an angle error alone). SE-Sync's kappa is the same entry.
        """
        return self.information[:, 2, 2]

    def translation_weights(self) -> np.ndarray:
        """SE-Sync's tau for d = 2: ``2 / tr(Sigma_t)`` = ``2 det(info_tt) / tr(info_tt)``
        of the 2x2 translational block (0 where that block is 0)."""
        info = self.information
        trace = info[:, 0, 0] + info[:, 1, 1]
        det = info[:, 0, 0] * info[:, 1, 1] - info[:, 0, 1] * info[:, 1, 0]
        return np.divide(2.0 * det, trace, out=np.zeros_like(trace), where=trace > 0)

    def to_values(self, poses: np.ndarray, points: np.ndarray | None = None) -> gtsam.Values:
        """GTSAM values of the given (n, 3) poses under this graph's keys, completed with the
        other variables (:meth:`PoseArrays.with_others`; ``points``: the landmarks' positions,
        else placed given the poses)."""
        values = gtsam.Values()
        insert, pose2 = pose2_inserter(values), gtsam.Pose2
        for key, x, y, theta in zip(self.keys.tolist(), *poses.T.tolist(), strict=True):
            insert(key, pose2(x, y, theta))
        return self.with_others(values, poses, points) if self.whole else values

    def poses_of(self, values: gtsam.Values) -> np.ndarray:
        """(n, 3) x, y, theta of ``values`` in this graph's pose order."""
        return poses_of_values(values, self.keys.tolist())


def pose2_inserter(values: gtsam.Values) -> Callable[[int, gtsam.Pose2], None]:
    """``values.insert`` for a key and a Pose2, the faster way where this GTSAM allows it.

    ``Values.insert`` has some 46 overloads, which pybind11 tries in turn; naming the pose
    argument (``pose2`` in GTSAM's wrapper) passes over the others unconverted: 5.1 us a
    pose instead of 10.1 (5000 inserts, CPU time, GTSAM 4.3).
    """
    insert = values.insert
    return (lambda key, pose: insert(key, pose2=pose)) if _insert_names_pose2() else insert


@functools.cache
def _insert_names_pose2() -> bool:
    try:
        gtsam.Values().insert(0, pose2=gtsam.Pose2())
    except TypeError:  # a wrapper that names it otherwise
        return False
    return True


@dataclass(frozen=True, eq=False, kw_only=True)
class PoseGraph3D(PoseArrays):
    """The measurements of a 3D pose graph as arrays (with :class:`PoseArrays`' ``keys``,
    ``edges``, ``information`` (m, 6, 6), ``anchor``, ``fixed``, ``graph``, ``cache``).

    Attributes:
        rotations: (n, 3, 3) rotation of each pose in the values the graph came with.
        translations: (n, 3) position of each pose in those values.
        measured_rotations: (m, 3, 3) rotation of pose j in the frame of pose i, measured.
        measured_translations: (m, 3) position of pose j in the frame of pose i, measured.
        fixed_rotations, fixed_translations: (k, 3, 3) and (k, 3), the poses the hard
            priors hold.
        anchor_rotation, anchor_translation: where the initializers put the anchor: its
            prior's value if it has one, else its pose in ``values``.
        printed: the printed matrix (6, 6) of each information that GTSAM's model holds as
            a partial Cholesky factor of an indefinite printed matrix
            (:func:`~rlpgo_gtsam.information.printed_informations`), keyed by that
            information's bytes: the relaxation weighs such an edge by it (:attr:`weighed`).
            Keyed by content, so that a graph made from this one by ``dataclasses.replace``
            with some of its edges (the robust path's subgraphs) keeps it.
    """

    group: ClassVar[Group] = SE3
    rotations: np.ndarray
    translations: np.ndarray
    measured_rotations: np.ndarray
    measured_translations: np.ndarray
    fixed_rotations: np.ndarray
    fixed_translations: np.ndarray
    anchor_rotation: np.ndarray
    anchor_translation: np.ndarray
    printed: dict[bytes, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @cached_property
    def weighed(self) -> np.ndarray:
        """(m, 6, 6) the information the relaxation's weights come from: each edge's
        ``information``, or its printed matrix where it has one (``printed``)."""
        if not self.printed:
            return self.information
        return np.array([self.printed.get(matrix.tobytes(), matrix)
                         for matrix in self.information]).reshape(-1, 6, 6)

    @cached_property
    def poses(self) -> np.ndarray:
        """(n, 3, 4) ``[R | t]`` of each pose in the values the graph came with."""
        return pose_matrices(self.rotations, self.translations)

    @cached_property
    def held(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices and poses (k, 3, 4) the initializers keep: the anchor first, then every
        other hard-prior pose. Made once per graph, read only (the certified initializer
        read it three times: 0.07 ms of tinyGrid3D's run)."""
        mask = self.fixed != self.anchor
        held = (np.concatenate([[self.anchor], self.fixed[mask]]).astype(np.int64),
                pose_matrices(
                    np.concatenate([self.anchor_rotation[None], self.fixed_rotations[mask]]),
                    np.vstack([self.anchor_translation[None], self.fixed_translations[mask]])))
        for array in held:
            array.setflags(write=False)
        return held

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, *,
                   check_information: bool = True) -> PoseGraph3D:
        """Extract the arrays; the graph must be connected and made of Pose3 factors only.

        Each edge's information must pass
        :func:`~rlpgo_gtsam.information.information_problem_6`, or be GTSAM's model of a
        printed matrix that :func:`~rlpgo_gtsam.information.information_rule_3d` keeps as
        printed
        (indefinite through the rotation-translation coupling alone): ``gtsam.readG2o``
        turns cubicle's 5021 such matrices into partial Cholesky factors (Eigen's stops at
        the indefinite pivot and GTSAM keeps it) whose information has a condition number
        near 1e16; chi2 is that model's, and the relaxation's weights come from the printed
        matrix it was made from (:func:`~rlpgo_gtsam.information.printed_informations`,
        kept in ``printed``), as
        SE-Sync reads the file. What
        the 3D reader makes always passes.
        ``check_information=False`` accepts any information a Gaussian model holds (finite,
        positive semidefinite).

        Raises:
            GraphError: a factor other than BetweenFactorPose3 / PriorFactorPose3, a noise
                model that is not Gaussian, an unusable information matrix, a key without a
                Pose3 value, or a graph that is not connected.
        """
        keys = np.array(sorted(values.keys()), dtype=np.uint64)
        index = {int(key): k for k, key in enumerate(keys)}
        try:
            rotations, translations = _poses(values, keys.tolist())
        except RuntimeError as error:
            raise GraphError(f"values hold something other than Pose3: "
                             f"{' '.join(str(error).split())}") from None
        factors = sort_factors(graph, index, SE3, lambda pose: pose, False)
        information = np.array(factors.information).reshape(-1, 6, 6)
        printed = printed_of(graph, information, check_information)
        hard = factors.hard
        anchor, anchor_prior = factors.anchor
        fixed_r, fixed_t = pose3_arrays([pose for _, pose in hard])
        measured_r, measured_t = pose3_arrays(factors.measured)
        if anchor_prior is None:
            anchor_r, anchor_t = rotations[anchor], translations[anchor]
        else:
            anchor_r, anchor_t = anchor_prior.rotation().matrix(), anchor_prior.translation()
        result = cls(
            keys=keys, rotations=rotations, translations=translations,
            edges=np.array(factors.edges, dtype=np.int64), measured_rotations=measured_r,
            measured_translations=measured_t, information=information,
            anchor=anchor, fixed=np.array([k for k, _ in hard], dtype=np.int64),
            fixed_rotations=fixed_r, fixed_translations=fixed_t,
            anchor_rotation=np.asarray(anchor_r, float),
            anchor_translation=np.asarray(anchor_t, float), graph=graph,
            printed=printed, **_soft_priors(factors, SE3.pose_arrays),
        )
        result.check_connected()
        return result

    def rotation_weights(self) -> np.ndarray:
        """SE-Sync's kappa for d = 3: ``3 / (2 tr(Sigma_R))``, ``Sigma_R`` the inverse of the
        3x3 rotational block of the information (as SE-Sync's ``read_g2o_file``; of
        :attr:`weighed`: the printed matrix where GTSAM's model is a partial factor of it)."""
        return 3.0 / (2.0 * np.trace(np.linalg.inv(self.weighed[:, :3, :3]),
                                     axis1=1, axis2=2))

    def translation_weights(self) -> np.ndarray:
        """SE-Sync's tau for d = 3: ``3 / tr(Sigma_t)``, ``Sigma_t`` the inverse of the 3x3
        translational block of the information (of :attr:`weighed`)."""
        return 3.0 / np.trace(np.linalg.inv(self.weighed[:, 3:, 3:]), axis1=1, axis2=2)

    def to_values(self, poses: np.ndarray, points: np.ndarray | None = None) -> gtsam.Values:
        """GTSAM values of the given (n, 3, 4) ``[R | t]`` poses under this graph's keys,
        completed as :meth:`PoseGraph2D.to_values` says."""
        values = gtsam.Values()
        insert = values.insert  # pose3= passes over insert's other overloads
        pose3, rot3 = gtsam.Pose3, gtsam.Rot3
        for key, pose in zip(self.keys.tolist(), np.asarray(poses, float), strict=True):
            insert(key, pose3=pose3(rot3(pose[:, :3]), pose[:, 3]))
        return self.with_others(values, poses, points) if self.whole else values

    def poses_of(self, values: gtsam.Values) -> np.ndarray:
        """(n, 3, 4) ``[R | t]`` of ``values`` in this graph's order."""
        return pose_matrices(*_poses(values, self.keys.tolist()))


PoseGraph = PoseGraph2D | PoseGraph3D
_GRAPH_OF_GROUP: dict[Group, type[PoseGraph2D] | type[PoseGraph3D]] = {
    SE2: PoseGraph2D, SE3: PoseGraph3D}


def extract_pose_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> PoseGraph:
    """The one extraction of a pose graph of either group, by what it holds
    (:func:`~rlpgo_gtsam.groups.graph_group`): :class:`PoseGraph2D` or :class:`PoseGraph3D`.
    A graph mixing both is the chosen one's ``GraphError``.

    A whole graph (landmarks measured by bearing and range, point priors, factors of other
    kinds, other variables) is taken apart (:func:`~rlpgo_gtsam.landmarks.split_graph`): its
    pose factors make the pose graph, the landmarks its ``points``, the rest is ``carried``
    (refined, not modeled); ``graph`` stays the user's whole graph, and
    :meth:`~PoseArrays.to_values` completes every estimate with the other variables.
    """
    if not isinstance(graph, gtsam.NonlinearFactorGraph):
        raise GraphError(f"graph must be a gtsam.NonlinearFactorGraph, got "
                         f"{type(graph).__name__}")
    if not isinstance(values, gtsam.Values):
        raise GraphError(f"values must be gtsam.Values, got {type(values).__name__}")
    group = graph_group(graph)
    extraction = _GRAPH_OF_GROUP[group]
    try:
        return extraction.from_gtsam(graph, values)
    except GraphError as error:
        refused = error
    split = split_graph(graph, values, group)
    if not (split.measurements or split.point_priors or split.ranges or split.carried
            or split.carried_values.size()):
        raise refused
    pose_graph = extraction.from_gtsam(split.pose_factors, split.pose_values)
    return replace(pose_graph, graph=graph, points=_points(pose_graph, split),
                   ranges=_ranges(pose_graph, split), carried=split.carried,
                   carried_values=split.carried_values)


# Beyond this distance from the origin, or this length of a measurement, a double keeps
# less than a tenth of a millimetre (its spacing at 1e12 is 1.2e-4): a map there, or beside
# such an edge, has lost its digits before any method runs (a 1e300 m edge overflows).
FARTHEST_M = 1e12


def check_reach(g: PoseGraph, out: np.ndarray | None = None) -> PoseGraph:
    """``g``, after checking that no value and no measurement lies beyond
    :data:`FARTHEST_M` (edges ``out``, a bool mask, left aside: the robust path rejects
    wild closures before it asks). Every initializer asks it first.

    Raises:
        GraphError: the first such value (its key) or measurement (its factor's keys).
    """
    if out is None and g.cache.get("within_reach"):
        return g  # asked once per extraction: by the default, then by each of its stages
    group, keys = g.group, g.keys

    def edge(k: int) -> str:
        i, j = g.edges[k]
        return f"between factor {key_text(keys[i])}-{key_text(keys[j])} measures"

    wrong = "; the robust path rejects a wrong closure of that size"

    measured = group.translations(group.measured(g))
    if out is not None:
        measured = np.where(out[:, None], 0.0, measured)
    checks: list[tuple[np.ndarray, Callable[[int], str]]] = [
        (measured, edge),
        (group.translations(g.poses), lambda k: f"the value of key {key_text(keys[k])} lies at")]
    if g.prior_poses is not None:
        priors = g.priors
        checks.append((group.translations(g.prior_poses),
                       lambda k: f"the prior on key {key_text(keys[priors[k]])} lies at"))
    points = g.points
    if points is not None:
        checks.append((points.measured, lambda k: (
            f"landmark measurement {key_text(keys[points.edges[k, 0]])}-"
            f"{key_text(points.keys[points.edges[k, 1]])} measures")))
        checks.append((points.values,
                       lambda k: f"the value of key {key_text(points.keys[k])} lies at"))
    for vectors, name in checks:
        far = np.flatnonzero(~(np.abs(vectors) <= FARTHEST_M).all(axis=1))
        if len(far):
            size = float(np.max(np.abs(vectors[far[0]])))
            raise GraphError(f"{name(int(far[0]))} {size:.3g} m: beyond {FARTHEST_M:.0e} m a "
                             "double keeps no millimetre of a map"
                             + (wrong if name is edge and out is None else ""))
    if out is None:
        g.cache["within_reach"] = True
    return g


def _ranges(pose_graph: PoseGraph, split: Any) -> Ranges | None:
    """The ranges of a split graph between translation nodes (poses, then points)."""
    if not split.ranges:
        return None
    node = {int(key): k for k, key in enumerate(pose_graph.keys)}
    node.update({key: pose_graph.num_poses + k for k, key in enumerate(split.point_keys)})
    return Ranges(nodes=np.array([(node[a], node[b]) for a, b, _, _ in split.ranges],
                                 np.int64).reshape(-1, 2),
                  measured=np.array([r for _, _, r, _ in split.ranges], float),
                  weights=np.array([w for _, _, _, w in split.ranges], float))


def _points(pose_graph: PoseGraph, split: Any) -> Points | None:
    """The landmarks of a split graph as arrays indexed by ``pose_graph``'s poses.

    Raises:
        GraphError: a point measured by ranges alone without a value.
    """
    if not split.point_keys:
        return None
    d = pose_graph.group.d
    pose_index = {int(key): k for k, key in enumerate(pose_graph.keys)}
    point_index = {key: k for k, key in enumerate(split.point_keys)}
    rotations = pose_graph.group.rotation_matrices(pose_graph.group.rotations(pose_graph.poses))
    positions = pose_graph.group.translations(pose_graph.poses)
    values = np.zeros((len(split.point_keys), d))
    have = np.zeros(len(split.point_keys), bool)
    for key, value in split.point_values.items():
        values[point_index[key]], have[point_index[key]] = value, True
    edges = np.array([(pose_index[pose], point_index[point])
                      for pose, point, _, _ in split.measurements], np.int64).reshape(-1, 2)
    measured = np.array([p for _, _, p, _ in split.measurements]).reshape(-1, d)
    for (i, k), z in zip(edges, measured, strict=True):
        if not have[k]:  # no value: where its first sighting puts it
            values[k], have[k] = positions[i] + rotations[i] @ z, True
    if not have.all():
        key = split.point_keys[int(np.flatnonzero(~have)[0])]
        raise GraphError(f"landmark {key_text(key)} is measured by ranges alone and has no "
                         "value: give it one")
    priors = split.point_priors
    return Points(
        keys=np.array(split.point_keys, np.uint64), values=values, edges=edges,
        measured=measured,
        information=np.array([info for _, _, _, info in split.measurements]).reshape(-1, d, d),
        priors=np.array([point_index[key] for key, _, _ in priors], np.int64),
        prior_values=np.array([value for _, value, _ in priors]).reshape(-1, d),
        prior_information=np.array([info for _, _, info in priors]).reshape(-1, d, d))


def _poses(values: gtsam.Values, keys: list[int]) -> tuple[np.ndarray, np.ndarray]:
    return pose3_arrays([values.atPose3(key) for key in keys])


def rotation_weights(pose_graph: PoseGraph) -> np.ndarray:
    """(m,) the weight of each edge's rotation error (the graph's
    :meth:`~PoseGraph2D.rotation_weights`)."""
    return pose_graph.rotation_weights()


def translation_weights(pose_graph: PoseGraph) -> np.ndarray:
    """(m,) the weight of each edge's translation error in the relaxation (the graph's
    :meth:`~PoseGraph2D.translation_weights`)."""
    return pose_graph.translation_weights()


def odometry_edges(pose_graph: PoseGraph) -> np.ndarray:
    """(m,) bool: the odometry chain, found from the graph itself: every edge between poses
    adjacent in sorted-key order, completed to span the graph.

    The one definition of "odometry edge":

    1. every edge between poses adjacent in sorted-key order (index ``k`` and ``k + 1``:
       keys k, k + 1, or 0, 10, 20 with gaps), a second edge between the same two poses
       included (the generator's lawn mower closes a loop between the two poses of each
       turn): a robot's odometry;
    2. where those leave the graph in pieces, the other edges in graph (file) order, each
       kept when it joins two pieces not yet connected (Kruskal, union-find): the edge that
       first joins a new pose, as a front end writes them (shuffled ids, a star, a graph
       built in any order).

    On a graph whose keys run 0..n-1 along the robot's path this is the edges (k, k + 1).
    """
    g = pose_graph
    parent = list(range(g.num_poses))
    root = functools.partial(find_root, parent)

    adjacent = np.abs(g.edges[:, 1] - g.edges[:, 0]) == 1
    order = np.concatenate([np.flatnonzero(adjacent), np.flatnonzero(~adjacent)])
    chain = np.zeros(g.num_edges, bool)
    for e, (i, j) in zip(order.tolist(), g.edges[order].tolist(), strict=True):
        a, b = root(i), root(j)
        if a != b or adjacent[e]:
            parent[a] = b
            chain[e] = True
    return chain


def _soft_priors(factors: Factors, rows: Callable[[list[Any]], np.ndarray]) -> dict[str, Any]:
    """The extraction's soft-prior fields from the sorted factors (``rows`` packs the
    priors' poses in the group's form); no fields where the graph has none."""
    if not factors.soft:
        return {}
    size = len(factors.soft_information[0])
    return {"priors": np.array([k for k, _ in factors.soft], dtype=np.int64),
            "prior_poses": rows([pose for _, pose in factors.soft]),
            "prior_information": np.array(factors.soft_information).reshape(-1, size, size)}


def find_root(parent: list[int], a: int) -> int:
    """The root of ``a`` in a union-find forest ``parent`` (paths halved on the way)."""
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


def poses_of_values(values: gtsam.Values, keys: list[int]) -> np.ndarray:
    """(n, 3) x, y, theta of ``values`` at ``keys``, in that order: where ``keys`` are all
    of ``values``' keys in ascending order and every value a Pose2, GTSAM's own
    ``extractPose2`` in one call (the same numbers, 7 times faster than a call per pose)."""
    if len(keys) == values.size() and keys == sorted(keys):
        every = gtsam.utilities.extractPose2(values)
        if every.shape == (len(keys), 3):
            return np.ascontiguousarray(every)
    return np.array([_pose_array(values.atPose2(key)) for key in keys]).reshape(-1, 3)


def _pose_array(pose: gtsam.Pose2) -> tuple[float, float, float]:
    """x, y, theta of ``pose`` (a tuple: the callers make one array of many)."""
    return pose.x(), pose.y(), pose.theta()


def chi2(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """g2o's chi2: 2 x GTSAM error of the whole graph (every prior included).

    A hard (FIX) prior adds nothing while its pose is held; g2o fixes its first pose, so on a
    graph read from a g2o file this is g2o's own chi2.

    Raises:
        GraphError: a factor's key has no value.
    """
    try:
        return 2.0 * graph.error(values)
    except RuntimeError as error:
        raise GraphError(f"cannot evaluate the graph: {' '.join(str(error).split())}") from None


def edge_chi2(pose_graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """(m,) each edge's chi2 at ``poses`` ((n, 3) or (n, 3, 4)), as GTSAM's between factor
    charges it: ``e^T Lambda e`` with ``e`` from :func:`edge_errors`."""
    return pose_graph.group.edge_chi2(pose_graph, poses)


def edge_errors(pose_graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """(m, dof) each edge's error at ``poses``, GTSAM's between factor's:
    ``e = Logmap(measured^-1 (X_i^-1 X_j))`` (3D: rotation first)."""
    return pose_graph.group.edge_errors(pose_graph, poses)


def disconnection(keys: Iterable[int] | np.ndarray,
                  pairs: Iterable[tuple[int, int]] | np.ndarray) -> str | None:
    """None if ``pairs`` join all ``keys`` into one component, else a message naming them.

    Keys are GTSAM keys (below 2**64); arrays (keys, (m, 2) pairs) are taken as they are.
    """
    keys = np.sort(np.fromiter(keys, np.uint64) if not isinstance(keys, np.ndarray)
                   else keys.astype(np.uint64))
    keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))] if len(keys) else keys
    pairs = np.asarray(pairs if isinstance(pairs, np.ndarray) else list(pairs),
                       dtype=np.uint64).reshape(-1, 2)
    index = np.searchsorted(keys, pairs)
    if len(pairs) and (not len(keys)
                       or not (keys[np.minimum(index, len(keys) - 1)] == pairs).all()):
        raise KeyError("a pair names a key that is not in keys")
    labels = component_labels(len(keys), index)
    count = int(np.count_nonzero(labels == np.arange(len(keys))))
    if count <= 1:
        return None
    parts: dict[int, list[int]] = {}
    for key, label in zip(keys.tolist(), labels.tolist(), strict=True):
        parts.setdefault(label, []).append(key)
    ordered = sorted(parts.values(), key=lambda part: part[0])
    shown = " and ".join(f"keys {format_ranges(part)}" for part in ordered[:3])
    more = f" and {len(ordered) - 3} more" if len(ordered) > 3 else ""
    return (f"graph has {count} connected components ({shown}{more}); an initializer "
            "needs one")


def component_labels(count: int, pairs: np.ndarray) -> np.ndarray:
    """(count,) the connected component of each of ``count`` nodes that the (m, 2) index
    ``pairs`` join, as the smallest node index in it (a node is its component's label
    exactly when it is the smallest there).

    numpy only (SciPy's ``connected_components`` cost its 5 ms import to every read): each
    round hooks every component's label onto the smallest label an edge joins it to, then
    points every node straight at its label; on a pose graph's files (odometry in key
    order) one or two rounds.
    """
    labels = np.arange(count)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    first, second = pairs[:, 0], pairs[:, 1]
    while True:
        one, other = labels[first], labels[second]
        apart = one != other
        if not apart.any():
            return labels
        # labels only ever move down: no cycle, and a label is always its own label
        np.minimum.at(labels, np.maximum(one, other)[apart], np.minimum(one, other)[apart])
        while True:
            jumped = labels[labels]
            if np.array_equal(jumped, labels):
                break
            labels = jumped


def format_ranges(keys: list[int], limit: int = 4) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``'0-2, 5, 7-8'`` (at most ``limit`` runs, then '...')."""
    runs: list[list[int]] = []
    for key in keys:
        if runs and key == runs[-1][1] + 1:
            runs[-1][1] = key
        else:
            runs.append([key, key])
    text = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit]]
    return ", ".join(text) + (", ..." if len(runs) > limit else "")
