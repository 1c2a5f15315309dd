"""Reading a g2o file of either pose group into a GTSAM graph and values.

:func:`read_table` reads the file into a :class:`~rlpgo_gtsam.io.formats.Table`: by the fast
reader (:func:`~rlpgo_gtsam.io.scan.scan`) where it takes the file, else by the careful one
(:func:`parse`), line by line, which raises a :class:`~rlpgo_gtsam.errors.G2oFormatError`
naming the first bad line. :func:`build` then makes the checks across lines (undefined
vertices, FIX ids, connectivity), the chained initial guess of a file without vertices, and
the GTSAM graph: one noise model per distinct information matrix, one between factor per
edge line, one bearing-range factor per landmark measurement, one constrained prior per
FIXed id (the first FIXed pose is the anchor; a held pose adds nothing to chi2). What the
format's information rule changed is told in an
:class:`~rlpgo_gtsam.errors.InformationWarning` per file and kind (:func:`warn_changes`).

The landmark lines (:data:`~rlpgo_gtsam.io.formats.POINT_LINES`; :mod:`rlpgo_gtsam.io` says
how each reads) only the careful reader reads: the fast one hands any file with them over.
"""

from __future__ import annotations

import itertools
import math
import os
import stat
import warnings
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, InformationWarning
from rlpgo_gtsam.graph import disconnection
from rlpgo_gtsam.groups import GROUPS, SE2, Group
from rlpgo_gtsam.information import (
    INDEFINITE,
    LIFTED,
    MAX_CONDITION_3D,
    ROUNDING_3D,
    information_problem,
)
from rlpgo_gtsam.io.formats import (
    POINT_LINES,
    SPATIAL,
    Landmarks,
    Table,
    format_of,
    landmark_group,
)
from rlpgo_gtsam.io.lines import (
    LineSource,
    line_records,
    open_g2o,
    parse_fix,
    parse_id,
    parse_numbers,
    short_token,
)
from rlpgo_gtsam.io.scan import scan
from rlpgo_gtsam.landmarks import bearing_range_factor, landmark_key

if TYPE_CHECKING:
    from rlpgo_gtsam.io.formats import Format

__all__ = ["read_file", "read_table", "group_of_lines", "parse", "build", "warn_changes",
           "warn_landmark_changes",
           "check_references"]


def read_file(path: Path) -> tuple[Format, Table]:
    """The format of the file at ``path`` (:func:`group_of_lines`) and its table, as
    :func:`read_table` reads it; the file is opened once (a pipe is read once)."""
    with open_g2o(path) as handle:
        if stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            form = format_of(group_of_lines(line_records(path, handle)))
            handle.seek(0)
            return form, _read_open(path, handle, form, True)
        recorded = _Recorded(handle)
        form = format_of(group_of_lines(line_records(path, recorded)))
        recorded.replaying = True
        return form, parse(path, recorded, form)


def read_table(path: Path, form: Format, fast: bool = True) -> Table:
    """The table of the file at ``path``, a file of ``form``: by the fast reader where it
    takes the file (``fast``, a regular file), else by the careful one on the same open file
    (a pipe or device is read once, by the careful reader)."""
    with open_g2o(path) as handle:
        return _read_open(path, handle, form,
                          fast and stat.S_ISREG(os.fstat(handle.fileno()).st_mode))


def _read_open(path: Path, handle: BinaryIO, form: Format, fast: bool) -> Table:
    if fast:
        table = scan(handle, form)
        if table is not None:
            return table
        handle.seek(0)
    return parse(path, handle, form)


def group_of_lines(records: Iterator[tuple[int, str, list[str]]]) -> Group:
    """The pose group of a g2o file's lines (:func:`~rlpgo_gtsam.io.lines.line_records`):
    the one whose tags start its first pose or landmark line, else SE2. It reads up to that
    line only: a later line of the other group is the reader's ``file:line`` error (a file
    holds 2D or 3D lines, not both); a file without such a line is SE2 (the planar reader
    names what it holds)."""
    for _, tag, _ in records:
        upper = tag.upper()
        for group in GROUPS:
            if upper.startswith(group.g2o_tags):
                return group
        landmark = landmark_group(tag)
        if landmark is not None:
            return landmark
        if tag != "FIX":
            return SE2  # an unknown tag: the planar reader names it
    return SE2


