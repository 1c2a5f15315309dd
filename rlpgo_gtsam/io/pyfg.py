"""CORA's PyFG files (planar) read into GTSAM graphs and written from them, each error naming
its line.

PyFG is the text format of PyFactorGraph (``py_factor_graph/io/pyfg_text.py``, whose writer
and reader fix the layout of every line) and the input of CORA (``src/pyfg_text_parser.cpp``,
which reads the same lines). The planar lines, one a line, fields separated by spaces::

    VERTEX_SE2 t name x y theta
    VERTEX_XY name x y                                        (no timestamp)
    VERTEX_SE2:PRIOR t name x y theta C_xx C_xy C_xt C_yy C_yt C_tt
    VERTEX_XY:PRIOR t name x y C_xx C_xy C_yy
    EDGE_SE2 t a b dx dy dtheta C_xx C_xy C_xt C_yy C_yt C_tt
    EDGE_SE2_XY t pose landmark dx dy C_xx C_xy C_yy
    EDGE_RANGE t a b range variance

``t`` is a timestamp (seconds; GTSAM has no use for it: it is kept and written back as read,
:class:`PyfgTimes`). ``C`` is a covariance, not an information: its upper triangle row by
row (the lower one column by column, which PyFactorGraph calls column-major; CORA's
``readSymmetric`` reads ``(i, j >= i)``), in the order of the measurement's numbers, (x, y,
theta) for a pose: GTSAM's ``Pose2`` tangent order, so it becomes
``noiseModel.Gaussian.Covariance(C)`` as it is. ``EDGE_RANGE``'s last number is the range's
variance (PyFactorGraph's reader takes its square root as the standard deviation).

Names are a letter and an index, ``A12`` (robot A, pose 12) or ``L0`` (landmark 0): CORA's
``Symbol`` reads a name as its first character and the number after it, in 8 + 56 bits, which
is GTSAM's ``Symbol`` layout, so a name's key is ``gtsam.symbol(letter, index)``, CORA's own
key for it, and ``gtsam.DefaultKeyFormatter`` prints the name back. The index is written
without leading zeros (``A012`` would come back ``A12``, so it is refused); letters keep their
case. What a name is, pose or landmark, its vertex line says.

What each line becomes, in file order (``lines[k]`` of :func:`read_pyfg_file` is the line of
factor ``k``):

- ``VERTEX_SE2`` a ``Pose2`` value, ``VERTEX_XY`` a ``Point2`` one. PyFactorGraph writes its
  variables' true poses there and CORA ignores them; here they are the initial values, as a
  g2o file's vertex lines are;
- ``EDGE_SE2`` a ``BetweenFactorPose2``; ``VERTEX_SE2:PRIOR`` a ``PriorFactorPose2``;
  ``VERTEX_XY:PRIOR`` a ``PriorFactorPoint2``;
- ``EDGE_SE2_XY`` (the landmark in the pose's frame) a ``BearingRangeFactor2D``
  (:func:`~rlpgo_gtsam.landmarks.bearing_range_factor`, the information ``C^-1`` carried to
  bearing-range coordinates, exact to rounding);
- ``EDGE_RANGE`` between two poses a ``RangeFactorPose2``, between a pose and a landmark a
  ``RangeFactor2D`` (pose first, as GTSAM's factor takes it: a line that names the landmark
  first is written back pose first), between two landmarks a ``RangeFactor2`` (which the
  relaxation does not model: LM refines it with the rest); noise
  ``Isotropic.Sigma(1, sqrt(variance))``.

Every name must have a vertex line (anywhere in the file), every vertex must be named by a
factor line (GTSAM's optimizers need each variable in a factor), an edge joins two different
variables of the kinds its tag says; a covariance must be positive definite, a range at least
0, a variance above 0. Blank lines and lines starting with ``#`` are skipped (PyFG's own
readers take neither: the writer writes none). 3D lines (``VERTEX_SE3:QUAT``,
``EDGE_SE3:QUAT``, ``VERTEX_XYZ``, ...) are refused by name: this reader is planar.

The writer writes the vertices first (poses, then landmarks, each by key: PyFactorGraph's
reader tells a file's dimension from its first line, which must be ``VERTEX_SE2``), then one
line per factor in graph order. Positions, ranges and timestamps are written exactly; angles,
covariances and variances with 15 significant digits
(:func:`~rlpgo_gtsam.io.lines.format_15`), since GTSAM keeps an angle as (cos, sin) and a noise
model as its square-root information: a file's own decimals come back unchanged. A key is
written as its name: a symbol whose character is a letter as ``<letter><index>``; a plain
integer key ``k`` (``chr`` 0, as :func:`~rlpgo_gtsam.synthetic.generate` keys poses) as
``A<k>`` for a pose, robot A's, and ``L<k>`` for a landmark, as PyFactorGraph names them.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, GraphError, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.groups import key_text
from rlpgo_gtsam.io.lines import format_15, line_records, parse_numbers, short_token
from rlpgo_gtsam.landmarks import bearing_range_factor, relative_point

__all__ = ["PyfgFile", "PyfgTimes", "read_pyfg", "read_pyfg_file", "pyfg_text", "write_pyfg",
           "check_pyfg_graph", "pyfg_name", "PYFG_TAGS", "RANGE_FACTORS"]

# the range factors a PyFG file holds, each an EDGE_RANGE line
RANGE_FACTORS = (gtsam.RangeFactor2D, gtsam.RangeFactorPose2, gtsam.RangeFactor2)
# GTSAM keeps 56 bits of a symbol's index (CORA's Symbol too)
_INDEX_LIMIT = 2**56
_NAME = re.compile(r"[A-Za-z](0|[1-9][0-9]*)")
# a covariance entry this small against the largest diagonal one is a zero's rounding
_ZERO_ENTRY = 1e-13
_POSE, _POINT = "pose", "landmark"


@dataclass(frozen=True)
class _Line:
    """The layout of one planar line kind: its fields after the tag."""

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
    "VERTEX_SE2": _Line(True, 1, 3, 0, "t name x y theta"),
    "VERTEX_XY": _Line(False, 1, 2, 0, "name x y"),
    "VERTEX_SE2:PRIOR": _Line(True, 1, 3, 3, "t name x y theta and 6 covariance entries"),
    "VERTEX_XY:PRIOR": _Line(True, 1, 2, 2, "t name x y and 3 covariance entries"),
    "EDGE_SE2": _Line(True, 2, 3, 3, "t a b dx dy dtheta and 6 covariance entries"),
    "EDGE_SE2_XY": _Line(True, 2, 2, 2, "t pose landmark dx dy and 3 covariance entries"),
    "EDGE_RANGE": _Line(True, 2, 2, 0, "t a b range variance"),
}
"""The planar PyFG lines this reader takes, by tag."""
# PyFG's 3D tags (PyFactorGraph's writer, CORA's parser): named when refused
_SPATIAL_TAGS = ("VERTEX_SE3:QUAT", "VERTEX_SE3:QUAT:PRIOR", "VERTEX_XYZ", "VERTEX_XYZ:PRIOR",
                 "EDGE_SE3:QUAT", "EDGE_SE3_XYZ")


@dataclass(frozen=True, eq=False)
class PyfgTimes:
    """The timestamps of a PyFG file, which GTSAM has no place for: the writer puts them back.

    Attributes:
        vertices: the timestamp of each pose's ``VERTEX_SE2`` line, by key.
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
    """

    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    lines: list[int]
    times: PyfgTimes
    poses: int
    landmarks: int

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
    covariance: np.ndarray | None


def read_pyfg(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a planar PyFG file into a GTSAM factor graph and initial values (the vertices'
    values), as :func:`~rlpgo_gtsam.io.read_g2o` reads a g2o file.

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed (``file:line: reason``;
            a missing file is an :class:`~rlpgo_gtsam.errors.InputNotFoundError`).
    """
    read = read_pyfg_file(path)
    return read.graph, read.values


