"""Reading and writing 3D g2o files as GTSAM graphs, with line-by-line validation.

The Pose3 sibling of :mod:`rlpgo_gtsam.g2o`: every malformed line is a
:class:`~rlpgo_gtsam.errors.G2oFormatError` of the form ``file:line: reason``.

Supported lines::

    VERTEX_SE3:QUAT id x y z qx qy qz qw
    EDGE_SE3:QUAT i j x y z qx qy qz qw I_11 I_12 ... I_66   (21 entries, upper triangle)
    FIX id [id ...]
    # comment

The information is in g2o's order (translation first, then rotation); the graph holds it in
GTSAM's tangent order (rotation first), as ``gtsam.readG2o(path, True)`` does. Quaternions
are normalized; a zero or non-finite one is an error. A line of a planar file (``VERTEX_SE2``,
``EDGE_SE2``) is an error naming that line. A file without vertices gets its initial guess
chained from the edges (i -> i+1 first, then through any edge). A ``FIX``-ed vertex becomes
a :class:`gtsam.PriorFactorPose3` with a constrained noise model. Information matrices follow
the 3D rule (:func:`~rlpgo_gtsam.graph3d.information_rule_3d`); one it changes, or keeps
indefinite as ``gtsam.readG2o`` does, is told in an
:class:`~rlpgo_gtsam.errors.InformationWarning` per file and kind.

Files and graphs of either dimension are told apart, and handed here or to
:mod:`rlpgo_gtsam.g2o`, by :mod:`rlpgo_gtsam.dimension` (``read_pose_graph``,
``write_pose_graph``).
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, InformationWarning, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.g2o import (
    TAGS_2D,
    check_references,
    distinct_rows,
    fix_lines,
    format_15,
    information_texts,
    line_records,
    parse_fix,
    parse_id,
    parse_numbers,
    plain_keys,
    read_either,
    scan_blocks,
    short_token,
    texts_15,
    with_fix_lines,
    writable_factors,
)
from rlpgo_gtsam.graph import disconnection
from rlpgo_gtsam.graph3d import (
    INDEFINITE,
    LIFTED,
    MAX_CONDITION_3D,
    ROUNDING_3D,
    information_problem_6,
    information_problems_6,
    information_rule_3d,
    printed_informations,
)
from rlpgo_gtsam.se3 import compose, inverse, quaternions_to_rotations, rotations_to_quaternions
from rlpgo_gtsam.textscan import Text

__all__ = ["read_g2o3d", "read_g2o3d_lines", "write_g2o3d", "g2o3d_text", "g2o3d_text_lines",
           "G2O_TO_GTSAM"]

VERTEX = "VERTEX_SE3:QUAT"
EDGE = "EDGE_SE3:QUAT"
_VERTEX_FIELDS = 8
_EDGE_FIELDS = 30
# g2o's tangent order (x y z, then rotation) -> GTSAM's (rotation, then x y z): the
# information in GTSAM's order is info_g2o[G2O_TO_GTSAM][:, G2O_TO_GTSAM]
G2O_TO_GTSAM = np.array([3, 4, 5, 0, 1, 2])
_UPPER = np.triu_indices(6)
_QUATERNION_FLOOR = 1e-9  # a quaternion shorter than this has no direction to normalize


@dataclass(eq=False)
class _Parsed:
    """What the careful 3D reader has parsed so far."""

    vertices: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    vertex_lines: dict[int, int] = field(default_factory=dict)
    # (line, i, j, rotation, translation, information in GTSAM's order)
    edges: list[tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=list)
    fixed: list[tuple[int, int]] = field(default_factory=list)  # (id, line)
    # what the information rule did: LIFTED / INDEFINITE -> the lines of those edges
    changed: dict[str, list[int]] = field(default_factory=dict)


@dataclass(eq=False)
class _Table:
    """A 3D g2o file as arrays, in file order: what both readers produce.

    Attributes:
        vertex_keys: (n,) uint64 the VERTEX_SE3:QUAT ids.
        vertex_rotations, vertex_translations: (n, 3, 3) and (n, 3) their poses.
        edge_keys: (m, 2) uint64 the ids i, j of each EDGE_SE3:QUAT line.
        edge_lines: (m,) the 1-based line of each edge.
        rotations, translations: (m, 3, 3) and (m, 3) the measured relative poses.
        information: (d, 6, 6) the distinct information matrices, GTSAM's order (each checked
            once).
        model: (m,) the index of each edge's matrix in ``information``.
        fixed: (id, line) of each id of the FIX lines.
        changed: what the information rule did (:data:`~rlpgo_gtsam.graph3d.LIFTED`,
            :data:`~rlpgo_gtsam.graph3d.INDEFINITE`) -> the lines of those edges, in order.
    """

    vertex_keys: np.ndarray
    vertex_rotations: np.ndarray
    vertex_translations: np.ndarray
    edge_keys: np.ndarray
    edge_lines: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    information: np.ndarray
    model: np.ndarray
    fixed: list[tuple[int, int]]
    changed: dict[str, list[int]]


def read_g2o3d(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a 3D g2o file into a GTSAM factor graph and initial values.

    Each ``EDGE_SE3:QUAT`` becomes a :class:`gtsam.BetweenFactorPose3` whose Gaussian noise
    model is GTSAM's of the edge's full 6x6 information (``noiseModel.Gaussian.Information``,
    as ``gtsam.readG2o``; read by :func:`~rlpgo_gtsam.graph3d.information_rule_3d`: a matrix
    it does not take as it is, or takes indefinite, is told in an
    :class:`~rlpgo_gtsam.errors.InformationWarning`); then one constrained
    :class:`gtsam.PriorFactorPose3` per ``FIX``-ed id. Keys are the file's ids.

    A regular file is read a few megabytes at a time, record by record in numpy; anything
    that reader does not take as plainly valid is read again line by line, which names the
    first bad line (as :func:`rlpgo_gtsam.g2o.read_g2o`).

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed, or its graph is not
            connected; the message names the file and the line.
    """
    graph, values, _ = _read(Path(path))
    return graph, values


