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
:data:`_CHUNK_BYTES` (:func:`~rlpgo_gtsam.textscan.blocks`); numpy finds every line and field
of a chunk (:class:`~rlpgo_gtsam.textscan.Text`), the ``VERTEX_SE2`` and ``EDGE_SE2`` records
are checked and gathered column by column (ids by numpy, numbers by ``float()``'s own parser,
each distinct information matrix checked once, in a batch). It only ever accepts: at the
first thing it does not recognise as valid (a malformed line, an unusual token, a duplicate
id, an unusable information matrix, a very long line) the careful reader reads the file
again line by line and raises the error of the first bad line, or accepts what it accepts.
Both produce the same :class:`_Table`; the checks across lines (undefined vertices, FIX ids,
connectivity), the chained initial guess and the GTSAM graph are built from it once: one
noise model per distinct matrix, and the values, where the fast reader read every vertex
line as plain text, by ``gtsam.readG2o`` from those lines held in memory (Linux), kept only
if they are the values this reader read (:func:`_values_by_gtsam`).
:func:`read_g2o_extracted` also hands over the graph's extraction
(:class:`~rlpgo_gtsam.graph.PoseGraph2D`), made from the table and the objects just built
(the same arrays as a walk over the factors, which a command then does not repeat).

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
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, TypeVar

import gtsam
import numpy as np

from rlpgo_gtsam.errors import G2oFormatError, InputNotFoundError, OutputError
from rlpgo_gtsam.files import write_text
from rlpgo_gtsam.graph import (
    PoseGraph2D,
    disconnection,
    information_problem,
    information_problems,
    pose2_inserter,
    poses_of_values,
)
from rlpgo_gtsam.se2 import chain, compose, inverse, wrap
from rlpgo_gtsam.textscan import BOM, Text, blocks

__all__ = ["read_g2o", "read_g2o_lines", "read_g2o_extracted", "write_g2o", "g2o_text",
           "g2o_text_lines", "edge_list_text", "EDGE_LIST_LINE"]

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
TAGS_2D = ("VERTEX_SE2", "EDGE_SE2", "VERTEX2", "EDGE2")  # a line's tag starting so is planar
# The fast reader's chunk (2 MiB: about 10 000 edge lines) and the longest line it takes;
# a longer one, or anything near MAX_LINE_BYTES, is the careful reader's to judge.
_CHUNK_BYTES = 1 << 21
_FAST_LINE_BYTES = MAX_LINE_BYTES // 2
_KEY_DIGITS = 20  # 2**64 - 1 has 20 digits
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # g2o's order of the information
T = TypeVar("T")