def read_pyfg_file(path: str | os.PathLike[str]) -> PyfgFile:
    """:func:`read_pyfg`, with each factor's line and the file's timestamps.

    Raises:
        G2oFormatError: as :func:`read_pyfg`.
    """
    path = Path(path)
    vertices: dict[str, _Vertex] = {}
    values = gtsam.Values()
    times: dict[int, float] = {}
    records: list[_Record] = []
    for number, tag, fields in line_records(path, kind="PyFG"):
        form = _form(path, number, tag)
        if len(fields) != form.fields:
            raise G2oFormatError(path, number, f"{tag} needs {form.fields} fields after the tag "
                                 f"({form.layout}), found {len(fields)}")
        record = _record(path, number, tag, form, fields)
        if tag in ("VERTEX_SE2", "VERTEX_XY"):
            name = record.names[0]
            if name in vertices:
                raise G2oFormatError(path, number, f"vertex {name} defined twice (first on "
                                     f"line {vertices[name].line})")
            key = _key(path, number, name)
            if tag == "VERTEX_SE2":
                x, y, theta = record.numbers
                values.insert(key, gtsam.Pose2(x, y, theta))
                times[key] = record.time
            else:
                values.insert(key, gtsam.Point2(*record.numbers))
            vertices[name] = _Vertex(key, _POSE if tag == "VERTEX_SE2" else _POINT, number)
        else:
            records.append(record)
    if not vertices:
        raise G2oFormatError(path, None, "holds no VERTEX_SE2 or VERTEX_XY line: not a planar "
                             "PyFG file")
    graph = gtsam.NonlinearFactorGraph()
    for record in records:
        graph.add(_factor(path, record, vertices))
    for name, vertex in vertices.items():
        if not vertex.used:
            tag = "VERTEX_SE2" if vertex.kind == _POSE else "VERTEX_XY"
            raise G2oFormatError(path, vertex.line, f"{tag} {name}: no factor line names it "
                                 "(GTSAM's optimizers need each variable in a factor)")
    poses = sum(vertex.kind == _POSE for vertex in vertices.values())
    return PyfgFile(graph, values, [record.line for record in records],
                    PyfgTimes(times, tuple(record.time for record in records)),
                    poses, len(vertices) - poses)


