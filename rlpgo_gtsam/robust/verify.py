"""The verify step: every closure judged by the map's fit, in rounds, until nothing changes.

From the optimum of the kept edges each closure is judged by its statistic under the map's
own uncertainty (:mod:`rlpgo_gtsam.robust.innovation`): a kept closure by its leave-one-out
residual, a closure left out by its innovation; runs of parallel closures are judged as a
whole as well (:mod:`rlpgo_gtsam.robust.sets`). A round does the first of these that finds
something, then solves the kept edges again:

1. the kept closures the map refutes go (the map a closure is admitted against holds no
   closure it refutes). A closure refuted after it was admitted here is not admitted again,
   unless it came in with others in the last admitting round: a group of aliased closures,
   agreeing with itself, bends the map until the true closures admitted beside it misfit as
   badly; those misfits go back out unjudged and come back by halves, best-fitting first;
2. the closures left out that pass come in, in tiers where the map is loose: those whose
   innovation spread is at most ``tight`` or ``admit_tier`` times the tightest's (a closure
   the map checks loosely may pass though wrong), and every closure a wrong one would pass
   less often than ``admit_chance`` (unless a map here refuted it); none that the map would
   have to turn more than ``linear_rad`` to fit (the linearization does not reach that far);
3. the false-rejection bar (adaptive Benjamini-Hochberg at ``false_rejection_rate``) rejects
   kept closures that fit within the inlier bar, but unlikely so where many are refuted: a
   wrong closure between nearby poses can fit (Vertigo's ``local`` policy). They come back
   only where a later map fits them as a true closure does (p >= ``doubtful_below``);
4. solves where the linear test cannot judge: the set that fits but must turn the map too far
   is admitted when the optimum with it costs at most its bar more; a kept run or cluster
   that holds its stretch (residual spread below ``leverage_check``) is refuted when the
   optimum without it falls by its bar or more;
5. the exchange of a suspect for its rivals (:mod:`rlpgo_gtsam.robust.exchange`).

The rounds end where none of these finds anything, where they came back to an earlier state
and the rounds left to ``verify_rounds`` are whole turns of that cycle (the last round's state
is then the one at hand), or after ``verify_rounds``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import gtsam
import numpy as np

from rlpgo_gtsam.robust.exchange import rival_exchange
from rlpgo_gtsam.robust.innovation import innovation_draws, set_statistics
from rlpgo_gtsam.robust.problem import Problem
from rlpgo_gtsam.robust.sets import clusters, left_out_runs, runs
from rlpgo_gtsam.robust.statistics import (
    adaptive_bh_rejections,
    chi2_quantile,
    set_bar,
    statistic_at,
)

__all__ = ["Verified", "verify"]

# what a round did: changed the kept set (solve again), handed over a solved map, or nothing
_Outcome = Literal["changed", "solved", "settled"]
# a set of closures with the spread of its residual covariance (how loosely the map checks it)
_Spread = tuple[float, np.ndarray]


@dataclass
class Verified:
    """What the verify step found.

    Attributes:
        values: the last optimum of the kept edges.
        kept: (m,) the edges kept.
        rounds: the rounds run.
        unlikely: (m,) the closures the false-rejection bar rejected.
        fits: (m,) each closure's statistic alone in the last round that judged it (NaN:
            never judged).
        ties: what the exchange could not tell apart: (kept, alternative) edge indices.
    """

    values: gtsam.Values
    kept: np.ndarray
    rounds: int
    unlikely: np.ndarray
    fits: np.ndarray
    ties: list[tuple[np.ndarray, np.ndarray]]


@dataclass
class _Rounds:
    """The rounds' state: the map, the kept edges and what the rounds learned, per edge."""

    values: gtsam.Values
    kept: np.ndarray
    admitted: np.ndarray  # let in by a round here
    batch: np.ndarray  # let in by the last admitting round
    clashed: np.ndarray  # members of a batch that clashed, out unjudged
    banned: np.ndarray  # refuted after admission here: not admitted again
    was_refuted: np.ndarray
    tried: np.ndarray  # judged by a solve (turned too far, or holding their stretch)
    questioned: np.ndarray  # kept closures the exchange has tried
    unlikely: np.ndarray  # rejected by the false-rejection bar
    fits: np.ndarray
    ties: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    held_checks: int = 0  # solves without a holding set so far
    count: int = 0

    def signature(self) -> bytes:
        """What the next rounds depend on besides the map's values (which only settle)."""
        masks = (self.kept, self.admitted, self.batch, self.clashed, self.banned,
                 self.was_refuted, self.tried, self.questioned, self.unlikely)
        return b"".join(np.packbits(mask).tobytes() for mask in masks) + \
            repr((self.held_checks, [(a.tobytes(), b.tobytes()) for a, b in self.ties])).encode()

    @classmethod
    def starting(cls, values: gtsam.Values, kept: np.ndarray) -> _Rounds:
        def none() -> np.ndarray:
            return np.zeros(len(kept), bool)

        return cls(values, kept, none(), none(), none(), none(), none(), none(), none(), none(),
                   np.full(len(kept), np.nan))