class _Recorded:
    """A stream read line by line twice: first to find its group, its lines kept, then
    again by the careful reader (``replaying``), those lines first."""

    def __init__(self, handle: BinaryIO) -> None:
        self.handle, self.lines, self.replaying = handle, deque[bytes](), False

    def readline(self, size: int = -1, /) -> bytes:
        if self.replaying and self.lines:
            return self.lines.popleft()
        line = self.handle.readline(size)
        if not self.replaying:
            self.lines.append(line)
        return line


# --------------------------------------------------------------------------- the careful reader


@dataclass(eq=False)
class _Parsed:
    """What the careful reader has parsed so far."""

    form: Format
    vertices: dict[int, list[float]] = field(default_factory=dict)
    vertex_lines: dict[int, int] = field(default_factory=dict)
    edge_lines: list[int] = field(default_factory=list)
    edge_keys: list[tuple[int, int]] = field(default_factory=list)
    edge_numbers: list[list[float]] = field(default_factory=list)
    model: list[int] = field(default_factory=list)
    # the file's matrix -> its index in information, or why the rule refuses it
    matrix_index: dict[bytes, int | str] = field(default_factory=dict)
    information: list[np.ndarray] = field(default_factory=list)
    changes: list[tuple[str, ...]] = field(default_factory=list)
    fixed: list[tuple[int, int]] = field(default_factory=list)  # (id, line)
    changed: dict[str, list[int]] = field(default_factory=dict)


# TORO's tags (GTSAM's example data ships such files): their information matrices are laid
# out one way in some files and another in others, so they are refused, not guessed at
_TORO_TAGS = ("VERTEX2", "EDGE2", "VERTEX3", "EDGE3", "EQUIV")


def parse(path: Path, handle: LineSource, form: Format) -> Table:
    """The careful reader: line by line, raising at the first bad line."""
    parsed = _Parsed(form)
    landmarks: _LandmarkReader | None = None
    own = POINT_LINES[form.group].tags
    for number, tag, fields in line_records(path, handle):
        if tag == form.vertex_tag:
            _parse_vertex(path, number, fields, parsed)
        elif tag == form.edge_tag:
            _parse_edge(path, number, fields, parsed)
        elif tag == "FIX":
            parsed.fixed.extend(parse_fix(path, number, fields))
        elif tag in own:
            if landmarks is None:
                landmarks = _LandmarkReader(form)
            landmarks.read_line(path, number, tag, fields)
        elif (other := _other_group(tag, form.group)) is not None:
            raise G2oFormatError(path, number, f"{short_token(tag)}: a {other.kind} line in a "
                                 f"{form.group.kind} file (a file holds 2D or 3D lines, not "
                                 "both)")
        else:
            toro = "TORO's, not g2o's: " if tag.upper() in _TORO_TAGS else ""
            raise G2oFormatError(path, number, f"unknown tag '{short_token(tag)}' ({toro}this "
                                 f"reader takes {form.vertex_tag}, {form.edge_tag} and FIX)")
    if landmarks is not None:
        landmarks.finish(path)
    p = form.pose_numbers
    return Table(
        vertex_keys=np.array(list(parsed.vertices), dtype=np.uint64),
        vertex_numbers=np.array(list(parsed.vertices.values()), dtype=float).reshape(-1, p),
        edge_keys=np.array(parsed.edge_keys, dtype=np.uint64).reshape(-1, 2),
        edge_lines=np.array(parsed.edge_lines, dtype=np.int64),
        edge_numbers=np.array(parsed.edge_numbers, dtype=float).reshape(-1, p),
        information=parsed.information,
        model=np.array(parsed.model, dtype=np.int64),
        fixed=parsed.fixed,
        changed=parsed.changed,
        landmarks=landmarks.table if landmarks is not None else None,
    )


