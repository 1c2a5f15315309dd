"""Reading and writing planar g2o files as GTSAM graphs, with line-by-line validation.

``gtsam.readG2o`` names no line when a file is malformed, and accepts files that no
initializer can work on. :func:`read_g2o` checks every line itself and raises a
:class:`~rlpgo_gtsam.errors.G2oFormatError` of the form ``file:line: reason``.

Supported lines::

    VERTEX_SE2 id x y theta
    EDGE_SE2 i j dx dy dtheta I_xx I_xy I_xt I_yy I_yt I_tt     (upper triangle, g2o order)
    FIX id [id ...]
    # comment

Lines longer than :data:`MAX_LINE_BYTES` (64 KiB) are refused, so that a file without
newlines is read in bounded memory.

A ``FIX``-ed vertex becomes a :class:`gtsam.PriorFactorPose2` with a constrained noise
model: the pose is held where its vertex line puts it (the first FIXed pose is the anchor;
a held pose adds nothing to :func:`~rlpgo_gtsam.graph.chi2`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, InputNotFoundError, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.graph import disconnection, information_problem
from rlpgo_gtsam.se2 import chain, compose, inverse, wrap

__all__ = ["read_g2o", "read_g2o_lines", "write_g2o", "g2o_text", "g2o_text_lines",
           "edge_list_text", "EDGE_LIST_LINE"]

# The longest line the reader takes: an EDGE_SE2 line with 64-bit ids and 11 numbers written
# with 17 significant digits is under 300 bytes; 64 KiB leaves room for any comment.
MAX_LINE_BYTES = 65536
_EDGE_NUMBERS = 11
_VERTEX_NUMBERS = 4
# A line of an edge list (:func:`edge_list_text`): L is the edge's line in its g2o file.
EDGE_LIST_LINE = "line <L> EDGE_SE2 <id_i> <id_j>"
_FIX_PER_LINE = 1000  # 21-byte ids: at most 22 KB a line, well inside MAX_LINE_BYTES
_3D_TAGS = ("VERTEX_SE3", "EDGE_SE3", "VERTEX3", "EDGE3", "VERTEX_TRACKXYZ", "EDGE_SE3_")


@dataclass
class _Edge:
    line: int
    i: int
    j: int
    measured: tuple[float, float, float]
    information: np.ndarray


@dataclass
class _Parsed:
    vertices: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    vertex_lines: dict[int, int] = field(default_factory=dict)
    edges: list[_Edge] = field(default_factory=list)
    fixed: list[tuple[int, int]] = field(default_factory=list)  # (id, line)


def read_g2o(path: str | os.PathLike[str]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """Read a planar g2o file into a GTSAM factor graph and initial values.

    Each ``EDGE_SE2`` becomes a :class:`gtsam.BetweenFactorPose2` whose Gaussian noise model
    holds the edge's full 3x3 information (correlations kept). Keys are the file's ids.
    A file without any ``VERTEX_SE2`` line gets its initial guess chained from the odometry
    edges ``i -> i+1`` (ids in increasing order; a gap is bridged through any edge).

    Raises:
        G2oFormatError: the file is missing, unreadable or malformed, or its graph is not
            connected; the message names the file and the line.
    """
    graph, values, _lines = read_g2o_lines(path)
    return graph, values


def read_g2o_lines(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int]]:
    """:func:`read_g2o`, and the file line (1-based) each factor came from.

    Factor ``k`` is the ``k``-th ``EDGE_SE2`` line for the edges, in file order; then one
    :class:`gtsam.PriorFactorPose2` per id of the ``FIX`` lines, each with its ``FIX`` line.
    A missing file raises :class:`~rlpgo_gtsam.errors.InputNotFoundError`, which is both a
    :class:`G2oFormatError` and a :class:`FileNotFoundError`.
    ``lines[k]`` is the line of ``graph.at(k)``: what a message about a factor should name.

    Raises:
        G2oFormatError: as :func:`read_g2o`.
    """
    path = Path(path)
    parsed = _parse(path)
    _check_edges(path, parsed)
    _check_connected(path, parsed)
    if not parsed.vertices:
        parsed.vertices = _chain_odometry(parsed.edges)
        for key, pose in parsed.vertices.items():
            if not all(math.isfinite(v) for v in pose):
                raise G2oFormatError(
                    path, None, f"chaining the edges overflows at vertex {key}: give VERTEX_SE2 "
                    "lines"
                )
    graph = gtsam.NonlinearFactorGraph()
    lines = []
    for edge in parsed.edges:
        noise = gtsam.noiseModel.Gaussian.Information(edge.information)
        graph.add(gtsam.BetweenFactorPose2(edge.i, edge.j, gtsam.Pose2(*edge.measured), noise))
        lines.append(edge.line)
    values = gtsam.Values()
    for key in sorted(parsed.vertices):
        values.insert(key, gtsam.Pose2(*parsed.vertices[key]))
    for key, line in parsed.fixed:
        graph.add(
            gtsam.PriorFactorPose2(key, values.atPose2(key), gtsam.noiseModel.Constrained.All(3))
        )
        lines.append(line)
    return graph, values, lines


def numbered_lines(path: Path) -> Iterator[tuple[int, str]]:
    try:
        handle = path.open("rb")
    except FileNotFoundError:
        raise InputNotFoundError(path) from None
    except IsADirectoryError:
        raise G2oFormatError(path, None, "is a directory, not a g2o file") from None
    except PermissionError:
        raise G2oFormatError(path, None, "permission denied") from None
    with handle:
        if path.is_dir():
            raise G2oFormatError(path, None, "is a directory, not a g2o file")
        number = 0
        while True:
            # readline with a limit: a file without newlines (/dev/zero, a huge sparse file)
            # costs at most MAX_LINE_BYTES of memory before it is refused.
            raw = handle.readline(MAX_LINE_BYTES + 1)
            if not raw:
                return
            number += 1
            if len(raw) > MAX_LINE_BYTES:
                if b"\r" in raw and b"\n" not in raw:
                    raise G2oFormatError(path, number, "lines end in CR alone (classic Mac "
                                         "line endings); convert them to LF or CR LF")
                raise G2oFormatError(path, number,
                                     f"line longer than {MAX_LINE_BYTES} bytes (not a g2o file?)")
            if b"\r" in raw.rstrip(b"\r\n"):
                raise G2oFormatError(path, number, "a CR inside a line (classic Mac line "
                                     "endings?); convert them to LF or CR LF")
            if number == 1 and raw.startswith(b"\xef\xbb\xbf"):  # a UTF-8 byte-order mark
                raw = raw[3:]
            if b"\x00" in raw:
                raise G2oFormatError(path, number, "binary data, not a g2o text file")
            try:
                yield number, raw.decode("utf-8")
            except UnicodeDecodeError:
                raise G2oFormatError(path, number, "not UTF-8 text (binary file?)") from None


def _parse(path: Path) -> _Parsed:
    parsed = _Parsed()
    for number, text in numbered_lines(path):
        tokens = text.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        tag = tokens[0]
        fields = tokens[1:]
        if tag == "VERTEX_SE2":
            _parse_vertex(path, number, fields, parsed)
        elif tag == "EDGE_SE2":
            _parse_edge(path, number, fields, parsed)
        elif tag == "FIX":
            if not fields:
                raise G2oFormatError(path, number, "FIX needs at least one vertex id")
            parsed.fixed.extend((parse_id(path, number, f), number) for f in fields)
        elif tag.upper().startswith(_3D_TAGS):
            raise G2oFormatError(path, number, f"{short_token(tag)}: 3D graphs are not supported")
        else:
            raise G2oFormatError(
                path, number, f"unknown tag '{short_token(tag)}' (this reader takes VERTEX_SE2, "
                "EDGE_SE2 and FIX)"
            )
    if not parsed.vertices and not parsed.edges:
        raise G2oFormatError(path, None, "holds no VERTEX_SE2 or EDGE_SE2 line")
    if not parsed.edges:
        raise G2oFormatError(path, None, "holds no EDGE_SE2 line: a pose graph needs edges")
    return parsed


def short_token(token: str, limit: int = 40) -> str:
    printable = token.encode("unicode_escape").decode("ascii")
    return printable if len(printable) <= limit else printable[:limit] + "..."


def parse_id(path: Path, line: int, token: str) -> int:
    if not token.isascii() or not token.isdigit():
        raise G2oFormatError(
            path, line, f"vertex id must be a non-negative integer, found '{short_token(token)}'"
        )
    # GTSAM keys are 64-bit; the length test first keeps int() off huge digit strings.
    if len(token.lstrip("0")) > 20 or int(token) >= 2**64:
        raise G2oFormatError(path, line, f"vertex id {short_token(token)} is too large")
    return int(token)


def parse_numbers(path: Path, line: int, tag: str, tokens: list[str], first: int) -> list[float]:
    """Parse ``tokens`` as floats; ``first`` is the position of tokens[0] after the tag."""
    numbers = []
    for position, token in enumerate(tokens, start=first):
        try:
            if not token.isascii() or "_" in token:  # float() takes '1_0' and other digits
                raise ValueError(token)
            number = float(token)
        except ValueError:
            raise G2oFormatError(
                path, line, f"{tag} field {position} is not a number: '{short_token(token)}'"
            ) from None
        if not math.isfinite(number):
            raise G2oFormatError(path, line, f"{tag} field {position} is not finite: '{token}'")
        numbers.append(number)
    return numbers


def _parse_vertex(path: Path, line: int, fields: list[str], parsed: _Parsed) -> None:
    if len(fields) != _VERTEX_NUMBERS:
        raise G2oFormatError(
            path, line,
            f"VERTEX_SE2 needs {_VERTEX_NUMBERS} numbers after the tag, found {len(fields)}",
        )
    key = parse_id(path, line, fields[0])
    x, y, theta = parse_numbers(path, line, "VERTEX_SE2", fields[1:], first=2)
    if key in parsed.vertices:
        raise G2oFormatError(
            path, line,
            f"VERTEX_SE2 id {key} defined twice (first on line {parsed.vertex_lines[key]})",
        )
    parsed.vertices[key] = (x, y, theta)
    parsed.vertex_lines[key] = line


def _parse_edge(path: Path, line: int, fields: list[str], parsed: _Parsed) -> None:
    if len(fields) != _EDGE_NUMBERS:
        raise G2oFormatError(
            path, line,
            f"EDGE_SE2 needs {_EDGE_NUMBERS} numbers after the tag, found {len(fields)}",
        )
    i, j = parse_id(path, line, fields[0]), parse_id(path, line, fields[1])
    if i == j:
        raise G2oFormatError(path, line, f"EDGE_SE2 joins vertex {i} to itself")
    numbers = parse_numbers(path, line, "EDGE_SE2", fields[2:], first=3)
    xx, xy, xt, yy, yt, tt = numbers[3:]
    information = np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]])
    problem = information_problem(information)
    if problem is not None:
        raise G2oFormatError(path, line, f"EDGE_SE2 {problem}")
    parsed.edges.append(_Edge(line, i, j, (numbers[0], numbers[1], numbers[2]), information))


def _check_edges(path: Path, parsed: _Parsed) -> None:
    if parsed.vertices:
        for edge in parsed.edges:
            for key in (edge.i, edge.j):
                if key not in parsed.vertices:
                    raise G2oFormatError(
                        path, edge.line,
                        f"EDGE_SE2 refers to vertex {key}, which no VERTEX_SE2 line defines",
                    )
    known = parsed.vertices.keys() | {k for e in parsed.edges for k in (e.i, e.j)}
    for key, line in parsed.fixed:
        if key not in known:
            raise G2oFormatError(path, line, f"FIX refers to vertex {key}, which is not defined")


def _chain_odometry(edges: list[_Edge]) -> dict[int, tuple[float, float, float]]:
    """Initial poses composed along i -> i+1 edges; vertices off the chain via any edge.

    The chain runs from the smallest key through consecutive keys for as long as an edge
    joins them (the first such edge in file order, inverted if it runs j -> i); the other
    vertices are reached depth-first through any edge. Poses that overflow come back
    non-finite (the caller names the first).
    """
    first: dict[tuple[int, int], tuple[int, bool]] = {}  # pair -> (edge index, inverted?)
    neighbours: dict[int, list[tuple[int, int, bool]]] = {}
    for index, edge in enumerate(edges):
        first.setdefault((edge.i, edge.j), (index, False))
        first.setdefault((edge.j, edge.i), (index, True))
        neighbours.setdefault(edge.i, []).append((edge.j, index, False))
        neighbours.setdefault(edge.j, []).append((edge.i, index, True))
    keys = sorted(neighbours)
    length = 1
    while length < len(keys) and (keys[length - 1], keys[length]) in first:
        length += 1
    measured = np.array([edge.measured for edge in edges], dtype=float).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        steps = _steps(measured, [first[pair] for pair in zip(keys, keys[1:length], strict=False)])
        chained = chain(steps)
        poses = {key: chained[k] for k, key in enumerate(keys[:length])}
        frontier = list(poses)
        while frontier:
            key = frontier.pop()
            for other, index, inverted in neighbours[key]:
                if other not in poses:
                    step = _steps(measured, [(index, inverted)])
                    poses[other] = compose(poses[key][None], step)[0]
                    frontier.append(other)
    return {key: (float(x), float(y), float(theta)) for key, (x, y, theta) in poses.items()}


def _steps(measured: np.ndarray, chosen: list[tuple[int, bool]]) -> np.ndarray:
    """(k, 3) the measurements of the chosen edges (angles wrapped, as a ``gtsam.Pose2``
    holds them), inverted where marked."""
    index = np.array([i for i, _ in chosen], dtype=np.int64)
    inverted = np.array([flag for _, flag in chosen], dtype=bool)
    steps = measured[index]
    steps[:, 2] = wrap(steps[:, 2])
    steps[inverted] = inverse(steps[inverted])
    return steps


def _check_connected(path: Path, parsed: _Parsed) -> None:
    keys = parsed.vertices.keys() or {k for edge in parsed.edges for k in (edge.i, edge.j)}
    problem = disconnection(keys, [(edge.i, edge.j) for edge in parsed.edges])
    if problem is not None:
        raise G2oFormatError(path, None, problem)


def format_15(value: float) -> str:
    # GTSAM stores an angle as (cos, sin) and a noise model as its square-root information,
    # so theta() and R^T R come back within an ulp or so of what was read. Fifteen
    # significant digits undo that: a file's own decimals come back unchanged, and
    # write -> read -> write gives the same text.
    return repr(float(f"{value:.15g}"))


def g2o_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """The planar g2o text of ``graph`` and ``values`` (what :func:`write_g2o` writes).

    Raises:
        OutputError: a factor or information that a g2o file cannot hold.
    """
    return g2o_text_lines(graph, values)[0]


def g2o_text_lines(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> tuple[str, list[int | None]]:
    """:func:`g2o_text`, and the line (1-based) of that text which holds each factor.

    ``lines[k]`` is the ``EDGE_SE2`` line of ``graph.at(k)``, or the one ``FIX`` line for a
    prior, or None for an empty factor slot: the lines :func:`read_g2o_lines` names when it
    reads the text back.

    Raises:
        OutputError: a factor or information that a g2o file cannot hold.
    """
    lines = []
    factor_lines: list[int | None] = []
    priors = []
    for key in sorted(values.keys()):
        try:
            pose = values.atPose2(key)
        except RuntimeError:
            raise OutputError(f"value of key {key} is not a Pose2: a planar g2o file holds "
                              "Pose2 vertices only") from None
        numbers = (pose.x(), pose.y(), pose.theta())
        if not all(math.isfinite(v) for v in numbers):
            raise OutputError(f"vertex {key} is not finite ({numbers[0]!r}, {numbers[1]!r}, "
                              f"{numbers[2]!r}): the file would not read back")
        lines.append(f"VERTEX_SE2 {key} {pose.x()!r} {pose.y()!r} {format_15(pose.theta())}")
    fixed = []
    for index in range(graph.size()):
        factor = graph.at(index)
        for key in [] if factor is None else factor.keys():
            if not values.exists(key):
                raise OutputError(f"factor {index} refers to key {key}, which has no value: "
                                  "the file would not read back")
        if isinstance(factor, gtsam.BetweenFactorPose2):
            i, j = factor.keys()
            z = factor.measured()
            if i == j:
                raise OutputError(f"edge {i}-{j} joins a vertex to itself: the file would not "
                                  "read back")
            model = factor.noiseModel()
            if not isinstance(model, gtsam.noiseModel.Gaussian) or isinstance(
                    model, gtsam.noiseModel.Constrained):
                raise OutputError(f"edge {i}-{j} has a {type(model).__name__} noise model: a g2o "
                                  "edge holds a Gaussian information matrix only")
            if not all(math.isfinite(v) for v in (z.x(), z.y(), z.theta())):
                raise OutputError(f"edge {i}-{j}: the measurement is not finite")
            info = model.information()
            problem = information_problem(info)
            if problem is not None:
                raise OutputError(f"edge {i}-{j}: {problem} (the reader would refuse it)")
            upper = (info[0, 0], info[0, 1], info[0, 2], info[1, 1], info[1, 2], info[2, 2])
            lines.append(
                f"EDGE_SE2 {i} {j} {z.x()!r} {z.y()!r} {format_15(z.theta())} "
                + " ".join(format_15(v) for v in upper)
            )
            factor_lines.append(len(lines))
        elif isinstance(factor, gtsam.PriorFactorPose2):
            if not isinstance(factor.noiseModel(), gtsam.noiseModel.Constrained):
                raise OutputError(f"prior on key {factor.keys()[0]}: a soft prior has no planar "
                                  "g2o line (FIX holds a pose exactly)")
            fixed.append(factor.keys()[0])
            priors.append(index)
            factor_lines.append(None)  # the FIX line, numbered once every edge is written
        elif factor is not None:
            raise OutputError(f"cannot write a {type(factor).__name__} as a planar g2o line")
        else:
            factor_lines.append(None)
    # FIX lines of at most _FIX_PER_LINE ids: one line for every FIXed id would outgrow the
    # reader's line limit (15 001 ids made 78 899 bytes)
    for start in range(0, len(fixed), _FIX_PER_LINE):
        lines.append("FIX " + " ".join(str(key) for key in fixed[start:start + _FIX_PER_LINE]))
        for index in priors[start:start + _FIX_PER_LINE]:
            factor_lines[index] = len(lines)
    return "\n".join(lines) + "\n", factor_lines


def edge_list_text(
    graph: gtsam.NonlinearFactorGraph, indices: list[int], lines: list[int | None], *,
    title: str, g2o_name: str,
) -> str:
    """A list of some edges of a g2o file, one a line: ``line <L> EDGE_SE2 <id_i> <id_j>``.

    ``L`` is the edge's line in the g2o file ``g2o_name`` (``lines[k]`` for factor ``k``, as
    :func:`read_g2o_lines` or :func:`g2o_text_lines` give them), ``id_i`` and ``id_j`` its
    vertex ids, in the order of ``indices``. One comment line opens the list: ``# <title>:``
    and the format. Lines that start with ``#`` are comments; every other line has those five
    fields.

    Raises:
        OutputError: an index that is not an edge with a line.
    """
    header = f"{title}: {EDGE_LIST_LINE}, L the edge's line in {g2o_name}"
    rows = ["# " + " ".join(header.splitlines())]  # one line, whatever the name holds
    for index in indices:
        factor = graph.at(index) if 0 <= index < graph.size() else None
        line = lines[index] if 0 <= index < len(lines) else None
        if not isinstance(factor, gtsam.BetweenFactorPose2) or line is None:
            raise OutputError(f"factor {index} is not an edge of the g2o file")
        i, j = factor.keys()
        rows.append(f"line {line} EDGE_SE2 {i} {j}")
    return "\n".join(rows) + "\n"


def write_g2o(
    path: str | os.PathLike[str], graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> None:
    """Write ``graph`` and ``values`` as a planar g2o file, atomically.

    The text goes to a temporary file beside ``path`` that then replaces it, so a failed
    write leaves any existing file untouched. Positions round-trip exactly through
    :func:`read_g2o`; angles and information entries are written with 15 significant
    digits, so values read from a file with up to 15 digits come back exactly.

    Raises:
        OutputError: ``path`` is a directory or cannot be written. (Refusing to overwrite
            an input is the caller's policy: the commands check it before any work.)
    """
    write_text(path, g2o_text(graph, values))