def _form(path: Path, line: int, tag: str) -> _Line:
    form = PYFG_TAGS.get(tag)
    if form is not None:
        return form
    if tag in _SPATIAL_TAGS:
        raise G2oFormatError(path, line, f"{tag} is a 3D PyFG line; this reader is planar "
                             f"({', '.join(PYFG_TAGS)})")
    raise G2oFormatError(path, line, f"unknown PyFG line '{short_token(tag)}' (planar PyFG: "
                         f"{', '.join(PYFG_TAGS)})")


def _record(path: Path, line: int, tag: str, form: _Line, fields: list[str]) -> _Record:
    """The fields of one line, each checked: timestamp, names, numbers, covariance."""
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
    covariance = None
    if form.covariance:
        covariance = _symmetric(rest, form.covariance)
        try:
            np.linalg.cholesky(covariance)
        except np.linalg.LinAlgError:
            raise G2oFormatError(path, line, f"{tag} covariance is not positive definite "
                                 f"({' '.join(fields[at + form.numbers:])})") from None
    if tag == "EDGE_RANGE":
        if measured[0] < 0:
            raise G2oFormatError(path, line, f"EDGE_RANGE range must be >= 0, found "
                                 f"{fields[at]}")
        if not measured[1] > 0:
            raise G2oFormatError(path, line, f"EDGE_RANGE variance must be positive, found "
                                 f"{fields[at + 1]}")
    return _Record(line, tag, time, names, measured, covariance)


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


