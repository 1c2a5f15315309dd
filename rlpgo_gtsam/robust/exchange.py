"""The verify step's last question: two mutually exclusive sets of closures that each fit,
the larger kept.

Vertigo's ``local`` policy puts a wrong closure where the odometry holds loosely; the map
bends to it, it fits the bent map barely, and the true closures of that stretch misfit (on
the generator's 300-pose graph with sigma_R 0.3: a wrong closure at p 0.044 kept eight true
closures of two runs out, the map 5.1x the optimum). A wrong group does the same as a run,
and fits the map it bends well. Where the rounds have settled, a suspect (a kept closure
that fits poorly, or a kept run) with more refuted closures near it than it has members is
taken out; the nearby closures that then fit come in, and those that still fit after a
solve are its rivals. Where the rivals outnumber the suspect's closures that misfit the new
map, the two are exchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from rlpgo_gtsam.robust.innovation import innovation_draws, set_statistics
from rlpgo_gtsam.robust.problem import Problem
from rlpgo_gtsam.robust.sets import runs
from rlpgo_gtsam.robust.statistics import chi2_quantile, statistic_at

__all__ = ["Exchange", "rival_exchange"]


@dataclass
class Exchange:
    """A suspect exchanged for its rivals: the new map ``values``, the ``kept`` edges (the
    rivals in, the suspect's other closures left out, to be judged again) and the suspect's
    closures that go (``out``)."""

    values: gtsam.Values
    kept: np.ndarray
    out: np.ndarray


@dataclass
class _Suspect:
    """Kept ``closures`` (one, or a run), the refuted closures ``nearby``, how contested it
    is (``count``: the contested nearby closures beyond its size) and its ``worst`` fit."""

    closures: np.ndarray
    nearby: np.ndarray
    count: int
    worst: float


def rival_exchange(problem: Problem, values: gtsam.Values, kept: np.ndarray,
                   failing: np.ndarray, fits: np.ndarray, tried: np.ndarray,
                   ambiguous: list[tuple[np.ndarray, np.ndarray]]) -> Exchange | None:
    """The first exchange of a suspect for its rivals, or None.

    ``values`` is the optimum of the ``kept`` edges; ``failing`` the closures left out that
    the map refutes; ``fits`` per edge the verify step's statistic of each closure alone.
    The suspects, untried (``tried``, per edge, marked here) and kept, are tried the most
    contested first, then the worst-fitting, at most ``exchange_tries`` of them. Two such
    sets, the smaller at least ``ambiguous_ratio`` of the larger's size, are appended to
    ``ambiguous`` (edges: the larger, kept, then the smaller)."""
    settings = problem.settings
    bar = chi2_quantile(settings.inlier_probability, problem.group.dof)
    suspects = [found for found in _suspects(problem, kept, failing, fits, tried, bar)
                if found.count >= 1][:settings.exchange_tries]
    for suspect in suspects:
        tried[suspect.closures] = True
        answer = _exchange_of(problem, values, kept, suspect, bar, ambiguous)
        if answer is not None:
            return answer
    return None


def _suspects(problem: Problem, kept: np.ndarray, failing: np.ndarray, fits: np.ndarray,
              tried: np.ndarray, bar: float) -> list[_Suspect]:
    """The suspects, most contested first (then the worst-fitting): a kept closure that fits
    poorly (p-value below ``doubtful_below``) with at least two refuted closures near it that
    misfit by less than ``exchange_misfit`` bars, and a run of kept closures with more
    refuted closures near it than it has members, two of them within ``exchange_misfit``
    bars (near: each of the suspect's ends within ``exchange_reach`` poses of one of theirs);
    either only where the nearest of those misfits by less than ``exchange_nearest`` bars.
    Where they misfit by more, taking the suspect out brought no two of them within the bar,
    and the question costs two solves for nothing."""
    settings, g = problem.settings, problem.g
    left_out = np.flatnonzero(failing)

    def near(which: np.ndarray) -> np.ndarray:
        ends = g.edges[which].ravel()
        return left_out[(np.abs(g.edges[left_out][:, :, None] - ends[None, None, :])
                         .min(axis=1) <= settings.exchange_reach).all(axis=1)]

    def contested(index: np.ndarray) -> int:
        misfits = fits[index] / bar
        return (int((misfits < settings.exchange_misfit).sum())
                if len(index) and misfits.min() < settings.exchange_nearest else 0)

    found = []
    poor = statistic_at(settings.doubtful_below, problem.group.dof, settings.samples)
    for w in np.flatnonzero(kept & ~tried & (fits > poor)).tolist():
        index = near(np.array([w]))
        if (within := contested(index)) >= 2:
            found.append(_Suspect(np.array([w]), index, within - 1, float(fits[w])))
    for run in runs(g, kept & ~tried, settings):
        index = near(run)
        if contested(index) >= 2:
            found.append(_Suspect(run, index, len(index) - len(run), float(fits[run].max())))
    order = np.lexsort((-np.array([s.worst for s in found]),
                        -np.array([s.count for s in found], dtype=np.int64)))
    return [found[n] for n in order.tolist()]


def _exchange_of(problem: Problem, values: gtsam.Values, kept: np.ndarray, suspect: _Suspect,
                 bar: float, ambiguous: list[tuple[np.ndarray, np.ndarray]]) -> Exchange | None:
    """Without the suspect the kept edges are solved again; every nearby closure that then
    fits alone comes in, and after a second solve the ones that still fit are its rivals.
    The suspect's closures that misfit there go where the rivals outnumber them, or, of two
    sets as large (the whole suspect against every closure that came in), where the rivals'
    map lies lower."""
    settings = problem.settings
    iterations, tolerance = settings.round_iterations, settings.round_tolerance
    closures, index = suspect.closures, suspect.nearby
    shrunk = kept.copy()
    shrunk[closures] = False
    without = problem.optimum(shrunk, values, iterations, tolerance).values
    alone = set_statistics(problem, innovation_draws(problem, without, shrunk),
                           [np.array([e]) for e in index.tolist()]).chi2
    passing = index[alone < bar]
    if len(passing) < 2:
        return None
    grown = shrunk.copy()
    grown[passing] = True
    swapped = problem.optimum(grown, without, iterations, tolerance)
    verdict = set_statistics(problem, innovation_draws(problem, swapped.values, grown),
                             [np.array([e]) for e in [*passing.tolist(), *closures.tolist()]]
                             ).chi2
    rivals, misfits = passing[verdict[:len(passing)] < bar], verdict[len(passing):] >= bar
    if not misfits.any():
        return None  # not exclusive: the rounds would keep both
    out = closures[misfits]
    swap = len(rivals) > len(out) or (
        len(rivals) == len(out) == len(closures) == len(passing)
        and bool(swapped.chi2 < problem.kept_chi2(kept, values)))
    if min(len(rivals), len(out)) >= settings.ambiguous_ratio * max(len(rivals), len(out)):
        ambiguous.append((rivals, out) if swap else (out, rivals))  # (nearly) as large
    if not swap:
        return None  # outnumbered; or as many, and the suspect's map lies no higher
    if len(rivals) < len(passing):  # those that fit once all came in
        grown = shrunk.copy()
        grown[rivals] = True
        return Exchange(problem.optimum(grown, swapped.values, iterations, tolerance).values,
                        grown, out)
    return Exchange(swapped.values, grown, out)
