"""CORA's PyFG files, planar and 3D, read into GTSAM graphs and written from them, each error
naming its line.

PyFG is the text format of PyFactorGraph (``py_factor_graph/io/pyfg_text.py``, whose writer
and reader fix the layout of every line) and the input of CORA (``src/pyfg_text_parser.cpp``,
which reads the same lines; ``include/CORA/Measurements.h`` says in which order a
covariance is). The lines, one a line, fields separated by spaces::

    VERTEX_SE2 t name x y theta
    VERTEX_XY name x y                                        (no timestamp)
    VERTEX_SE2:PRIOR t name x y theta C_xx C_xy C_xt C_yy C_yt C_tt
    VERTEX_XY:PRIOR t name x y C_xx C_xy C_yy
    EDGE_SE2 t a b dx dy dtheta C_xx C_xy C_xt C_yy C_yt C_tt
    EDGE_SE2_XY t pose landmark dx dy C_xx C_xy C_yy

    VERTEX_SE3:QUAT t name x y z qx qy qz qw
    VERTEX_XYZ name x y z                                     (no timestamp)
    VERTEX_SE3:QUAT:PRIOR t name x y z qx qy qz qw C_11 C_12 ... C_66     (21 entries)
    VERTEX_XYZ:PRIOR t name x y z C_xx C_xy C_xz C_yy C_yz C_zz
    EDGE_SE3:QUAT t a b dx dy dz qx qy qz qw C_11 C_12 ... C_66           (21 entries)
    EDGE_SE3_XYZ t pose landmark dx dy dz C_xx C_xy C_xz C_yy C_yz C_zz

    EDGE_RANGE t a b range variance                           (either dimension)

``t`` is a timestamp (seconds; GTSAM has no use for it: it is kept and written back as read,
:class:`PyfgTimes`). A file is planar or 3D: its first line of either kind (any but
``EDGE_RANGE``) says which, as PyFactorGraph's reader tells a file's dimension from its
first line and CORA's from its first vertex line; a line of the other dimension is an error.

A quaternion is ``qx qy qz qw``, the scalar last (PyFactorGraph writes ``true_quat`` so,
CORA's ``readQuat`` builds ``Eigen::Quaterniond(qw, qx, qy, qz)``); it is divided by its
length, as the g2o reader does (:mod:`rlpgo_gtsam.io.formats`), and one of zero length is an
error. ``C`` is a covariance, not an information: its upper triangle row by row (the lower
one column by column, which PyFactorGraph calls column-major; CORA's ``readSymmetric`` reads
``(i, j >= i)``), in the order of the measurement's numbers. For a planar pose that is (x, y,
theta), GTSAM's ``Pose2`` tangent order, so the matrix becomes
``noiseModel.Gaussian.Covariance(C)`` as it is. For a 3D pose it is translation first, then
rotation (CORA's ``RelativePoseMeasurement::cov``, "in order of: translation, rotation";
PyFactorGraph's ``get_measurement_precisions_from_covariance_matrix`` in
``py_factor_graph/utils/matrix_utils.py`` takes ``C[:3, :3]`` as the translation's and
``C[3:, 3:]`` as the rotation's): g2o's order, so it is permuted to GTSAM's ``Pose3`` tangent
order (rotation first) as the g2o reader permutes an information
(:data:`~rlpgo_gtsam.io.formats.G2O_TO_GTSAM`), and the writer permutes it back.
``EDGE_RANGE``'s last number is the range's variance (PyFactorGraph's reader takes its
square root as the standard deviation).

Names are a letter and an index, ``A12`` (robot A, pose 12) or ``L0`` (landmark 0): CORA's
``Symbol`` reads a name as its first character and the number after it, in 8 + 56 bits, which
is GTSAM's ``Symbol`` layout, so a name's key is ``gtsam.symbol(letter, index)``, CORA's own
key for it, and ``gtsam.DefaultKeyFormatter`` prints the name back. The index is written
without leading zeros (``A012`` would come back ``A12``, so it is refused); letters keep their
case. What a name is, pose or landmark, its vertex line says.

What each line becomes, in file order (``lines[k]`` of :func:`read_pyfg_file` is the line of
factor ``k``):

- ``VERTEX_SE2`` a ``Pose2`` value, ``VERTEX_XY`` a ``Point2`` one; ``VERTEX_SE3:QUAT`` a
  ``Pose3``, ``VERTEX_XYZ`` a ``Point3``. PyFactorGraph writes its variables' true poses there
  and CORA ignores them; here they are the initial values, as a g2o file's vertex lines are;
- ``EDGE_SE2`` / ``EDGE_SE3:QUAT`` a ``BetweenFactorPose2`` / ``BetweenFactorPose3``;
  ``VERTEX_SE2:PRIOR`` / ``VERTEX_SE3:QUAT:PRIOR`` a ``PriorFactorPose2`` /
  ``PriorFactorPose3``; ``VERTEX_XY:PRIOR`` / ``VERTEX_XYZ:PRIOR`` a ``PriorFactorPoint2`` /
  ``PriorFactorPoint3``;
- ``EDGE_SE2_XY`` / ``EDGE_SE3_XYZ`` (the landmark in the pose's frame) a
  ``BearingRangeFactor2D`` / ``BearingRangeFactor3D``
  (:func:`~rlpgo_gtsam.landmarks.bearing_range_factor`, the information ``C^-1`` carried to
  bearing-range coordinates, exact to rounding);
- ``EDGE_RANGE`` between two poses a ``RangeFactorPose2`` / ``RangeFactorPose3``, between a
  pose and a landmark a ``RangeFactor2D`` / ``RangeFactor3D`` (pose first, as GTSAM's factor
  takes it: a line that names the landmark first is written back pose first), between two
  landmarks a ``RangeFactor2`` / ``RangeFactor3`` (which the relaxation does not model: LM
  refines it with the rest); noise ``Isotropic.Sigma(1, sqrt(variance))``.

Every name must have a vertex line (anywhere in the file), every vertex must be named by a
factor line (GTSAM's optimizers need each variable in a factor), an edge joins two different
variables of the kinds its tag says; a covariance must be positive definite, a quaternion
nonzero, a range at least 0, a variance above 0. Blank lines and lines starting with ``#``
are skipped (PyFG's own readers take neither: the writer writes none).

The writer writes the vertices first (poses, then landmarks, each by key: PyFactorGraph's
reader tells a file's dimension from its first line, which must be a pose vertex), then one
line per factor in graph order. Positions, ranges and timestamps are written exactly; angles,
quaternions, covariances and variances with 15 significant digits
(:func:`~rlpgo_gtsam.io.lines.format_15`), since GTSAM keeps an angle as (cos, sin), a
rotation as a matrix and a noise model as its square-root information: a file's own
decimals come back unchanged, but for a quaternion's (written with ``qw >= 0``, of unit
length), which through a rotation matrix and back can move in its 15th digit, as the g2o
writer's does. A key is written as its name: a symbol whose character is a letter as
``<letter><index>``; a plain integer key ``k`` (``chr`` 0, as
:func:`~rlpgo_gtsam.synthetic.generate` keys poses) as ``A<k>`` for a pose, robot A's, and
``L<k>`` for a landmark, as PyFactorGraph names them.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, GraphError, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.groups import SE2, SE3, Group, key_text
from rlpgo_gtsam.io.formats import G2O_TO_GTSAM, SPATIAL
from rlpgo_gtsam.io.lines import format_15, line_records, parse_numbers, short_token
from rlpgo_gtsam.landmarks import RANGE_FACTORS, bearing_range_factor, relative_point
from rlpgo_gtsam.se3 import rotations_to_quaternions

__all__ = ["PyfgFile", "PyfgTimes", "read_pyfg", "read_pyfg_file", "pyfg_group", "pyfg_text",
           "write_pyfg", "check_pyfg_graph", "pyfg_name", "PYFG_TAGS", "RANGE_FACTORS"]

# GTSAM keeps 56 bits of a symbol's index (CORA's Symbol too)
_INDEX_LIMIT = 2**56
_NAME = re.compile(r"[A-Za-z](0|[1-9][0-9]*)")
# a covariance entry this small against the largest diagonal one is a zero's rounding
_ZERO_ENTRY = 1e-13
_POSE, _POINT = "pose", "landmark"
# GTSAM's Pose3 tangent order (rotation first) -> PyFG's (translation first); its own inverse
_GTSAM_TO_PYFG = np.argsort(G2O_TO_GTSAM)


@dataclass(frozen=True)
class _Line:
    """The layout of one line kind: its fields after the tag."""

    dimension: int  # 2 or 3; 0: a line of either dimension (EDGE_RANGE)
    timestamp: bool
    names: int
    numbers: int  # the value's or the measurement's (a range's variance included)
    covariance: int  # the size of the covariance matrix after them (0: none)
    layout: str  # the fields, as a message shows them

    @property
    def fields(self) -> int:
        size = self.covariance
        return int(self.timestamp) + self.names + self.numbers + size * (size + 1) // 2


PYFG_TAGS: dict[str, _Line] = {
    "VERTEX_SE2": _Line(2, True, 1, 3, 0, "t name x y theta"),
    "VERTEX_XY": _Line(2, False, 1, 2, 0, "name x y"),
    "VERTEX_SE2:PRIOR": _Line(2, True, 1, 3, 3, "t name x y theta and 6 covariance entries"),
    "VERTEX_XY:PRIOR": _Line(2, True, 1, 2, 2, "t name x y and 3 covariance entries"),
    "EDGE_SE2": _Line(2, True, 2, 3, 3, "t a b dx dy dtheta and 6 covariance entries"),
    "EDGE_SE2_XY": _Line(2, True, 2, 2, 2, "t pose landmark dx dy and 3 covariance entries"),
    "VERTEX_SE3:QUAT": _Line(3, True, 1, 7, 0, "t name x y z qx qy qz qw"),
    "VERTEX_XYZ": _Line(3, False, 1, 3, 0, "name x y z"),
    "VERTEX_SE3:QUAT:PRIOR": _Line(3, True, 1, 7, 6, "t name x y z qx qy qz qw and 21 "
                                   "covariance entries"),
    "VERTEX_XYZ:PRIOR": _Line(3, True, 1, 3, 3, "t name x y z and 6 covariance entries"),
    "EDGE_SE3:QUAT": _Line(3, True, 2, 7, 6, "t a b dx dy dz qx qy qz qw and 21 covariance "
                           "entries"),
    "EDGE_SE3_XYZ": _Line(3, True, 2, 3, 3, "t pose landmark dx dy dz and 6 covariance "
                          "entries"),
    "EDGE_RANGE": _Line(0, True, 2, 2, 0, "t a b range variance"),
}
"""The PyFG lines this reader takes, by tag."""


@dataclass(frozen=True)
class _Dimension:
    """What PyFG and GTSAM call the variables and factors of one dimension."""

    group: Group
    kind: str  # as messages name it
    pose_vertex: str
    point_vertex: str
    pose_prior: str
    point_prior: str
    between: str
    point_edge: str
    pose_type: str  # GTSAM's value types, as messages name them
    point_type: str
    ranges: tuple[type, type, type]  # between two poses, a pose and a point, two points
    point_prior_factor: type
    bearing_range_factor: type
    pose_at: Callable[[gtsam.Values, int], Any]
    point_at: Callable[[gtsam.Values, int], Any]

    @property
    def tags(self) -> list[str]:
        return [tag for tag, form in PYFG_TAGS.items() if form.dimension in (0, self.dimension)]

    @property
    def dimension(self) -> int:
        return self.group.dimension

    @property
    def factors(self) -> tuple[type, ...]:
        """The GTSAM factors a file of this dimension has a line for."""
        return (*self.ranges, self.group.between_factor, self.group.prior_factor,
                self.point_prior_factor, self.bearing_range_factor)


_PLANAR = _Dimension(SE2, "planar", "VERTEX_SE2", "VERTEX_XY", "VERTEX_SE2:PRIOR",
                     "VERTEX_XY:PRIOR", "EDGE_SE2", "EDGE_SE2_XY", "Pose2", "Point2",
                     RANGE_FACTORS[:3],
                     gtsam.PriorFactorPoint2, gtsam.BearingRangeFactor2D,
                     gtsam.Values.atPose2, gtsam.Values.atPoint2)
_SPATIAL = _Dimension(SE3, "3D", "VERTEX_SE3:QUAT", "VERTEX_XYZ", "VERTEX_SE3:QUAT:PRIOR",
                      "VERTEX_XYZ:PRIOR", "EDGE_SE3:QUAT", "EDGE_SE3_XYZ", "Pose3", "Point3",
                      RANGE_FACTORS[3:],
                      gtsam.PriorFactorPoint3, gtsam.BearingRangeFactor3D,
                      gtsam.Values.atPose3, gtsam.Values.atPoint3)
_DIMENSIONS = {2: _PLANAR, 3: _SPATIAL}



@dataclass(frozen=True, eq=False)
class PyfgTimes:
    """The timestamps of a PyFG file, which GTSAM has no place for: the writer puts them back.

    Attributes:
        vertices: the timestamp of each pose's vertex line (``VERTEX_SE2`` or
            ``VERTEX_SE3:QUAT``), by key.
        factors: the timestamp of each factor's line, by factor index.
    """

    vertices: dict[int, float] = field(default_factory=dict)
    factors: tuple[float, ...] = ()

    def vertex(self, key: int) -> float:
        return self.vertices.get(key, 0.0)

    def factor(self, index: int) -> float:
        return self.factors[index] if index < len(self.factors) else 0.0


@dataclass(frozen=True, eq=False)
class PyfgFile:
    """A PyFG file as read (:func:`read_pyfg_file`).

    Attributes:
        graph, values: the GTSAM graph and the vertices' values (see the module docstring).
        lines: the file line (1-based) of each factor: ``lines[k]`` is ``graph.at(k)``'s.
        times: the timestamps, for :func:`pyfg_text` to write back.
        poses, landmarks: how many of each kind of vertex the file holds.
        group: the poses' group, SE2 (a planar file) or SE3 (a 3D one).
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    lines: list[int]
    times: PyfgTimes
    poses: int
    landmarks: int
    group: Group = SE2

    def count(self, kind: type) -> int:
        """How many factors of GTSAM class ``kind`` the graph holds."""
        return sum(isinstance(self.graph.at(k), kind) for k in range(self.graph.size()))


