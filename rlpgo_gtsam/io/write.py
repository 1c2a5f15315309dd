"""Writing a pose graph as g2o text, for either pose group: the format
(:class:`~rlpgo_gtsam.io.formats.Format`) says how its lines read.

The text holds the vertices by key, then one line per between factor in graph order, then
the ``FIX`` lines of the hard priors (:func:`fix_lines`). Positions are written exactly;
angles, quaternions and information entries with 15 significant digits
(:func:`~rlpgo_gtsam.io.lines.format_15`), so a file's own decimals come back unchanged and
write -> read -> write gives the same text.

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

from rlpgo_gtsam.errors import OutputError

if TYPE_CHECKING:
    from rlpgo_gtsam.io.formats import Format

__all__ = ["EDGE_LIST_LINE", "fix_lines", "text_lines", "text_fast", "text_careful",
           "text_of_extraction", "edge_list_text"]

# A line of an edge list (:func:`edge_list_text`): L is the edge's line in its g2o file.
EDGE_LIST_LINE = "line <L> EDGE_SE2 <id_i> <id_j>"
_FIX_PER_LINE = 1000  # 21-byte ids: at most 22 KB a line, well inside MAX_LINE_BYTES


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
    g2o file of ``form`` cannot hold."""
    group = form.group
    between: Any = group.between_factor  # Any: isinstance with a type narrows to object
    prior: Any = group.prior_factor
    factor_lines: list[int | None] = [None] * graph.size()
    priors: list[int] = []
    fixed = []
    lines = [form.vertex_line(key, form.pose_at(values, key)) for key in sorted(values.keys())]
    for index in range(graph.size()):
        factor: Any = graph.at(index)
        if factor is None:
            continue
        missing = [key for key in factor.keys() if not values.exists(key)]
        if missing:
            raise OutputError(f"factor {index} refers to key {missing[0]}, which has no value: "
                              "the file would not read back")
        if isinstance(factor, between):
            lines.append(form.edge_line(factor))
            factor_lines[index] = len(lines)
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
    for fix, part in fix_lines(fixed):
        lines.append(fix)
        for index in priors[part]:
            factor_lines[index] = len(lines)
    return "\n".join(lines) + "\n", factor_lines


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
