"""Writing a pose graph as g2o text, for either pose group: the format
(:class:`~rlpgo_gtsam.io.formats.Format`) says how its lines read.

The text holds the vertices by key, then one line per between factor in graph order, then
the ``FIX`` lines of the hard priors (:func:`fix_lines`). Positions are written exactly;
angles, quaternions and information entries with 15 significant digits
(:func:`~rlpgo_gtsam.io.lines.format_15`), so a file's own decimals come back unchanged and
write -> read -> write gives the same text.

A graph with landmarks (points at keys ``l<j>``, measured by bearing-range factors) has
their vertex lines after the poses', and each measurement as an edge line among the between
factors' (:func:`text_careful`): the point in the pose's frame and its information there
(:func:`~rlpgo_gtsam.landmarks.relative_point`), with 15 significant digits, since they come
back from bearing-range coordinates; the graph they read back into has the same error to
rounding, its text may differ in a last digit.

Two writers produce it. The fast one (:func:`text_fast`) gets each vertex and factor from
GTSAM once, formats each distinct information matrix once and the numbers in bulk (``%``
over one template); at anything it does not take as plainly writable it returns None, and
the careful one (:func:`text_careful`), one vertex and one factor at a time, writes the text
or raises the :class:`~rlpgo_gtsam.errors.OutputError` that names what a g2o file cannot
hold. Given the graph's extraction, :func:`text_of_extraction` takes the edges' numbers from
its arrays instead of a walk over the factors.
"""

from __future__ import annotations

import itertools
import operator
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError, OutputError
from rlpgo_gtsam.information import information_problem
from rlpgo_gtsam.io.formats import POINT_LINES, PointLines
from rlpgo_gtsam.io.lines import format_15
from rlpgo_gtsam.landmarks import relative_point

if TYPE_CHECKING:
    from rlpgo_gtsam.io.formats import Format

__all__ = ["EDGE_LIST_LINE", "IDENTITY_OFFSET", "fix_lines", "text_lines", "text_fast",
           "text_careful", "text_of_extraction", "edge_list_text"]

# A line of an edge list (:func:`edge_list_text`): L is the edge's line in its g2o file.
EDGE_LIST_LINE = "line <L> EDGE_SE2 <id_i> <id_j>"
_FIX_PER_LINE = 1000  # 21-byte ids: at most 22 KB a line, well inside MAX_LINE_BYTES
# The one sensor offset a 3D file's landmark measurements name: the body frame itself.
IDENTITY_OFFSET = "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1"
# An information entry this small against the largest is a zero's rounding (landmark edges).
_ZERO_ENTRY = 1e-13


def fix_lines(keys: list[int]) -> list[tuple[str, slice]]:
    """The ``FIX`` lines (without line ends) that hold ``keys``, each with the slice of
    ``keys`` it holds: at most :data:`_FIX_PER_LINE` ids a line, since one line for every
    FIXed id would outgrow the reader's line limit (15 001 ids made 78 899 bytes)."""
    parts = [slice(start, start + _FIX_PER_LINE) for start in range(0, len(keys), _FIX_PER_LINE)]
    return [("FIX " + " ".join(map(str, keys[part])), part) for part in parts]


# --------------------------------------------------------------------------- the text


def text_lines(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               form: Format) -> tuple[str, list[int | None]]:
    """The g2o text of ``graph`` and ``values`` in ``form``, and the line (1-based) of that
    text which holds each factor: its edge line, or the ``FIX`` line of a prior, or None
    for an empty slot.

    Raises:
        OutputError: a factor, value or information that a g2o file cannot hold.
    """
    written = text_fast(graph, values, form)
    return written if written is not None else text_careful(graph, values, form)