def _other_group(tag: str, group: Group) -> Group | None:
    """The other pose group whose pose or landmark tags ``tag`` is, or None."""
    upper = tag.upper()
    return next((other for other in GROUPS if other is not group
                 and (upper.startswith(other.g2o_tags) or landmark_group(tag) is other)), None)


def _check_count(path: Path, line: int, tag: str, fields: list[str], count: int) -> None:
    if len(fields) != count:
        raise G2oFormatError(path, line, f"{tag} needs {count} numbers after the tag, found "
                             f"{len(fields)}")


def _parse_vertex(path: Path, line: int, fields: list[str], parsed: _Parsed) -> None:
    tag = parsed.form.vertex_tag
    _check_count(path, line, tag, fields, 1 + parsed.form.pose_numbers)
    key = parse_id(path, line, fields[0])
    numbers = parse_numbers(path, line, tag, fields[1:], first=2)
    if key in parsed.vertices:
        raise G2oFormatError(path, line, f"{tag} id {key} defined twice (first on line "
                             f"{parsed.vertex_lines[key]})")
    parsed.form.check_pose(path, line, tag, numbers)
    parsed.vertices[key] = numbers
    parsed.vertex_lines[key] = line


def _parse_edge(path: Path, line: int, fields: list[str], parsed: _Parsed) -> None:
    form = parsed.form
    tag, p = form.edge_tag, form.pose_numbers
    _check_count(path, line, tag, fields, 2 + p + form.information_numbers)
    i, j = parse_id(path, line, fields[0]), parse_id(path, line, fields[1])
    if i == j:
        raise G2oFormatError(path, line, f"{tag} joins vertex {i} to itself")
    numbers = parse_numbers(path, line, tag, fields[2:], first=3)
    form.check_pose(path, line, tag, numbers[:p])
    matrix = form.informations(np.array([numbers[p:]]))
    key = matrix.tobytes()
    if key not in parsed.matrix_index:  # the rule once per distinct matrix
        used, problems, changes = form.rule(matrix)
        parsed.matrix_index[key] = problems[0] or len(parsed.information)
        if problems[0] is None:
            parsed.information.append(used[0])
            parsed.changes.append(changes[0])
    index = parsed.matrix_index[key]
    if isinstance(index, str):
        raise G2oFormatError(path, line, f"{tag} {index}")
    for change in parsed.changes[index]:
        parsed.changed.setdefault(change, []).append(line)
    parsed.edge_lines.append(line)
    parsed.edge_keys.append((i, j))
    parsed.edge_numbers.append(numbers[:p])
    parsed.model.append(index)


# --------------------------------------------------------------------------- landmark lines

_MAX_LANDMARK_ID = 2**56 - 1  # a gtsam.Symbol's index: the 56 bits below its character
# load2D's LANDMARK rule: v1 and v3 this close are one variance, read at a range of 10 m
_SAME_VARIANCE = 1e-4
_RANGE_OF_VARIANCE_M = 10.0
_UPPER = {size: np.triu_indices(size) for size in (2, 3)}  # an information's fields


