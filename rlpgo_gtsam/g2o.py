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

Two readers apply these rules. The fast one reads a regular file in chunks of
:data:`_CHUNK_BYTES` and parses all ``VERTEX_SE2`` and ``EDGE_SE2`` lines of a chunk at once
(fields split and counted per chunk, numbers converted column by column, each distinct
information matrix checked once). It only ever accepts: at the first thing it does not
recognise as valid (a malformed line, an unusual token or separator, a duplicate id, an
unusable information matrix, a very long line) the careful reader reads the file again
line by line and raises the error of the first bad line, or accepts what it accepts. Both
produce the same :class:`_Table`; the checks across lines (undefined vertices, FIX ids,
connectivity), the chained initial guess and the GTSAM graph are built from it once.

The writer gets each vertex and factor from GTSAM once, formats each distinct information
matrix once and the numbers in bulk (``%`` over one template); anything it cannot write as
is goes to the careful writer, which raises the error that names it.
"""

from __future__ import annotations

import itertools
import math
import operator
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

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
# A line whose tag starts so is a 3D one.
TAGS_3D = ("VERTEX_SE3", "EDGE_SE3", "VERTEX3", "EDGE3", "VERTEX_TRACKXYZ", "EDGE_SE3_")
# The fast reader's chunk (2 MiB: about 10 000 edge lines) and the longest line it takes;
# a longer one, or anything near MAX_LINE_BYTES, is the careful reader's to judge.
_CHUNK_BYTES = 1 << 21
_FAST_LINE_BYTES = MAX_LINE_BYTES // 2
_BOM = b"\xef\xbb\xbf"  # a UTF-8 byte-order mark, skipped at the start of line 1
_KEY_DIGITS = 20  # 2**64 - 1 has 20 digits
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # g2o's order of the information


@dataclass
class _Table:
    """A g2o file as arrays, in file order: what both readers produce.

    Attributes:
        vertex_keys: (n,) uint64 the VERTEX_SE2 ids.
        vertex_poses: (n, 3) x, y, theta of those lines.
        edge_keys: (m, 2) uint64 the ids i, j of each EDGE_SE2 line.
        edge_lines: (m,) the 1-based line of each edge.
        measured: (m, 3) dx, dy, dtheta of each edge.
        information: the distinct 3x3 information matrices (each checked once).
        model: (m,) the index of each edge's matrix in ``information``.
        fixed: (id, line) of each id of the FIX lines.
    """

    vertex_keys: np.ndarray
    vertex_poses: np.ndarray
    edge_keys: np.ndarray
    edge_lines: np.ndarray
    measured: np.ndarray
    information: list[np.ndarray]
    model: np.ndarray
    fixed: list[tuple[int, int]]


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
    return _build(path, _read_table(path, fast=True))


def _read_table(path: Path, fast: bool) -> _Table:
    """The file's table: by the fast reader where it accepts the file (``fast``, a regular
    file), else by the careful one, on the same open file."""
    with _open(path) as handle:
        table = None
        if stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            table = _scan(handle) if fast else None
            handle.seek(0)
        # a pipe or device is read once, by the careful reader
        return table if table is not None else _parse(path, handle)


def _open(path: Path) -> BinaryIO:
    try:
        handle = path.open("rb")
    except FileNotFoundError:
        raise InputNotFoundError(path) from None
    except IsADirectoryError:
        raise G2oFormatError(path, None, "is a directory, not a g2o file") from None
    except PermissionError:
        raise G2oFormatError(path, None, "permission denied") from None
    if path.is_dir():
        handle.close()
        raise G2oFormatError(path, None, "is a directory, not a g2o file")
    return handle


# --------------------------------------------------------------------------- the fast reader


@dataclass
class _Scan:
    """What the fast reader has gathered so far, one list entry per chunk."""

    vertex_keys: list[np.ndarray] = field(default_factory=list)
    vertex_poses: list[np.ndarray] = field(default_factory=list)
    edge_keys: list[np.ndarray] = field(default_factory=list)
    edge_lines: list[np.ndarray] = field(default_factory=list)
    measured: list[np.ndarray] = field(default_factory=list)
    model: list[np.ndarray] = field(default_factory=list)
    information: list[np.ndarray] = field(default_factory=list)
    matrix_index: dict[bytes, int] = field(default_factory=dict)  # matrix bytes -> index
    fixed: list[tuple[int, int]] = field(default_factory=list)
    lines: int = 0  # lines read so far


def _scan(handle: BinaryIO) -> _Table | None:
    """The fast reader: the table of the file, or None where the careful reader must judge.

    Memory: one chunk of text and the arrays of the lines parsed so far.
    """
    scan = _Scan()
    pending = b""  # the unfinished last line of the previous chunk
    first = True
    while True:
        chunk = handle.read(_CHUNK_BYTES)
        data = pending + chunk
        if chunk:
            cut = data.rfind(b"\n") + 1
            data, pending = data[:cut], data[cut:]
            if len(pending) > _FAST_LINE_BYTES:
                return None
        if data:
            if first and data.startswith(_BOM):
                data = data[len(_BOM):]
            first = False
            if not _scan_block(data, scan):
                return None
        if not chunk:
            break
    keys = np.concatenate(scan.vertex_keys) if scan.vertex_keys else np.zeros(0, np.uint64)
    if len(np.unique(keys)) != len(keys):
        return None  # an id defined twice: the careful reader names both lines
    return _Table(
        vertex_keys=keys,
        vertex_poses=_stack(scan.vertex_poses, (0, 3), float),
        edge_keys=_stack(scan.edge_keys, (0, 2), np.uint64),
        edge_lines=_stack(scan.edge_lines, (0,), np.int64),
        measured=_stack(scan.measured, (0, 3), float),
        information=scan.information,
        model=_stack(scan.model, (0,), np.int64),
        fixed=scan.fixed,
    )


def _stack(parts: list[np.ndarray], empty: tuple[int, ...], dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty, dtype)


def _scan_block(data: bytes, scan: _Scan) -> bool:
    """Parse the whole lines in ``data`` into ``scan``; False at anything unusual."""
    if b"\x00" in data:
        return False
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    if "\r" in text and text.count("\r") != text.count("\r\n"):
        return False  # a CR that does not end a line
    lines = text.split("\n")  # as the careful reader: b"\n" ends a line, nothing else
    if text.endswith("\n"):
        lines.pop()
    width = 1 if text.isascii() else 4  # UTF-8 bytes per character, at most
    if len(data) > _FAST_LINE_BYTES and max(map(len, lines)) * width > _FAST_LINE_BYTES:
        return False
    vertices: list[str] = []
    edges: list[str] = []
    edge_numbers: list[int] = []
    number = scan.lines
    for line in lines:
        number += 1
        if line.startswith("EDGE_SE2 "):
            edges.append(line)
            edge_numbers.append(number)
        elif line.startswith("VERTEX_SE2 "):
            vertices.append(line)
        else:  # comments, blank lines, FIX, other spacing; anything else is not for us
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            if tokens[0] == "EDGE_SE2":
                edges.append(line)
                edge_numbers.append(number)
            elif tokens[0] == "VERTEX_SE2":
                vertices.append(line)
            elif tokens[0] == "FIX" and len(tokens) > 1:
                keys = _plain_keys(tokens[1:])
                if keys is None:
                    return False
                scan.fixed.extend((key, number) for key in keys)
            else:
                return False
    scan.lines = number
    return ((not vertices or _scan_vertices(vertices, scan))
            and (not edges or _scan_edges(edges, edge_numbers, scan)))


def _columns(lines: list[str], tag: str, count: int) -> list[list[str]] | None:
    """The fields of ``lines`` (each starting with ``tag``) column by column, if each line
    has ``count`` fields after its tag: ``columns[c]`` is field c + 1 of every line.

    The lines' tags sit at every (count + 1)-th token; the callers check every other token
    to be a number, so none is a tag and each line holds exactly count + 1 tokens.
    """
    tokens = " ".join(lines).split()
    width = count + 1
    if len(tokens) != width * len(lines) or tokens[0::width].count(tag) != len(lines):
        return None
    return [tokens[c::width] for c in range(1, width)]


def _plain_keys(tokens: list[str]) -> list[int] | None:
    """The ids, if every token is ASCII digits for a value below 2**64 (no leading zeros
    beyond 20 digits); None otherwise (the careful reader then judges them)."""
    joined = "".join(tokens)
    if not (joined.isascii() and joined.isdigit()) or max(map(len, tokens)) > _KEY_DIGITS:
        return None
    keys = list(map(int, tokens))
    return keys if max(keys) < 2**64 else None


def _plain_numbers(columns: list[list[str]]) -> np.ndarray | None:
    """(len(columns[0]), len(columns)) finite floats, if every token is an ASCII number
    without '_' (what the careful reader takes); None otherwise."""
    joined = "".join("".join(column) for column in columns)
    if not joined.isascii() or "_" in joined:
        return None
    numbers = np.empty((len(columns[0]), len(columns)))
    try:
        for c, column in enumerate(columns):
            numbers[:, c] = list(map(float, column))
    except ValueError:
        return None
    return numbers if np.isfinite(numbers).all() else None


def _scan_vertices(lines: list[str], scan: _Scan) -> bool:
    columns = _columns(lines, "VERTEX_SE2", _VERTEX_NUMBERS)
    if columns is None:
        return False
    keys, poses = _plain_keys(columns[0]), _plain_numbers(columns[1:])
    if keys is None or poses is None:
        return False
    scan.vertex_keys.append(np.array(keys, dtype=np.uint64))
    scan.vertex_poses.append(poses)
    return True


def _scan_edges(lines: list[str], numbers: list[int], scan: _Scan) -> bool:
    columns = _columns(lines, "EDGE_SE2", _EDGE_NUMBERS)
    if columns is None:
        return False
    keys_i, keys_j = _plain_keys(columns[0]), _plain_keys(columns[1])
    measured = _plain_numbers(columns[2:5])
    if keys_i is None or keys_j is None or measured is None:
        return False
    if any(map(operator.eq, keys_i, keys_j)):
        return False  # an edge from a vertex to itself
    # The information's six fields, as text: each distinct one is parsed and checked once.
    columns = columns[5:]
    if all(column.count(column[0]) == len(column) for column in columns):  # one for all
        index = _scan_information(tuple(column[0] for column in columns), scan)
        if index is None:
            return False
        model = np.full(len(lines), index, dtype=np.int64)
    else:
        rows = list(zip(*columns, strict=True))
        distinct: dict[tuple[str, ...], int] = dict.fromkeys(rows, 0)
        for row in distinct:
            index = _scan_information(row, scan)
            if index is None:
                return False
            distinct[row] = index
        model = np.fromiter(map(distinct.__getitem__, rows), np.int64, len(rows))
    scan.edge_keys.append(np.array([keys_i, keys_j], dtype=np.uint64).T)
    scan.edge_lines.append(np.array(numbers, dtype=np.int64))
    scan.measured.append(measured)
    scan.model.append(model)
    return True


def _scan_information(row: tuple[str, ...], scan: _Scan) -> int | None:
    """The index of the information matrix of ``row`` in ``scan.information`` (added if
    new), or None if a field is not a plain number or the matrix is unusable."""
    numbers = _plain_numbers([[token] for token in row])
    if numbers is None:
        return None
    information = _information(numbers[0].tolist())
    key = information.tobytes()
    index = scan.matrix_index.get(key)
    if index is None:
        if information_problem(information) is not None:
            return None
        index = scan.matrix_index[key] = len(scan.information)
        scan.information.append(information)
    return index


def _information(upper: list[float]) -> np.ndarray:
    """The symmetric 3x3 information of its six g2o fields (upper triangle, row by row)."""
    xx, xy, xt, yy, yt, tt = upper
    return np.array([[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]])


# --------------------------------------------------------------------------- the careful reader


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
    problems: dict[bytes, str | None] = field(default_factory=dict)  # information checked


def numbered_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, text) of each line of the file at ``path``, with the careful reader's
    checks (line length, NUL bytes, UTF-8, a byte-order mark): the 3D reader's lines."""
    with _open(path) as handle:
        yield from _lines(path, handle)


