"""The fast g2o reader: a regular file a few megabytes at a time, record by record in numpy.

numpy finds every line and field of a chunk (:class:`~rlpgo_gtsam.io.lines.Text`); the
vertex and edge records are checked and gathered column by column (ids by numpy, numbers by
``float()``'s own parser), each distinct information matrix checked once, in a batch, by the
format's rule. It only ever accepts: at the first thing it does not recognise as valid (a
malformed line, an unusual token, a duplicate id, an unusable information matrix or pose, a
very long line) it returns None, and the careful reader (:mod:`~rlpgo_gtsam.io.read`) reads
the file again line by line and raises the error of the first bad line, or accepts what it
accepts. Both produce the same :class:`~rlpgo_gtsam.io.formats.Table`. Landmark lines are
among what it does not recognise: a file with them is the careful reader's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from rlpgo_gtsam.io.formats import Table
from rlpgo_gtsam.io.lines import (
    MAX_LINE_BYTES,
    Text,
    blocks,
    distinct_rows,
    plain_keys,
    plain_numbers,
)

if TYPE_CHECKING:
    from rlpgo_gtsam.io.formats import Format

__all__ = ["scan"]

# The fast reader's chunk (2 MiB: about 10 000 planar edge lines) and the longest line it
# takes; a longer one, or anything near MAX_LINE_BYTES, is the careful reader's to judge.
_CHUNK_BYTES = 1 << 21
_FAST_LINE_BYTES = MAX_LINE_BYTES // 2


@dataclass(eq=False)
class _Scan:
    """What the fast reader has gathered so far, one list entry per chunk."""

    form: Format
    vertex_keys: list[np.ndarray] = field(default_factory=list)
    vertex_numbers: list[np.ndarray] = field(default_factory=list)
    # the vertex lines as read, for GTSAM's parser; None once one is not plain text
    vertex_text: list[bytes] | None = None
    edge_keys: list[np.ndarray] = field(default_factory=list)
    edge_lines: list[np.ndarray] = field(default_factory=list)
    edge_numbers: list[np.ndarray] = field(default_factory=list)
    model: list[np.ndarray] = field(default_factory=list)
    information: list[np.ndarray] = field(default_factory=list)  # as the rule uses them
    changes: list[tuple[str, ...]] = field(default_factory=list)  # the rule's, per matrix
    matrix_index: dict[bytes, int] = field(default_factory=dict)  # file's matrix -> index
    fixed: list[tuple[int, int]] = field(default_factory=list)
    changed: dict[str, list[int]] = field(default_factory=dict)
    lines: int = 0  # lines read so far


def scan(handle: BinaryIO, form: Format) -> Table | None:
    """The fast reader: the table of the file of ``form``, or None where the careful reader
    must judge.

    Memory: one chunk of text and its arrays, and what the lines parsed so far hold.
    """
    state = _Scan(form, vertex_text=[] if form.reads_vertex_text else None)
    for text in blocks(handle, _CHUNK_BYTES, _FAST_LINE_BYTES):
        if text is None or not _scan_block(text, state):
            return None
    keys = np.concatenate(state.vertex_keys) if state.vertex_keys else np.zeros(0, np.uint64)
    ordered = np.sort(keys)
    if (ordered[1:] == ordered[:-1]).any():
        return None  # an id defined twice: the careful reader names both lines
    p = form.pose_numbers
    return Table(
        vertex_keys=keys,
        vertex_numbers=_stack(state.vertex_numbers, (0, p), float),
        edge_keys=_stack(state.edge_keys, (0, 2), np.uint64),
        edge_lines=_stack(state.edge_lines, (0,), np.int64),
        edge_numbers=_stack(state.edge_numbers, (0, p), float),
        information=state.information,
        model=_stack(state.model, (0,), np.int64),
        fixed=state.fixed,
        changed=state.changed,
        vertex_text=state.vertex_text,
    )


def _stack(parts: list[np.ndarray], empty: tuple[int, ...], dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty, dtype)


def _scan_block(text: Text, state: _Scan) -> bool:
    """Parse the lines of ``text`` into ``state``; False at anything unusual.

    The vertex and edge lines of plain text (:data:`~rlpgo_gtsam.io.lines.PLAIN`) are read
    column by column; comments and blank lines are passed over; the other lines (FIX, the
    records that hold other bytes) one at a time, as the careful reader splits them.
    """
    form = state.form
    plain = text.plain_lines()
    vertices = np.flatnonzero(plain & text.first_field_is(form.vertex_tag.encode()))
    edges = np.flatnonzero(plain & text.first_field_is(form.edge_tag.encode()))
    others = ~plain | ((text.count > 0) & (text.first_byte() != ord("#")))
    others[vertices] = others[edges] = False
    odd_vertices: list[list[str]] = []  # the tokens of records that hold other bytes
    odd_edges: list[tuple[int, list[str]]] = []  # (line, tokens)
    for index in np.flatnonzero(others).tolist():
        number = state.lines + index + 1
        tokens = text.line(index).decode("utf-8").split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0] == form.vertex_tag:
            odd_vertices.append(tokens)
        elif tokens[0] == form.edge_tag:
            odd_edges.append((number, tokens))
        elif tokens[0] == "FIX" and len(tokens) > 1:
            keys = plain_keys(tokens[1:])
            if keys is None:
                return False
            state.fixed.extend((key, number) for key in keys)
        else:
            return False
    if not (_scan_vertices(text, vertices, odd_vertices, state)
            and _scan_edges(text, edges, odd_edges, state)):
        return False
    state.lines += len(text)
    return True


def _scan_vertices(text: Text, lines: np.ndarray, odd: list[list[str]], state: _Scan) -> bool:
    form = state.form
    width = 2 + form.pose_numbers  # the tag, the id, the pose
    if len(lines):
        records = text.records(lines, width, 1, form.pose_numbers)
        if records is None or not form.usable(records[1]):
            return False
        state.vertex_keys.append(records[0][:, 0])
        state.vertex_numbers.append(records[1])
        if state.vertex_text is not None:
            state.vertex_text.append(text.lines_text(lines))
    for tokens in odd:
        if len(tokens) != width:
            return False
        keys, pose = plain_keys(tokens[1:2]), plain_numbers(tokens[2:])
        if keys is None or pose is None or not form.usable(pose[None]):
            return False
        state.vertex_keys.append(np.array(keys, dtype=np.uint64))
        state.vertex_numbers.append(pose[None])
        state.vertex_text = None  # GTSAM's parser would not split this line as we do
    return True


def _scan_edges(text: Text, lines: np.ndarray, odd: list[tuple[int, list[str]]],
                state: _Scan) -> bool:
    form = state.form
    p = form.pose_numbers
    first = 3 + p  # the information's first field: after the tag, the ids, the pose
    width = first + form.information_numbers
    numbers, keys, measured = [], [], []
    upper, inverse = [], []  # distinct information rows; each edge's row among them
    if len(lines):
        records = text.records(lines, width, 2, p)
        if records is None:
            return False
        numbers.append(lines + (state.lines + 1))
        keys.append(records[0])
        measured.append(records[1])
        # the information's fields: usually the same text on every line, read once
        starts, ends = text.fields(lines, width)
        if text.same_text(starts[:, first], ends[:, width - 1]):
            rows = text.numbers(lines[:1], first, form.information_numbers)
            inverse.append(np.zeros(len(lines), np.int64))
        else:
            rows = text.numbers(lines, first, form.information_numbers)
            if rows is not None:
                distinct, index = distinct_rows(rows)  # in the order they first appear
                rows = rows[distinct]
                inverse.append(index)
        if rows is None:
            return False
        upper.append(rows)
    for number, tokens in odd:
        fields = plain_numbers(tokens[3:]) if len(tokens) == width else None
        pair = plain_keys(tokens[1:3]) if fields is not None else None
        if pair is None or fields is None:
            return False
        numbers.append(np.array([number]))
        keys.append(np.array([pair], dtype=np.uint64))
        measured.append(fields[None, :p])
        inverse.append(np.array([sum(map(len, upper))]))
        upper.append(fields[None, p:])
    if not numbers:
        return True
    edge_keys, edge_numbers = np.concatenate(keys), np.concatenate(measured)
    if (edge_keys[:, 0] == edge_keys[:, 1]).any() or not form.usable(edge_numbers):
        return False  # an edge from a vertex to itself; a pose the careful reader names
    rows, index = np.concatenate(upper), np.concatenate(inverse)
    if odd:  # the odd lines' rows may repeat a row already found
        distinct, again = distinct_rows(rows)
        rows, index = rows[distinct], again[index]
    matrices = _matrix_indices(form.informations(rows), state)
    if matrices is None:
        return False
    model, edge_lines = matrices[index], np.concatenate(numbers)
    if odd:
        order = np.argsort(edge_lines, kind="stable")  # the odd lines in their place
        edge_keys, edge_lines = edge_keys[order], edge_lines[order]
        edge_numbers, model = edge_numbers[order], model[order]
    _note_changes(edge_lines, model, state)
    state.edge_keys.append(edge_keys)
    state.edge_lines.append(edge_lines)
    state.edge_numbers.append(edge_numbers)
    state.model.append(model)
    return True


def _matrix_indices(matrices: np.ndarray, state: _Scan) -> np.ndarray | None:
    """The index in ``state.information`` of each (distinct) matrix of the file: the new ones
    through the format's information rule, in one batch, and added as it uses them; None if
    the rule refuses one of them."""
    keys = [matrix.tobytes() for matrix in matrices]
    new = [k for k, key in enumerate(keys) if key not in state.matrix_index]
    if new:
        used, problems, changes = state.form.rule(matrices[new])
        if any(problem is not None for problem in problems):
            return None
        for k, matrix, change in zip(new, used, changes, strict=True):
            state.matrix_index[keys[k]] = len(state.information)
            state.information.append(matrix)
            state.changes.append(change)
    return np.array([state.matrix_index[key] for key in keys], dtype=np.int64)


def _note_changes(lines: np.ndarray, model: np.ndarray, state: _Scan) -> None:
    """Add the lines of the edges whose matrix the rule changed to ``state.changed``, as the
    careful reader does: by line, in order."""
    changed = [k for k, change in enumerate(state.changes) if change]
    if not changed:
        return
    mask = np.isin(model, changed)
    for line, k in zip(lines[mask].tolist(), model[mask].tolist(), strict=True):
        for change in state.changes[k]:
            state.changed.setdefault(change, []).append(line)