def _factor(path: Path, record: _Record, vertices: dict[str, _Vertex]) -> Any:
    """The GTSAM factor of one line, its names resolved to keys of the right kind."""
    tag, line = record.tag, record.line
    ends = []
    for name in record.names:
        vertex = vertices.get(name)
        if vertex is None:
            raise G2oFormatError(path, line, f"{tag} names {name}, which no vertex line "
                                 "(VERTEX_SE2, VERTEX_XY) defines")
        vertex.used = True
        ends.append(vertex)
    if len(ends) == 2 and ends[0] is ends[1]:
        raise G2oFormatError(path, line, f"{tag} joins {record.names[0]} to itself")
    wanted = {"VERTEX_SE2:PRIOR": (_POSE,), "VERTEX_XY:PRIOR": (_POINT,),
              "EDGE_SE2": (_POSE, _POSE), "EDGE_SE2_XY": (_POSE, _POINT)}.get(tag)
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
        if kinds == [_POSE, _POSE]:
            return gtsam.RangeFactorPose2(keys[0], keys[1], numbers[0], sigma)
        if kinds == [_POINT, _POINT]:
            return gtsam.RangeFactor2(keys[0], keys[1], numbers[0], sigma)
        pose, point = keys if kinds[0] == _POSE else keys[::-1]
        return gtsam.RangeFactor2D(pose, point, numbers[0], sigma)
    assert covariance is not None  # every other factor line has one (PYFG_TAGS)
    if tag == "EDGE_SE2_XY":
        try:
            return bearing_range_factor(keys[0], keys[1], np.array(numbers),
                                        np.linalg.inv(covariance))
        except GraphError as error:
            raise G2oFormatError(path, line, f"EDGE_SE2_XY: {error}") from None
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    if tag == "EDGE_SE2":
        return gtsam.BetweenFactorPose2(keys[0], keys[1], gtsam.Pose2(*numbers), noise)
    if tag == "VERTEX_SE2:PRIOR":
        return gtsam.PriorFactorPose2(keys[0], gtsam.Pose2(*numbers), noise)
    return gtsam.PriorFactorPoint2(keys[0], gtsam.Point2(*numbers), noise)


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
    for a factor of ``graph`` (its kind or its noise model), without writing anything: what a
    command checks before its work.

    Raises:
        OutputError: the first factor a PyFG file cannot hold.
    """
    for index in range(graph.size()):
        factor = graph.at(index)
        if factor is not None:
            _noise(index, factor)


def pyfg_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              times: PyfgTimes | None = None) -> str:
    """The PyFG text of a planar ``graph`` and its ``values`` (see the module docstring), with
    the timestamps of ``times`` (0 where it has none): what :func:`write_pyfg` writes.

    Raises:
        OutputError: a factor, noise model or value that a PyFG file cannot hold (a 3D graph,
            a robust or constrained noise model, a variable that no factor names), or two
            keys that would have the same name.
    """
    times = times or PyfgTimes()
    names, poses, points = _names(values)
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
                                  "has no Pose2 or Point2 value")
        used.update(keys)
        factor_lines.append(_factor_line(index, factor, [names[key] for key in keys],
                                         times.factor(index)))
    unused = [key for key in names if key not in used]
    if unused:
        raise OutputError(f"value {key_text(unused[0])} is named by no factor: a PyFG reader "
                          "refuses a variable that nothing measures")
    lines = [f"VERTEX_SE2 {_exact(times.vertex(key))} {names[key]} {_exact(pose.x())} "
             f"{_exact(pose.y())} {format_15(pose.theta())}" for key, pose in poses]
    lines += [f"VERTEX_XY {names[key]} {_exact(point[0])} {_exact(point[1])}"
              for key, point in points]
    return "\n".join(lines + factor_lines) + "\n"


def write_pyfg(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
               values: gtsam.Values, times: PyfgTimes | None = None) -> None:
    """Write ``graph`` and ``values`` as a PyFG file (:func:`pyfg_text`), atomically: the
    text goes to a temporary file beside ``path`` that then replaces it, so a failed write
    leaves any existing file untouched. :func:`read_pyfg` reads back the same graph (the same
    error to rounding) and the same values.

    Raises:
        OutputError: as :func:`pyfg_text`, or ``path`` cannot be written.
    """
    write_text(path, pyfg_text(graph, values, times))


def _names(values: gtsam.Values
           ) -> tuple[dict[int, str], list[tuple[int, Any]], list[tuple[int, np.ndarray]]]:
    """Each value's name, and the poses and the points by key."""
    names: dict[int, str] = {}
    poses, points = [], []
    taken: dict[str, int] = {}
    for key in map(int, values.keys()):
        try:
            poses.append((key, values.atPose2(key)))
            pose = True
        except RuntimeError:
            try:
                points.append((key, np.asarray(values.atPoint2(key), float)))
            except RuntimeError:
                raise OutputError(f"value {key_text(key)} is neither a Pose2 nor a Point2: a "
                                  "planar PyFG file holds those") from None
            pose = False
        name = pyfg_name(key, pose)
        if name in taken:
            raise OutputError(f"keys {key_text(taken[name])} and {key_text(key)} would both be "
                              f"written as {name}")
        taken[name] = key
        names[key] = name
    return names, poses, points