@dataclass(eq=False)
class _LandmarkReader:
    """The careful reader of a file's landmark lines: one line at a time (:meth:`read_line`),
    then :meth:`finish` at the end of the file; ``table`` holds what it read."""

    form: Format
    table: Landmarks = field(default_factory=Landmarks)
    # sensor id -> (rotation, translation, line) of its PARAMS_SE3OFFSET line
    offsets: dict[int, tuple[np.ndarray, np.ndarray, int]] = field(default_factory=dict)
    # (measurement index, sensor id, point, information) of the measurements in the frame
    # of a sensor whose line comes further on; their factor is None until then
    pending: list[tuple[int, int, np.ndarray, np.ndarray]] = field(default_factory=list)
    # the file's information matrix -> why it cannot be used (None: it can), each checked
    # once (a file's sightings mostly share one)
    problems: dict[bytes, str | None] = field(default_factory=dict)

    def read_line(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        """Read one landmark line of the file's group (``tag`` exactly one of its tags), or
        raise the error that names it."""
        if tag in ("VERTEX_XY", "VERTEX_TRACKXYZ"):
            self._vertex(path, line, tag, fields)
        elif tag in ("EDGE_SE2_XY", "LANDMARK2"):
            self._point_edge(path, line, tag, fields)
        elif tag == "EDGE_SE3_TRACKXYZ":
            self._sensor_edge(path, line, tag, fields)
        elif tag == "PARAMS_SE3OFFSET":
            self._offset(path, line, tag, fields)
        elif tag == "BR":
            self._bearing_range(path, line, tag, fields)
        else:  # LANDMARK
            self._landmark(path, line, tag, fields)

    def _vertex(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 1 + POINT_LINES[self.form.group].d)
        j = _landmark_id(path, line, fields[0])
        position = np.array(parse_numbers(path, line, tag, fields[1:], first=2))
        vertices = self.table.vertices
        if j in vertices:
            raise G2oFormatError(path, line, f"{tag} id {j} defined twice (first on line "
                                 f"{vertices[j][1]})")
        vertices[j] = (position, line)

    def _point_edge(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 2 + 2 + 3)
        i, j = parse_id(path, line, fields[0]), _landmark_id(path, line, fields[1])
        numbers = parse_numbers(path, line, tag, fields[2:], first=3)
        point, information = np.array(numbers[:2]), _symmetric(numbers[2:], 2)
        self._check_information(path, line, tag, information)
        self._add(path, line, tag, i, j, point, information)

    def _sensor_edge(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 3 + 3 + 6)
        i, j = parse_id(path, line, fields[0]), _landmark_id(path, line, fields[1])
        sensor = parse_id(path, line, fields[2])
        numbers = parse_numbers(path, line, tag, fields[3:], first=4)
        point, information = np.array(numbers[:3]), _symmetric(numbers[3:], 3)
        self._check_information(path, line, tag, information)  # a rotation keeps the answer
        if sensor in self.offsets:
            self._add(path, line, tag, i, j, *self._in_body(sensor, point, information))
        else:
            self.pending.append((len(self.table.factors), sensor, point, information))
            self._append(None, tag, line, i, j, point)

    def _offset(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 1 + 7)
        sensor = parse_id(path, line, fields[0])
        numbers = parse_numbers(path, line, tag, fields[1:], first=2)
        SPATIAL.check_pose(path, line, tag, numbers)  # a zero quaternion is no rotation
        if sensor in self.offsets:
            raise G2oFormatError(path, line, f"{tag} id {sensor} defined twice (first on line "
                                 f"{self.offsets[sensor][2]})")
        rotations, translations = SPATIAL.poses(np.array([numbers]))
        self.offsets[sensor] = (rotations[0], translations[0], line)

    def _bearing_range(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 2 + 4)
        i, j = parse_id(path, line, fields[0]), _landmark_id(path, line, fields[1])
        bearing, range_m, sigma_bearing, sigma_range = parse_numbers(
            path, line, tag, fields[2:], first=3)
        if not (sigma_bearing > 0 and sigma_range > 0):
            raise G2oFormatError(path, line, f"{tag} standard deviations must be positive, "
                                 f"found {sigma_bearing!r} and {sigma_range!r}")
        self._add_bearing_range(path, line, tag, i, j, bearing, range_m,
                                sigma_bearing, sigma_range)

    def _landmark(self, path: Path, line: int, tag: str, fields: list[str]) -> None:
        _check_count(path, line, tag, fields, 2 + 5)
        i, j = parse_id(path, line, fields[0]), _landmark_id(path, line, fields[1])
        dx, dy, v1, _v2, v3 = parse_numbers(path, line, tag, fields[2:], first=3)
        if abs(v1 - v3) < _SAME_VARIANCE:
            if not v1 > 0:
                raise G2oFormatError(path, line, f"{tag} variance must be positive, found "
                                     f"{v1!r}")
            sigma_bearing, sigma_range = math.sqrt(v1 / _RANGE_OF_VARIANCE_M), math.sqrt(v1)
        else:
            sigma_bearing = sigma_range = 1.0
            self.table.unit_sigma_lines.append(line)
        # load2D's arithmetic, so that the factor is the one gtsam.readG2o makes
        self._add_bearing_range(path, line, tag, i, j, math.atan2(dy, dx),
                                math.sqrt(dx * dx + dy * dy), sigma_bearing, sigma_range)

    def _check_information(self, path: Path, line: int, tag: str,
                           information: np.ndarray) -> None:
        key = information.tobytes()
        if key not in self.problems:
            self.problems[key] = information_problem(information, len(information),
                                                     self.form.group.max_condition)
        problem = self.problems[key]
        if problem is not None:
            raise G2oFormatError(path, line, f"{tag} {problem}")

    def _in_body(self, sensor: int, point: np.ndarray,
                 information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A point and its information in sensor ``sensor``'s frame, in the body frame."""
        rotation, translation, _ = self.offsets[sensor]
        return rotation @ point + translation, rotation @ information @ rotation.T

    def _add(self, path: Path, line: int, tag: str, i: int, j: int, point: np.ndarray,
             information: np.ndarray) -> None:
        self._append(_point_factor(path, line, tag, i, j, point, information), tag, line, i,
                     j, point)

    def _add_bearing_range(self, path: Path, line: int, tag: str, i: int, j: int,
                           bearing: float, range_m: float, sigma_bearing: float,
                           sigma_range: float) -> None:
        _check_range(path, line, tag, i, j, range_m)
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_bearing, sigma_range]))
        rotation = gtsam.Rot2(bearing)
        factor = gtsam.BearingRangeFactor2D(i, landmark_key(j), rotation, range_m, noise)
        _check_model(path, line, tag, factor)
        # load2D's first sighting: the bearing's rotation of (range, 0)
        self._append(factor, tag, line, i, j,
                     np.asarray(rotation.rotate(np.array([range_m, 0.0]))))

    def _append(self, factor: Any, tag: str, line: int, i: int, j: int,
                point: np.ndarray) -> None:
        table = self.table
        table.factors.append(factor)
        table.tags.append(tag)
        table.lines.append(line)
        table.pose_ids.append(i)
        table.landmark_ids.append(j)
        table.points.append(point)

    def finish(self, path: Path) -> None:
        """The end of the file: the measurements in the frame of a sensor read after them,
        or the error naming the first whose sensor no line defines."""
        table = self.table
        for index, sensor, point, information in self.pending:
            line, tag = table.lines[index], table.tags[index]
            if sensor not in self.offsets:
                raise G2oFormatError(path, line, f"{tag} names sensor offset {sensor}, which "
                                     "no PARAMS_SE3OFFSET line defines")
            point, information = self._in_body(sensor, point, information)
            table.factors[index] = _point_factor(path, line, tag, table.pose_ids[index],
                                                 table.landmark_ids[index], point, information)
            table.points[index] = point
        self.pending.clear()


