"""Wrong loop closures: find them, say which they were, and hand over the right start.

One wrong loop closure bends the chordal estimate, costs the relaxation its certificate and
leads LM to a wrong map; GTSAM's graduated non-convexity (``GncLMOptimizer``) rejects wrong
closures but needs a start near the right map. :func:`robust_initialize` builds that start
and lets GTSAM's GNC-LM (truncated least squares) finish from it. A closure is rejected only
on evidence against it, never for lack of support. The steps, each reported in
:attr:`RobustResult.steps`:

- ``reach``, before the others and only where it rejects something: an edge no map of the
  other edges can fit (its measured translation far beyond their summed reach,
  :mod:`~rlpgo_gtsam.robust.reach`: a closure of 1e20 m on a 300 m map) is rejected at once,
  trusted or not; its scale would break the steps' arithmetic. An edge that no cycle checks
  and that is too long for the rest of the map to keep its digits beside it is refused.
- ``held``, instead of every other step, where the anchor and the FIX lines hold every pose:
  the map is the held poses, and each edge is judged by its chi2 there.

0. ``all edges``: the clean default on every edge (the certified relaxation at its lowest
   rank, then LM to convergence). Where it is certified and every edge's chi2 lies within
   the inlier bound (at the noise level the odometry chain shows, where that is above the
   nominal one: :func:`~rlpgo_gtsam.robust.noise.noise_scale`), nothing speaks against any
   closure: the run stops there and hands over that optimum. On planar graphs step 1 runs
   first, and this step is skipped where a share of the tested pairs conflict that no clean
   file reaches (``skip_conflicts_2d``, but not where most do: then the cycles contradict
   the stated noise, ``noise_conflicts``).
1. ``consistency``: pairwise consistency maximization with bounded tests
   (:mod:`~rlpgo_gtsam.robust.consistency`); the seed is the closures left that have
   positive support. Sets that conflict and are nearly equally supported are reported in
   :attr:`RobustResult.ambiguous`.
2. ``start``: the relaxation of the odometry and the seed at its lowest rank gives the
   orientations; GNC-TLS on the translation step at those orientations
   (:func:`~rlpgo_gtsam.robust.gnc.robust_positions`) drops the seed closures that agreed by
   chance. On planar graphs the rounds start from the certified relaxation of the edges
   kept (the dropped closures had bent the seed's orientations); in 3D from the start's own
   map (``relaxed_start_2d``, ``relaxed_start_3d``).
3. ``verify``: every closure judged by the map's fit, in rounds
   (:mod:`~rlpgo_gtsam.robust.verify`). Then the certified relaxation of the edges kept:
   where it turns some pose of the rounds' map by ``same_basin_rad`` or more and lies lower,
   the rounds settled in a wrong basin, and run again from it (``restarts`` at most).
4. ``gnc``: GTSAM's ``GncLMOptimizer`` from the verified optimum on the edges kept, the
   trusted edges as known inliers (:func:`~rlpgo_gtsam.robust.gnc.gnc_lm`); its weights are
   the last word on those edges.

With ``trust_odometry=True`` (the default) the odometry chain (the spanning tree
:func:`~rlpgo_gtsam.graph.odometry_edges` finds) is known inliers in every step; without it
those edges are judged like closures in steps 2-4; an edge that alone places a pose (rejected
on both sides of it) stays. The anchor and every FIXed pose keep their poses in every step,
exactly in the map handed over, and the steps judge with them held: a closure that only a held
pose's move would fit is rejected. Thresholds are chi-square quantiles at
``inlier_probability``: the group's dof for an edge or a cycle (3 planar, 6 in 3D), the
translation dimension in step 2 (2 or 3). They bound
the noise the covariances state; ``covariance_scale`` judges with the covariances times a
factor (docs/robust.md, "When the covariances are too small"). 3D graphs run the same steps in
SE(3) (:mod:`rlpgo_gtsam.groups`). Every tuning constant is a field of
:class:`~rlpgo_gtsam.robust.settings.RobustSettings`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError, SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph, check_reach, chi2, extract_pose_graph
from rlpgo_gtsam.groups import group_of
from rlpgo_gtsam.landmarks import outside_kinds
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.robust.consistency import Consistency, pairwise_consistency
from rlpgo_gtsam.robust.gnc import gnc_lm, robust_positions
from rlpgo_gtsam.robust.noise import (
    graph_with_printed_blocks,
    graph_with_scaled_covariances,
    noise_scale,
)
from rlpgo_gtsam.robust.problem import (
    Problem,
    edge_factor_indices,
    relaxation,
    relaxation_rotations,
    without_factors,
)
from rlpgo_gtsam.robust.reach import check_scale, out_of_reach
from rlpgo_gtsam.robust.results import (
    AllEdgesStep,
    ConsistencyStep,
    JudgedStep,
    RobustResult,
    Step,
    VerifyStep,
)
from rlpgo_gtsam.robust.settings import RobustSettings
from rlpgo_gtsam.robust.statistics import chi2_quantile, innovation_p_value, statistic_at
from rlpgo_gtsam.robust.verify import Verified, verify
from rlpgo_gtsam.solvers import refine, solver_params

__all__ = ["RobustResult", "robust_initialize"]

_EVERY_EDGE_FITS = ("every edge fits: the relaxation of all edges is certified and every "
                    "residual lies within the inlier bound after refinement")


@numeric_call
def robust_initialize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    *,
    trust_odometry: bool = True,
    inlier_probability: float | None = None,
    gnc_iterations: int | None = None,
    pose_graph: PoseGraph | None = None,
    covariance_scale: float = 1.0,
    false_rejection_rate: float | None = None,
    settings: RobustSettings | None = None,
) -> RobustResult:
    """Reject wrong loop closures and return the refined guess; see the module docstring.

    Args:
        graph: a planar or 3D pose graph (what :class:`~rlpgo_gtsam.graph.PoseGraph2D` or
            :class:`~rlpgo_gtsam.graph.PoseGraph3D` accepts; a Pose3 factor makes it 3D).
        values: its initial values (they give the anchor's pose; the estimate itself starts
            from the seed's certified relaxation, not from them).
        trust_odometry: the odometry chain's edges are known inliers.
        inlier_probability: the chi-square quantile that separates inliers, in (0, 1)
            (None: the settings', 0.9999 by default).
        gnc_iterations: cap on the outer iterations of each GNC, the translation step's and
            GTSAM's (None: the settings', 100 by default).
        pose_graph: the graph's extraction, if the caller has it (a ``PoseGraph3D`` read with
            ``check_information=False`` lets through informations the reader refuses).
        covariance_scale: how many times larger the edges' noise is than their stated
            covariances say: every step judges with each between factor's covariance times
            this; the map, its chi2 and the weights are those of ``graph`` as given. 1: as
            stated (docs/robust.md, "When the covariances are too small").
        false_rejection_rate: the verify step's last bar (adaptive Benjamini-Hochberg):
            closures that fit within the ``inlier_probability`` bar are still rejected where
            their p-values are small enough that, with the closures the evidence already
            rejects, at most this share of the rejections is expected to be true closures;
            in [0, 1), 0 turns the bar off (None: the settings', 0.0025 by default).
        settings: every tuning constant (None: the defaults); the arguments above, where
            given, replace its fields of the same names.

    Raises:
        GraphError: a graph the package cannot work on.
        SolverError: a bad parameter, or a solve that failed.
    """
    began = time.perf_counter()
    settings = _settings_with(settings, inlier_probability=inlier_probability,
                              gnc_iterations=gnc_iterations,
                              false_rejection_rate=false_rejection_rate)
    if not (math.isfinite(covariance_scale) and covariance_scale > 0.0):
        raise SolverError(f"covariance_scale must be a positive number, got {covariance_scale}")
    reported, problem = _judged_problem(graph, values, pose_graph, covariance_scale, settings)
    if len(np.unique(problem.g.held[0])) == problem.g.num_poses:
        return _every_pose_held(problem, reported, trust_odometry, began)
    problem, before = _within_reach(problem)
    try:
        return _robust_run(problem, reported, trust_odometry, began, before)
    except (RuntimeError, ArithmeticError, ValueError, np.linalg.LinAlgError) as error:
        # a numerical failure inside GTSAM, SciPy or numpy on extreme input that no step
        # guards (a bridge measured 1e50 m: no cycle judges it, and the map cannot hold it)
        raise SolverError(f"robust initialization failed: {type(error).__name__}: "
                          f"{one_line(error)}") from None


@dataclass
class _Before:
    """What was decided before the steps: their records and the factors rejected."""

    steps: list[Step] = field(default_factory=list)
    rejected: list[int] = field(default_factory=list)


def _within_reach(problem: Problem) -> tuple[Problem, _Before]:
    """The problem without the edges no map of the others can fit
    (:func:`~rlpgo_gtsam.robust.reach.out_of_reach`; their factor slots left empty) and the
    record of their rejection; ``problem`` itself where there is none.

    Raises:
        GraphError: an edge left so long that the rest of the map loses its digits beside it
            (:func:`~rlpgo_gtsam.robust.reach.check_scale`), or a value or an edge left beyond
            :data:`~rlpgo_gtsam.graph.FARTHEST_M` (:func:`~rlpgo_gtsam.graph.check_reach`).
    """
    began = time.perf_counter()
    g, settings = problem.g, problem.settings
    out = out_of_reach(g, chi2_quantile(settings.inlier_probability, problem.group.dof),
                       settings.reach_margin)
    check_scale(g, out)
    check_reach(g, out)
    if not out.any():
        return problem, _Before()
    graph = without_factors(problem.graph, problem.factor_of_edge[out].tolist())
    within = Problem(graph, replace(problem.group.subgraph(g, ~out), graph=graph),
                     problem.factor_of_edge[~out], settings)
    step = JudgedStep.counted("reach", time.perf_counter() - began, None, ~out,
                              np.zeros(g.num_edges, bool))  # trusted or not, out of reach
    return within, _Before([step], sorted(problem.factor_of_edge[out].tolist()))


def _every_pose_held(problem: Problem, reported: gtsam.NonlinearFactorGraph,
                     trust_odometry: bool, began: float) -> RobustResult:
    """Every pose held (the anchor and FIX lines cover them all): nothing to estimate. The
    map is the held poses, and each edge that is not trusted is judged by its chi2 there:
    a map without uncertainty leaves a residual only its own noise, the verify step's
    statistic with no map covariance."""
    g, group, settings = problem.g, problem.group, problem.settings
    held, held_poses = g.held
    poses = np.empty((g.num_poses, *held_poses.shape[1:]))
    poses[held] = held_poses
    known = problem.chain if trust_odometry else np.zeros(g.num_edges, bool)
    fits = group.edge_chi2(g, poses) < chi2_quantile(settings.inlier_probability, group.dof)
    kept = known | fits  # a non-finite chi2 (a wild measurement) does not fit
    step = JudgedStep.counted("held", time.perf_counter() - began, None, kept, known)
    return _robust_result(reported, problem, problem.holding(group.to_values(g, poses)), kept,
                          np.ones(g.num_edges), known, began, [step], [],
                          "every pose is held: each edge judged by its chi2 at the held poses")


def _robust_run(problem: Problem, reported: gtsam.NonlinearFactorGraph, trust_odometry: bool,
                began: float, before: _Before) -> RobustResult:
    """The steps on the judged ``problem`` after what was decided ``before`` them; the
    result's chi2 and weights on ``reported``."""
    g, settings = problem.g, problem.settings
    chain = problem.chain
    known = chain if trust_odometry else np.zeros(g.num_edges, bool)
    bar = chi2_quantile(settings.inlier_probability, problem.group.dof)  # an edge's, a cycle's
    steps: list[Step] = list(before.steps)

    consistency, consistency_s = _consistency_first(problem, chain, bar)
    clean = _all_edges_step(problem, chain, bar, consistency, steps)
    if clean is not None:  # no evidence against any edge: keep them all
        steps[-1] = replace(steps[-1], seconds=steps[-1].seconds + consistency_s)
        return _robust_result(reported, problem, clean, np.ones(g.num_edges, bool),
                              np.ones(g.num_edges), known, began, steps, [], _EVERY_EDGE_FITS,
                              before=before)
    if consistency is None:
        consistency, consistency_s = _timed_consistency(problem, chain, bar)
    kept = consistency.seed | chain
    steps.append(ConsistencyStep.counted(
        "consistency", consistency_s, None, kept, known, pairs=consistency.pairs,
        conflicts=consistency.conflicts, ambiguous=len(consistency.ambiguous)))
    ambiguous = [(sorted(problem.factor_of_edge[k].tolist()),
                  sorted(problem.factor_of_edge[r].tolist())) for k, r in consistency.ambiguous]

    step_began = time.perf_counter()
    start = _start(problem, kept, known)
    steps.append(JudgedStep.counted("start", time.perf_counter() - step_began, start.iterations,
                                    start.kept, known))

    step_began = time.perf_counter()
    verified, restarts, ties = _verified_with_restarts(problem, start, known)
    kept = verified.kept
    ambiguous += ties
    steps.append(VerifyStep.counted("verify", time.perf_counter() - step_began, verified.rounds,
                                    kept, known, restarts=restarts,
                                    unlikely_fits=int((verified.unlikely & ~kept).sum())))

    step_began = time.perf_counter()
    result, gnc_weights = gnc_lm(problem, verified.values, kept, known)
    kept = problem.spanning(kept & (gnc_weights >= settings.rejected_below), kept,
                            np.argsort(-gnc_weights, kind="stable"))
    steps.append(JudgedStep.counted("gnc", time.perf_counter() - step_began, None, kept, known))
    return _robust_result(reported, problem, result, kept, gnc_weights, known, began, steps,
                          ambiguous, "GNC-LM from the consistent set's verified optimum",
                          _doubtful(problem, verified.fits, kept & ~known), before)


def _settings_with(settings: RobustSettings | None, **given: Any) -> RobustSettings:
    """``settings`` (None: the defaults) with the fields ``given`` that are not None."""
    settings = settings if settings is not None else RobustSettings()
    changed = {name: value for name, value in given.items() if value is not None}
    return replace(settings, **changed) if changed else settings


def _judged_problem(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                    pose_graph: PoseGraph | None, covariance_scale: float,
                    settings: RobustSettings) -> tuple[gtsam.NonlinearFactorGraph, Problem]:
    """The graph the result's chi2 and weights are taken on, and the problem the steps judge:
    its covariances scaled by ``covariance_scale`` and 3D edges read by their printed blocks
    (:mod:`rlpgo_gtsam.robust.noise`)."""
    g = pose_graph if pose_graph is not None else extract_pose_graph(graph, values)
    if g.whole:
        held = [f"{g.points.count} landmarks"] if g.points is not None else []
        held += [f"{kind}" for kind in outside_kinds(g.carried)]
        if g.carried_values is not None and g.carried_values.size() and not g.carried:
            held.append("values of other variables")
        raise GraphError("the robust path judges pose graphs (between factors, priors, FIX "
                         f"lines); this graph also holds {', '.join(held)}: run the default "
                         "path, or give the robust path its pose factors")
    graph, g = graph_with_printed_blocks(graph, values, g)
    reported = graph
    if covariance_scale != 1.0:
        graph, g = graph_with_scaled_covariances(graph, values, covariance_scale)
    factor_of_edge = edge_factor_indices(graph, g.num_edges, group_of(g).between_factor)
    return reported, Problem(graph, g, factor_of_edge, settings)


def _timed_consistency(problem: Problem, chain: np.ndarray,
                       bar: float) -> tuple[Consistency, float]:
    """The pairwise tests and their seconds."""
    began = time.perf_counter()
    found = pairwise_consistency(problem.g, chain, bar, problem.settings)
    return found, time.perf_counter() - began


def _consistency_first(problem: Problem, chain: np.ndarray,
                       bar: float) -> tuple[Consistency | None, float]:
    """The pairwise tests where they come before the all-edges step (planar graphs: where
    more pairs conflict than noise made conflict on any clean file, the all-edges
    relaxation cannot pass and is skipped; on City10K with 10% random wrong closures it took
    62 s, 20x the clean default); (None, 0) in 3D, where no share tells clean files from
    corrupted ones."""
    if problem.settings.skip_conflicts(problem.g.dimension) is None:
        return None, 0.0
    return _timed_consistency(problem, chain, bar)


def _all_edges_step(problem: Problem, chain: np.ndarray, bar: float,
                    consistency: Consistency | None, steps: list[Step]) -> gtsam.Values | None:
    """Step 0, its record appended to ``steps``: the clean default's optimum where every edge
    fits, else None (also where the step is skipped: enough of the tested pairs conflict,
    but not most, where the cycles contradict the stated noise rather than a minority of
    closures)."""
    settings = problem.settings
    skip = settings.skip_conflicts(problem.g.dimension)
    if consistency is not None and skip is not None and (
            skip * consistency.pairs <= consistency.conflicts
            < settings.noise_conflicts * consistency.pairs):
        steps.append(AllEdgesStep(seconds=0.0, certified=None, worst_edge_chi2=None,
                                  passed=False, skipped=f"{consistency.conflicts} of "
                                  f"{consistency.pairs} tested pairs of closures conflict"))
        return None
    began = time.perf_counter()
    clean = _all_edges(problem, bar, chain)
    steps.append(AllEdgesStep(seconds=time.perf_counter() - began, certified=clean.certified,
                              worst_edge_chi2=clean.worst, noise_scale=clean.noise_scale,
                              passed=clean.passed))
    return clean.values if clean.passed else None


# An edge whose chi2 at the certified optimum of all edges is this many times the bar is not
# brought under it by LM: the step fails there without LM. Of the shared files, those this
# step passes have their worst edges at up to 3.7x their bar there (Intel; 0.29x after LM),
# MIT 2.5x, the others below 1x; cubicle, which it fails either way, 3983x (6.6x after LM).
_HOPELESS = 1e3


@dataclass
class _AllEdges:
    values: gtsam.Values
    certified: bool
    # None: not computed (no refined optimum to judge the edges at); where LM did not run
    # (_HOPELESS), at the relaxation's optimum
    worst: float | None
    passed: bool
    noise_scale: list[float] | None = None  # per tangent component, see noise_scale


def _all_edges(problem: Problem, bar: float, trusted: np.ndarray) -> _AllEdges:
    """The clean default on every edge: the certified relaxation, then LM to convergence
    (only when certified); it passes when certified and every edge's chi2 (its error scaled
    by the ``trusted`` edges' :func:`~rlpgo_gtsam.robust.noise.noise_scale`) lies below
    ``bar``. Wrong closures break one or the other.

    The staircase stops at the group's lowest rank after ``all_edges_iterations``
    trust-region iterations: every shared planar file certifies there in 3-19 and SE-Sync's
    seven 3D files in 4-8, while on graphs with wrong closures the relaxation is where the
    time went (City10K with 10% random ones: 100 iterations at rank 1, 74 s). A clean graph
    that would need more goes on to the steps below, which reject only on evidence."""
    g, group, settings = problem.g, problem.group, problem.settings
    init = relaxation(group, settings, max_rank=group.lowest_rank,
                      max_iterations=settings.all_edges_iterations).run(g)
    certified = bool(init.certificate is not None and init.certificate.certified)
    if not certified:
        return _AllEdges(init.values, False, None, False)
    worst, scale = _worst_edge(problem, init.values, trusted)
    if worst > _HOPELESS * bar:
        # LM refines the certified optimum of the relaxation's cost nearby; an edge this far
        # past the bar stays past it (Intel with 4 wrong closures per true one: 3.4e5 at
        # both), and LM on every wrong closure is the step's dearest part
        return _AllEdges(init.values, True, worst, False, scale.tolist())
    params = solver_params("lm", settings.lm_iterations)
    params.setRelativeErrorTol(settings.tolerance)
    refined = refine(problem.graph, init.values, params, pose_graph=g)
    if refined.failure is not None:
        return _AllEdges(init.values, True, None, False)
    worst, scale = _worst_edge(problem, refined.values, trusted)
    return _AllEdges(refined.values, True, worst, worst < bar, scale.tolist())


def _worst_edge(problem: Problem, values: gtsam.Values, trusted: np.ndarray
                ) -> tuple[float, np.ndarray]:
    """The largest edge chi2 at ``values``, errors scaled by the ``trusted`` edges'
    :func:`~rlpgo_gtsam.robust.noise.noise_scale`, and that scale."""
    g, group = problem.g, problem.group
    errors = group.edge_errors(g, group.poses_of(g, values))
    scale = noise_scale(errors[trusted], g.information[trusted], problem.settings.max_noise_scale)
    errors = errors / np.sqrt(scale)
    return float(np.einsum("ea,eab,eb->e", errors, g.information, errors).max()), scale


@dataclass
class _Start:
    """The start step's map ``values`` (``settled``: refined on the kept edges already, as
    far as a round is), the translation step's solves and the edges it kept."""

    values: gtsam.Values
    settled: bool
    iterations: int
    kept: np.ndarray


def _start(problem: Problem, kept: np.ndarray, known: np.ndarray) -> _Start:
    """Step 2: the relaxation of the seed at its lowest rank gives the orientations, GNC-TLS
    on the translation step at them drops the seed closures at odds with the seed's map.
    (Chordal orientations fail under heavy rotation noise: imprecise, they put true closures'
    translations at odds too.) On planar graphs the rounds then start from the certified
    relaxation of the edges kept: the closures just dropped had bent the seed's rotations
    (City10K, 10% grouped wrong closures: chi2 407 in 2 s against 2742 in 30 s)."""
    settings, g, group = problem.settings, problem.g, problem.group
    translation_bar = chi2_quantile(settings.inlier_probability, group.d)
    rotations = relaxation_rotations(group.subgraph(g, kept), settings.start_iterations,
                                     settings)
    positions, weights, iterations = robust_positions(g, rotations, known, ~kept,
                                                      translation_bar, settings.gnc_iterations)
    kept = problem.spanning(kept & (weights >= settings.rejected_below), kept,
                            np.argsort(-weights, kind="stable"))
    if settings.relaxed_start(g.dimension):
        relaxed = _kept_edges_relaxation(problem, kept, None, settings.round_iterations,
                                         settings.round_tolerance)
        if relaxed is not None:
            return _Start(relaxed, True, iterations, kept)
    return _Start(group.to_values(g, group.with_positions(rotations, positions)), False,
                  iterations, kept)


def _verified_with_restarts(problem: Problem, start: _Start, known: np.ndarray
                            ) -> tuple[Verified, int, list[tuple[list[int], list[int]]]]:
    """Step 3: the rounds from the start's map, then again from the certified relaxation of
    the edges kept while it lies lower (the rounds' map grew from the seed's start and can
    settle in a wrong basin: City10K, 10% local wrong closures, 1.83x the optimum), at most
    ``restarts`` times. Returns the last verification (its rounds and false-rejection
    rejections summed over every run), the restarts and what the exchanges could not tell
    apart (factor indices; a set questioned again is listed once, with its last
    alternative)."""
    settings, g, group = problem.settings, problem.g, problem.group
    verified = verify(problem, start.values, start.settled, start.kept, known)
    rounds, unlikely, ties = verified.rounds, verified.unlikely, list(verified.ties)
    restarts = 0
    while restarts < settings.restarts:
        restart = _kept_edges_relaxation(problem, verified.kept,
                                         group.poses_of(g, verified.values),
                                         settings.restart_iterations, settings.tolerance)
        kept_graph = problem.kept_graph(verified.kept)
        if restart is None or not chi2(kept_graph, restart) < (
                1.0 - settings.restart_gain) * chi2(kept_graph, verified.values):
            break
        restarts += 1
        verified = verify(problem, restart, True, verified.kept, known)
        rounds += verified.rounds
        unlikely |= verified.unlikely
        ties += verified.ties
    factor_of_edge = problem.factor_of_edge
    last = {tuple(sorted(factor_of_edge[k].tolist())): sorted(factor_of_edge[r].tolist())
            for k, r in ties}
    return (replace(verified, rounds=rounds, unlikely=unlikely), restarts,
            [(list(k), r) for k, r in last.items()])


def _kept_edges_relaxation(problem: Problem, kept: np.ndarray, near: np.ndarray | None,
                           iterations: int, tolerance: float) -> gtsam.Values | None:
    """The certified relaxation of the kept edges, refined by GTSAM on them (``iterations``
    at most, stopped at a relative change below ``tolerance``); None where they do not span
    the graph, or where the relaxation's estimate turns no pose more than
    ``same_basin_rad`` from ``near`` (the map it would be compared with, poses as the
    group's rows: the same basin, nothing to refine)."""
    g, group = problem.g, problem.group
    inliers = group.subgraph(g, kept)
    try:
        inliers.check_connected()
    except GraphError:  # the edges kept do not span the graph (odometry judged and rejected)
        return None
    poses = _certified_estimate(inliers, near, problem.settings)
    if near is not None:  # compared as arrays: GTSAM values only for a map that goes on
        turned = group.logmap(group.between(near, poses))
        if (np.linalg.norm(turned[:, group.rotation_axes], axis=1).max()
                < problem.settings.same_basin_rad):
            return None
    return problem.optimum(kept, group.to_values(g, poses), iterations, tolerance).values


def _certified_estimate(g: PoseGraph, warm: np.ndarray | None,
                        settings: RobustSettings) -> np.ndarray:
    """The poses of the certified relaxation of ``g``: from ``warm`` at the group's lowest
    rank (at most ``warm_iterations`` trust-region iterations) where that is certified, else
    from the chordal estimate (the clean default's relaxation). A certified estimate is the
    relaxation's global optimum whatever the start; warm, the restart check took 31-36 ms
    against 37-42 cold on MIT. The start step does not start warm: the edges it keeps may
    still hold wrong closures, and where their relaxation is not tight the warm attempt is
    lost time."""
    group = group_of(g)
    if warm is not None:
        quick = relaxation(group, settings, max_rank=group.lowest_rank,
                           max_iterations=settings.warm_iterations)
        estimate = quick.estimate(g, warm)
        if estimate.certificate is not None and estimate.certificate.certified:
            return estimate.poses
    return relaxation(group, settings).estimate(g, None).poses


def _doubtful(problem: Problem, fits: np.ndarray, kept: np.ndarray) -> list[tuple[int, float]]:
    """``RobustResult.doubtful``: (factor index, p-value) of the ``kept`` closures whose
    statistic in ``fits`` (per edge, the verify step's last, NaN where not judged) has a
    p-value below ``doubtful_below``, smallest first; only those p-values are computed."""
    settings, dof = problem.settings, problem.group.dof
    poor = statistic_at(settings.doubtful_below, dof, settings.samples)
    pairs = [(int(problem.factor_of_edge[e]),
              innovation_p_value(float(fits[e]), dof, settings.samples))
             for e in np.flatnonzero(kept & (fits >= poor)).tolist()]
    return sorted((pair for pair in pairs if pair[1] < settings.doubtful_below),
                  key=lambda pair: (pair[1], pair[0]))


def _robust_result(graph: gtsam.NonlinearFactorGraph, problem: Problem, values: gtsam.Values,
                   kept: np.ndarray, edge_weights: np.ndarray, known: np.ndarray,
                   began: float, steps: list[Step],
                   ambiguous: list[tuple[list[int], list[int]]], stopped: str,
                   doubtful: list[tuple[int, float]] | None = None,
                   before: _Before | None = None) -> RobustResult:
    """The result on ``graph`` (the caller's, or its printed blocks read): every factor's
    weight, the rejected factors (with those rejected ``before`` the steps) and the chi2
    without them, at ``values`` with every held pose exactly where it is held."""
    factor_of_edge = problem.factor_of_edge
    before = before if before is not None else _Before()
    weights = np.full(graph.size(), np.nan)
    for k in range(graph.size()):
        if graph.at(k) is not None:
            weights[k] = 1.0
    weights[factor_of_edge] = np.where(kept, np.maximum(edge_weights, 0.0), 0.0)
    weights[factor_of_edge[known]] = 1.0
    weights[before.rejected] = 0.0
    rejected = sorted(factor_of_edge[~kept].tolist() + before.rejected)
    if before.rejected:
        stopped = (f"{stopped}; before the steps, {len(before.rejected)} edges that no map of "
                   "the others can fit were rejected")
    values = problem.holding(values)
    return RobustResult(
        values=values,
        rejected=rejected,
        weights=weights,
        chi2=chi2(without_factors(graph, rejected), values),
        seconds=time.perf_counter() - began,
        steps=steps,
        trusted=sorted(factor_of_edge[known].tolist()),
        ambiguous=ambiguous,
        stopped=stopped,
        doubtful=[] if doubtful is None else doubtful,
    )