@dataclass(eq=False)
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
        vertex_text: the VERTEX_SE2 lines as read (a block per chunk), where the fast reader
            read them all as plain text (GTSAM's own parser may then build the values).
    """

    vertex_keys: np.ndarray
    vertex_poses: np.ndarray
    edge_keys: np.ndarray
    edge_lines: np.ndarray
    measured: np.ndarray
    information: list[np.ndarray]
    model: np.ndarray
    fixed: list[tuple[int, int]]
    vertex_text: list[bytes] | None = None


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
    path = Path(path)
    graph, values, _, _ = _build(path, _read_table(path, fast=True), lines=False)
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
    graph, values, lines, _ = _build(path, _read_table(path, fast=True))
    return graph, values, lines


def read_g2o_extracted(
    path: str | os.PathLike[str],
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], PoseGraph2D | None]:
    """:func:`read_g2o_lines`, and the graph's extraction
    (:meth:`~rlpgo_gtsam.graph.PoseGraph2D.from_gtsam`'s arrays, made from what the reader
    read), or None where the extraction would refuse the graph (its ``GraphError`` is then
    the caller's to raise, by extracting).

    Raises:
        G2oFormatError: as :func:`read_g2o`.
    """
    path = Path(path)
    return _build(path, _read_table(path, fast=True), extract=True)


def _read_table(path: Path, fast: bool) -> _Table:
    """The file's table: by the fast reader where it accepts the file (``fast``, a regular
    file), else by the careful one."""
    return read_either(path, _scan if fast else None, _parse)


def read_either(path: Path, scan: Callable[[BinaryIO], T | None] | None,
                parse: Callable[[Path, BinaryIO], T]) -> T:
    """What the fast reader ``scan`` makes of the file at ``path`` where it is a regular file
    and ``scan`` takes it (not None), else what the careful reader ``parse`` makes of it, on
    the same open file (a pipe or device is read once, by ``parse``)."""
    with open_g2o(path) as handle:
        if scan is not None and stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            table = scan(handle)
            if table is not None:
                return table
            handle.seek(0)
        return parse(path, handle)


def scan_blocks(handle: BinaryIO) -> Iterator[Text | None]:
    """The fast readers' blocks of a file (:func:`textscan.blocks`, with this module's chunk
    and line limit)."""
    return blocks(handle, _CHUNK_BYTES, _FAST_LINE_BYTES)


def open_g2o(path: Path) -> BinaryIO:
    """``path`` opened for reading (binary), or the one-line error that says why not."""
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


@dataclass(eq=False)
class _Scan:
    """What the fast reader has gathered so far, one list entry per chunk."""

    vertex_keys: list[np.ndarray] = field(default_factory=list)
    vertex_poses: list[np.ndarray] = field(default_factory=list)
    # the VERTEX_SE2 lines as read, for GTSAM's parser; None once one is not plain text
    vertex_text: list[bytes] | None = field(default_factory=list)
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

    Memory: one chunk of text and its arrays, and what the lines parsed so far hold.
    """
    scan = _Scan()
    for text in scan_blocks(handle):
        if text is None or not _scan_block(text, scan):
            return None
    keys = np.concatenate(scan.vertex_keys) if scan.vertex_keys else np.zeros(0, np.uint64)
    ordered = np.sort(keys)
    if (ordered[1:] == ordered[:-1]).any():
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
        vertex_text=scan.vertex_text,
    )


def _stack(parts: list[np.ndarray], empty: tuple[int, ...], dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty, dtype)


def _scan_block(text: Text, scan: _Scan) -> bool:
    """Parse the lines of ``text`` into ``scan``; False at anything unusual.

    The ``VERTEX_SE2`` and ``EDGE_SE2`` lines of plain text (:data:`textscan.PLAIN`) are
    read column by column; comments and blank lines are passed over; the other lines (FIX,
    the records that hold other bytes) one at a time, as the careful reader splits them.
    """
    plain = text.plain_lines()
    vertices = np.flatnonzero(plain & text.first_field_is(b"VERTEX_SE2"))
    edges = np.flatnonzero(plain & text.first_field_is(b"EDGE_SE2"))
    others = ~plain | ((text.count > 0) & (text.first_byte() != ord("#")))
    others[vertices] = others[edges] = False
    odd_vertices: list[list[str]] = []  # the tokens of records that hold other bytes
    odd_edges: list[tuple[int, list[str]]] = []  # (line, tokens)
    for index in np.flatnonzero(others).tolist():
        number = scan.lines + index + 1
        tokens = text.line(index).decode("utf-8").split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0] == "VERTEX_SE2":
            odd_vertices.append(tokens)
        elif tokens[0] == "EDGE_SE2":
            odd_edges.append((number, tokens))
        elif tokens[0] == "FIX" and len(tokens) > 1:
            keys = plain_keys(tokens[1:])
            if keys is None:
                return False
            scan.fixed.extend((key, number) for key in keys)
        else:
            return False
    if not (_scan_vertices(text, vertices, odd_vertices, scan)
            and _scan_edges(text, edges, odd_edges, scan)):
        return False
    scan.lines += len(text)
    return True


def plain_keys(tokens: list[str]) -> list[int] | None:
    """The ids, if every token is ASCII digits for a value below 2**64 (no leading zeros
    beyond 20 digits); None otherwise (the careful reader then judges them): the fast
    readers' FIX ids."""
    joined = "".join(tokens)
    if not (joined.isascii() and joined.isdigit()) or max(map(len, tokens)) > _KEY_DIGITS:
        return None
    keys = list(map(int, tokens))
    return keys if max(keys) < 2**64 else None