def _landmark_id(path: Path, line: int, token: str) -> int:
    j = parse_id(path, line, token)
    if j > _MAX_LANDMARK_ID:
        raise G2oFormatError(path, line, f"landmark id {j} is too large: GTSAM's key l<id> "
                             "holds ids up to 2^56 - 1")
    return j


def _symmetric(upper: list[float], size: int) -> np.ndarray:
    """The symmetric matrix of an upper triangle, row by row."""
    matrix = np.zeros((size, size))
    rows, columns = _UPPER[size]
    matrix[rows, columns] = upper
    matrix[columns, rows] = upper
    return matrix


def _point_factor(path: Path, line: int, tag: str, i: int, j: int, point: np.ndarray,
                  information: np.ndarray) -> Any:
    """The bearing-range factor of pose ``i`` seeing landmark ``j`` at ``point`` in its frame
    with ``information`` (checked usable), or the error naming the line."""
    _check_range(path, line, tag, i, j, float(np.linalg.norm(point)))
    factor = bearing_range_factor(i, landmark_key(j), point, information)
    _check_model(path, line, tag, factor)
    return factor


def _check_range(path: Path, line: int, tag: str, i: int, j: int, range_m: float) -> None:
    if not (math.isfinite(range_m) and range_m > 0.0):
        raise G2oFormatError(path, line, f"{tag} sees landmark {j} from pose {i} at range "
                             f"{range_m!r}: a bearing needs a positive, finite range")