def text_fast(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              form: Format) -> tuple[str, list[int | None]] | None:
    """The text and factor lines, each vertex and factor read from GTSAM once and the
    numbers formatted in bulk; None at anything :func:`text_careful` must judge (it then
    raises the error for it)."""
    keys = list(values.keys())
    if not keys or keys != sorted(keys):
        return None
    vertices = form.vertex_columns(values, len(keys))
    if vertices is None:
        return None  # a value that is not this group's pose, or not finite
    between: Any = form.group.between_factor
    found = _writable_factors(graph, between, form.group.prior_factor)
    if found is None:
        return None
    kinds, edges, edge_keys, priors, fixed = found
    information = form.information_fields(list(map(between.noiseModel, edges)))
    if information is None:
        return None
    known = set(keys)
    if not known.issuperset(edge_keys) or not known.issuperset(fixed):
        return None  # a factor on a key without a value
    if any(map(operator.eq, edge_keys[0::2], edge_keys[1::2])):
        return None  # an edge from a vertex to itself
    measured = form.edge_columns(edges)
    if measured is None:
        return None
    text = _lines_text(form, keys, vertices, edge_keys[0::2], edge_keys[1::2], measured,
                       information)
    return _with_fix_lines(text, kinds, between, len(keys), priors, fixed)


def text_of_extraction(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                       pose_graph: Any, form: Format) -> str | None:
    """:func:`text_fast`'s text from the extraction ``pose_graph`` of ``graph``; None where
    it is not this graph's, or the graph holds more than its edges and FIX priors (a soft
    prior, an empty slot: the walk judges those), or the fast writer would decline it."""
    g = pose_graph
    if g.graph is not graph or graph.size() != g.num_edges + len(g.fixed):
        return None  # extraction takes every factor as an edge, a hard or a soft prior
    keys = list(values.keys())
    if keys != g.keys.tolist() or (g.edges[:, 0] == g.edges[:, 1]).any():
        return None
    columns = form.extraction_columns(g)
    vertices = form.vertex_columns(values, len(keys))
    if columns is None or vertices is None:
        return None
    text = _lines_text(form, keys, vertices, g.keys[g.edges[:, 0]].tolist(),
                       g.keys[g.edges[:, 1]].tolist(), *columns)
    return "".join([text, *(fix + "\n" for fix, _ in fix_lines(g.keys[g.fixed].tolist()))])


def _lines_text(form: Format, keys: list[int], vertices: list[list], edge_i: list[int],
                edge_j: list[int], measured: list[list], information: list[str]) -> str:
    """The vertex and edge lines of the fast writers, the numbers formatted in bulk: the
    columns ``vertices`` and ``measured`` give each line's numbers after its ids (positions
    by ``%r``, then the angle fields' texts); ``information`` each edge's fields."""
    numbers = " %r" * form.group.d + " %s" * form.angle_fields
    vertex = f"{form.vertex_tag} %d{numbers}\n"
    edge = f"{form.edge_tag} %d %d{numbers} %s\n"
    return ((vertex * len(keys)) % tuple(_interleaved([keys, *vertices]))
            + (edge * len(edge_i)) % tuple(_interleaved([edge_i, edge_j, *measured,
                                                           information])))


def _interleaved(columns: list[list]) -> list[object]:
    """The fields of lines, line after line, from their columns."""
    fields: list[object] = [None] * (len(columns) * len(columns[0]))
    for c, column in enumerate(columns):
        fields[c::len(columns)] = column
    return fields


def _writable_factors(graph: gtsam.NonlinearFactorGraph, edge: Any, prior: type
                      ) -> tuple[list[type], list, list[int], list[int], list[int]] | None:
    """The fast writer's view of ``graph``: the type of each factor, the ``edge`` factors
    and their keys (i, j, i, j, ...), the indices of the ``prior`` factors and their keys;
    None where a factor is of another type (or a subclass) or a prior is soft: the careful
    writer judges those."""
    factors: list[Any] = list(map(graph.at, range(graph.size())))
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


def _with_fix_lines(text: str, kinds: list[type], edge: type, vertices: int,
                    priors: list[int], fixed: list[int]) -> tuple[str, list[int | None]]:
    """The fast writer's whole text: ``text`` (the lines of ``vertices`` vertices, then one
    line per factor of type ``edge`` in ``kinds``, the graph's factor types), then the FIX
    lines of the ids ``fixed`` (of the prior factors ``priors``); and the line of each factor
    (None for an empty slot), as :func:`text_lines` gives them."""
    factor_lines: list[int | None] = [None] * len(kinds)
    line = vertices
    for index, kind in enumerate(kinds):
        if kind is edge:
            line += 1
            factor_lines[index] = line
    parts = [text]
    for fix, part in fix_lines(fixed):
        parts.append(fix + "\n")
        line += 1
        for index in priors[part]:
            factor_lines[index] = line
    return "".join(parts), factor_lines


