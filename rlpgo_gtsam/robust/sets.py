"""The sets of closures the verify step judges together: runs of parallel closures and
clusters of nearby ones.

Vertigo's groups of wrong closures hold each other up: each member fits the map the others
bend, and only the set, judged as one, misfits. Closures are taken by pose indices, low end
first; ``j - i`` is a closure's diagonal.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.graph import PoseGraph, component_labels
from rlpgo_gtsam.robust.settings import RobustSettings

__all__ = ["runs", "left_out_runs", "clusters"]


def runs(g: PoseGraph, among: np.ndarray, settings: RobustSettings) -> list[np.ndarray]:
    """Runs of parallel closures among the edges ``among``: closures ``(i + k, j + k)`` on one
    diagonal (not the odometry's, ``j = i + 1``), consecutive ones at most ``run_reach``
    apart, cut into pieces of at most ``run_max``; only pieces of two or more."""
    index = np.flatnonzero(among)
    low, high = np.sort(g.edges[index], axis=1).T
    keep = high - low > 1
    index, low, high = index[keep], low[keep], high[keep]
    order = np.lexsort((low, high - low))
    index, low, diagonal = index[order], low[order], (high - low)[order]
    if len(index) < 2:
        return []
    starts = np.flatnonzero(np.concatenate([[True], (np.diff(diagonal) != 0)
                                            | (np.diff(low) > settings.run_reach)]))
    # each run cut into pieces of run_max from its start, as arrays: most runs are one
    # closure, and a loop over them took 30 ms a round on M3500 with 5800 wrong closures
    size = settings.run_max
    lengths = np.diff(np.append(starts, len(index)))
    count = -(-lengths // size)  # pieces per run
    first = np.cumsum(count) - count  # each run's first piece
    cuts = np.repeat(starts, count) + size * (np.arange(count.sum()) - np.repeat(first, count))
    ends = np.minimum(cuts + size, np.repeat(starts + lengths, count))
    two = ends - cuts >= 2
    return [index[a:b] for a, b in zip(cuts[two].tolist(), ends[two].tolist(), strict=True)]


def left_out_runs(g: PoseGraph, among: np.ndarray, fits: np.ndarray, bar: float,
                  fits_well: float, settings: RobustSettings) -> list[np.ndarray]:
    """:func:`runs` of the closures left out (``among``), but for runs in which one closure
    alone passes (its statistic in ``fits``, per edge, below ``bar``) and fits as a true
    closure does (below ``fits_well``, the statistic at the doubtful p-value): the others
    misfit by themselves, and the run's verdict would keep out the true closure they sit
    beside (Vertigo's local policy puts wrong closures beside true ones). Where the lone one
    passes barely, the run still judges it: a wrong group's member that passes alone does
    so barely, and its run keeps it out."""
    found = runs(g, among, settings)
    if not found:
        return found
    # counted as arrays: a loop took 5 ms a round over M3500's 900 runs of wrong closures
    members = np.concatenate(found)
    owner = np.repeat(np.arange(len(found)), [len(run) for run in found])
    passing = fits[members] < bar
    alone = np.bincount(owner, passing, len(found)) == 1
    well = np.bincount(owner, passing & (fits[members] < fits_well), len(found)) == 1
    return [run for run, lone in zip(found, (alone & well).tolist(), strict=True) if not lone]


def clusters(g: PoseGraph, among: np.ndarray, settings: RobustSettings) -> list[np.ndarray]:
    """Clusters of nearby closures among the edges ``among`` that are not one run: closures
    linked when their low ends and their diagonals both differ by at most ``run_reach``, in
    connected pieces of at most ``run_max`` (in order of their low ends); only pieces of two
    or more with two diagonals. Wrong closures between nearby poses of one stretch
    (Vertigo's local groups, overlapping) bend it together, and each fits the map the others
    hold; left out together, they do not fit."""
    reach, size = settings.run_reach, settings.run_max
    index = np.flatnonzero(among)
    low, high = np.sort(g.edges[index], axis=1).T
    keep = high - low > 1
    order = np.argsort(low[keep], kind="stable")
    index, low, diagonal = index[keep][order], low[keep][order], (high - low)[keep][order]
    # each closure linked to the next ones by low end (a bounded window), as arrays: a loop
    # over City10K's 10,000 closures took 0.25 s a round
    offsets = [np.column_stack([np.arange(len(index) - k), np.arange(k, len(index))])
               for k in range(1, min(settings.cluster_window, len(index) - 1) + 1)]
    pairs = np.concatenate(offsets) if offsets else np.empty((0, 2), np.int64)
    a, b = pairs.T
    near = (low[b] - low[a] <= reach) & (np.abs(diagonal[b] - diagonal[a]) <= reach)
    roots = component_labels(len(index), pairs[near])
    linked = np.flatnonzero(np.bincount(roots, minlength=len(index))[roots] >= 2)
    by_root = linked[np.argsort(roots[linked], kind="stable")]  # members in low-end order
    pieces = []
    for members in np.split(by_root, np.flatnonzero(np.diff(roots[by_root])) + 1):
        for k in range(0, len(members), size):
            piece = members[k:k + size]
            if len(piece) >= 2 and len(np.unique(diagonal[piece])) >= 2:
                pieces.append(index[piece])
    return pieces