def _factor_line(index: int, factor: Any, names: list[str], time: float) -> str:
    stamp = _exact(time)
    covariance = _noise(index, factor)
    if isinstance(factor, RANGE_FACTORS):
        return (f"EDGE_RANGE {stamp} {names[0]} {names[1]} {_exact(factor.measured())} "
                f"{format_15(float(covariance[0, 0]))}")
    if isinstance(factor, gtsam.BetweenFactorPose2):
        measured = factor.measured()
        return (f"EDGE_SE2 {stamp} {names[0]} {names[1]} {_exact(measured.x())} "
                f"{_exact(measured.y())} {format_15(measured.theta())} {_upper(covariance)}")
    if isinstance(factor, gtsam.PriorFactorPose2):
        prior = factor.prior()
        return (f"VERTEX_SE2:PRIOR {stamp} {names[0]} {_exact(prior.x())} {_exact(prior.y())} "
                f"{format_15(prior.theta())} {_upper(covariance)}")
    if isinstance(factor, gtsam.PriorFactorPoint2):
        position = np.asarray(factor.prior(), np.float64)
        return (f"VERTEX_XY:PRIOR {stamp} {names[0]} {_exact(position[0])} {_exact(position[1])} "
                f"{_upper(covariance)}")
    point, information = relative_point(factor)  # a BearingRangeFactor2D (_noise)
    return (f"EDGE_SE2_XY {stamp} {names[0]} {names[1]} {format_15(point[0])} "
            f"{format_15(point[1])} {_upper(np.linalg.inv(information))}")


_WRITTEN = (*RANGE_FACTORS, gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2,
            gtsam.PriorFactorPoint2, gtsam.BearingRangeFactor2D)


def _noise(index: int, factor: Any) -> np.ndarray:
    """The covariance of a factor a PyFG line holds, or the error that names it."""
    if not isinstance(factor, _WRITTEN):
        raise OutputError(f"factor {index} ({_describe(factor)}): a planar PyFG file has no "
                          "line for it")
    model: Any = factor.noiseModel()
    if isinstance(model, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
        raise OutputError(f"factor {index} ({_describe(factor)}): a {type(model).__name__} "
                          "noise model; a PyFG line holds a Gaussian covariance")
    inverse = np.linalg.inv(np.asarray(model.R(), np.float64))  # Sigma = R^-1 R^-T
    return inverse @ inverse.T


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