def _check_model(path: Path, line: int, tag: str, factor: Any) -> None:
    # a huge range or a tiny standard deviation overflows the bearing-range information
    if not np.isfinite(factor.noiseModel().R()).all():
        raise G2oFormatError(path, line, f"{tag} information overflows in bearing-range "
                             "coordinates (a range or an information too large)")


def _check_landmarks(path: Path, landmarks: Landmarks, form: Format, pose_keys: np.ndarray,
                     from_vertices: bool) -> None:
    """The checks across landmark lines: each measurement's pose has a pose (``pose_keys``,
    ascending: the vertex lines' ids where ``from_vertices``, else the pose edges'), each
    landmark vertex is measured, and no pose id is a landmark's key."""
    posed = _members(np.array(landmarks.pose_ids, dtype=np.uint64), pose_keys)
    if not posed.all():
        k = int(np.argmin(posed))
        where = (f"no {form.vertex_tag} line defines" if from_vertices
                 else f"no {form.vertex_tag} or {form.edge_tag} line names")
        raise G2oFormatError(path, landmarks.lines[k], f"{landmarks.tags[k]} refers to pose "
                             f"{landmarks.pose_ids[k]}, which {where}")
    seen = set(landmarks.landmark_ids)
    unseen = sorted((line, j) for j, (_, line) in landmarks.vertices.items() if j not in seen)
    if unseen:
        line, j = unseen[0]
        raise G2oFormatError(path, line, f"{POINT_LINES[form.group].vertex_tag} {j}: no line "
                             f"measures landmark {j} (an initializer needs a connected graph)")
    keys = landmarks.keys()
    clash = np.flatnonzero(_members(keys, pose_keys))
    if len(clash):
        key = int(keys[clash[0]])
        j = int(gtsam.Symbol(key).index())
        line = (landmarks.vertices[j][1] if j in landmarks.vertices
                else landmarks.lines[landmarks.landmark_ids.index(j)])
        raise G2oFormatError(path, line, f"pose id {key} is the GTSAM key of landmark {j} "
                             f"(l{j}): the two would be one variable")


def _add_landmarks(landmarks: Landmarks, form: Format, graph: gtsam.NonlinearFactorGraph,
                   values: gtsam.Values) -> list[int]:
    """Add the landmarks' values to ``values`` (which hold the poses): a vertex line's
    position, else the first sighting's (the pose's value composed with the measured point);
    and the measurements' factors to ``graph``. Returns the measurements' lines."""
    at_pose = getattr(values, f"at{form.group.pose_type.__name__}")
    # point2= / point3=: a fixed-size point, as gtsam.readG2o makes (not a dynamic Vector)
    name = "point2" if POINT_LINES[form.group].d == 2 else "point3"
    positions = {j: position for j, (position, _) in landmarks.vertices.items()}
    for i, j, point in zip(landmarks.pose_ids, landmarks.landmark_ids, landmarks.points,
                           strict=True):
        if j not in positions:
            positions[j] = np.asarray(at_pose(i).transformFrom(point), dtype=float)
    for j, position in positions.items():
        values.insert(landmark_key(j), **{name: position})
    for factor in landmarks.factors:
        graph.add(factor)
    return list(landmarks.lines)


# --------------------------------------------------------------------------- both readers