def _lines(path: Path, handle: BinaryIO) -> Iterator[tuple[int, str]]:
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
        if number == 1 and raw.startswith(_BOM):
            raw = raw[len(_BOM):]
        if b"\x00" in raw:
            raise G2oFormatError(path, number, "binary data, not a g2o text file")
        try:
            yield number, raw.decode("utf-8")
        except UnicodeDecodeError:
            raise G2oFormatError(path, number, "not UTF-8 text (binary file?)") from None


def _parse(path: Path, handle: BinaryIO) -> _Table:
    """The careful reader: line by line, raising at the first bad line."""
    parsed = _Parsed()
    for number, text in _lines(path, handle):
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
            parsed.fixed.extend(parse_fix(path, number, fields))
        elif tag.upper().startswith(TAGS_3D):
            if parsed.vertices or parsed.edges:
                raise G2oFormatError(path, number, f"{short_token(tag)}: a 3D line in a planar "
                                     "file (a file holds 2D or 3D lines, not both)")
            raise G2oFormatError(path, number, f"{short_token(tag)}: 3D graphs are not "
                                 "supported by the planar reader (read them with "
                                 "rlpgo_gtsam.read_g2o3d or read_pose_graph)")
        else:
            raise G2oFormatError(
                path, number, f"unknown tag '{short_token(tag)}' (this reader takes VERTEX_SE2, "
                "EDGE_SE2 and FIX)"
            )
    matrix_index: dict[bytes, int] = {}
    information: list[np.ndarray] = []
    for edge in parsed.edges:
        index = matrix_index.setdefault(edge.information.tobytes(), len(information))
        if index == len(information):
            information.append(edge.information)
    return _Table(
        vertex_keys=np.array(list(parsed.vertices), dtype=np.uint64),
        vertex_poses=np.array(list(parsed.vertices.values()), dtype=float).reshape(-1, 3),
        edge_keys=np.array([(e.i, e.j) for e in parsed.edges], dtype=np.uint64).reshape(-1, 2),
        edge_lines=np.array([e.line for e in parsed.edges], dtype=np.int64),
        measured=np.array([e.measured for e in parsed.edges], dtype=float).reshape(-1, 3),
        information=information,
        model=np.array([matrix_index[e.information.tobytes()] for e in parsed.edges],
                       dtype=np.int64),
        fixed=parsed.fixed,
    )


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