@dataclass(frozen=True)
class _Bars:
    """What every round judges with: the closures ``judged`` (not trusted), an edge's
    ``bar``, the statistic below which a closure ``fits_well`` (p at least
    ``doubtful_below``) and each edge's measurement ``volume`` (sqrt det covariance)."""

    problem: Problem
    judged: np.ndarray
    bar: float
    fits_well: float
    volume: np.ndarray


@dataclass
class _Verdict:
    """One round's judgment of the candidates (edge ``index``): the ``sets`` the bars judge
    (single closures, then runs) with their ``chi2``, the singles' ``spread``; per edge
    whether it ``fails`` (a bar, or a turn too far) or ``misfit`` (a bar), and how ``loose``
    the map checks it; the sets that fit but turn too far (``turning``) and the kept sets
    that hold their stretch (``holding``)."""

    index: np.ndarray
    sets: list[np.ndarray]
    chi2: np.ndarray
    spread: np.ndarray
    fails: np.ndarray
    misfit: np.ndarray
    loose: np.ndarray
    turning: list[_Spread] = field(default_factory=list)
    holding: list[_Spread] = field(default_factory=list)


def verify(problem: Problem, values: gtsam.Values, settled: bool, kept: np.ndarray,
           known: np.ndarray) -> Verified:
    """The rounds from ``values``, the map of the ``kept`` edges (refined already where
    ``settled``); ``known`` edges are trusted. See the module docstring."""
    settings = problem.settings
    dof = problem.group.dof
    bars = _Bars(problem, ~known, chi2_quantile(settings.inlier_probability, dof),
                 statistic_at(settings.doubtful_below, dof, settings.samples),
                 1.0 / np.sqrt(np.linalg.det(problem.g.information)))
    state = _Rounds.starting(values, kept)
    if not settled:
        state.values = problem.optimum(kept, values, settings.lm_iterations,
                                       settings.tolerance).values
    seen: dict[bytes, int] = {}  # each state's round
    while state.count < settings.verify_rounds:
        state.count += 1
        outcome = _round(bars, state)
        if outcome == "settled":
            break
        if outcome == "changed":
            # a round's map needs its shape and its residuals to a few digits, not
            # convergence; GTSAM's GNC-LM converges from the last one
            state.values = problem.optimum(state.kept, state.values, settings.round_iterations,
                                           settings.round_tolerance).values
        # rounds that came back to an earlier state go round that cycle to the last round:
        # where the rounds left are whole turns of it, the last round's state is this one
        # (a clashing batch re-admitted and sent out again every second round: 52 of Intel's
        # 60 rounds with 9 wrong closures per true one)
        signature = state.signature()
        if signature in seen and \
                (settings.verify_rounds - state.count) % (state.count - seen[signature]) == 0:
            break
        seen[signature] = state.count
    return Verified(state.values, state.kept, state.count, state.unlikely, state.fits,
                    state.ties)


def _round(bars: _Bars, state: _Rounds) -> _Outcome:
    """One round: refute, else admit, else the false-rejection bar, else the solves."""
    candidates = bars.judged & (state.kept | ~state.banned)
    verdict = _verdict(bars, state, candidates)
    refuted = _placing_kept(bars.problem, state, state.kept & verdict.fails)
    if refuted.any() and (refuted & state.batch).any() and state.batch.sum() > 1:
        # the last admissions clash: the batch's misfits go back out, unjudged (not banned)
        back = state.batch & refuted
        state.kept = state.kept & ~back
        state.admitted &= ~back
        state.clashed |= back
        state.batch = np.zeros(len(state.kept), bool)
    elif refuted.any():
        state.banned |= refuted & state.admitted
        state.was_refuted |= refuted
        state.kept = state.kept & ~refuted
    else:
        admit = (~state.kept & candidates & ~verdict.fails
                 & ~(state.unlikely & ~(state.fits < bars.fits_well)))
        if not admit.any():
            return _after_the_bars(bars, state, candidates, verdict)
        _admit(bars, state, admit, verdict)
    return "changed"