def text_careful(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                 form: Format) -> tuple[str, list[int | None]]:
    """:func:`text_lines` one vertex and one factor at a time, raising at the first that a
    g2o file of ``form`` cannot hold.

    Landmarks (points at keys ``l<j>``, measured by bearing-range factors) are written after
    the poses, by key, and each measurement as an edge line in graph order; a 3D file's
    measurements name the identity sensor offset :data:`IDENTITY_OFFSET`, written once
    before the edges. A landmark without a measurement, or a measurement of a key without a
    point, is an error: the file would not read back."""
    group = form.group
    between: Any = group.between_factor  # Any: isinstance with a type narrows to object
    prior: Any = group.prior_factor
    points = POINT_LINES[group]
    point_factor: Any = points.factor
    factor_lines: list[int | None] = [None] * graph.size()
    priors: list[int] = []
    fixed = []
    lines, point_lines = _vertex_lines(values, form)
    point_keys = {key for key, _ in point_lines}
    lines.extend(text for _, text in point_lines)
    measured: set[int] = set()
    edges: list[tuple[int, str]] = []  # (factor index, its line)
    for index in range(graph.size()):
        factor: Any = graph.at(index)
        if factor is None:
            continue
        missing = [key for key in factor.keys() if not values.exists(key)]
        if missing:
            raise OutputError(f"factor {index} refers to key {missing[0]}, which has no value: "
                              "the file would not read back")
        if isinstance(factor, between):
            edges.append((index, form.edge_line(factor)))
        elif isinstance(factor, point_factor):
            text, point_key = _point_edge_line(factor, form)
            if point_key not in point_keys:
                raise OutputError(f"factor {index} measures key "
                                  f"{gtsam.DefaultKeyFormatter(point_key)}, which holds no "
                                  f"{points.point_name}: the file would not read back")
            edges.append((index, text))
            measured.add(point_key)
        elif isinstance(factor, prior):
            if not isinstance(factor.noiseModel(), gtsam.noiseModel.Constrained):
                key = gtsam.DefaultKeyFormatter(factor.keys()[0])
                raise OutputError(f"prior on key {key}: a soft prior has no "
                                  f"{form.soft_prior_line} (FIX holds a pose exactly)")
            fixed.append(factor.keys()[0])
            priors.append(index)
        else:
            raise OutputError(f"cannot write a {type(factor).__name__} as a {group.kind} g2o "
                              "line")
    unmeasured = sorted(point_keys - measured)
    if unmeasured:
        raise OutputError(f"landmark {gtsam.DefaultKeyFormatter(unmeasured[0])} has a value "
                          "but no factor measures it: the file would not read back")
    if measured and points.d == 3:
        lines.append(IDENTITY_OFFSET)
    for index, text in edges:
        lines.append(text)
        factor_lines[index] = len(lines)
    for fix, part in fix_lines(fixed):
        lines.append(fix)
        for index in priors[part]:
            factor_lines[index] = len(lines)
    return "\n".join(lines) + "\n", factor_lines


def _vertex_lines(values: gtsam.Values, form: Format) -> tuple[list[str], list[tuple[int, str]]]:
    """The vertex lines of the poses of ``values``, and (key, line) of its landmarks, each by
    key; or the error naming a value that is neither."""
    points = POINT_LINES[form.group]
    poses: list[str] = []
    landmarks: list[tuple[int, str]] = []
    for key in sorted(values.keys()):
        try:
            pose = form.pose_at(values, key)
        except OutputError:
            point = _point_value(values, key, points)
            if point is None:
                name = form.group.pose_type.__name__
                raise OutputError(f"value of key {key} is neither a {name} nor a "
                                  f"{points.point_name}: a {form.group.kind} g2o file holds "
                                  f"{name} poses and {points.point_name} landmarks only"
                                  ) from None
            landmarks.append((key, _point_vertex_line(key, point, points)))
            continue
        poses.append(form.vertex_line(key, pose))
    return poses, landmarks