def parse_fix(path: Path, line: int, fields: list[str]) -> list[tuple[int, int]]:
    """(id, line) of each id of a ``FIX`` line (2D and 3D files alike)."""
    if not fields:
        raise G2oFormatError(path, line, "FIX needs at least one vertex id")
    return [(parse_id(path, line, field), line) for field in fields]


def fix_lines(keys: list[int]) -> list[tuple[str, slice]]:
    """The ``FIX`` lines (without line ends) that hold ``keys``, each with the slice of
    ``keys`` it holds: at most :data:`_FIX_PER_LINE` ids a line, since one line for every
    FIXed id would outgrow the reader's line limit (15 001 ids made 78 899 bytes)."""
    parts = [slice(start, start + _FIX_PER_LINE) for start in range(0, len(keys), _FIX_PER_LINE)]
    return [("FIX " + " ".join(map(str, keys[part])), part) for part in parts]


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
    information = _information(numbers[3:])
    key = information.tobytes()
    if key not in parsed.problems:  # one check per distinct matrix
        parsed.problems[key] = information_problem(information)
    problem = parsed.problems[key]
    if problem is not None:
        raise G2oFormatError(path, line, f"EDGE_SE2 {problem}")
    parsed.edges.append(_Edge(line, i, j, (numbers[0], numbers[1], numbers[2]), information))