def build(path: Path, table: Table, form: Format, lines: bool = True, extract: bool = False
          ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], Any]:
    """The checks across lines, then the GTSAM graph, values and factor lines (``lines``;
    else an empty list), and (``extract``) the graph's extraction as the format makes it
    from the table (:meth:`~rlpgo_gtsam.io.formats.Format.extraction`; else None, and None
    for a file with landmark lines: the caller extracts those).

    The graph holds the between factors (edge lines, in file order), then the landmark
    measurements' factors (in file order), then the FIX priors; connectivity counts the
    landmarks and their measurements."""
    vertex, edge = form.vertex_tag, form.edge_tag
    landmarks = table.landmarks
    sighted = landmarks is not None and len(landmarks.factors) > 0
    if not len(table.vertex_keys) and not len(table.edge_keys) and not sighted:
        raise G2oFormatError(path, None, f"holds no {vertex} or {edge} line")
    if not len(table.edge_keys) and not sighted:
        raise G2oFormatError(path, None, f"holds no {edge} line: a pose graph needs edges")
    check_references(path, table, form)
    known = table.vertex_keys if len(table.vertex_keys) else table.edge_keys.ravel()
    pairs = table.edge_keys
    if landmarks is not None:
        _check_landmarks(path, landmarks, form, np.sort(known),
                         from_vertices=bool(len(table.vertex_keys)))
        known = np.concatenate([known, landmarks.keys()])
        pairs = np.concatenate([pairs, landmarks.pairs()])
    problem = disconnection(known, pairs)
    if problem is not None:
        raise G2oFormatError(path, None, problem)
    keys, edge_poses = table.vertex_keys, form.poses(table.edge_numbers)
    if len(keys):
        poses = form.poses(table.vertex_numbers)
    else:
        chained = _chain(form, table.edge_keys, edge_poses)
        for key, pose in chained.items():
            if not form.finite(pose):
                raise G2oFormatError(path, None, f"chaining the edges overflows at vertex "
                                     f"{key}: give {vertex} lines")
        keys = np.array(list(chained), dtype=np.uint64)
        poses = form.stack(list(chained.values()))
    # One noise model per distinct information matrix, shared by its edges; maps, not a
    # loop (a list of lists per edge would wake the garbage collector thousands of times)
    models = [gtsam.noiseModel.Gaussian.Information(matrix) for matrix in table.information]
    edge_models = (itertools.repeat(models[0], len(table.model)) if len(models) == 1
                   else map(models.__getitem__, table.model.tolist()))
    graph = gtsam.NonlinearFactorGraph()
    measured: Any = form.gtsam_poses(edge_poses)
    if extract:
        measured = list(measured)  # kept for the extraction
    between = form.group.between_factor
    deque(map(graph.add, map(between, *table.edge_keys.T.tolist(), measured, edge_models)),
          maxlen=0)
    order = np.argsort(keys, kind="stable")
    keys, poses = keys[order], form.take(poses, order)
    values = form.values(keys, poses, table.vertex_text)
    factor_lines = table.edge_lines.tolist() if lines else []
    if landmarks is not None:
        measurement_lines = _add_landmarks(landmarks, form, graph, values)
        if lines:
            factor_lines.extend(measurement_lines)
    prior, at = form.group.prior_factor, getattr(values, f"at{form.group.pose_type.__name__}")
    for key, line in table.fixed:
        graph.add(prior(key, at(key), gtsam.noiseModel.Constrained.All(form.group.dof)))
        if lines:
            factor_lines.append(line)
    if not extract or landmarks is not None:
        return graph, values, factor_lines, None
    return (graph, values, factor_lines,
            form.extraction(table, graph, values, keys, measured, models))


def _members(values: np.ndarray, ordered: np.ndarray) -> np.ndarray:
    """(k,) bool: which ``values`` occur in the ascending array ``ordered`` (``np.isin``
    without the sort of both that it does, and without numpy.ma, which numpy 2.4's
    ``unique`` imports under it: 4.5 ms of every command)."""
    if not len(ordered):
        return np.zeros(len(values), bool)
    at = np.minimum(np.searchsorted(ordered, values), len(ordered) - 1)
    return ordered[at] == values


def check_references(path: Path, table: Table, form: Format) -> None:
    """Raise the error of the first edge line (in file order) that names an id no vertex
    line defines (where the file has vertex lines), then of the first FIX id that no line
    names."""
    keys_i, keys_j = table.edge_keys[:, 0], table.edge_keys[:, 1]
    if len(table.vertex_keys):
        defined = np.sort(table.vertex_keys)
        known_i, known_j = _members(keys_i, defined), _members(keys_j, defined)
        unknown = np.flatnonzero(~(known_i & known_j))
        if len(unknown):
            k = unknown[0]
            key = int(keys_i[k] if not known_i[k] else keys_j[k])
            raise G2oFormatError(path, int(table.edge_lines[k]),
                                 f"{form.edge_tag} refers to vertex {key}, which no "
                                 f"{form.vertex_tag} line defines")
    if table.fixed:
        known = _members(np.array([key for key, _ in table.fixed], dtype=np.uint64),
                         np.sort(np.concatenate([table.vertex_keys, table.edge_keys.ravel()])))
        if not known.all():
            key, line = table.fixed[int(np.argmin(known))]
            raise G2oFormatError(path, line, f"FIX refers to vertex {key}, which is not defined")