# --------------------------------------------------------------------------- reading


@dataclass
class _Vertex:
    key: int
    kind: str
    line: int
    used: bool = False


@dataclass
class _Record:
    line: int
    tag: str
    time: float
    names: list[str]
    numbers: list[float]
    covariance: np.ndarray | None  # in GTSAM's tangent order


def read_pyfg(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a planar or 3D PyFG file into a GTSAM factor graph and initial values (the
    vertices' values), as :func:`~rlpgo_gtsam.io.read_g2o` reads a g2o file.

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed (``file:line: reason``;
            a missing file is an :class:`~rlpgo_gtsam.errors.InputNotFoundError`).
    """
    read = read_pyfg_file(path)
    return read.graph, read.values


def pyfg_group(path: str | os.PathLike[str]) -> Group:
    """The pose group of the PyFG file at ``path``: SE3 if its first line of one dimension
    (any but ``EDGE_RANGE``) is a 3D line, else SE2. It reads up to that line only, as
    :func:`~rlpgo_gtsam.io.file_group` does for g2o: a later line of the other dimension is
    the reader's ``file:line`` error.

    Raises:
        G2oFormatError: the file is missing or unreadable, or a line before the first
            line of one dimension is (too long, binary, not UTF-8).
    """
    for _, tag, _ in line_records(Path(path), kind="PyFG"):
        form = PYFG_TAGS.get(tag)
        if form is not None and form.dimension:
            return _DIMENSIONS[form.dimension].group
    return SE2


def read_pyfg_file(path: str | os.PathLike[str]) -> PyfgFile:
    """:func:`read_pyfg`, with each factor's line, the file's timestamps and its group.

    Raises:
        G2oFormatError: as :func:`read_pyfg`.
    """
    path = Path(path)
    vertices: dict[str, _Vertex] = {}
    values = gtsam.Values()
    times: dict[int, float] = {}
    records: list[_Record] = []
    dimension: _Dimension | None = None
    first = (0, "")  # the line that told the file's dimension, and its tag
    for number, tag, fields in line_records(path, kind="PyFG"):
        form = _form(path, number, tag, dimension)
        if form.dimension and dimension is None:
            dimension, first = _DIMENSIONS[form.dimension], (number, tag)
        elif form.dimension and dimension is not None and form.dimension != dimension.dimension:
            raise G2oFormatError(path, number, f"{tag} is a {_DIMENSIONS[form.dimension].kind} "
                                 f"PyFG line; this file is {dimension.kind} ({first[1]} on "
                                 f"line {first[0]})")
        if len(fields) != form.fields:
            raise G2oFormatError(path, number, f"{tag} needs {form.fields} fields after the tag "
                                 f"({form.layout}), found {len(fields)}")
        record = _record(path, number, tag, form, fields)
        if dimension is not None and tag in (dimension.pose_vertex, dimension.point_vertex):
            name = record.names[0]
            if name in vertices:
                raise G2oFormatError(path, number, f"vertex {name} defined twice (first on "
                                     f"line {vertices[name].line})")
            key = _key(path, number, name)
            if tag == dimension.pose_vertex:
                values.insert(key, _pose(form, record.numbers))
                times[key] = record.time
            else:
                values.insert(key, np.array(record.numbers))
            vertices[name] = _Vertex(key, _POSE if tag == dimension.pose_vertex else _POINT,
                                     number)
        else:
            records.append(record)
    if dimension is None or not vertices:
        raise G2oFormatError(path, None, "holds no VERTEX_SE2 or VERTEX_XY line, nor a 3D one "
                             f"({_SPATIAL.pose_vertex}, {_SPATIAL.point_vertex}): not a PyFG "
                             "file")
    graph = gtsam.NonlinearFactorGraph()
    for record in records:
        graph.add(_factor(path, record, vertices, dimension))
    for name, vertex in vertices.items():
        if not vertex.used:
            tag = dimension.pose_vertex if vertex.kind == _POSE else dimension.point_vertex
            raise G2oFormatError(path, vertex.line, f"{tag} {name}: no factor line names it "
                                 "(GTSAM's optimizers need each variable in a factor)")
    poses = sum(vertex.kind == _POSE for vertex in vertices.values())
    return PyfgFile(graph, values, [record.line for record in records],
                    PyfgTimes(times, tuple(record.time for record in records)),
                    poses, len(vertices) - poses, dimension.group)


def _form(path: Path, line: int, tag: str, dimension: _Dimension | None) -> _Line:
    form = PYFG_TAGS.get(tag)
    if form is not None:
        return form
    known = (f"{dimension.kind} PyFG: {', '.join(dimension.tags)}" if dimension is not None
             else f"PyFG: {', '.join(PYFG_TAGS)}")
    raise G2oFormatError(path, line, f"unknown PyFG line '{short_token(tag)}' ({known})")


def _record(path: Path, line: int, tag: str, form: _Line, fields: list[str]) -> _Record:
    """The fields of one line, each checked: timestamp, names, numbers, quaternion,
    covariance."""
    at = 0
    time = 0.0
    if form.timestamp:
        time = parse_numbers(path, line, tag, fields[:1], 1)[0]
        at = 1
    names = fields[at:at + form.names]
    for position, name in enumerate(names, start=at + 1):
        if not _NAME.fullmatch(name):
            raise G2oFormatError(path, line, f"{tag} field {position} is not a PyFG name (a "
                                 f"letter and an index without leading zeros, A12 or L0): "
                                 f"'{short_token(name)}'")
    at += form.names
    numbers = parse_numbers(path, line, tag, fields[at:], at + 1)
    measured, rest = numbers[:form.numbers], numbers[form.numbers:]
    if form.numbers == 7:  # a 3D pose: x y z qx qy qz qw
        SPATIAL.check_pose(path, line, tag, measured)
    covariance = None
    if form.covariance:
        covariance = _symmetric(rest, form.covariance)
        try:
            np.linalg.cholesky(covariance)
        except np.linalg.LinAlgError:
            raise G2oFormatError(path, line, f"{tag} covariance is not positive definite "
                                 f"({' '.join(fields[at + form.numbers:])})") from None
        if form.covariance == 6:  # translation first in the file, rotation first in GTSAM
            covariance = covariance[G2O_TO_GTSAM][:, G2O_TO_GTSAM]
    if tag == "EDGE_RANGE":
        if measured[0] < 0:
            raise G2oFormatError(path, line, f"EDGE_RANGE range must be >= 0, found "
                                 f"{fields[at]}")
        if not measured[1] > 0:
            raise G2oFormatError(path, line, f"EDGE_RANGE variance must be positive, found "
                                 f"{fields[at + 1]}")
    return _Record(line, tag, time, names, measured, covariance)


def _pose(form: _Line, numbers: list[float]) -> Any:
    """The GTSAM pose of a line's numbers: planar (x, y, theta), or 3D (x, y, z, qx, qy, qz,
    qw) with the quaternion divided by its length (nonzero: :func:`_record`)."""
    if form.dimension == 2:
        return gtsam.Pose2(*numbers)
    rotations, translations = SPATIAL.poses(np.array(numbers))
    return gtsam.Pose3(gtsam.Rot3(rotations[0]), translations[0])


def _symmetric(entries: list[float], size: int) -> np.ndarray:
    """The symmetric matrix of its upper triangle, row by row."""
    matrix = np.zeros((size, size))
    rows, cols = np.triu_indices(size)
    matrix[rows, cols] = entries
    matrix[cols, rows] = entries
    return matrix


def _key(path: Path, line: int, name: str) -> int:
    index = int(name[1:])
    if index >= _INDEX_LIMIT:
        raise G2oFormatError(path, line, f"name {short_token(name)}: its index is too large "
                             "(GTSAM keys hold 56 bits of an index)")
    return int(gtsam.symbol(name[0], index))


def _factor(path: Path, record: _Record, vertices: dict[str, _Vertex],
            dimension: _Dimension) -> Any:
    """The GTSAM factor of one line, its names resolved to keys of the right kind."""
    tag, line = record.tag, record.line
    ends = []
    for name in record.names:
        vertex = vertices.get(name)
        if vertex is None:
            raise G2oFormatError(path, line, f"{tag} names {name}, which no vertex line "
                                 f"({dimension.pose_vertex}, {dimension.point_vertex}) "
                                 "defines")
        vertex.used = True
        ends.append(vertex)
    if len(ends) == 2 and ends[0] is ends[1]:
        raise G2oFormatError(path, line, f"{tag} joins {record.names[0]} to itself")
    wanted = {dimension.pose_prior: (_POSE,), dimension.point_prior: (_POINT,),
              dimension.between: (_POSE, _POSE), dimension.point_edge: (_POSE, _POINT)}.get(tag)
    if wanted is not None:
        for name, vertex, kind in zip(record.names, ends, wanted, strict=True):
            if vertex.kind != kind:
                raise G2oFormatError(path, line, f"{tag}: {name} is a {vertex.kind} (its vertex "
                                     f"is on line {vertex.line}); {tag} takes a {kind} there")
    numbers, covariance = record.numbers, record.covariance
    keys = [vertex.key for vertex in ends]
    if tag == "EDGE_RANGE":
        sigma = gtsam.noiseModel.Isotropic.Sigma(1, math.sqrt(numbers[1]))
        kinds = [vertex.kind for vertex in ends]
        between_poses, pose_point, between_points = dimension.ranges
        if kinds == [_POSE, _POSE]:
            return between_poses(keys[0], keys[1], numbers[0], sigma)
        if kinds == [_POINT, _POINT]:
            return between_points(keys[0], keys[1], numbers[0], sigma)
        pose, point = keys if kinds[0] == _POSE else keys[::-1]
        return pose_point(pose, point, numbers[0], sigma)
    assert covariance is not None  # every other factor line has one (PYFG_TAGS)
    if tag == dimension.point_edge:
        try:
            return bearing_range_factor(keys[0], keys[1], np.array(numbers),
                                        np.linalg.inv(covariance))
        except GraphError as error:
            raise G2oFormatError(path, line, f"{tag}: {error}") from None
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    form = PYFG_TAGS[tag]
    if tag == dimension.between:
        return dimension.group.between_factor(keys[0], keys[1], _pose(form, numbers), noise)
    if tag == dimension.pose_prior:
        return dimension.group.prior_factor(keys[0], _pose(form, numbers), noise)
    return dimension.point_prior_factor(keys[0], np.array(numbers), noise)


# --------------------------------------------------------------------------- writing


def pyfg_name(key: int, pose: bool) -> str:
    """The PyFG name of ``key``: ``<letter><index>`` for a symbol whose character is a
    letter; ``A<key>`` (a pose) or ``L<key>`` (a landmark) for a plain integer key.

    Raises:
        OutputError: a symbol whose character is not an ASCII letter.
    """
    symbol = gtsam.Symbol(int(key))
    letter = symbol.chr()
    if letter == 0:
        return f"{'A' if pose else 'L'}{int(key)}"
    if not chr(letter).isascii() or not chr(letter).isalpha():
        raise OutputError(f"key {key_text(key)}: a PyFG name is a letter and an index; this "
                          "key's character is not a letter")
    return f"{chr(letter)}{symbol.index()}"


def check_pyfg_graph(graph: gtsam.NonlinearFactorGraph) -> None:
    """Raise the :class:`~rlpgo_gtsam.errors.OutputError` that :func:`pyfg_text` would raise
    for a factor of ``graph`` (its kind, its dimension or its noise model), without writing
    anything: what a command checks before its work.

    Raises:
        OutputError: the first factor a PyFG file cannot hold.
    """
    dimension = _graph_dimension(graph)
    for index in range(graph.size()):
        factor = graph.at(index)
        if factor is not None:
            _noise(index, factor, dimension)


def pyfg_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              times: PyfgTimes | None = None) -> str:
    """The PyFG text of a planar or 3D ``graph`` and its ``values`` (see the module
    docstring), with the timestamps of ``times`` (0 where it has none): what
    :func:`write_pyfg` writes.

    Raises:
        OutputError: a factor, noise model or value that a PyFG file cannot hold (a robust
            or constrained noise model, planar and 3D variables together, a variable that no
            factor names), or two keys that would have the same name.
    """
    times = times or PyfgTimes()
    dimension = _values_dimension(values) or _graph_dimension(graph)
    names, poses, points = _names(values, dimension)
    used: set[int] = set()
    factor_lines = []
    for index in range(graph.size()):
        factor = graph.at(index)
        if factor is None:
            continue
        keys = [int(key) for key in factor.keys()]
        for key in keys:
            if key not in names:
                raise OutputError(f"factor {index} ({_describe(factor)}): key {key_text(key)} "
                                  f"has no {dimension.pose_type} or {dimension.point_type} "
                                  "value")
        used.update(keys)
        factor_lines.append(_factor_line(index, factor, [names[key] for key in keys],
                                         times.factor(index), dimension))
    unused = [key for key in names if key not in used]
    if unused:
        raise OutputError(f"value {key_text(unused[0])} is named by no factor: a PyFG reader "
                          "refuses a variable that nothing measures")
    lines = [f"{dimension.pose_vertex} {_exact(times.vertex(key))} {names[key]} "
             f"{_pose_text(pose, f'value {key_text(key)}')}" for key, pose in poses]
    lines += [f"{dimension.point_vertex} {names[key]} {' '.join(map(_exact, point))}"
              for key, point in points]
    return "\n".join(lines + factor_lines) + "\n"


def write_pyfg(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
               values: gtsam.Values, times: PyfgTimes | None = None) -> None:
    """Write ``graph`` and ``values`` as a PyFG file (:func:`pyfg_text`), atomically: the
    text goes to a temporary file beside ``path`` that then replaces it, so a failed write
    leaves any existing file untouched. :func:`read_pyfg` reads back the same graph (the same
    error to rounding) and the same values (3D rotations to rounding).

    Raises:
        OutputError: as :func:`pyfg_text`, or ``path`` cannot be written.
    """
    write_text(path, pyfg_text(graph, values, times))


def _value_kind(values: gtsam.Values, key: int, first: _Dimension = _PLANAR
                ) -> tuple[_Dimension, bool, Any] | None:
    """The dimension of the value at ``key``, whether it is a pose, and the value (its types
    in ``first`` tried first); None for a value of no PyFG kind."""
    for dimension in (first, *(other for other in _DIMENSIONS.values() if other is not first)):
        for pose, read in ((True, dimension.pose_at), (False, dimension.point_at)):
            try:
                value = read(values, key)
            except RuntimeError:
                continue
            return dimension, pose, value
    return None


def _values_dimension(values: gtsam.Values) -> _Dimension | None:
    """The dimension of the first value of a PyFG kind (None: no such value)."""
    for key in map(int, values.keys()):
        kind = _value_kind(values, key)
        if kind is not None:
            return kind[0]
    return None


def _graph_dimension(graph: gtsam.NonlinearFactorGraph) -> _Dimension:
    """The dimension of the first factor a PyFG file of one dimension holds (planar if
    none)."""
    for index in range(graph.size()):
        factor = graph.at(index)
        for dimension in _DIMENSIONS.values():
            if isinstance(factor, dimension.factors):
                return dimension
    return _PLANAR


def _names(values: gtsam.Values, dimension: _Dimension
           ) -> tuple[dict[int, str], list[tuple[int, Any]], list[tuple[int, np.ndarray]]]:
    """Each value's name, and the poses and the points by key."""
    names: dict[int, str] = {}
    poses, points = [], []
    taken: dict[str, int] = {}
    kinds = f"{dimension.pose_type} or {dimension.point_type}"
    for key in map(int, values.keys()):
        kind = _value_kind(values, key, dimension)
        if kind is None:
            raise OutputError(f"value {key_text(key)} is neither a {dimension.pose_type} nor "
                              f"a {dimension.point_type}: a {dimension.kind} PyFG file holds "
                              "those")
        if kind[0] is not dimension:
            raise OutputError(f"value {key_text(key)} is a "
                              f"{kind[0].pose_type if kind[1] else kind[0].point_type} among "
                              f"{kinds} values: a PyFG file is planar or 3D")
        pose = kind[1]
        if pose:
            poses.append((key, kind[2]))
        else:
            points.append((key, np.asarray(kind[2], float)))
        name = pyfg_name(key, pose)
        if name in taken:
            raise OutputError(f"keys {key_text(taken[name])} and {key_text(key)} would both be "
                              f"written as {name}")
        taken[name] = key
        names[key] = name
    return names, poses, points


def _factor_line(index: int, factor: Any, names: list[str], time: float,
                 dimension: _Dimension) -> str:
    stamp = _exact(time)
    covariance = _noise(index, factor, dimension)
    ends = " ".join(names)
    kind = type(factor)  # tested by issubclass: isinstance would narrow factor to object
    if issubclass(kind, RANGE_FACTORS):
        return (f"EDGE_RANGE {stamp} {ends} {_exact(factor.measured())} "
                f"{format_15(float(covariance[0, 0]))}")
    describe = f"factor {index} ({_describe(factor)})"
    if issubclass(kind, dimension.group.between_factor):
        return (f"{dimension.between} {stamp} {ends} {_pose_text(factor.measured(), describe)} "
                f"{_upper(_file_order(covariance))}")
    if issubclass(kind, dimension.group.prior_factor):
        return (f"{dimension.pose_prior} {stamp} {ends} {_pose_text(factor.prior(), describe)} "
                f"{_upper(_file_order(covariance))}")
    if issubclass(kind, dimension.point_prior_factor):
        position = np.asarray(factor.prior(), np.float64)
        return (f"{dimension.point_prior} {stamp} {ends} {' '.join(map(_exact, position))} "
                f"{_upper(covariance)}")
    point, information = relative_point(factor)  # a bearing-range factor (_noise)
    return (f"{dimension.point_edge} {stamp} {ends} {' '.join(map(format_15, point))} "
            f"{_upper(np.linalg.inv(information))}")


def _noise(index: int, factor: Any, dimension: _Dimension) -> np.ndarray:
    """The covariance of a factor a PyFG line holds (in GTSAM's tangent order), or the error
    that names it."""
    if not issubclass(type(factor), dimension.factors):
        raise OutputError(f"factor {index} ({_describe(factor)}): a {dimension.kind} PyFG file "
                          "has no line for it")
    model: Any = factor.noiseModel()
    if isinstance(model, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
        raise OutputError(f"factor {index} ({_describe(factor)}): a {type(model).__name__} "
                          "noise model; a PyFG line holds a Gaussian covariance")
    inverse = np.linalg.inv(np.asarray(model.R(), np.float64))  # Sigma = R^-1 R^-T
    return inverse @ inverse.T


def _file_order(covariance: np.ndarray) -> np.ndarray:
    """A pose covariance in PyFG's order: a Pose3's translation first (a Pose2's as it is)."""
    if len(covariance) != 6:
        return covariance
    return covariance[_GTSAM_TO_PYFG][:, _GTSAM_TO_PYFG]


def _pose_text(pose: Any, name: str) -> str:
    """A pose's numbers: positions exactly; the angle or the quaternion (``qw >= 0``) with
    15 significant digits."""
    if isinstance(pose, gtsam.Pose2):
        numbers = [_exact(pose.x()), _exact(pose.y()), format_15(pose.theta())]
    else:
        quaternion = rotations_to_quaternions(pose.rotation().matrix())[0]
        numbers = [*map(_exact, np.asarray(pose.translation(), float)),
                   *map(format_15, quaternion)]
    if not all(math.isfinite(float(number)) for number in numbers):
        raise OutputError(f"{name} is not finite: the file would not read back")
    return " ".join(numbers)


def _upper(covariance: np.ndarray) -> str:
    """The upper triangle, row by row, each entry with 15 significant digits; an off-diagonal
    entry that is a zero's rounding written as 0."""
    scale = float(np.max(np.abs(np.diag(covariance))))
    rows, cols = np.triu_indices(len(covariance))
    entries = covariance[rows, cols]
    entries = np.where((rows != cols) & (np.abs(entries) < _ZERO_ENTRY * scale), 0.0, entries)
    return " ".join(format_15(float(entry)) for entry in entries)


def _exact(value: float) -> str:
    return repr(float(value))


def _describe(factor: Any) -> str:
    return f"{type(factor).__name__} on {' '.join(key_text(k) for k in factor.keys())}"