# --------------------------------------------------------------------------- both readers


def _build(
    path: Path, table: _Table
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int]]:
    """The checks across lines, then the GTSAM graph, values and factor lines."""
    if not len(table.vertex_keys) and not len(table.edge_keys):
        raise G2oFormatError(path, None, "holds no VERTEX_SE2 or EDGE_SE2 line")
    if not len(table.edge_keys):
        raise G2oFormatError(path, None, "holds no EDGE_SE2 line: a pose graph needs edges")
    _check_edges(path, table)
    _check_connected(path, table)
    keys, poses = table.vertex_keys, table.vertex_poses
    if not len(keys):
        chained = _chain_odometry(table.edge_keys, table.measured)
        for key, pose in chained.items():
            if not all(math.isfinite(v) for v in pose):
                raise G2oFormatError(
                    path, None, f"chaining the edges overflows at vertex {key}: give VERTEX_SE2 "
                    "lines"
                )
        keys = np.array(list(chained), dtype=np.uint64)
        poses = np.array(list(chained.values()), dtype=float).reshape(-1, 3)
    # One noise model per distinct information matrix, shared by its edges. Flat lists of
    # numbers: a list of lists per edge would wake the garbage collector thousands of times.
    models = [gtsam.noiseModel.Gaussian.Information(matrix) for matrix in table.information]
    graph = gtsam.NonlinearFactorGraph()
    add, between, pose2 = graph.add, gtsam.BetweenFactorPose2, gtsam.Pose2
    for i, j, x, y, theta, model in zip(*table.edge_keys.T.tolist(), *table.measured.T.tolist(),
                                        map(models.__getitem__, table.model.tolist()),
                                        strict=True):
        add(between(i, j, pose2(x, y, theta), model))
    values = gtsam.Values()
    insert = _pose2_inserter(values)
    order = np.argsort(keys, kind="stable")
    for key, x, y, theta in zip(keys[order].tolist(), *poses[order].T.tolist(), strict=True):
        insert(key, pose2(x, y, theta))
    lines = table.edge_lines.tolist()
    for key, line in table.fixed:
        graph.add(
            gtsam.PriorFactorPose2(key, values.atPose2(key), gtsam.noiseModel.Constrained.All(3))
        )
        lines.append(line)
    return graph, values, lines


