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
the 3D rule (:func:`~rlpgo_gtsam.graph3d.information_rule_3d`); one it reads in a changed
form is told in an :class:`~rlpgo_gtsam.errors.InformationWarning` per file and kind.

:func:`read_pose_graph` reads a g2o file of either dimension, told by its first pose line
(:func:`g2o_dimension`); :func:`write_pose_graph` writes a graph of either dimension.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, InformationWarning, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.g2o import (
    TAGS_3D,
    fix_lines,
    format_15,
    g2o_text,
    numbered_lines,
    parse_fix,
    parse_id,
    parse_numbers,
    read_g2o,
    short_token,
    write_g2o,
)
from rlpgo_gtsam.graph import disconnection
from rlpgo_gtsam.graph3d import (
    LIFTED,
    MAX_CONDITION_3D,
    ROUNDING_3D,
    UNCOUPLED,
    graph_dimension,
    information_problem_6,
    information_rule_3d,
)
from rlpgo_gtsam.se3 import compose, inverse, quaternions_to_rotations, rotations_to_quaternions

__all__ = ["read_g2o3d", "write_g2o3d", "g2o3d_text", "g2o3d_text_lines", "G2O_TO_GTSAM",
           "TAGS_2D", "g2o_dimension", "read_pose_graph", "write_pose_graph", "pose_graph_text"]

VERTEX = "VERTEX_SE3:QUAT"
EDGE = "EDGE_SE3:QUAT"
_VERTEX_FIELDS = 8
_EDGE_FIELDS = 30
TAGS_2D = ("VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2")  # a line's tag starting so is planar
# g2o's tangent order (x y z, then rotation) -> GTSAM's (rotation, then x y z): the
# information in GTSAM's order is info_g2o[G2O_TO_GTSAM][:, G2O_TO_GTSAM]
G2O_TO_GTSAM = np.array([3, 4, 5, 0, 1, 2])
_UPPER = np.triu_indices(6)
_QUATERNION_FLOOR = 1e-9  # a quaternion shorter than this has no direction to normalize