def read_g2o3d_lines(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int]]:
    """:func:`read_g2o3d`, and the file line (1-based) each factor came from: ``lines[k]`` is
    the line of ``graph.at(k)`` (the ``EDGE_SE3:QUAT`` lines in file order, then each
    ``FIX``-ed id's ``FIX`` line), as :func:`rlpgo_gtsam.g2o.read_g2o_lines` in 2D.

    Raises:
        G2oFormatError: as :func:`read_g2o3d`.
    """
    graph, values, table = _read(Path(path))
    return graph, values, [*table.edge_lines.tolist(), *(line for _, line in table.fixed)]


def _read(path: Path) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, _Table]:
    """The file's graph, values and table, the information rule's changes warned of."""
    table = _read_table(path, fast=True)
    _warn_changes(path, table.changed)
    return (*_build(path, table), table)


def _read_table(path: Path, fast: bool) -> _Table:
    """The file's table, by the fast reader where it takes the file, else the careful one."""
    return read_either(path, _scan if fast else None,
                       lambda path, handle: _table(_parse(path, handle)))


def _build(path: Path, table: _Table) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The checks across lines, then the GTSAM graph and values."""
    check_references(path, table.vertex_keys, table.edge_keys, table.edge_lines, table.fixed,
                     VERTEX, EDGE)
    known = np.concatenate([table.vertex_keys, table.edge_keys.ravel()])
    problem = disconnection(known, table.edge_keys)
    if problem is not None:
        raise G2oFormatError(path, None, problem)
    keys, rotations, translations = (table.vertex_keys, table.vertex_rotations,
                                     table.vertex_translations)
    if not len(keys):
        chained = _chain(table)
        for key, (r, t) in chained.items():
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
                raise G2oFormatError(path, None, f"chaining the edges overflows at vertex "
                                     f"{key}: give {VERTEX} lines")
        keys = np.array(list(chained), dtype=np.uint64)
        rotations = np.array([r for r, _ in chained.values()]).reshape(-1, 3, 3)
        translations = np.array([t for _, t in chained.values()]).reshape(-1, 3)
    # One noise model per distinct matrix, shared by its edges; a Rot3 from its nine numbers
    # and a Pose3 from it and a row of the translations: the cheapest calls into GTSAM.
    models = [gtsam.noiseModel.Gaussian.Information(matrix) for matrix in table.information]
    graph = gtsam.NonlinearFactorGraph()
    add, between, pose3, rot3 = (graph.add, gtsam.BetweenFactorPose3, gtsam.Pose3,
                                 gtsam.Rot3)
    for i, j, r, t, model in zip(*table.edge_keys.T.tolist(),
                                 table.rotations.reshape(-1, 9).tolist(), table.translations,
                                 map(models.__getitem__, table.model.tolist()), strict=True):
        add(between(i, j, pose3(rot3(*r), t), model))
    values = gtsam.Values()
    insert = values.insert
    order = np.argsort(keys, kind="stable")
    for key, r, t in zip(keys[order].tolist(), rotations[order].reshape(-1, 9).tolist(),
                         translations[order], strict=True):
        insert(key, pose3=pose3(rot3(*r), t))
    for key, _ in table.fixed:
        graph.add(gtsam.PriorFactorPose3(key, values.atPose3(key),
                                         gtsam.noiseModel.Constrained.All(6)))
    return graph, values


# --------------------------------------------------------------------------- the fast reader


@dataclass(eq=False)
class _Scan:
    """What the fast reader has gathered so far, one list entry per chunk."""

    vertex_keys: list[np.ndarray] = field(default_factory=list)
    vertex_numbers: list[np.ndarray] = field(default_factory=list)  # (k, 7) x y z qx qy qz qw
    edge_keys: list[np.ndarray] = field(default_factory=list)
    edge_lines: list[np.ndarray] = field(default_factory=list)
    edge_numbers: list[np.ndarray] = field(default_factory=list)  # (k, 7) as the vertices'
    model: list[np.ndarray] = field(default_factory=list)
    information: list[np.ndarray] = field(default_factory=list)  # as the rule uses them
    changes: list[tuple[str, ...]] = field(default_factory=list)  # the rule's, per matrix
    matrix_index: dict[bytes, int] = field(default_factory=dict)  # file's matrix -> index
    fixed: list[tuple[int, int]] = field(default_factory=list)
    changed: dict[str, list[int]] = field(default_factory=dict)
    lines: int = 0  # lines read so far


def _scan(handle: BinaryIO) -> _Table | None:
    """The fast reader: the table of the file, or None where the careful reader must judge.

    The ``VERTEX_SE3:QUAT`` and ``EDGE_SE3:QUAT`` lines of plain text are read column by
    column (:class:`~rlpgo_gtsam.textscan.Text`), comments and blank lines passed over, FIX
    lines read one by one; any other line, or anything unusual, is the careful reader's.
    """
    scan = _Scan()
    for text in scan_blocks(handle):
        if text is None or not _scan_block(text, scan):
            return None
    keys = np.concatenate(scan.vertex_keys) if scan.vertex_keys else np.zeros(0, np.uint64)
    ordered = np.sort(keys)
    if (ordered[1:] == ordered[:-1]).any() or not scan.edge_keys:
        return None  # an id defined twice, or no edge: the careful reader says so
    vertex_numbers = _stack(scan.vertex_numbers, (0, 7))
    edge_numbers = _stack(scan.edge_numbers, (0, 7))
    return _Table(
        vertex_keys=keys,
        vertex_rotations=_rotations(vertex_numbers[:, 3:])[0],
        vertex_translations=vertex_numbers[:, :3],
        edge_keys=np.concatenate(scan.edge_keys),
        edge_lines=np.concatenate(scan.edge_lines),
        rotations=_rotations(edge_numbers[:, 3:])[0],
        translations=edge_numbers[:, :3],
        information=np.array(scan.information).reshape(-1, 6, 6),
        model=np.concatenate(scan.model),
        fixed=scan.fixed,
        changed=scan.changed,
    )


def _stack(parts: list[np.ndarray], empty: tuple[int, ...]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty)


def _scan_block(text: Text, scan: _Scan) -> bool:
    """Parse the lines of ``text`` into ``scan``; False at anything unusual."""
    plain = text.plain_lines()
    vertices = np.flatnonzero(plain & text.first_field_is(VERTEX.encode()))
    edges = np.flatnonzero(plain & text.first_field_is(EDGE.encode()))
    others = ~plain | ((text.count > 0) & (text.first_byte() != ord("#")))
    others[vertices] = others[edges] = False
    for index in np.flatnonzero(others).tolist():
        tokens = text.line(index).decode("utf-8").split()
        if tokens and tokens[0].startswith("#"):
            continue
        keys = plain_keys(tokens[1:]) if tokens and tokens[0] == "FIX" and len(tokens) > 1 \
            else None
        if keys is None:
            return False  # a blank line of other spaces is the careful reader's too
        scan.fixed.extend((key, scan.lines + index + 1) for key in keys)
    if len(vertices):
        records = text.records(vertices, _VERTEX_FIELDS + 1, 1, 7)
        if records is None or not _usable_quaternions(records[1][:, 3:]):
            return False
        scan.vertex_keys.append(records[0][:, 0])
        scan.vertex_numbers.append(records[1])
    if len(edges):
        records = text.records(edges, _EDGE_FIELDS + 1, 2, 7)
        if records is None or not _usable_quaternions(records[1][:, 3:]):
            return False
        keys, numbers = records
        if (keys[:, 0] == keys[:, 1]).any():
            return False  # an edge from a vertex to itself
        starts, ends = text.fields(edges, _EDGE_FIELDS + 1)
        # the information's 21 fields: usually the same text on every line, read once
        if text.same_text(starts[:, 10], ends[:, 30]):
            upper = text.numbers(edges[:1], 10, 21)
            inverse = np.zeros(len(edges), np.int64)
        else:
            upper = text.numbers(edges, 10, 21)
            if upper is not None:
                first, inverse = distinct_rows(upper)  # in the order they first appear
                upper = upper[first]
        index = None if upper is None else _matrix_indices(_informations(upper), scan)
        if index is None:
            return False
        model, lines = index[inverse], edges + (scan.lines + 1)
        changed = [k for k, change in enumerate(scan.changes) if change]
        for line, k in zip(lines[np.isin(model, changed)].tolist(),
                           model[np.isin(model, changed)].tolist(), strict=True):
            for change in scan.changes[k]:  # as the careful reader: by line, in order
                scan.changed.setdefault(change, []).append(line)
        scan.edge_keys.append(keys)
        scan.edge_lines.append(lines)
        scan.edge_numbers.append(numbers)
        scan.model.append(model)
    scan.lines += len(text)
    return True


def _usable_quaternions(quaternions: np.ndarray) -> bool:
    """Whether every quaternion is long enough to normalize, with room to spare (a shorter
    one, even by rounding, is the careful reader's to name)."""
    return bool((_rotations(quaternions)[1] >= 2 * _QUATERNION_FLOOR).all())


def _matrix_indices(matrices: np.ndarray, scan: _Scan) -> np.ndarray | None:
    """The index in ``scan.information`` of each matrix of the file (the new ones through
    the information rule, in one batch, and added as it uses them); None if the rule
    refuses one of them."""
    keys = [matrix.tobytes() for matrix in matrices]
    new = [k for k, key in enumerate(keys) if key not in scan.matrix_index]
    if new:
        used, problems, changes = information_rule_3d(matrices[new])
        if any(problem is not None for problem in problems):
            return None
        for k, matrix, change in zip(new, used, changes, strict=True):
            scan.matrix_index[keys[k]] = len(scan.information)
            scan.information.append(matrix)
            scan.changes.append(change)
    return np.array([scan.matrix_index[key] for key in keys], dtype=np.int64)


# --------------------------------------------------------------------------- the careful reader


def _table(parsed: _Parsed) -> _Table:
    """The careful reader's table: its dictionaries and edge list as arrays."""
    matrix_index: dict[bytes, int] = {}
    information: list[np.ndarray] = []
    model = []
    for edge in parsed.edges:
        index = matrix_index.setdefault(edge[5].tobytes(), len(information))
        if index == len(information):
            information.append(edge[5])
        model.append(index)
    return _Table(
        vertex_keys=np.array(list(parsed.vertices), dtype=np.uint64),
        vertex_rotations=np.array([r for r, _ in parsed.vertices.values()]).reshape(-1, 3, 3),
        vertex_translations=np.array([t for _, t in parsed.vertices.values()]).reshape(-1, 3),
        edge_keys=np.array([e[1:3] for e in parsed.edges], dtype=np.uint64).reshape(-1, 2),
        edge_lines=np.array([e[0] for e in parsed.edges], dtype=np.int64),
        rotations=np.array([e[3] for e in parsed.edges]).reshape(-1, 3, 3),
        translations=np.array([e[4] for e in parsed.edges]).reshape(-1, 3),
        information=np.array(information).reshape(-1, 6, 6),
        model=np.array(model, dtype=np.int64),
        fixed=parsed.fixed,
        changed=parsed.changed,
    )


def _rotations(quaternions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3, 3) the rotations of (k, 4) quaternions (qx, qy, qz, qw), each divided by its
    length first, and (k,) those lengths: the one computation both readers make, row by row
    alike whatever k."""
    q = np.asarray(quaternions, dtype=float).reshape(-1, 4)
    with np.errstate(all="ignore"):  # a zero or huge one is refused by the caller
        size = np.sqrt(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1] + q[:, 2] * q[:, 2]
                       + q[:, 3] * q[:, 3])
        return quaternions_to_rotations(q / size[:, None]), size


def _informations(upper: np.ndarray) -> np.ndarray:
    """(k, 6, 6) the information in GTSAM's order of (k, 21) upper triangles in g2o's."""
    full = np.zeros((len(upper), 6, 6))
    full[:, _UPPER[0], _UPPER[1]] = upper
    information = full + np.transpose(np.triu(full, 1), (0, 2, 1))
    return information[:, G2O_TO_GTSAM][:, :, G2O_TO_GTSAM]


def _parse(path: Path, handle: BinaryIO) -> _Parsed:
    parsed = _Parsed()
    for number, tag, fields in line_records(path, handle):
        if tag == VERTEX:
            _check_count(path, number, tag, fields, _VERTEX_FIELDS)
            key = parse_id(path, number, fields[0])
            numbers = parse_numbers(path, number, tag, fields[1:], first=2)
            if key in parsed.vertices:
                raise G2oFormatError(path, number, f"{VERTEX} id {key} defined twice (first "
                                     f"on line {parsed.vertex_lines[key]})")
            rotation = _rotation(path, number, tag, numbers[3:7])
            parsed.vertices[key] = (rotation, np.array(numbers[:3]))
            parsed.vertex_lines[key] = number
        elif tag == EDGE:
            _check_count(path, number, tag, fields, _EDGE_FIELDS)
            i, j = parse_id(path, number, fields[0]), parse_id(path, number, fields[1])
            if i == j:
                raise G2oFormatError(path, number, f"{EDGE} joins vertex {i} to itself")
            numbers = parse_numbers(path, number, tag, fields[2:], first=3)
            rotation = _rotation(path, number, tag, numbers[3:7])
            used, problems, changes = information_rule_3d(_informations(np.array([numbers[7:]])))
            if problems[0] is not None:
                raise G2oFormatError(path, number, f"{EDGE} {problems[0]}")
            information = used[0]
            for change in changes[0]:
                parsed.changed.setdefault(change, []).append(number)
            parsed.edges.append((number, i, j, rotation, np.array(numbers[:3]), information))
        elif tag == "FIX":
            parsed.fixed.extend(parse_fix(path, number, fields))
        elif tag.upper().startswith(TAGS_2D):
            raise G2oFormatError(path, number, f"{short_token(tag)}: a planar line in a 3D file "
                                 "(a file holds 2D or 3D lines, not both)")
        else:
            raise G2oFormatError(path, number, f"unknown tag '{short_token(tag)}' (this reader "
                                 f"takes {VERTEX}, {EDGE} and FIX)")
    if not parsed.edges:
        raise G2oFormatError(path, None, f"holds no {EDGE} line: a pose graph needs edges")
    return parsed


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


def _warn_changes(path: Path, changed: dict[str, list[int]]) -> None:
    for change, lines in changed.items():
        many = len(lines) > 1
        warnings.warn(InformationWarning(
            f"{path}: {len(lines)} {EDGE} information matri{'ces' if many else 'x'} (first on "
            f"line {lines[0]}) {'are' if many else 'is'} {_CHANGES[change]}"), stacklevel=3)


def _check_count(path: Path, line: int, tag: str, fields: list[str], count: int) -> None:
    if len(fields) != count:
        raise G2oFormatError(path, line, f"{tag} needs {count} numbers after the tag, found "
                             f"{len(fields)}")


def _rotation(path: Path, line: int, tag: str, quaternion: list[float]) -> np.ndarray:
    rotations, size = _rotations(np.array([quaternion]))
    if not size[0] >= _QUATERNION_FLOOR:
        raise G2oFormatError(path, line, f"{tag} quaternion ({', '.join(map(repr, quaternion))}) "
                             "is zero: it names no rotation")
    return rotations[0]


def _chain(table: _Table) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Initial poses composed along i -> i+1 edges from the smallest key, then through any
    edge (depth-first) to the vertices off that chain."""
    step: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    neighbours: dict[int, list[int]] = {}
    for (i, j), r, t in zip(table.edge_keys.tolist(), table.rotations, table.translations,
                            strict=True):
        if (i, j) not in step:
            step[(i, j)] = (r, t)
            r_inv, t_inv = inverse(r[None], t[None])
            step.setdefault((j, i), (r_inv[0], t_inv[0]))
        neighbours.setdefault(i, []).append(j)
        neighbours.setdefault(j, []).append(i)
    keys = sorted(neighbours)
    poses = {keys[0]: (np.eye(3), np.zeros(3))}
    with np.errstate(all="ignore"):
        for a, b in zip(keys, keys[1:], strict=False):
            if (a, b) not in step:
                break
            poses[b] = _then(poses[a], step[(a, b)])
        frontier = list(poses)
        while frontier:
            key = frontier.pop()
            for other in neighbours[key]:
                if other not in poses:
                    poses[other] = _then(poses[key], step[(key, other)])
                    frontier.append(other)
    return poses


def _then(pose: tuple[np.ndarray, np.ndarray],
          move: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    r, t = compose(pose[0][None], pose[1][None], move[0][None], move[1][None])
    return r[0], t[0]


def g2o3d_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """The 3D g2o text of ``graph`` and ``values`` (what :func:`write_g2o3d` writes).

    Raises:
        OutputError: a factor, value or information that a 3D g2o file cannot hold.
    """
    return g2o3d_text_lines(graph, values)[0]


def g2o3d_text_lines(graph: gtsam.NonlinearFactorGraph,
                     values: gtsam.Values) -> tuple[str, list[int | None]]:
    """:func:`g2o3d_text`, and the line (1-based) of that text which holds each factor:
    its ``EDGE_SE3:QUAT`` line, or the ``FIX`` line of a prior, or None for an empty slot
    (as :func:`rlpgo_gtsam.g2o.g2o_text_lines` for planar files).

    Raises:
        OutputError: a factor, value or information that a 3D g2o file cannot hold.
    """
    written = _text_fast(graph, values)
    return written if written is not None else _text_careful(graph, values)


def _text_fast(graph: gtsam.NonlinearFactorGraph,
               values: gtsam.Values) -> tuple[str, list[int | None]] | None:
    """The text and factor lines, each vertex and factor read from GTSAM once, the poses
    turned into quaternions in one batch and the numbers formatted in bulk; None at anything
    :func:`_text_careful` must judge (it then raises the error for it)."""
    keys = list(values.keys())
    if keys != sorted(keys):
        return None
    poses = gtsam.utilities.extractPose3(values)  # by key: R row by row, then t
    if poses.shape != (len(keys), 12) or not np.isfinite(poses).all():
        return None  # a value that is not a Pose3, or not finite
    between = gtsam.BetweenFactorPose3
    found = writable_factors(graph, between, gtsam.PriorFactorPose3)
    if found is None:
        return None
    kinds, edges, edge_keys, priors, fixed = found
    measured = np.array(list(map(gtsam.Pose3.matrix, map(between.measured, edges))))
    measured = measured.reshape(-1, 4, 4)
    models = list(map(between.noiseModel, edges))
    information = information_texts(models, 6, information_problems_6,
                                    np.argsort(G2O_TO_GTSAM))  # GTSAM's order -> g2o's
    if information is None:
        information = _printed_texts(models)
    if information is None:
        return None
    if not set(keys).issuperset(edge_keys + fixed) or not np.isfinite(measured).all():
        return None  # a factor on a key without a value; a measurement not finite
    vertex_fields = _pose_fields(poses[:, :9].reshape(-1, 3, 3), poses[:, 9:], [keys])
    edge_fields = _pose_fields(measured[:, :3, :3], measured[:, :3, 3],
                               [edge_keys[0::2], edge_keys[1::2]], information)
    if vertex_fields is None or edge_fields is None:
        return None
    text = [(f"{VERTEX} %d %r %r %r %s %s %s %s\n" * len(keys)) % tuple(vertex_fields),
            (f"{EDGE} %d %d %r %r %r %s %s %s %s %s\n" * len(edges)) % tuple(edge_fields)]
    return with_fix_lines(text, kinds, between, len(keys), priors, fixed)


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
    refused = [k for k, problem in enumerate(information_problems_6(matrices))
               if problem is not None]
    printed, found = printed_informations(np.array([distinct[k].R() for k in refused]))
    if not found.all():
        return None
    matrices[refused] = printed
    back = np.argsort(G2O_TO_GTSAM)  # GTSAM's order -> g2o's
    numbers = texts_15(matrices[:, back][:, :, back][:, _UPPER[0], _UPPER[1]].ravel().tolist())
    text = {id(model): " ".join(numbers[21 * k:21 * k + 21]) for k, model in enumerate(distinct)}
    return [text[id(model)] for model in models]


def _pose_fields(rotations: np.ndarray, translations: np.ndarray, first: list[list[int]],
                 last: list[str] | None = None) -> list[object] | None:
    """The fields of pose lines, line after line: the columns ``first`` (ids), x y z, the
    quaternion's four numbers as :func:`_pose_text` writes them, then ``last`` if given;
    None if a quaternion is not finite."""
    quaternions = rotations_to_quaternions(rotations)
    if not np.isfinite(quaternions).all():
        return None
    columns = [*first, *translations.T.tolist(),
               *[texts_15(column) for column in quaternions.T.tolist()]]
    if last is not None:
        columns.append(last)
    fields: list[object] = [None] * (len(columns) * len(translations))
    for c, column in enumerate(columns):
        fields[c::len(columns)] = column
    return fields


def _text_careful(graph: gtsam.NonlinearFactorGraph,
                  values: gtsam.Values) -> tuple[str, list[int | None]]:
    """:func:`g2o3d_text_lines` one vertex and one factor at a time, raising at the first
    that a 3D g2o file cannot hold."""
    factor_lines: list[int | None] = [None] * graph.size()
    priors: list[int] = []
    lines = [f"{VERTEX} {key} " + _pose_text(_pose3(values, key), f"vertex {key}")
             for key in sorted(values.keys())]
    fixed = []
    for index in range(graph.size()):
        factor = graph.at(index)
        if factor is None:
            continue
        missing = [key for key in factor.keys() if not values.exists(key)]
        if missing:
            raise OutputError(f"factor {index} refers to key {missing[0]}, which has no value: "
                              "the file would not read back")
        if isinstance(factor, gtsam.BetweenFactorPose3):
            i, j = factor.keys()
            model = factor.noiseModel()
            if not isinstance(model, gtsam.noiseModel.Gaussian) or isinstance(
                    model, gtsam.noiseModel.Constrained):
                raise OutputError(f"edge {i}-{j} has a {type(model).__name__} noise model: a g2o "
                                  "edge holds a Gaussian information matrix only")
            information = model.information()
            problem = information_problem_6(information)
            if problem is not None:
                printed, found = printed_informations(model.R()[None])
                if not found[0]:
                    raise OutputError(f"edge {i}-{j}: {problem} (the reader would refuse it)")
                information = printed[0]  # GTSAM's factor of a printed indefinite matrix
            back = np.argsort(G2O_TO_GTSAM)  # GTSAM's order -> g2o's
            upper = information[back][:, back][_UPPER]
            lines.append(f"{EDGE} {i} {j} " + _pose_text(factor.measured(), f"edge {i}-{j}")
                         + " " + " ".join(format_15(v) for v in upper))
            factor_lines[index] = len(lines)
        elif isinstance(factor, gtsam.PriorFactorPose3):
            if not isinstance(factor.noiseModel(), gtsam.noiseModel.Constrained):
                raise OutputError(f"prior on key {factor.keys()[0]}: a soft prior has no g2o "
                                  "line (FIX holds a pose exactly)")
            fixed.append(factor.keys()[0])
            priors.append(index)
        else:
            raise OutputError(f"cannot write a {type(factor).__name__} as a 3D g2o line")
    for fix, part in fix_lines(fixed):
        lines.append(fix)
        for index in priors[part]:
            factor_lines[index] = len(lines)
    return "\n".join(lines) + "\n", factor_lines


def _pose3(values: gtsam.Values, key: int) -> gtsam.Pose3:
    try:
        return values.atPose3(key)
    except RuntimeError:
        raise OutputError(f"value of key {key} is not a Pose3: a 3D g2o file holds Pose3 "
                          "vertices only") from None


def _pose_text(pose: gtsam.Pose3, name: str) -> str:
    # positions exactly; quaternions and (below) information with 15 significant digits, as
    # the planar writer: matrix -> quaternion and R^T R drift by an ulp, which 15 digits undo
    position = np.asarray(pose.translation(), float).tolist()
    quaternion = rotations_to_quaternions(pose.rotation().matrix())[0].tolist()
    if not all(math.isfinite(v) for v in position + quaternion):
        raise OutputError(f"{name} is not finite: the file would not read back")
    return " ".join([repr(float(v)) for v in position] + [format_15(v) for v in quaternion])


def write_g2o3d(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
                values: gtsam.Values) -> None:
    """Write ``graph`` and ``values`` as a 3D g2o file, atomically (a temporary file beside
    ``path`` replaces it).

    Raises:
        OutputError: ``path`` cannot be written, or the graph holds what a 3D g2o file
            cannot (see :func:`g2o3d_text`).
    """
    write_text(path, g2o3d_text(graph, values))