def _pose2_inserter(values: gtsam.Values):
    """``values.insert`` for a key and a Pose2, the faster way where this GTSAM allows it.

    ``Values.insert`` has some 46 overloads, which pybind11 tries in turn; naming the pose
    argument (``pose2`` in GTSAM's wrapper) passes over the others unconverted: about 5 us
    a pose instead of 8, more than all the rest of a vertex line costs.
    """
    try:
        gtsam.Values().insert(0, pose2=gtsam.Pose2())
    except TypeError:  # a wrapper that names it otherwise
        return values.insert
    insert = values.insert
    return lambda key, pose: insert(key, pose2=pose)


def _check_edges(path: Path, table: _Table) -> None:
    keys_i, keys_j = table.edge_keys[:, 0], table.edge_keys[:, 1]
    if len(table.vertex_keys):
        known_i = np.isin(keys_i, table.vertex_keys)
        known_j = np.isin(keys_j, table.vertex_keys)
        unknown = np.flatnonzero(~(known_i & known_j))
        if len(unknown):
            k = unknown[0]
            key = int(keys_i[k] if not known_i[k] else keys_j[k])
            raise G2oFormatError(
                path, int(table.edge_lines[k]),
                f"EDGE_SE2 refers to vertex {key}, which no VERTEX_SE2 line defines",
            )
    if table.fixed:
        known = np.isin(np.array([key for key, _ in table.fixed], dtype=np.uint64),
                        np.concatenate([table.vertex_keys, table.edge_keys.ravel()]))
        if not known.all():
            key, line = table.fixed[int(np.argmin(known))]
            raise G2oFormatError(path, line, f"FIX refers to vertex {key}, which is not defined")