def _point_value(values: gtsam.Values, key: int, points: PointLines) -> np.ndarray | None:
    """The point at ``key`` (an array of ``points.d``), or None where the value is not one."""
    try:
        point = np.asarray(points.at(values)(key), dtype=float)
    except RuntimeError:
        return None
    return point if point.shape == (points.d,) else None


def _landmark_id(key: int, what: str) -> int:
    """The id ``j`` of the landmark key ``l<j>``, or the error that says ``what`` (a value,
    a factor) has another key."""
    symbol = gtsam.Symbol(key)
    if symbol.chr() != ord("l"):
        raise OutputError(f"{what} has key {gtsam.DefaultKeyFormatter(key)}: a g2o file names "
                          "a landmark l<j> by its id j, and holds no other point")
    return int(symbol.index())


def _point_vertex_line(key: int, point: np.ndarray, points: PointLines) -> str:
    """The vertex line of the landmark at ``key``, or the error that says why it cannot be
    written."""
    j = _landmark_id(key, f"a {points.point_name} value")
    if not np.isfinite(point).all():
        raise OutputError(f"landmark l{j} is not finite: the file would not read back")
    return f"{points.vertex_tag} {j} " + " ".join(repr(float(v)) for v in point)


def _point_edge_line(factor: Any, form: Format) -> tuple[str, int]:
    """The edge line of a bearing-range factor, and its landmark's key; or the error that
    says why it cannot be written."""
    points = POINT_LINES[form.group]
    i, key = factor.keys()
    name = (f"{type(factor).__name__} {gtsam.DefaultKeyFormatter(i)}-"
            f"{gtsam.DefaultKeyFormatter(key)}")
    j = _landmark_id(key, name)
    try:
        point, information = relative_point(factor)
    except GraphError as error:
        raise OutputError(str(error)) from None
    if not np.isfinite(point).all():
        raise OutputError(f"{name}: the measurement is not finite")
    problem = information_problem(information, points.d, form.group.max_condition)
    if problem is not None:
        raise OutputError(f"{name}: {problem} in the point's coordinates (the reader would "
                          "refuse it)")
    # The point and information come back from bearing-range coordinates within some ulps
    # (of the largest entry, for the information): 15 significant digits, and a zero for an
    # entry that small, give back the numbers a file held.
    scale = float(np.abs(information).max())
    information = np.where(np.abs(information) <= _ZERO_ENTRY * scale, 0.0, information)
    upper = information[np.triu_indices(points.d)]
    sensor = " 0" if points.d == 3 else ""  # IDENTITY_OFFSET's id
    return (f"{points.edge_tag} {i} {j}{sensor} " + " ".join(format_15(v) for v in point)
            + " " + " ".join(format_15(v) for v in upper)), key


def edge_list_text(graph: gtsam.NonlinearFactorGraph, indices: list[int],
                   lines: Sequence[int | None], title: str, g2o_name: str, form: Format) -> str:
    """A list of some edges of a g2o file of ``form``, one a line: ``line <L> <tag> <id_i>
    <id_j>`` (:data:`EDGE_LIST_LINE`, the format's edge tag).

    ``L`` is the edge's line in the g2o file ``g2o_name`` (``lines[k]`` for factor ``k``, as
    the reader's or the writer's factor lines give them), ``id_i`` and ``id_j`` its vertex
    ids, in the order of ``indices``. One comment line opens the list: ``# <title>:`` and the
    format. Lines that start with ``#`` are comments; every other line has those five fields.

    Raises:
        OutputError: an index that is not an edge with a line.
    """
    edge: Any = form.group.between_factor
    tag = form.edge_tag
    header = f"{title}: {EDGE_LIST_LINE.replace('EDGE_SE2', tag)}, L the edge's line in {g2o_name}"
    rows = ["# " + " ".join(header.splitlines())]  # one line, whatever the name holds
    for index in indices:
        factor: Any = graph.at(index) if 0 <= index < graph.size() else None
        line = lines[index] if 0 <= index < len(lines) else None
        if not isinstance(factor, edge) or line is None:
            raise OutputError(f"factor {index} is not an edge of the g2o file")
        i, j = factor.keys()
        rows.append(f"line {line} {tag} {i} {j}")
    return "\n".join(rows) + "\n"
