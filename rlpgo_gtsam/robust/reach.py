"""Edges out of reach: measurements no map of the other edges can fit, found before any step.

An edge's error within its bar (``e^T Lambda e <= bar``) bounds the translation part of its
Logmap by ``slack = sqrt(bar / lambda_min(Lambda))``, and so the move of its measured
translation by the same (the Logmap's translation is ``V^-1`` of the translation error, and
``V`` shrinks no vector). Along any path of edges that fit, a relative pose's translation is
a sum of rotated measured translations, each within its slack: no longer than the sum of the
path's *reaches* (length plus slack). So where a set of edges spans the graph, every map in
which they fit puts every two poses within their summed reach, and an edge whose measured
length, less its own slack, lies beyond that cannot fit any such map: its residual at every
reasonable map is enormous. Such an edge (a closure of 1e20 m on a map 300 m across) is
rejected before the steps, whatever the trust in it: the steps' arithmetic does not survive
its scale (squared in the cycles' covariances, its 1e40 swamps the rest of double's digits).

The spanning set is found from below: the edges in order of reach until they span the graph
(Kruskal), then every edge beyond ``reach_margin`` times their summed reach is out; the sum
grows with each edge let back in until none is left to let in. The edges kept span the
graph, and every edge out lies beyond ``reach_margin`` times their summed reach.

An edge that no cycle checks (a bridge to poses seen from nowhere else) is never out of
reach, whatever its length: nothing contradicts it. Where it is so long that double
arithmetic cannot hold the rest of the map beside it, :func:`check_scale` refuses the graph.
"""

from __future__ import annotations

import functools

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.graph import PoseGraph, find_root
from rlpgo_gtsam.groups import group_of

__all__ = ["out_of_reach", "check_scale"]

# An edge longer than this times every other edge together leaves the rest of the map too few
# of double's digits: MIT beside a bridge of 1e15 m (5e11 times its other edges) ends with its
# chi2 off by 2e-8, beside one of 1e25 m 1e17 times too high; at 1e12 m it is exact.
LONGEST_RATIO = 1e10


def out_of_reach(g: PoseGraph, bar: float, margin: float) -> np.ndarray:
    """(m,) bool: the edges no map of the others can fit (see the module docstring), each
    edge's error bounded by ``bar`` (the chi-square of its dof), beyond ``margin`` times the
    reach of edges that span the graph without them."""
    out = np.zeros(g.num_edges, bool)
    if g.num_poses < 2:
        return out
    length = _lengths(g)
    lowest = np.linalg.eigvalsh(g.information)[:, 0]
    # an information without a positive floor bounds nothing: that edge reaches anywhere
    slack = np.full(g.num_edges, np.inf)
    np.sqrt(bar / lowest, out=slack, where=lowest > 0.0)
    reach, least = length + slack, length - slack
    # edges that span the graph are at least n - 1 of them: where no edge lies beyond the
    # n - 1 shortest reaches, none is out (every clean graph stops here)
    if len(reach) < g.num_poses - 1 or not (
            least > margin * np.partition(reach, g.num_poses - 2)[:g.num_poses - 1].sum()).any():
        return out
    order = np.argsort(reach, kind="stable")
    spanning = _spanning_prefix(g, order)
    if spanning is None:  # the edges do not span the graph: the extraction says so
        return out
    out[order[spanning:]] = True
    while True:
        within = margin * reach[~out].sum()
        still = out & (least > within)
        if (still == out).all():
            return out
        out = still


def check_scale(g: PoseGraph, out: np.ndarray) -> None:
    """Refuse (GraphError) a graph whose longest edge not ``out`` is more than
    :data:`LONGEST_RATIO` times longer than the others together (see the module
    docstring)."""
    length = _lengths(g)
    length[out] = 0.0
    longest = int(np.argmax(length))
    rest = np.delete(length, longest).sum()  # not the total less it: that cancels
    if not length[longest] > LONGEST_RATIO * rest or not rest > 0.0:
        return
    i, j = (gtsam.DefaultKeyFormatter(int(g.keys[k])) for k in g.edges[longest])
    raise GraphError(f"between factor {i}-{j} measures {length[longest]:.3g} m, "
                     f"{length[longest] / rest:.2g} times every other edge together: no cycle "
                     "contradicts it, and beside it double arithmetic cannot hold the rest "
                     "of the map")


def _lengths(g: PoseGraph) -> np.ndarray:
    """(m,) the edges' measured translation lengths, scaled first so that none overflows
    (1e300 m is 1e300 m, not inf)."""
    group = group_of(g)
    translations = group.translations(group.measured(g))
    scale = np.abs(translations).max(axis=1)
    unit = np.divide(translations, scale[:, None], out=np.zeros_like(translations),
                     where=scale[:, None] > 0.0)
    return scale * np.linalg.norm(unit, axis=1)


def _spanning_prefix(g: PoseGraph, order: np.ndarray) -> int | None:
    """How many edges of ``order`` from its start span the graph (None: all do not)."""
    parent = list(range(g.num_poses))
    root = functools.partial(find_root, parent)

    pieces = g.num_poses
    for count, (i, j) in enumerate(g.edges[order].tolist(), start=1):
        a, b = root(i), root(j)
        if a != b:
            parent[a] = b
            pieces -= 1
            if pieces == 1:
                return count
    return None