def _chain_odometry(
    edge_keys: np.ndarray, measured: np.ndarray
) -> dict[int, tuple[float, float, float]]:
    """Initial poses composed along i -> i+1 edges; vertices off the chain via any edge.

    The chain runs from the smallest key through consecutive keys for as long as an edge
    joins them (the first such edge in file order, inverted if it runs j -> i); the other
    vertices are reached depth-first through any edge. Poses that overflow come back
    non-finite (the caller names the first).
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


def _check_connected(path: Path, table: _Table) -> None:
    keys = table.vertex_keys if len(table.vertex_keys) else np.unique(table.edge_keys)
    problem = disconnection(keys.tolist(), table.edge_keys.tolist())
    if problem is not None:
        raise G2oFormatError(path, None, problem)


# --------------------------------------------------------------------------- writing


def format_15(value: float) -> str:
    # GTSAM stores an angle as (cos, sin) and a noise model as its square-root information,
    # so theta() and R^T R come back within an ulp or so of what was read. Fifteen
    # significant digits undo that: a file's own decimals come back unchanged, and
    # write -> read -> write gives the same text.
    return repr(float(f"{value:.15g}"))


def _round_15(values: list[float]) -> list[float]:
    """``float(f"{v:.15g}")`` of each value, formatted in one call: what :func:`format_15`
    writes is the ``repr`` of these."""
    return list(map(float, (("%.15g " * len(values)) % tuple(values)).split()))


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
    written = _text_fast(graph, values)
    return written if written is not None else _text_careful(graph, values)


def _text_fast(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> tuple[str, list[int | None]] | None:
    """The text and factor lines, each vertex and factor read from GTSAM once and the
    numbers formatted in bulk; None at anything :func:`_text_careful` must judge (it then
    raises the error for it)."""
    keys = list(values.keys())
    if not keys or keys != sorted(keys):
        return None
    poses = gtsam.utilities.extractPose2(values)  # x, y, theta() of the Pose2 values, by key
    if poses.shape != (len(keys), 3) or not np.isfinite(poses).all():
        return None  # a value that is not a Pose2, or not finite
    between, prior = gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2
    factors = list(map(graph.at, range(graph.size())))
    kinds = list(map(type, factors))
    if kinds.count(between) + kinds.count(prior) + kinds.count(type(None)) != len(kinds):
        return None  # another factor type (or a subclass): the careful writer judges it
    edges = [factor for factor, kind in zip(factors, kinds, strict=True) if kind is between]
    priors = [index for index, kind in enumerate(kinds) if kind is prior]
    # Each call runs over all edges at once (map of the unbound methods).
    edge_keys = list(itertools.chain.from_iterable(map(between.keys, edges)))
    measured = list(map(between.measured, edges))
    dx, dy = list(map(gtsam.Pose2.x, measured)), list(map(gtsam.Pose2.y, measured))
    dtheta = list(map(gtsam.Pose2.theta, measured))
    models = list(map(between.noiseModel, edges))  # held: each id stays its model's own
    texts: dict[int, str | None] = dict.fromkeys(map(id, models))
    by_matrix: dict[bytes, str] = {}
    for model in models:
        if texts[id(model)] is None:
            text = _information_text(model, by_matrix)
            if text is None:
                return None
            texts[id(model)] = text
    information = list(map(texts.__getitem__, map(id, models)))
    fixed = [factors[index].keys()[0] for index in priors]
    if not all(isinstance(factors[index].noiseModel(), gtsam.noiseModel.Constrained)
               for index in priors):
        return None  # a soft prior
    known = set(keys)
    if not known.issuperset(edge_keys) or not known.issuperset(fixed):
        return None  # a factor on a key without a value
    if any(map(operator.eq, edge_keys[0::2], edge_keys[1::2])):
        return None  # an edge from a vertex to itself
    if not all(map(math.isfinite, dx + dy + dtheta)):
        return None
    xs, ys, thetas = poses.T.tolist()
    vertex_fields: list[object] = [None] * (4 * len(keys))
    vertex_fields[0::4], vertex_fields[1::4] = keys, xs
    vertex_fields[2::4], vertex_fields[3::4] = ys, _round_15(thetas)
    edge_fields: list[object] = [None] * (6 * len(edges))
    edge_fields[0::6], edge_fields[1::6] = edge_keys[0::2], edge_keys[1::2]
    edge_fields[2::6], edge_fields[3::6] = dx, dy
    edge_fields[4::6], edge_fields[5::6] = _round_15(dtheta), information
    text = [("VERTEX_SE2 %d %r %r %r\n" * len(keys)) % tuple(vertex_fields),
            ("EDGE_SE2 %d %d %r %r %r %s\n" * len(edges)) % tuple(edge_fields)]
    factor_lines: list[int | None] = [None] * len(factors)
    line = len(keys)
    for index, kind in enumerate(kinds):
        if kind is between:
            line += 1
            factor_lines[index] = line
    for fix, part in fix_lines(fixed):
        text.append(fix + "\n")
        line += 1
        for index in priors[part]:
            factor_lines[index] = line
    return "".join(text), factor_lines


def _information_text(model, by_matrix: dict[bytes, str]) -> str | None:
    """The six g2o fields of a Gaussian noise model's information (``by_matrix`` caches
    them per matrix), or None if a g2o edge cannot hold it."""
    if not isinstance(model, gtsam.noiseModel.Gaussian) or isinstance(
            model, gtsam.noiseModel.Constrained):
        return None
    info = model.information()
    key = info.tobytes()
    text = by_matrix.get(key)
    if text is None:
        if information_problem(info) is not None:
            return None
        text = by_matrix[key] = " ".join(format_15(info[a, b]) for a, b in _UPPER)
    return text


def _text_careful(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> tuple[str, list[int | None]]:
    """:func:`g2o_text_lines` one vertex and one factor at a time, raising at the first
    that a g2o file cannot hold."""
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
            lines.append(
                f"EDGE_SE2 {i} {j} {z.x()!r} {z.y()!r} {format_15(z.theta())} "
                + " ".join(format_15(info[a, b]) for a, b in _UPPER)
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
    for fix, part in fix_lines(fixed):
        lines.append(fix)
        for index in priors[part]:
            factor_lines[index] = len(lines)
    return "\n".join(lines) + "\n", factor_lines


def edge_list_text(
    graph: gtsam.NonlinearFactorGraph, indices: list[int], lines: list[int | None], *,
    title: str, g2o_name: str, tag: str = "EDGE_SE2",
) -> str:
    """A list of some edges of a g2o file, one a line: ``line <L> EDGE_SE2 <id_i> <id_j>``
    (``tag="EDGE_SE3:QUAT"``: the ``BetweenFactorPose3`` edges of a 3D file).

    ``L`` is the edge's line in the g2o file ``g2o_name`` (``lines[k]`` for factor ``k``, as
    :func:`read_g2o_lines`, :func:`g2o_text_lines` or
    :func:`rlpgo_gtsam.g2o3d.g2o3d_text_lines` give them), ``id_i`` and ``id_j`` its vertex
    ids, in the order of ``indices``. One comment line opens the list: ``# <title>:`` and the
    format. Lines that start with ``#`` are comments; every other line has those five fields.

    Raises:
        OutputError: an index that is not an edge with a line.
    """
    edge = gtsam.BetweenFactorPose3 if tag == "EDGE_SE3:QUAT" else gtsam.BetweenFactorPose2
    header = f"{title}: {EDGE_LIST_LINE.replace('EDGE_SE2', tag)}, L the edge's line in {g2o_name}"
    rows = ["# " + " ".join(header.splitlines())]  # one line, whatever the name holds
    for index in indices:
        factor = graph.at(index) if 0 <= index < graph.size() else None
        line = lines[index] if 0 <= index < len(lines) else None
        if not isinstance(factor, edge) or line is None:
            raise OutputError(f"factor {index} is not an edge of the g2o file")
        i, j = factor.keys()
        rows.append(f"line {line} {tag} {i} {j}")
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