def _plain_numbers(tokens: list[str]) -> np.ndarray | None:
    """The tokens as finite floats, if every one is an ASCII number without '_' (what the
    careful reader takes); None otherwise."""
    joined = "".join(tokens)
    if not joined.isascii() or "_" in joined:
        return None
    try:
        numbers = np.array(list(map(float, tokens)))
    except ValueError:
        return None
    return numbers if np.isfinite(numbers).all() else None


def _scan_vertices(text: Text, lines: np.ndarray, odd: list[list[str]], scan: _Scan) -> bool:
    if len(lines):
        records = text.records(lines, _VERTEX_NUMBERS + 1, 1, 3)
        if records is None:
            return False
        scan.vertex_keys.append(records[0][:, 0])
        scan.vertex_poses.append(records[1])
        if scan.vertex_text is not None:
            scan.vertex_text.append(text.lines_text(lines))
    for tokens in odd:
        if len(tokens) != _VERTEX_NUMBERS + 1:
            return False
        keys, pose = plain_keys(tokens[1:2]), _plain_numbers(tokens[2:])
        if keys is None or pose is None:
            return False
        scan.vertex_keys.append(np.array(keys, dtype=np.uint64))
        scan.vertex_poses.append(pose[None])
        scan.vertex_text = None  # GTSAM's parser would not split this line as we do
    return True


def _scan_edges(text: Text, lines: np.ndarray, odd: list[tuple[int, list[str]]],
                scan: _Scan) -> bool:
    numbers, keys, measured, upper = [], [], [], []
    if len(lines):
        records = text.records(lines, _EDGE_NUMBERS + 1, 2, 3)
        if records is None:
            return False
        numbers.append(lines + (scan.lines + 1))
        keys.append(records[0])
        measured.append(records[1])
        # the information's six fields: usually the same text on every line, read once
        starts, ends = text.fields(lines, _EDGE_NUMBERS + 1)
        if text.same_text(starts[:, 6], ends[:, 11]):
            information = text.numbers(lines[:1], 6, 6)
            upper.append(None if information is None
                         else np.repeat(information, len(lines), axis=0))
        else:
            upper.append(text.numbers(lines, 6, 6))
    for number, tokens in odd:
        if len(tokens) != _EDGE_NUMBERS + 1:
            return False
        numbers.append(np.array([number]))
        keys.append(plain_keys(tokens[1:3]))
        fields = _plain_numbers(tokens[3:])
        measured.append(None if fields is None else fields[None, :3])
        upper.append(None if fields is None else fields[None, 3:])
    if not numbers:
        return True
    if any(part is None for part in keys + measured + upper):
        return False
    edge_keys = np.concatenate([np.asarray(k, dtype=np.uint64).reshape(-1, 2) for k in keys])
    if (edge_keys[:, 0] == edge_keys[:, 1]).any():
        return False  # an edge from a vertex to itself
    model = _scan_information(np.concatenate(upper), scan)
    if model is None:
        return False
    edge_lines = np.concatenate(numbers)
    order = np.argsort(edge_lines, kind="stable")  # the odd lines in their place
    scan.edge_keys.append(edge_keys[order])
    scan.edge_lines.append(edge_lines[order])
    scan.measured.append(np.concatenate(measured)[order])
    scan.model.append(model[order])
    return True