def _placing_kept(problem: Problem, state: _Rounds, out: np.ndarray) -> np.ndarray:
    """``out`` (kept closures to reject) without those the kept edges need to place every
    pose (:meth:`~rlpgo_gtsam.robust.problem.Problem.spanning`), the best-fitting first."""
    kept = problem.spanning(state.kept & ~out, out, np.argsort(state.fits, kind="stable"))
    return out & ~kept


def _verdict(bars: _Bars, state: _Rounds, candidates: np.ndarray) -> _Verdict:
    """The candidates judged alone, in runs and in clusters at the round's map (clusters are
    judged by a solve only: under noise above the nominal, the joint linear test refuted true
    clusters)."""
    problem, settings, g = bars.problem, bars.problem.settings, bars.problem.g
    index = np.flatnonzero(candidates)
    draws = innovation_draws(problem, state.values, state.kept)
    alone = set_statistics(problem, draws, index[:, None])
    state.fits[index] = alone.chi2  # this round's, for every candidate
    run_sets = runs(g, candidates & state.kept, settings) + left_out_runs(
        g, candidates & ~state.kept, state.fits, bars.bar, bars.fits_well, settings)
    cluster_sets = clusters(g, candidates & state.kept, settings)
    together = set_statistics(problem, draws, run_sets + cluster_sets)
    singles = list(index[:, None])
    verdict = _Verdict(index, singles + run_sets,
                       np.concatenate([alone.chi2, together.chi2[:len(run_sets)]]),
                       alone.spread, np.zeros(len(state.kept), bool),
                       np.zeros(len(state.kept), bool), np.zeros(len(state.kept)))
    # single closures as arrays, one bar for all (a loop over M3500's 7400 candidates took
    # 30 ms a round); a set of one is never held
    dof = problem.group.dof
    misfit = alone.chi2 >= set_bar(settings.inlier_probability, dof, False, settings.samples)
    turning = ~misfit & ~state.kept[index] & (alone.turn > settings.linear_rad)
    verdict.fails[index[misfit | turning]] = True
    verdict.misfit[index[misfit]] = True
    verdict.turning = [(float(alone.spread[k]), singles[k]) for k in np.flatnonzero(turning)]
    verdict.loose[index] = np.maximum(verdict.loose[index], alone.spread)
    hotelling = settings.hotelling_runs(g.dimension)
    for k, which in enumerate(run_sets + cluster_sets):  # two closures or more
        value, wide = together.chi2[k], float(together.spread[k])
        bar = set_bar(settings.inlier_probability, dof * len(which), hotelling,
                      settings.samples)
        if state.kept[which[0]] and wide < settings.leverage_check and 0.5 * bar <= value:
            verdict.holding.append((wide, which))
        if k >= len(run_sets):
            continue
        if value >= bar:
            verdict.fails[which] = verdict.misfit[which] = True
        elif not state.kept[which[0]] and together.turn[k] > settings.linear_rad:
            verdict.fails[which] = True
            verdict.turning.append((wide, which))
        verdict.loose[which] = np.maximum(verdict.loose[which], wide)
    return verdict


