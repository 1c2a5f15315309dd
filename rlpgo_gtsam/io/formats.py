"""What differs between a planar and a 3D g2o file: one :class:`Format` per pose group.

The readers and writers (:mod:`~rlpgo_gtsam.io.scan`, :mod:`~rlpgo_gtsam.io.read`,
:mod:`~rlpgo_gtsam.io.write`) are written once and take a format; the group
(:mod:`rlpgo_gtsam.groups`: tags, GTSAM types, degrees of freedom) says what the lines are
called, and the format how their numbers become GTSAM poses and information, and back.

======================  ===================================  ==============================
                        planar (:data:`PLANAR`)              3D (:data:`SPATIAL`)
======================  ===================================  ==============================
vertex line             ``VERTEX_SE2 id x y theta``          ``VERTEX_SE3:QUAT id x y z qx
                                                             qy qz qw``
edge line               ``EDGE_SE2 i j dx dy dtheta`` and    ``EDGE_SE3:QUAT i j x y z qx
                        6 information entries                qy qz qw`` and 21 entries
information order       x, y, theta (GTSAM's)                g2o's x y z, rotation; GTSAM's
                                                             is rotation first
information rule        used as it is, or refused            :func:`~rlpgo_gtsam.information.
                                                             information_rule_3d`
pose                    ``Pose2(x, y, theta)``               quaternion normalized (a zero
                                                             one is an error)
======================  ===================================  ==============================

Both hold the information's upper triangle row by row. Poses are numpy arrays, one pose per
row: planar ``(k, 3)``; 3D a pair of rotations ``(k, 3, 3)`` and translations ``(k, 3)``.

Each group has its landmark lines too (:data:`POINT_LINES`: planar ``VERTEX_XY``,
``EDGE_SE2_XY``, ``LANDMARK2``, ``BR``, ``LANDMARK``; 3D ``VERTEX_TRACKXYZ``,
``EDGE_SE3_TRACKXYZ``, ``PARAMS_SE3OFFSET``; :mod:`rlpgo_gtsam.io` says how they read), which
the careful reader reads into the table's :class:`Landmarks`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, OutputError
from rlpgo_gtsam.graph import PoseGraph2D, pose2_inserter, poses_of_values
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.information import (
    information_problem,
    information_problems,
    information_rule_3d,
    printed_informations,
)
from rlpgo_gtsam.io.lines import distinct_rows, format_15, texts_15, upper_triangle_texts
from rlpgo_gtsam.landmarks import landmark_key
from rlpgo_gtsam.se2 import chain, compose, inverse, wrap
from rlpgo_gtsam.se3 import compose as compose3
from rlpgo_gtsam.se3 import inverse as inverse3
from rlpgo_gtsam.se3 import quaternions_to_rotations, rotations_to_quaternions

__all__ = ["Table", "Landmarks", "Format", "PLANAR", "SPATIAL", "FORMATS", "format_of",
           "G2O_TO_GTSAM", "PointLines", "POINT_LINES", "landmark_group"]

# g2o's tangent order (x y z, then rotation) -> GTSAM's (rotation, then x y z): the
# information in GTSAM's order is info_g2o[G2O_TO_GTSAM][:, G2O_TO_GTSAM]
G2O_TO_GTSAM = np.array([3, 4, 5, 0, 1, 2])
_GTSAM_TO_G2O = np.argsort(G2O_TO_GTSAM)
_QUATERNION_FLOOR = 1e-9  # a quaternion shorter than this has no direction to normalize
_VALUES_SAMPLE = 1024  # vertices whose poses GTSAM's reading is compared on

Poses = Any  # planar (k, 3); 3D (rotations (k, 3, 3), translations (k, 3))
Pose = Any  # one row of those


@dataclass(eq=False)
class Table:
    """A g2o file as arrays, in file order: what both readers produce.

    Attributes:
        vertex_keys: (n,) uint64 the vertex ids.
        vertex_numbers: (n, p) the numbers of those lines after the id (the format's
            ``pose_numbers``).
        edge_keys: (m, 2) uint64 the ids i, j of each edge line.
        edge_lines: (m,) the 1-based line of each edge.
        edge_numbers: (m, p) the measured pose's numbers of each edge.
        information: the distinct information matrices as the format's rule uses them
            (GTSAM's order; each checked once).
        model: (m,) the index of each edge's matrix in ``information``.
        fixed: (id, line) of each id of the FIX lines.
        changed: what the information rule did (its change's name) -> the lines of those
            edges, in order.
        vertex_text: the vertex lines as read (a block per chunk), where the fast reader
            read them all as plain text and the format asks for them (GTSAM's own parser
            may then build the values); else None.
        landmarks: the landmark lines (:class:`Landmarks`), where the file has any (the
            careful reader reads those files); else None.
    """

    vertex_keys: np.ndarray
    vertex_numbers: np.ndarray
    edge_keys: np.ndarray
    edge_lines: np.ndarray
    edge_numbers: np.ndarray
    information: list[np.ndarray]
    model: np.ndarray
    fixed: list[tuple[int, int]]
    changed: dict[str, list[int]]
    vertex_text: list[bytes] | None = None
    landmarks: Landmarks | None = None


@dataclass(eq=False)
class Landmarks:
    """The landmark lines of a file, in file order: what the careful reader makes of them
    (:func:`~rlpgo_gtsam.io.read.parse`).

    Attributes:
        vertices: landmark id -> (position (d,), line) of its vertex line.
        factors: each measurement's GTSAM bearing-range factor (pose key, ``l<id>``).
        tags, lines, pose_ids, landmark_ids: each measurement's tag, line, pose id and
            landmark id.
        points: each measurement's point in the pose's (body) frame.
        unit_sigma_lines: the ``LANDMARK`` lines read with GTSAM's unit sigmas.
    """

    vertices: dict[int, tuple[np.ndarray, int]] = field(default_factory=dict)
    factors: list[Any] = field(default_factory=list)
    tags: list[str] = field(default_factory=list)
    lines: list[int] = field(default_factory=list)
    pose_ids: list[int] = field(default_factory=list)
    landmark_ids: list[int] = field(default_factory=list)
    points: list[np.ndarray] = field(default_factory=list)
    unit_sigma_lines: list[int] = field(default_factory=list)

    def keys(self) -> np.ndarray:
        """(k,) uint64 the GTSAM keys of the landmarks (vertex lines and measurements),
        ascending."""
        ids = set(self.vertices) | set(self.landmark_ids)
        return np.array(sorted(landmark_key(j) for j in ids), dtype=np.uint64)

    def pairs(self) -> np.ndarray:
        """(m, 2) uint64 the (pose, landmark) keys of each measurement."""
        return np.array([(i, landmark_key(j)) for i, j in
                         zip(self.pose_ids, self.landmark_ids, strict=True)],
                        dtype=np.uint64).reshape(-1, 2)


class Format:
    """The g2o lines of one pose group; see the module docstring.

    Attributes:
        group: the pose group (tags, GTSAM types, ``dof``: the information's size).
        pose_numbers: the numbers of a pose on a line, after its ids (3, or 7).
        angle_fields: how many of them the writer writes with 15 significant digits (the
            rotation's: theta, or the quaternion's 4); the positions before them exactly.
        soft_prior_line: how the writer's error for a soft prior names the line it lacks.
        reads_vertex_text: whether :meth:`values` takes the vertex lines as read.
    """

    group: Group
    pose_numbers: int
    angle_fields: int
    soft_prior_line: str
    reads_vertex_text: bool = False

    @property
    def vertex_tag(self) -> str:
        return self.group.vertex_tag

    @property
    def edge_tag(self) -> str:
        return self.group.edge_tag

    @property
    def information_numbers(self) -> int:
        """The numbers of an edge's information: its upper triangle (6, or 21)."""
        return self.group.dof * (self.group.dof + 1) // 2

    # ----------------------------------------------------------------------- reading

    def informations(self, upper: np.ndarray) -> np.ndarray:
        """(k, dof, dof) the symmetric information, GTSAM's order, of (k, n) upper
        triangles as the file writes them."""
        raise NotImplementedError

    def rule(self, matrices: np.ndarray) -> tuple[np.ndarray, list[str | None],
                                                  list[tuple[str, ...]]]:
        """The information rule on (k, dof, dof) matrices: the matrices to use, why each
        cannot be used (None: it can), what was done with each (``()``: nothing)."""
        raise NotImplementedError

    def usable(self, numbers: np.ndarray) -> bool:
        """Whether every pose of (k, pose_numbers) is plainly one (the fast reader's test;
        where not, the careful reader judges)."""
        return True

    def check_pose(self, path: Path, line: int, tag: str, numbers: list[float]) -> None:
        """Raise the error of a line whose pose ``numbers`` name no pose."""

    def poses(self, numbers: np.ndarray) -> Poses:
        """The poses of (k, pose_numbers) numbers of the lines."""
        raise NotImplementedError

    def take(self, poses: Poses, order: np.ndarray) -> Poses:
        """The poses at the indices ``order``."""
        raise NotImplementedError

    def stack(self, poses: list[Pose]) -> Poses:
        """The poses of a list of single ones (:meth:`run`'s, :meth:`then`'s)."""
        raise NotImplementedError

    def finite(self, pose: Pose) -> bool:
        """Whether every number of one pose is finite."""
        raise NotImplementedError

    def run(self, steps: Poses, chosen: list[tuple[int, bool]]) -> list[Pose]:
        """The poses of a chain from the identity through the steps ``chosen`` ((index,
        inverted?) in ``steps``, the edges' poses): one more pose than steps."""
        raise NotImplementedError

    def then(self, pose: Pose, steps: Poses, index: int, inverted: bool) -> Pose:
        """``pose`` composed with step ``index`` of ``steps`` (inverted where marked)."""
        raise NotImplementedError

    def gtsam_poses(self, poses: Poses) -> Iterator[Any]:
        """GTSAM's poses of ``poses``, one by one."""
        raise NotImplementedError

    def values(self, keys: np.ndarray, poses: Poses,
               vertex_text: list[bytes] | None) -> gtsam.Values:
        """GTSAM values of ``poses`` at ``keys`` (ascending); ``vertex_text``: the file's
        vertex lines as read, where every one is plain text."""
        raise NotImplementedError

    def extraction(self, table: Table, graph: gtsam.NonlinearFactorGraph,
                   values: gtsam.Values, keys: np.ndarray, measured: list,
                   models: list) -> PoseGraph2D | None:
        """The extraction of the graph just built from ``table`` (its values' ``keys``,
        ascending; its edges' GTSAM ``measured`` poses; the distinct noise ``models``), or
        None: the caller extracts it."""
        return None

    # ----------------------------------------------------------------------- writing

    def vertex_columns(self, values: gtsam.Values, count: int) -> list[list] | None:
        """The columns of the vertex lines' numbers (positions, then the angle fields' texts)
        of all ``count`` values, by key; None where one is not this group's pose or not
        finite."""
        raise NotImplementedError

    def edge_columns(self, edges: list) -> list[list] | None:
        """The columns of the edge lines' measured numbers, as :meth:`vertex_columns`; None
        where one is not finite."""
        raise NotImplementedError

    def information_fields(self, models: list) -> list[str] | None:
        """The information fields of each edge's noise model, or None where one is not
        plainly writable (the careful writer judges)."""
        raise NotImplementedError

    def extraction_columns(self, pose_graph: Any) -> tuple[list[list], list[str]] | None:
        """:meth:`edge_columns` and :meth:`information_fields` from the graph's extraction,
        or None: the writer walks the factors."""
        return None

    def vertex_line(self, key: int, pose: Any) -> str:
        """The vertex line of ``pose``, or the error that says why it cannot be written."""
        raise NotImplementedError

    def edge_line(self, factor: Any) -> str:
        """The edge line of a between factor, or the error that says why it cannot be
        written."""
        raise NotImplementedError

    def pose_at(self, values: gtsam.Values, key: int) -> Any:
        """The value of ``key``, or the error that says it is not this group's pose."""
        name, kind = self.group.pose_type.__name__, self.group.kind
        try:
            return getattr(values, f"at{name}")(key)
        except RuntimeError:
            raise OutputError(f"value of key {key} is not a {name}: a {kind} g2o file holds "
                              f"{name} vertices only") from None


def gaussian_model(model: Any, i: int, j: int) -> Any:
    """The noise model of edge ``i``-``j``, or the error that says a g2o edge cannot hold
    it."""
    if not isinstance(model, gtsam.noiseModel.Gaussian) or isinstance(
            model, gtsam.noiseModel.Constrained):
        raise OutputError(f"edge {i}-{j} has a {type(model).__name__} noise model: a g2o "
                          "edge holds a Gaussian information matrix only")
    return model


def information_texts(models: list, size: int,
                      problems: Callable[[np.ndarray], list[str | None]],
                      order: np.ndarray | None = None) -> list[str] | None:
    """The g2o fields of each Gaussian noise model's ``size`` x ``size`` information (its
    upper triangle row by row, after reordering rows and columns by ``order``: 6 fields in
    2D, 21 in 3D), or None if a g2o edge cannot hold one of them.

    Each model object is asked for its information once, each distinct matrix checked
    once (all in one batch, by ``problems``: the careful writer's rule for a stack) and the
    numbers of all of them formatted in one call.
    """
    distinct = {id(model): model for model in models}  # held: each id stays its model's
    gaussian, constrained = gtsam.noiseModel.Gaussian, gtsam.noiseModel.Constrained
    if not all(isinstance(model, gaussian) and not isinstance(model, constrained)
               for model in distinct.values()):
        return None
    matrices = np.array([model.information() for model in distinct.values()])
    if matrices.shape != (len(distinct), size, size):
        return None
    first, _ = distinct_rows(matrices)
    if any(problem is not None for problem in problems(matrices[first])):
        return None
    if order is not None:
        matrices = matrices[:, order][:, :, order]
    text = dict(zip(distinct, upper_triangle_texts(matrices, size), strict=True))
    return [text[id(model)] for model in models]


class _Planar(Format):
    group = SE2
    pose_numbers, angle_fields = 3, 1
    soft_prior_line = "planar g2o line"
    reads_vertex_text = True

    def informations(self, upper):
        matrices = np.empty((len(upper), 3, 3))
        for column, (a, b) in enumerate(zip(*np.triu_indices(3), strict=True)):
            matrices[:, a, b] = matrices[:, b, a] = upper[:, column]
        return matrices

    def rule(self, matrices):
        return matrices, information_problems(matrices), [()] * len(matrices)

    def poses(self, numbers):
        return np.asarray(numbers, dtype=float).reshape(-1, 3)

    def take(self, poses, order):
        return poses[order]

    def stack(self, poses):
        return np.array(poses, dtype=float).reshape(-1, 3)

    def finite(self, pose):
        return all(math.isfinite(v) for v in pose)

    def run(self, steps, chosen):
        return list(chain(_planar_steps(steps, chosen)))

    def then(self, pose, steps, index, inverted):
        return compose(pose[None], _planar_steps(steps, [(index, inverted)]))[0]

    def gtsam_poses(self, poses):
        return map(gtsam.Pose2, *poses.T.tolist())

    def values(self, keys, poses, vertex_text):
        values = _values_by_gtsam(vertex_text, keys, poses) if vertex_text else None
        if values is None:
            values = gtsam.Values()
            insert, pose2 = pose2_inserter(values), gtsam.Pose2
            for key, x, y, theta in zip(keys.tolist(), *poses.T.tolist(), strict=True):
                insert(key, pose2(x, y, theta))
        return values

    def extraction(self, table, graph, values, keys, measured, models):
        """What :meth:`PoseGraph2D.from_gtsam` makes of the graph just built, the same arrays
        bit for bit, from the reader's own arrays and objects instead of a walk over the
        graph's factors (MIT, Intel, FR079: one noise model per edge, 10-19 ms a read): the
        angles and information matrices as GTSAM gives them back (``theta()`` of each
        measurement, ``information()`` of each distinct model); the edges' pose indices, the
        FIX poses (hard priors, in graph order: the first is the anchor) from the sorted
        keys. None where extraction would refuse an information matrix: the caller's
        extraction then raises that error."""
        information = np.array([m.information() for m in models]).reshape(-1, 3, 3)
        if any(problem is not None for problem in information_problems(information)):
            return None
        poses = poses_of_values(values, keys.tolist())
        thetas = np.fromiter(map(gtsam.Pose2.theta, measured), float, len(measured))
        held = np.searchsorted(keys, np.array([key for key, _ in table.fixed], dtype=np.uint64))
        anchor = int(held[0]) if len(held) else 0
        result = PoseGraph2D(
            keys=keys,
            poses=poses,
            edges=np.searchsorted(keys, table.edge_keys).astype(np.int64).reshape(-1, 2),
            measured=np.column_stack([table.edge_numbers[:, :2], thetas]),
            information=information[table.model],
            anchor=anchor,
            fixed=held.astype(np.int64),
            fixed_poses=poses[held].reshape(-1, 3),
            anchor_pose=poses[anchor] if len(held) == 0 else poses[anchor].copy(),
            graph=graph,
        )
        result.check_connected()
        return result

    def vertex_columns(self, values, count):
        poses = gtsam.utilities.extractPose2(values)  # x, y, theta() of the Pose2 values
        if poses.shape != (count, 3) or not np.isfinite(poses).all():
            return None
        xs, ys, thetas = poses.T.tolist()
        return [xs, ys, texts_15(thetas)]

    def edge_columns(self, edges):
        # each call runs over all edges at once (map of the unbound methods)
        measured = list(map(gtsam.BetweenFactorPose2.measured, edges))
        dx, dy = list(map(gtsam.Pose2.x, measured)), list(map(gtsam.Pose2.y, measured))
        dtheta = list(map(gtsam.Pose2.theta, measured))
        if not all(map(math.isfinite, dx + dy + dtheta)):
            return None
        return [dx, dy, texts_15(dtheta)]

    def information_fields(self, models):
        return information_texts(models, 3, information_problems)

    def extraction_columns(self, pose_graph):
        g = pose_graph
        if not isinstance(g, PoseGraph2D) or not np.isfinite(g.measured).all():
            return None
        # the informations passed extraction's check, the writer's (information_problems)
        first, inverse_index = distinct_rows(g.information)
        texts = upper_triangle_texts(g.information[first], 3)
        dx, dy, dtheta = g.measured.T.tolist()
        return [dx, dy, texts_15(dtheta)], [texts[k] for k in inverse_index.tolist()]

    def vertex_line(self, key, pose):
        numbers = (pose.x(), pose.y(), pose.theta())
        if not all(math.isfinite(v) for v in numbers):
            raise OutputError(f"vertex {key} is not finite ({numbers[0]!r}, {numbers[1]!r}, "
                              f"{numbers[2]!r}): the file would not read back")
        return f"VERTEX_SE2 {key} {pose.x()!r} {pose.y()!r} {format_15(pose.theta())}"

    def edge_line(self, factor):
        i, j = factor.keys()
        z = factor.measured()
        if i == j:
            raise OutputError(f"edge {i}-{j} joins a vertex to itself: the file would not "
                              "read back")
        model = gaussian_model(factor.noiseModel(), i, j)
        if not all(math.isfinite(v) for v in (z.x(), z.y(), z.theta())):
            raise OutputError(f"edge {i}-{j}: the measurement is not finite")
        info = model.information()
        problem = information_problem(info)
        if problem is not None:
            raise OutputError(f"edge {i}-{j}: {problem} (the reader would refuse it)")
        upper = np.asarray(info)[np.triu_indices(3)]
        return (f"EDGE_SE2 {i} {j} {z.x()!r} {z.y()!r} {format_15(z.theta())} "
                + " ".join(format_15(v) for v in upper))


def _planar_steps(measured: np.ndarray, chosen: list[tuple[int, bool]]) -> np.ndarray:
    """(k, 3) the measurements of the chosen edges (angles wrapped, as a ``gtsam.Pose2``
    holds them), inverted where marked."""
    index = np.array([i for i, _ in chosen], dtype=np.int64)
    inverted = np.array([flag for _, flag in chosen], dtype=bool)
    steps = measured[index]
    steps[:, 2] = wrap(steps[:, 2])
    steps[inverted] = inverse(steps[inverted])
    return steps


def _values_by_gtsam(text: list[bytes], keys: np.ndarray,
                     poses: np.ndarray) -> gtsam.Values | None:
    """The values of the VERTEX_SE2 lines ``text``, built by GTSAM's own parser from a file
    held in memory; None where that cannot be done, or where GTSAM read them otherwise.

    ``text`` holds every vertex line of the file (in blocks), which the reader has read (and
    checked) as ``keys`` (ascending) and ``poses``. ``Values.insert`` costs some 5 us a call
    from Python, more than the rest of a vertex line; ``gtsam.readG2o`` builds the same
    ``Pose2(x, y, theta)`` values in C++ in about half the time, reading the text included.
    It needs a file name: a memfd (Linux) read through /proc. Its values are kept only if they
    are the ones the reader read: the same keys, and on an even sample of the vertices (below)
    x and y bit for bit, theta to 1e-9 rad (``theta()`` comes back from cos and sin); else the
    caller inserts them one by one.
    """
    create = getattr(os, "memfd_create", None)
    if create is None:
        return None
    try:
        descriptor = create("rlpgo-g2o-vertices")
    except OSError:
        return None
    try:
        for block in text:
            view = memoryview(block)
            while view:
                view = view[os.write(descriptor, view):]
        _graph, values = gtsam.readG2o(f"/proc/self/fd/{descriptor}", False)
    except (OSError, RuntimeError, ValueError):  # no /proc, a line GTSAM refuses, ...
        return None
    finally:
        os.close(descriptor)
    if values.size() != len(keys) or values.keys() != keys.tolist():
        return None
    # Every line was checked as float() reads it (finite, plain ASCII), and the C library's
    # strtod under GTSAM's stream reads such a field to the same double, so the poses are
    # compared on an even sample of at most _VALUES_SAMPLE vertices (all of a smaller file):
    # enough to catch a GTSAM that reads these lines another way, at 2 ms instead of the
    # 37 ms extractPose2 takes for 200 000 vertices.
    # distinct, ascending: a step of exactly 1 up to _VALUES_SAMPLE vertices, above 1 beyond
    sample = np.linspace(0, len(keys) - 1, min(len(keys), _VALUES_SAMPLE)).astype(int)
    at = values.atPose2
    read = np.array([(pose.x(), pose.y(), pose.theta())
                     for pose in map(at, keys[sample].tolist())]).reshape(-1, 3)
    chosen = poses[sample]
    xy, chosen_xy = read[:, :2], chosen[:, :2]
    same_xy = (xy == chosen_xy) & (np.signbit(xy) == np.signbit(chosen_xy))
    if not same_xy.all() or not (np.abs(wrap(read[:, 2] - chosen[:, 2])) <= 1e-9).all():
        return None
    return values


class _Spatial(Format):
    group = SE3
    pose_numbers, angle_fields = 7, 4
    soft_prior_line = "g2o line"

    def informations(self, upper):
        full = np.zeros((len(upper), 6, 6))
        full[:, _UPPER_6[0], _UPPER_6[1]] = upper
        information = full + np.transpose(np.triu(full, 1), (0, 2, 1))
        return information[:, G2O_TO_GTSAM][:, :, G2O_TO_GTSAM]

    def rule(self, matrices):
        return information_rule_3d(matrices)

    def usable(self, numbers):
        # with room to spare: a shorter one, even by rounding, is the careful reader's
        return bool((_rotations(numbers[:, 3:])[1] >= 2 * _QUATERNION_FLOOR).all())

    def check_pose(self, path, line, tag, numbers):
        quaternion = numbers[3:7]
        if not _rotations(np.array([quaternion]))[1][0] >= _QUATERNION_FLOOR:
            raise G2oFormatError(path, line, f"{tag} quaternion "
                                 f"({', '.join(map(repr, quaternion))}) is zero: it names no "
                                 "rotation")

    def poses(self, numbers):
        numbers = np.asarray(numbers, dtype=float).reshape(-1, 7)
        return _rotations(numbers[:, 3:])[0], numbers[:, :3]

    def take(self, poses, order):
        return poses[0][order], poses[1][order]

    def stack(self, poses):
        return (np.array([r for r, _ in poses]).reshape(-1, 3, 3),
                np.array([t for _, t in poses]).reshape(-1, 3))

    def finite(self, pose):
        return bool(np.all(np.isfinite(pose[0])) and np.all(np.isfinite(pose[1])))

    def run(self, steps, chosen):
        poses = [(np.eye(3), np.zeros(3))]
        for index, inverted in chosen:
            poses.append(self.then(poses[-1], steps, index, inverted))
        return poses

    def then(self, pose, steps, index, inverted):
        r, t = steps[0][index], steps[1][index]
        if inverted:
            r_inverse, t_inverse = inverse3(r[None], t[None])
            r, t = r_inverse[0], t_inverse[0]
        r, t = compose3(pose[0][None], pose[1][None], r[None], t[None])
        return r[0], t[0]

    def gtsam_poses(self, poses):
        pose3, rot3 = gtsam.Pose3, gtsam.Rot3
        # a Rot3 from its nine numbers and a Pose3 from it: the cheapest calls into GTSAM
        return (pose3(rot3(*r), t)
                for r, t in zip(poses[0].reshape(-1, 9).tolist(), poses[1], strict=True))

    def values(self, keys, poses, vertex_text):
        values = gtsam.Values()
        insert = values.insert
        for key, pose in zip(keys.tolist(), self.gtsam_poses(poses), strict=True):
            insert(key, pose3=pose)  # pose3= passes over insert's other overloads
        return values

    def vertex_columns(self, values, count):
        poses = gtsam.utilities.extractPose3(values)  # by key: R row by row, then t
        if poses.shape != (count, 12) or not np.isfinite(poses).all():
            return None
        return _spatial_columns(poses[:, :9].reshape(-1, 3, 3), poses[:, 9:])

    def edge_columns(self, edges):
        measured = np.array(list(map(gtsam.Pose3.matrix,
                                     map(gtsam.BetweenFactorPose3.measured, edges))))
        measured = measured.reshape(-1, 4, 4)
        if not np.isfinite(measured).all():
            return None
        return _spatial_columns(measured[:, :3, :3], measured[:, :3, 3])

    def information_fields(self, models):
        fields = information_texts(models, 6, self._problems, _GTSAM_TO_G2O)
        return fields if fields is not None else _printed_texts(models)

    @staticmethod
    def _problems(matrices: np.ndarray) -> list[str | None]:
        return information_problems(matrices, SE3.max_condition)

    def vertex_line(self, key, pose):
        return f"VERTEX_SE3:QUAT {key} " + _pose_text(pose, f"vertex {key}")

    def edge_line(self, factor):
        i, j = factor.keys()
        model = gaussian_model(factor.noiseModel(), i, j)
        information = model.information()
        problem = information_problem(information, 6, SE3.max_condition)
        if problem is not None:
            printed, found = printed_informations(model.R()[None])
            if not found[0]:
                raise OutputError(f"edge {i}-{j}: {problem} (the reader would refuse it)")
            information = printed[0]  # GTSAM's factor of a printed indefinite matrix
        upper = information[_GTSAM_TO_G2O][:, _GTSAM_TO_G2O][_UPPER_6]
        return (f"EDGE_SE3:QUAT {i} {j} " + _pose_text(factor.measured(), f"edge {i}-{j}")
                + " " + " ".join(format_15(v) for v in upper))


_UPPER_6 = np.triu_indices(6)


def _rotations(quaternions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3, 3) the rotations of (k, 4) quaternions (qx, qy, qz, qw), each divided by its
    length first, and (k,) those lengths: the one computation both readers make, row by row
    alike whatever k."""
    q = np.asarray(quaternions, dtype=float).reshape(-1, 4)
    with np.errstate(all="ignore"):  # a zero or huge one is refused by the caller
        size = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2]
                       + q[:, 3] * q[:, 3])
        return quaternions_to_rotations(q / size[:, None]), size


def _spatial_columns(rotations: np.ndarray, translations: np.ndarray) -> list[list] | None:
    """The columns x, y, z and the quaternion's four texts of 3D poses; None if a quaternion
    is not finite."""
    quaternions = rotations_to_quaternions(rotations)
    if not np.isfinite(quaternions).all():
        return None
    return [*translations.T.tolist(), *[texts_15(column) for column in quaternions.T.tolist()]]


def _printed_texts(models: list) -> list[str] | None:
    """The 21 g2o fields of each Gaussian model's information where some are GTSAM's partial
    Cholesky factors of printed indefinite matrices (cubicle's, as ``gtsam.readG2o`` or the
    reader makes them): those are written as printed, so that the file reads back to the
    same models; None if a matrix is neither usable nor such a factor (the careful writer
    names it)."""
    distinct = list({id(model): model for model in models}.values())
    gaussian, constrained = gtsam.noiseModel.Gaussian, gtsam.noiseModel.Constrained
    if not all(isinstance(model, gaussian) and not isinstance(model, constrained)
               for model in distinct):
        return None
    matrices = np.array([model.information() for model in distinct]).reshape(-1, 6, 6)
    refused = [k for k, problem in enumerate(information_problems(matrices, SE3.max_condition))
               if problem is not None]
    printed, found = printed_informations(np.array([distinct[k].R() for k in refused]))
    if not found.all():
        return None
    matrices[refused] = printed
    texts = upper_triangle_texts(matrices[:, _GTSAM_TO_G2O][:, :, _GTSAM_TO_G2O], 6)
    text = {id(model): texts[k] for k, model in enumerate(distinct)}
    return [text[id(model)] for model in models]


def _pose_text(pose: gtsam.Pose3, name: str) -> str:
    # positions exactly; quaternions and the information with 15 significant digits, as the
    # planar writer: matrix -> quaternion and R^T R drift by an ulp, which 15 digits undo
    position = np.asarray(pose.translation(), float).tolist()
    quaternion = rotations_to_quaternions(pose.rotation().matrix())[0].tolist()
    if not all(math.isfinite(v) for v in position + quaternion):
        raise OutputError(f"{name} is not finite: the file would not read back")
    return " ".join([repr(float(v)) for v in position] + [format_15(v) for v in quaternion])


PLANAR: Format = _Planar()
SPATIAL: Format = _Spatial()
FORMATS: tuple[Format, ...] = (PLANAR, SPATIAL)


def format_of(group: Group) -> Format:
    """The g2o format of a pose group."""
    return next(form for form in FORMATS if form.group is group)


# --------------------------------------------------------------------------- landmark lines


@dataclass(frozen=True)
class PointLines:
    """The landmark lines of one pose group.

    Attributes:
        d: the points' dimension.
        vertex_tag, edge_tag: the tags the writer writes.
        tags: every landmark tag of the group (:func:`landmark_group`'s).
        point_name: GTSAM's point type, as messages name it.
        factor: GTSAM's bearing-range factor class.
    """

    d: int
    vertex_tag: str
    edge_tag: str
    tags: tuple[str, ...]
    point_name: str
    factor: Any

    def at(self, values: gtsam.Values) -> Any:
        """``values``' getter of this dimension's points."""
        return values.atPoint2 if self.d == 2 else values.atPoint3


POINT_LINES: dict[Group, PointLines] = {
    SE2: PointLines(2, "VERTEX_XY", "EDGE_SE2_XY",
                    ("VERTEX_XY", "EDGE_SE2_XY", "LANDMARK2", "BR", "LANDMARK"), "Point2",
                    gtsam.BearingRangeFactor2D),
    SE3: PointLines(3, "VERTEX_TRACKXYZ", "EDGE_SE3_TRACKXYZ",
                    ("VERTEX_TRACKXYZ", "EDGE_SE3_TRACKXYZ", "PARAMS_SE3OFFSET"), "Point3",
                    gtsam.BearingRangeFactor3D),
}


def landmark_group(tag: str) -> Group | None:
    """The pose group whose landmark tags hold ``tag`` (in any case, as the pose tags'
    prefixes are matched), or None."""
    upper = tag.upper()
    return next((group for group, lines in POINT_LINES.items() if upper in lines.tags), None)