def distinct_rows(array: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``array`` (one row per leading index), told apart by their
    bytes: where each first appears (in the order they first appear) and, for each row,
    its index among them. One matrix for every row, the usual file's, is found without a
    sort."""
    flat = np.ascontiguousarray(array).reshape(len(array), -1)
    rows = flat.view(np.dtype((np.void, flat.shape[1] * flat.itemsize))).ravel()
    if len(rows) and (rows == rows[0]).all():
        return np.zeros(1, np.int64), np.zeros(len(rows), np.int64)
    # the rows' bytes as unsigned words, sorted stably (np.unique would do the same, but
    # numpy 2.4's imports numpy.ma for it: 4.5 ms of a command on MIT, Intel or FR079)
    words = np.ascontiguousarray(flat.view(np.uint8)).reshape(len(flat), -1)
    if words.shape[1] % 8 == 0:
        words = words.view(np.uint64)
    order = np.lexsort(words.T[::-1]) if words.shape[1] else np.arange(len(words))
    ordered = words[order]
    new = np.ones(len(order), bool)
    new[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    first = order[new]  # stable: each group's first row in the file
    inverse = np.empty(len(order), np.int64)
    inverse[order] = np.cumsum(new) - 1
    rank = np.argsort(first)
    return first[rank], np.argsort(rank)[inverse]


def _scan_information(upper: np.ndarray, scan: _Scan) -> np.ndarray | None:
    """The index in ``scan.information`` of each row's information matrix (six g2o fields a
    row): each distinct matrix is checked once, the new ones in one batch; None if one of
    them is unusable."""
    first, inverse = distinct_rows(upper)  # by their bytes, as the careful reader
    matrices = _informations(upper[first])
    keys = [matrix.tobytes() for matrix in matrices]
    new = [k for k, key in enumerate(keys) if key not in scan.matrix_index]
    if new:
        if any(problem is not None for problem in information_problems(matrices[new])):
            return None
        for k in new:
            scan.matrix_index[keys[k]] = len(scan.information)
            scan.information.append(matrices[k])
    index = np.array([scan.matrix_index[key] for key in keys], dtype=np.int64)
    return index[inverse.ravel()]


def _informations(upper: np.ndarray) -> np.ndarray:
    """(k, 3, 3) the symmetric information of each row of six g2o fields (upper triangle,
    row by row)."""
    matrices = np.empty((len(upper), 3, 3))
    for column, (a, b) in enumerate(_UPPER):
        matrices[:, a, b] = matrices[:, b, a] = upper[:, column]
    return matrices


def _information(upper: list[float]) -> np.ndarray:
    """The symmetric 3x3 information of its six g2o fields (upper triangle, row by row)."""
    return _informations(np.array([upper], dtype=float))[0]


# --------------------------------------------------------------------------- the careful reader


@dataclass(eq=False)
class _Edge:
    """An EDGE_SE2 line as the careful reader parsed it."""

    line: int
    i: int
    j: int
    measured: tuple[float, float, float]
    information: np.ndarray


@dataclass(eq=False)
class _Parsed:
    """What the careful reader has parsed so far."""

    vertices: dict[int, tuple[float, float, float]] = field(default_factory=dict)
    vertex_lines: dict[int, int] = field(default_factory=dict)
    edges: list[_Edge] = field(default_factory=list)
    fixed: list[tuple[int, int]] = field(default_factory=list)  # (id, line)
    problems: dict[bytes, str | None] = field(default_factory=dict)  # information checked


def numbered_lines(path: Path, handle: BinaryIO | None = None) -> Iterator[tuple[int, str]]:
    """(line number, text) of each line of the file at ``path`` (read from ``handle`` where
    given), with the careful reader's checks (line length, NUL bytes, UTF-8, a byte-order
    mark): what :func:`line_records` reads."""
    if handle is not None:
        yield from _lines(path, handle)
        return
    with open_g2o(path) as opened:
        yield from _lines(path, opened)


def line_records(path: Path, handle: BinaryIO | None = None
                 ) -> Iterator[tuple[int, str, list[str]]]:
    """(line number, tag, fields) of each line of :func:`numbered_lines` that is neither
    blank nor a comment: what the careful readers (planar and 3D) and
    :func:`~rlpgo_gtsam.dimension.g2o_dimension` read."""
    for number, text in numbered_lines(path, handle):
        tokens = text.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens[0], tokens[1:]


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
        if b"\r" in raw.rstrip(b"\r\n") and raw.strip():  # a blank line's stray CR: blank
            raise G2oFormatError(path, number, "a CR inside a line (classic Mac line "
                                 "endings?); convert them to LF or CR LF")
        if number == 1 and raw.startswith(BOM):
            raw = raw[len(BOM):]
        if b"\x00" in raw:
            raise G2oFormatError(path, number, "binary data, not a g2o text file")
        try:
            yield number, raw.decode("utf-8")
        except UnicodeDecodeError:
            raise G2oFormatError(path, number, "not UTF-8 text (binary file?)") from None


def _parse(path: Path, handle: BinaryIO) -> _Table:
    """The careful reader: line by line, raising at the first bad line."""
    parsed = _Parsed()
    for number, tag, fields in line_records(path, handle):
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
    path: Path, table: _Table, extract: bool = False, lines: bool = True
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], PoseGraph2D | None]:
    """The checks across lines, then the GTSAM graph, values and factor lines (``lines``;
    else an empty list), and (``extract``) the graph's extraction (:func:`_extraction`;
    else None)."""
    if not len(table.vertex_keys) and not len(table.edge_keys):
        raise G2oFormatError(path, None, "holds no VERTEX_SE2 or EDGE_SE2 line")
    if not len(table.edge_keys):
        raise G2oFormatError(path, None, "holds no EDGE_SE2 line: a pose graph needs edges")
    check_references(path, table.vertex_keys, table.edge_keys, table.edge_lines, table.fixed)
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
    edge_models = (itertools.repeat(models[0], len(table.model)) if len(models) == 1
                   else map(models.__getitem__, table.model.tolist()))
    graph = gtsam.NonlinearFactorGraph()
    pose2 = gtsam.Pose2
    # maps, not a loop, and the measurements kept only for the extraction: 0.06 s less for
    # 250 000 edges (the rows are as long by construction)
    measured = map(pose2, *table.measured.T.tolist())
    if extract:
        measured = list(measured)
    deque(map(graph.add, map(gtsam.BetweenFactorPose2, *table.edge_keys.T.tolist(), measured,
                             edge_models)), maxlen=0)
    order = np.argsort(keys, kind="stable")
    keys, poses = keys[order], poses[order]
    values = _values_by_gtsam(table.vertex_text, keys, poses) if table.vertex_text else None
    if values is None:
        values = gtsam.Values()
        insert = pose2_inserter(values)
        for key, x, y, theta in zip(keys.tolist(), *poses.T.tolist(), strict=True):
            insert(key, pose2(x, y, theta))
    factor_lines = table.edge_lines.tolist() if lines else []
    for key, line in table.fixed:
        graph.add(
            gtsam.PriorFactorPose2(key, values.atPose2(key), gtsam.noiseModel.Constrained.All(3))
        )
        if lines:
            factor_lines.append(line)
    if not extract:
        return graph, values, factor_lines, None
    return graph, values, factor_lines, _extraction(table, graph, values, keys, measured, models)


def _extraction(table: _Table, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                keys: np.ndarray, measured: list[gtsam.Pose2],
                models: list) -> PoseGraph2D | None:
    """What :meth:`PoseGraph2D.from_gtsam` makes of the graph just built, the same arrays
    bit for bit, from the reader's own table and objects instead of a walk over the
    graph's factors (MIT, Intel, FR079: one noise model per edge, 10-19 ms a read): the
    angles and information matrices as GTSAM gives them back (``theta()`` of each
    measurement, ``information()`` of each distinct model); the edges' pose indices, the
    FIX poses (hard priors, in graph order: the first is the anchor) from the sorted keys.
    None where extraction would refuse an information matrix: the caller's extraction
    then raises that error."""
    information = np.array([model.information() for model in models]).reshape(-1, 3, 3)
    if any(problem is not None for problem in information_problems(information)):
        return None
    poses = poses_of_values(values, keys.tolist())
    thetas = np.fromiter(map(gtsam.Pose2.theta, measured), float, len(measured))
    fixed = np.searchsorted(keys, np.array([key for key, _ in table.fixed], dtype=np.uint64))
    anchor = int(fixed[0]) if len(fixed) else 0
    result = PoseGraph2D(
        keys=keys,
        poses=poses,
        edges=np.searchsorted(keys, table.edge_keys).astype(np.int64).reshape(-1, 2),
        measured=np.column_stack([table.measured[:, :2], thetas]),
        information=information[table.model],
        anchor=anchor,
        fixed=fixed.astype(np.int64),
        fixed_poses=poses[fixed].reshape(-1, 3),
        anchor_pose=poses[anchor] if len(fixed) == 0 else poses[anchor].copy(),
        graph=graph,
    )
    result.check_connected()
    return result


_VALUES_SAMPLE = 1024  # vertices whose poses GTSAM's reading is compared on


def _values_by_gtsam(text: list[bytes], keys: np.ndarray,
                     poses: np.ndarray) -> gtsam.Values | None:
    """The values of the VERTEX_SE2 lines ``text``, built by GTSAM's own parser from a file
    held in memory; None where that cannot be done, or where GTSAM read them otherwise.

    ``text`` holds every vertex line of the file (in blocks), which this reader has read
    (and checked) as ``keys`` (ascending) and ``poses``. ``Values.insert`` costs some 5 us a
    call from Python, more than the rest of a vertex line; ``gtsam.readG2o`` builds the same
    ``Pose2(x, y, theta)`` values in C++ in about half the time, reading the text included.
    It needs a file name: a memfd (Linux) read through /proc. Its values are kept only if they
    are the ones this reader read: the same keys, and on an even sample of the vertices
    (below) x and y bit for bit, theta to 1e-9 rad (``theta()`` comes back from cos and
    sin); else the caller inserts them one by one.
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


