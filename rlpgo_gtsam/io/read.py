"""Reading a g2o file of either pose group into a GTSAM graph and values.

:func:`read_table` reads the file into a :class:`~rlpgo_gtsam.io.formats.Table`: by the fast
reader (:func:`~rlpgo_gtsam.io.scan.scan`) where it takes the file, else by the careful one
(:func:`parse`), line by line, which raises a :class:`~rlpgo_gtsam.errors.G2oFormatError`
naming the first bad line. :func:`build` then makes the checks across lines (undefined
vertices, FIX ids, connectivity), the chained initial guess of a file without vertices, and
the GTSAM graph: one noise model per distinct information matrix, one between factor per
edge line, one constrained prior per FIXed id (the first FIXed pose is the anchor; a held
pose adds nothing to chi2). What the format's information rule changed is told in an
:class:`~rlpgo_gtsam.errors.InformationWarning` per file and kind (:func:`warn_changes`).
"""

from __future__ import annotations

import itertools
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
from rlpgo_gtsam.information import INDEFINITE, LIFTED, MAX_CONDITION_3D, ROUNDING_3D
from rlpgo_gtsam.io.formats import Table, format_of
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

if TYPE_CHECKING:
    from rlpgo_gtsam.io.formats import Format

__all__ = ["read_file", "read_table", "group_of_lines", "parse", "build", "warn_changes",
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
    the one whose tags start its first pose line, else SE2. It reads up to that line only:
    a later line of the other group is the reader's ``file:line`` error (a file holds 2D or
    3D lines, not both); a file without a pose line is SE2 (the planar reader names what it
    holds)."""
    for _, tag, _ in records:
        upper = tag.upper()
        for group in GROUPS:
            if upper.startswith(group.g2o_tags):
                return group
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
    others = [group for group in GROUPS if group is not form.group]
    for number, tag, fields in line_records(path, handle):
        if tag == form.vertex_tag:
            _parse_vertex(path, number, fields, parsed)
        elif tag == form.edge_tag:
            _parse_edge(path, number, fields, parsed)
        elif tag == "FIX":
            parsed.fixed.extend(parse_fix(path, number, fields))
        elif any(tag.upper().startswith(group.g2o_tags) for group in others):
            other = next(group for group in others if tag.upper().startswith(group.g2o_tags))
            raise G2oFormatError(path, number, f"{short_token(tag)}: a {other.kind} line in a "
                                 f"{form.group.kind} file (a file holds 2D or 3D lines, not "
                                 "both)")
        else:
            toro = "TORO's, not g2o's: " if tag.upper() in _TORO_TAGS else ""
            raise G2oFormatError(path, number, f"unknown tag '{short_token(tag)}' ({toro}this "
                                 f"reader takes {form.vertex_tag}, {form.edge_tag} and FIX)")
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
    )


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


# --------------------------------------------------------------------------- both readers


def build(path: Path, table: Table, form: Format, lines: bool = True, extract: bool = False
          ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, list[int], Any]:
    """The checks across lines, then the GTSAM graph, values and factor lines (``lines``;
    else an empty list), and (``extract``) the graph's extraction as the format makes it
    from the table (:meth:`~rlpgo_gtsam.io.formats.Format.extraction`; else None)."""
    vertex, edge = form.vertex_tag, form.edge_tag
    if not len(table.vertex_keys) and not len(table.edge_keys):
        raise G2oFormatError(path, None, f"holds no {vertex} or {edge} line")
    if not len(table.edge_keys):
        raise G2oFormatError(path, None, f"holds no {edge} line: a pose graph needs edges")
    check_references(path, table, form)
    known = table.vertex_keys if len(table.vertex_keys) else table.edge_keys.ravel()
    problem = disconnection(known, table.edge_keys)
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
    prior, at = form.group.prior_factor, getattr(values, f"at{form.group.pose_type.__name__}")
    for key, line in table.fixed:
        graph.add(prior(key, at(key), gtsam.noiseModel.Constrained.All(form.group.dof)))
        if lines:
            factor_lines.append(line)
    if not extract:
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