def _chain(form: Format, edge_keys: np.ndarray, steps: Any) -> dict[int, Any]:
    """Initial poses composed along i -> i+1 edges; vertices off the chain via any edge.

    The chain runs from the smallest key through consecutive keys for as long as an edge
    joins them (the first such edge in file order, inverted if it runs j -> i); the other
    vertices are reached depth-first through any edge (the first joining them, in file
    order). Poses that overflow come back non-finite (the caller names the first).
    """
    first: dict[tuple[int, int], tuple[int, bool]] = {}  # pair -> (edge index, inverted?)
    neighbours: dict[int, list[tuple[int, int, bool]]] = {}
    for index, (i, j) in enumerate(edge_keys.tolist()):
        first.setdefault((i, j), (index, False))
        first.setdefault((j, i), (index, True))
        neighbours.setdefault(i, []).append((j, index, False))
        neighbours.setdefault(j, []).append((i, index, True))
    keys = sorted(neighbours)
    length = 1
    while length < len(keys) and (keys[length - 1], keys[length]) in first:
        length += 1
    with np.errstate(all="ignore"):
        run = form.run(steps, [first[pair] for pair in zip(keys, keys[1:length], strict=False)])
        poses = dict(zip(keys[:length], run, strict=True))
        frontier = list(poses)
        while frontier:
            key = frontier.pop()
            for other, index, inverted in neighbours[key]:
                if other not in poses:
                    poses[other] = form.then(poses[key], steps, index, inverted)
                    frontier.append(other)
    return poses


# What each change of the information rule is, told once per file.
_CHANGES = {
    INDEFINITE: "indefinite through their rotation-translation coupling alone: kept as "
                "printed, as gtsam.readG2o keeps them (chi2 is GTSAM's model of each, a "
                "Cholesky factor stopped at the indefinite pivot); the relaxation weighs "
                "them by their printed rotation and translation blocks, as SE-Sync does, where "
                "that factor's own information is beyond use",
    LIFTED: f"positive definite only to rounding (a condition number above "
            f"{MAX_CONDITION_3D:g}, or eigenvalues down to -{ROUNDING_3D:g} x the largest): "
            "their smallest eigenvalues raised to 1e-11 x the largest",
}


def warn_landmark_changes(path: Path, landmarks: Landmarks | None, stacklevel: int = 2) -> None:
    """One :class:`InformationWarning` for the ``LANDMARK`` lines read with unit standard
    deviations (their v1 and v3 differ: GTSAM's ``load2D`` then ignores them), at the
    caller's ``stacklevel``."""
    if landmarks is None or not landmarks.unit_sigma_lines:
        return
    lines = landmarks.unit_sigma_lines
    many = len(lines) > 1
    warnings.warn(InformationWarning(
        f"{path}: {len(lines)} LANDMARK line{'s' if many else ''} (first on line {lines[0]}) "
        f"{'have' if many else 'has'} v1 and v3 apart by 1e-4 or more: read with standard "
        "deviations of 1 rad and 1 m, as gtsam.readG2o reads them"), stacklevel=stacklevel + 1)


def warn_changes(path: Path, form: Format, changed: dict[str, list[int]],
                 stacklevel: int = 2) -> None:
    """One :class:`InformationWarning` per kind of change the information rule made to the
    file's matrices (``changed``: its name -> the lines of those edges), at the caller's
    ``stacklevel``."""
    for change, lines in changed.items():
        many = len(lines) > 1
        warnings.warn(InformationWarning(
            f"{path}: {len(lines)} {form.edge_tag} information matri{'ces' if many else 'x'} "
            f"(first on line {lines[0]}) {'are' if many else 'is'} {_CHANGES[change]}"),
            stacklevel=stacklevel + 1)