def _members(values: np.ndarray, ordered: np.ndarray) -> np.ndarray:
    """(k,) bool: which ``values`` occur in the ascending array ``ordered`` (``np.isin``
    without the sort of both that it does, and without numpy.ma, which numpy 2.4's
    ``unique`` imports under it: 4.5 ms of every command)."""
    if not len(ordered):
        return np.zeros(len(values), bool)
    at = np.minimum(np.searchsorted(ordered, values), len(ordered) - 1)
    return ordered[at] == values


def check_references(path: Path, vertex_keys: np.ndarray, edge_keys: np.ndarray,
                     edge_lines: np.ndarray, fixed: list[tuple[int, int]],
                     vertex: str = "VERTEX_SE2", edge: str = "EDGE_SE2") -> None:
    """Raise the error of the first edge line (in file order) that names an id no vertex
    line defines (where the file has vertex lines), then of the first FIX id that no line
    names; ``vertex`` and ``edge`` are the tags in the messages."""
    keys_i, keys_j = edge_keys[:, 0], edge_keys[:, 1]
    if len(vertex_keys):
        defined = np.sort(vertex_keys)
        known_i, known_j = _members(keys_i, defined), _members(keys_j, defined)
        unknown = np.flatnonzero(~(known_i & known_j))
        if len(unknown):
            k = unknown[0]
            key = int(keys_i[k] if not known_i[k] else keys_j[k])
            raise G2oFormatError(path, int(edge_lines[k]),
                                 f"{edge} refers to vertex {key}, which no {vertex} line defines")
    if fixed:
        known = _members(np.array([key for key, _ in fixed], dtype=np.uint64),
                         np.sort(np.concatenate([vertex_keys, edge_keys.ravel()])))
        if not known.all():
            key, line = fixed[int(np.argmin(known))]
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
    problem = disconnection(keys, table.edge_keys)
    if problem is not None:
        raise G2oFormatError(path, None, problem)