@dataclass
class _Parsed:
    vertices: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    vertex_lines: dict[int, int] = field(default_factory=dict)
    # (line, i, j, rotation, translation, information in GTSAM's order)
    edges: list[tuple[int, int, int, np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=list)
    fixed: list[tuple[int, int]] = field(default_factory=list)  # (id, line)
    # what the information rule changed: LIFTED / UNCOUPLED -> the lines of those edges
    changed: dict[str, list[int]] = field(default_factory=dict)


def read_g2o3d(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a 3D g2o file into a GTSAM factor graph and initial values.

    Each ``EDGE_SE3:QUAT`` becomes a :class:`gtsam.BetweenFactorPose3` whose Gaussian noise
    model holds the edge's full 6x6 information (read by
    :func:`~rlpgo_gtsam.graph3d.information_rule_3d`: a matrix it changes is told in an
    :class:`~rlpgo_gtsam.errors.InformationWarning`); then one constrained
    :class:`gtsam.PriorFactorPose3` per ``FIX``-ed id. Keys are the file's ids.

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed, or its graph is not
            connected; the message names the file and the line.
    """
    path = Path(path)
    parsed = _parse(path)
    _warn_changes(path, parsed.changed)
    if parsed.vertices:
        for line, i, j, *_ in parsed.edges:
            for key in (i, j):
                if key not in parsed.vertices:
                    raise G2oFormatError(path, line, f"{EDGE} refers to vertex {key}, which no "
                                         f"{VERTEX} line defines")
    known = parsed.vertices.keys() | {k for e in parsed.edges for k in e[1:3]}
    for key, line in parsed.fixed:
        if key not in known:
            raise G2oFormatError(path, line, f"FIX refers to vertex {key}, which is not defined")
    problem = disconnection(known, [(e[1], e[2]) for e in parsed.edges])
    if problem is not None:
        raise G2oFormatError(path, None, problem)
    if not parsed.vertices:
        parsed.vertices = _chain(parsed.edges)
        for key, (r, t) in parsed.vertices.items():
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
                raise G2oFormatError(path, None, f"chaining the edges overflows at vertex "
                                     f"{key}: give {VERTEX} lines")
    graph = gtsam.NonlinearFactorGraph()
    for _, i, j, r, t, information in parsed.edges:
        graph.add(gtsam.BetweenFactorPose3(i, j, gtsam.Pose3(gtsam.Rot3(r), t),
                                           gtsam.noiseModel.Gaussian.Information(information)))
    values = gtsam.Values()
    for key in sorted(parsed.vertices):
        r, t = parsed.vertices[key]
        values.insert(key, gtsam.Pose3(gtsam.Rot3(r), t))
    for key, _ in parsed.fixed:
        graph.add(gtsam.PriorFactorPose3(key, values.atPose3(key),
                                         gtsam.noiseModel.Constrained.All(6)))
    return graph, values


def _records(path: Path) -> Iterator[tuple[int, str, list[str]]]:
    """(line number, tag, fields) of each line that is neither blank nor a comment."""
    for number, text in numbered_lines(path):
        tokens = text.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens[0], tokens[1:]


def _parse(path: Path) -> _Parsed:
    parsed = _Parsed()
    for number, tag, fields in _records(path):
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
            upper = np.zeros((6, 6))
            upper[_UPPER] = numbers[7:]
            information = upper + np.triu(upper, 1).T
            information = information[G2O_TO_GTSAM][:, G2O_TO_GTSAM]
            used, problems, changes = information_rule_3d(information)
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
    UNCOUPLED: "indefinite through their rotation-translation coupling alone: read as SE-Sync "
               "reads every edge, the rotation and translation blocks without the coupling",
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
    size = math.sqrt(math.fsum(q * q for q in quaternion))
    if not size >= _QUATERNION_FLOOR:
        raise G2oFormatError(path, line, f"{tag} quaternion ({', '.join(map(repr, quaternion))}) "
                             "is zero: it names no rotation")
    return quaternions_to_rotations(np.array(quaternion) / size)[0]


def _chain(edges: list) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Initial poses composed along i -> i+1 edges from the smallest key, then through any
    edge (depth-first) to the vertices off that chain."""
    step: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    neighbours: dict[int, list[int]] = {}
    for _, i, j, r, t, _ in edges:
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
                raise OutputError(f"edge {i}-{j}: {problem} (the reader would refuse it)")
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


# --------------------------------------------------------------------------- either dimension


def g2o_dimension(path: str | os.PathLike[str]) -> int:
    """3 if the first pose line of the g2o file at ``path`` is a 3D one (``VERTEX_SE3:QUAT``,
    ``EDGE_SE3:QUAT``, any tag of :data:`~rlpgo_gtsam.g2o.TAGS_3D`), else 2.

    It reads up to that line only: a later line of the other dimension is the reader's
    ``file:line`` error (a file holds 2D or 3D lines, not both). A file without a pose line
    is 2: the planar reader names what it holds.

    Raises:
        G2oFormatError: the file is missing or unreadable, or a line before the first pose
            line is (too long, binary, not UTF-8).
    """
    for _, tag, _ in _records(Path(path)):
        upper = tag.upper()
        if upper.startswith(TAGS_3D):
            return 3
        if upper.startswith(TAGS_2D) or tag != "FIX":
            return 2  # an unknown tag: the planar reader names it
    return 2


def read_pose_graph(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph,
                                                          gtsam.Values]:
    """Read a g2o file of either dimension (:func:`g2o_dimension`): a ``BetweenFactorPose2``
    graph by :func:`~rlpgo_gtsam.g2o.read_g2o` or a ``BetweenFactorPose3`` one by
    :func:`read_g2o3d`, with their ``file:line`` errors.

    Raises:
        G2oFormatError: as the reader of the file's dimension.
    """
    return read_g2o3d(path) if g2o_dimension(path) == 3 else read_g2o(path)


def pose_graph_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """The g2o text of a planar or a 3D graph (:func:`~rlpgo_gtsam.graph3d.graph_dimension`):
    :func:`~rlpgo_gtsam.g2o.g2o_text` or :func:`g2o3d_text`."""
    return g2o3d_text(graph, values) if graph_dimension(graph) == 3 else g2o_text(graph, values)


def write_pose_graph(path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph,
                     values: gtsam.Values) -> None:
    """Write a planar or a 3D graph as g2o, atomically (:func:`~rlpgo_gtsam.g2o.write_g2o` or
    :func:`write_g2o3d`).

    Raises:
        OutputError: as the writer of the graph's dimension.
    """
    if graph_dimension(graph) == 3:
        write_g2o3d(path, graph, values)
    else:
        write_g2o(path, graph, values)