def _admit(bars: _Bars, state: _Rounds, admit: np.ndarray, verdict: _Verdict) -> None:
    """Let in the closures in ``admit`` (they pass) that the map checks best, and those a
    wrong closure would rarely pass (the map's extent against each one's own test), but of
    the clashed ones only the best-fitting half once no other is waiting."""
    problem, settings = bars.problem, bars.problem.settings
    group = problem.group
    side = max(float(np.ptp(group.translations(group.poses_of(problem.g, state.values)),
                            axis=0).max()), 1e-9)
    chance = np.full(len(state.kept), np.inf)
    chance[verdict.index] = group.agreement_chance(
        bars.bar, verdict.spread ** (group.dof / 2) * bars.volume[verdict.index], side)
    tier = max(settings.tight,
               settings.admit_tier(problem.g.dimension) * verdict.loose[admit].min())
    admit &= (verdict.loose <= tier) | ((chance < settings.admit_chance) & ~state.was_refuted)
    if (admit & ~state.clashed).any():
        admit &= ~state.clashed
    else:  # the best half of the clashed ones that pass
        order = np.flatnonzero(admit)[np.argsort(state.fits[admit], kind="stable")]
        admit = np.zeros(len(state.kept), bool)
        admit[order[:max(1, len(order) // 2)]] = True
    state.kept = state.kept | admit
    state.admitted |= admit
    state.batch = admit


def _after_the_bars(bars: _Bars, state: _Rounds, candidates: np.ndarray,
                    verdict: _Verdict) -> _Outcome:
    """Nothing refuted and nothing to admit: the false-rejection bar, then the solves, then
    the exchange; "settled" where none finds anything."""
    problem, settings = bars.problem, bars.problem.settings
    doubted = adaptive_bh_rejections(verdict.chi2, verdict.sets, state.kept,
                                     bars.judged & ~candidates, problem.group.dof,
                                     settings.false_rejection_rate, settings.samples)
    doubted = _placing_kept(problem, state, doubted)
    if doubted.any():  # as refuted ones, but not banned: they come back where they fit well
        state.unlikely |= doubted
        state.was_refuted |= doubted
        state.kept = state.kept & ~doubted
        return "changed"
    trial = _optimum_with_turning_set(problem, state, candidates & ~verdict.misfit,
                                      verdict.turning)
    if trial is None:
        trial = _optimum_without_holding_set(problem, state, verdict.holding)
        if trial is not None:
            state.was_refuted |= state.kept & ~trial[1]
    if trial is not None:
        state.values, state.kept = trial
        return "solved"
    exchange = rival_exchange(problem, state.values, state.kept,
                              candidates & ~state.kept & verdict.misfit, state.fits,
                              state.questioned, state.ties)
    if exchange is None:
        return "settled"
    state.values = exchange.values
    state.banned[exchange.out] = state.was_refuted[exchange.out] = True
    state.admitted |= exchange.kept & ~state.kept
    state.kept = exchange.kept
    return "solved"


def _optimum_with_turning_set(problem: Problem, state: _Rounds, open_: np.ndarray,
                              turning: list[_Spread]) -> tuple[gtsam.Values, np.ndarray] | None:
    """The nonlinear test for closures whose innovation fits but which the map would have to
    turn more than ``linear_rad``: the untried set among ``turning`` that the map checks best
    is added and the kept edges solved again; it is admitted when the optimum's chi2 rose by
    less than its bar, the likelihood-ratio test the innovation linearizes (MIT's four true
    closures that close the last loop needed 1.0-1.4 rad). Only sets whose every closure is
    ``open_`` (a candidate no bar refuted); each set gets one solve. Returns the optimum and
    kept edges with the first set that passes, or None."""
    settings = problem.settings
    before = problem.kept_chi2(state.kept, state.values)
    for _, which in sorted(turning, key=lambda item: (len(item[1]), item[0])):
        if state.tried[which].any() or not open_[which].all():
            continue
        state.tried[which] = True
        grown = state.kept.copy()
        grown[which] = True
        refined = problem.optimum(grown, state.values, settings.lm_iterations,
                                  settings.round_tolerance)
        if refined.chi2 - before < chi2_quantile(settings.inlier_probability,
                                                 problem.group.dof * len(which)):
            return refined.values, grown
    return None


def _optimum_without_holding_set(problem: Problem, state: _Rounds, holding: list[_Spread]
                                 ) -> tuple[gtsam.Values, np.ndarray] | None:
    """The nonlinear leave-out test for kept sets (runs, clusters) that hold their stretch
    of the map, where the linear leave-out chi2 understates: the kept edges are solved again
    without the set, the most held first, and it is refuted when the optimum's chi2 falls by
    its bar or more (MIT: three wrong closures that collapse a 12-pose stretch, linear chi2
    23 against 34, fell by 59). Each set once, ``held_checks`` solves at most. Returns the
    optimum and kept edges without the first set refuted, or None."""
    settings = problem.settings
    before = problem.kept_chi2(state.kept, state.values)
    for _, which in sorted(holding, key=lambda item: item[0]):
        if state.tried[which].all() or state.held_checks >= settings.held_checks:
            continue
        state.held_checks += 1
        state.tried[which] = True
        shrunk = state.kept.copy()
        shrunk[which] = False
        refined = problem.optimum(shrunk, state.values, settings.lm_iterations,
                                  settings.round_tolerance)
        if before - refined.chi2 >= chi2_quantile(settings.inlier_probability,
                                                  problem.group.dof * len(which)):
            return refined.values, shrunk
    return None