# --------------------------------------------------------------------------- writing


def format_15(value: float) -> str:
    # GTSAM stores an angle as (cos, sin) and a noise model as its square-root information,
    # so theta() and R^T R come back within an ulp or so of what was read. Fifteen
    # significant digits undo that: a file's own decimals come back unchanged, and
    # write -> read -> write gives the same text.
    return repr(float(f"{value:.15g}"))


def texts_15(values: list[float]) -> list[str]:
    """:func:`format_15` of each value, with one formatting call for them all.

    For a normal double, ``'%.15g'`` writes the digits that ``repr`` writes of the double
    those digits name (any two decimals of 15 significant digits are distinct doubles, so
    none shorter names it), in the same style (an exponent below 1e-4) but for two things:
    ``repr`` adds '.0' to a whole number, and writes 1e15 .. 1e16 in full. Values from 1e15
    on (or rounded up to it) and subnormal ones are written by :func:`format_15` itself.
    """
    texts = (("%.15g " * len(values)) % tuple(values)).split()
    return [(text if "." in text or "e" in text else text + ".0")
            if value == 0 or (1e-300 < abs(value) < 1e15 and "e+15" not in text)
            else format_15(value) for text, value in zip(texts, values, strict=True)]


def g2o_text(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             pose_graph: PoseGraph2D | None = None) -> str:
    """The planar g2o text of ``graph`` and ``values`` (what :func:`write_g2o` writes).

    ``pose_graph``: the extraction of this very ``graph``, where the caller has it: the
    edges' measurements and informations and the FIXed ids then come from its arrays, not
    from a second walk over the factors (the same text; MIT, Intel, FR079: 5-9 ms less).

    Raises:
        OutputError: a factor or information that a g2o file cannot hold.
    """
    if pose_graph is not None:
        text = _text_of_extraction(graph, values, pose_graph)
        if text is not None:
            return text
    return g2o_text_lines(graph, values)[0]


def _text_of_extraction(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                        pose_graph: PoseGraph2D) -> str | None:
    """:func:`_text_fast`'s text from the extraction ``pose_graph`` of ``graph``; None where
    it is not this graph's, or the graph holds more than its edges and FIX priors (a soft
    prior, an empty slot: the walk judges those), or the fast writer would decline it."""
    g = pose_graph
    if g.graph is not graph or graph.size() != g.num_edges + len(g.fixed):
        return None  # extraction takes every factor as an edge, a hard or a soft prior
    keys = list(values.keys())
    if keys != g.keys.tolist() or (g.edges[:, 0] == g.edges[:, 1]).any() or \
            not np.isfinite(g.measured).all():
        return None
    poses = gtsam.utilities.extractPose2(values)
    if poses.shape != (len(keys), 3) or not np.isfinite(poses).all():
        return None
    # the informations passed extraction's check, the writer's (information_problems)
    first, inverse = distinct_rows(g.information)
    texts = upper_triangle_texts(g.information[first], 3)
    text = _lines_text(keys, poses, g.keys[g.edges[:, 0]].tolist(),
                       g.keys[g.edges[:, 1]].tolist(), g.measured,
                       [texts[k] for k in inverse.tolist()])
    return "".join([text, *(fix + "\n" for fix, _ in fix_lines(g.keys[g.fixed].tolist()))])


def _lines_text(keys: list[int], poses: np.ndarray, edge_i: list[int], edge_j: list[int],
                measured: np.ndarray | list, information: list[str]) -> str:
    """The VERTEX_SE2 and EDGE_SE2 lines of the fast writers, the numbers formatted in bulk:
    ``poses`` and ``measured`` (x, y, theta rows, or three lists of columns) give each line's
    numbers; ``information`` each edge's six fields."""
    xs, ys, thetas = poses.T.tolist()
    dx, dy, dtheta = measured.T.tolist() if isinstance(measured, np.ndarray) else measured
    vertex_fields: list[object] = [None] * (4 * len(keys))
    vertex_fields[0::4], vertex_fields[1::4] = keys, xs
    vertex_fields[2::4], vertex_fields[3::4] = ys, texts_15(thetas)
    edge_fields: list[object] = [None] * (6 * len(edge_i))
    edge_fields[0::6], edge_fields[1::6] = edge_i, edge_j
    edge_fields[2::6], edge_fields[3::6] = dx, dy
    edge_fields[4::6], edge_fields[5::6] = texts_15(dtheta), information
    return (("VERTEX_SE2 %d %r %r %s\n" * len(keys)) % tuple(vertex_fields)
            + ("EDGE_SE2 %d %d %r %r %s %s\n" * len(edge_i)) % tuple(edge_fields))


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
    between = gtsam.BetweenFactorPose2
    found = writable_factors(graph, between, gtsam.PriorFactorPose2)
    if found is None:
        return None
    kinds, edges, edge_keys, priors, fixed = found
    # Each call runs over all edges at once (map of the unbound methods).
    measured = list(map(between.measured, edges))
    dx, dy = list(map(gtsam.Pose2.x, measured)), list(map(gtsam.Pose2.y, measured))
    dtheta = list(map(gtsam.Pose2.theta, measured))
    information = information_texts(list(map(between.noiseModel, edges)), 3)
    if information is None:
        return None
    known = set(keys)
    if not known.issuperset(edge_keys) or not known.issuperset(fixed):
        return None  # a factor on a key without a value
    if any(map(operator.eq, edge_keys[0::2], edge_keys[1::2])):
        return None  # an edge from a vertex to itself
    if not all(map(math.isfinite, dx + dy + dtheta)):
        return None
    text = _lines_text(keys, poses, edge_keys[0::2], edge_keys[1::2], [dx, dy, dtheta],
                       information)
    return with_fix_lines([text], kinds, between, len(keys), priors, fixed)


def writable_factors(graph: gtsam.NonlinearFactorGraph, edge: type, prior: type
                     ) -> tuple[list[type], list, list[int], list[int], list[int]] | None:
    """A fast writer's view of ``graph``: the type of each factor, the ``edge`` factors and
    their keys (i, j, i, j, ...), the indices of the ``prior`` factors and their keys; None
    where a factor is of another type (or a subclass) or a prior is soft: the careful writer
    judges those."""
    factors = list(map(graph.at, range(graph.size())))
    kinds = list(map(type, factors))
    if kinds.count(edge) + kinds.count(prior) + kinds.count(type(None)) != len(kinds):
        return None
    edges = [factor for factor, kind in zip(factors, kinds, strict=True) if kind is edge]
    priors = [index for index, kind in enumerate(kinds) if kind is prior]
    if not all(isinstance(factors[index].noiseModel(), gtsam.noiseModel.Constrained)
               for index in priors):
        return None  # a soft prior
    edge_keys = list(itertools.chain.from_iterable(map(edge.keys, edges)))
    return kinds, edges, edge_keys, priors, [factors[index].keys()[0] for index in priors]


def with_fix_lines(text: list[str], kinds: list[type], edge: type, vertices: int,
                   priors: list[int], fixed: list[int]) -> tuple[str, list[int | None]]:
    """A fast writer's whole text: ``text`` (the lines of ``vertices`` vertices, then one
    line per factor of type ``edge`` in ``kinds``, the graph's factor types), then the FIX
    lines of the ids ``fixed`` (of the prior factors ``priors``); and the line of each factor
    (None for an empty slot), as :func:`g2o_text_lines` gives them."""
    factor_lines: list[int | None] = [None] * len(kinds)
    line = vertices
    for index, kind in enumerate(kinds):
        if kind is edge:
            line += 1
            factor_lines[index] = line
    text = list(text)
    for fix, part in fix_lines(fixed):
        text.append(fix + "\n")
        line += 1
        for index in priors[part]:
            factor_lines[index] = line
    return "".join(text), factor_lines


def information_texts(models: list, size: int,
                      problems: Callable[[np.ndarray], list[str | None]] = information_problems,
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


def upper_triangle_texts(matrices: np.ndarray, size: int) -> list[str]:
    """The g2o fields of each ``size`` x ``size`` matrix of the stack: its upper triangle row
    by row, each number by :func:`format_15`, all formatted in one call."""
    upper = matrices[:, np.triu_indices(size)[0], np.triu_indices(size)[1]]
    numbers = texts_15(upper.ravel().tolist())
    width = upper.shape[1]
    return [" ".join(numbers[k * width:(k + 1) * width]) for k in range(len(upper))]


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
