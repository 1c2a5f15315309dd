"""Wrong loop closures: find them, say which they were, and hand over the right start.

One wrong loop closure bends the chordal estimate, costs the relaxation its certificate and
leads LM to a wrong map; GTSAM's graduated non-convexity (``GncLMOptimizer``) rejects wrong
closures but needs a start near the right map. :func:`robust_initialize` builds that start
and lets GTSAM's GNC-LM (truncated least squares) finish from it:

0. ``all edges``: the clean default on every edge (the certified relaxation, then LM to
   convergence). When the relaxation is certified and every edge's chi2 lies within the
   inlier bound, nothing speaks against any closure: the run stops there, rejects nothing
   and hands over that optimum (the clean default's). A closure is rejected only on
   evidence against it, never for lack of support.
1. ``consistency``: pairwise consistency maximization with bounded tests
   (:func:`~rlpgo_gtsam.robust.consistency.pairwise_consistency`): closures whose cycle
   through the odometry conflicts go, the one with most conflicts first, until none is
   left; groups of wrong closures that agree with each other conflict with the many true
   closures they contradict. The seed is the closures left that have positive support
   (agreeing tests); the others are judged later by the map's fit. Sets that conflict and
   are nearly equally supported are reported in :attr:`RobustResult.ambiguous`.
2. ``start``: the certified relaxation (:mod:`rlpgo_gtsam.certified`) of the seed (the
   odometry edges and the seed closures) gives the orientations; then GNC-TLS on the
   translation step at those orientations (odometry at weight 1, seed closures judged, the
   rest left out): a seed closure that agreed by chance goes here, its translation at
   odds with the seed's map. (Chordal orientations instead fail under heavy rotation
   noise: imprecise, they put true closures' translations at odds too, and LM from the
   thinned seed's chordal estimate settled in a wrong basin on the generator's graphs with
   0.2 rad per measurement.)
3. ``verify``: Gauss-Newton (LM where GN does not lower the cost) on the edges kept, then
   every edge is judged by its chi2 (3 dof) at that optimum against a bar that falls from
   10x to 1x the inlier threshold (100x to 1x for closures with loose support: agreeing
   with three neighbours in any test): true closures the seed missed come back, closures
   that do not fit go. Repeated until the final bar leaves the decision unchanged (see
   :func:`_verify`).
4. ``gnc``: GTSAM's ``GncLMOptimizer`` (TLS, super-linear schedule, the project's LM
   settings) from the verified optimum on the edges kept, the trusted edges as known
   inliers. Its weights are the last word on those edges: rejected means weight < 0.5.
   (Edges the earlier steps rejected are left out of its graph: kept in, their residuals
   set GNC's first control parameter near zero, and it then spends dozens of outer
   iterations re-deriving what the steps above found.)

Trusted edges: with ``trust_odometry=True`` (the default) the odometry chain (the spanning
tree :func:`~rlpgo_gtsam.graph.odometry_edges` finds: edges between ids adjacent in sorted
order, completed in file order; any ids, a star) is known inliers in every step; without it
those edges are judged like closures in steps 2-4 (step 1 still uses the chain).
The anchor (and any FIXed pose) keeps its pose.

Thresholds are chi-square quantiles at ``inlier_probability`` (2 dof in step 2, 3 dof after).

:func:`outlier_suspicion` is the cheap test for the staged default: after a failed
certificate, are the refined result's per-edge residuals what Gaussian noise gives, or is the
tail too heavy (wrong closures)?
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError, SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph2D, chi2, edge_chi2, odometry_edges
from rlpgo_gtsam.initializers import make_initializer
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.robust.consistency import pairwise_consistency
from rlpgo_gtsam.robust.gnc import robust_positions
from rlpgo_gtsam.solvers import refine, solver_params

__all__ = ["RobustResult", "robust_initialize", "DEFAULT_INLIER_PROBABILITY", "REJECTED_BELOW"]

# An inlier's residual lies below the chi-square quantile at this probability.
DEFAULT_INLIER_PROBABILITY = 0.9999
REJECTED_BELOW = 0.5  # a GNC weight below this is a rejection
_MAX_GNC_ITERATIONS = 100
# verify: a closure is let in while its chi2 is below the inlier threshold times these, ...
_ANNEAL = (10.0, 3.0, 1.0)
# ... times this for closures with loose support (at least three agreeing
# neighbours in any test, informative or not) except at the final bar.
_SUPPORTED_BAR = 10.0
_VERIFY_ROUNDS = 4  # final-bar rounds at most
_LM_ITERS = 100
_LOOSE_LM_ITERS = 4
_LOOSE_LM_TOLERANCE = 1e-4
_ANCHOR_SIGMA = 1e-8
_TOLERANCE = 1e-10  # the final rounds' relative error tolerance (the project's)
_ALL_EDGES_RANK = 1  # the all-edges step's highest staircase rank (see _all_edges)



@dataclass
class RobustResult:
    """What :func:`robust_initialize` found.

    Attributes:
        values: the guess GTSAM's GNC-LM hands over (refined on the edges it kept).
        rejected: factor indices (into the caller's graph) of the loop closures judged wrong,
            ascending.
        weights: (graph.size(),) the final weight of every factor: GNC-LM's for the edges it
            judged, 0 for edges the earlier steps rejected, 1 for trusted edges and priors,
            NaN for empty factor slots.
        chi2: g2o chi2 of ``values`` on the graph without the rejected factors.
        seconds: wall time of the whole call, extraction included.
        steps: what each step did, in order (JSON-ready dicts: step, seconds, iterations,
            kept / rejected counts, ...).
        trusted: factor indices of the edges treated as known inliers.
        ambiguous: what the consistency step could not tell apart: per group of conflicting
            closures, the factor indices kept there and those of a rejected alternative that
            is (nearly) as well supported (at least ``AMBIGUOUS_RATIO`` of its size) and
            consistent in itself. The later steps decided by the map's fit; empty when
            nothing was ambiguous.
        stopped: why the run ended where it did, in words.
    """

    values: gtsam.Values
    rejected: list[int]
    weights: np.ndarray
    chi2: float
    seconds: float
    steps: list[dict[str, Any]] = field(default_factory=list)
    trusted: list[int] = field(default_factory=list)
    ambiguous: list[tuple[list[int], list[int]]] = field(default_factory=list)
    stopped: str = ""

    def record(self) -> dict[str, Any]:
        """JSON-ready summary: rejected indices, chi2, seconds, steps."""
        return {"rejected": self.rejected, "chi2": self.chi2, "seconds": self.seconds,
                "steps": self.steps, "trusted": len(self.trusted),
                "ambiguous": self.ambiguous, "stopped": self.stopped}

@numeric_call
def robust_initialize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    *,
    trust_odometry: bool = True,
    inlier_probability: float = DEFAULT_INLIER_PROBABILITY,
    gnc_iterations: int = _MAX_GNC_ITERATIONS,
    pose_graph: PoseGraph2D | None = None,
) -> RobustResult:
    """Reject wrong loop closures and return the refined guess; see the module docstring.

    Args:
        graph: a planar pose graph (what :class:`PoseGraph2D` accepts).
        values: its initial values (they give the anchor's pose; the estimate itself starts
            from the seed's certified relaxation, not from them).
        trust_odometry: edges between consecutive keys (k, k+1) are known inliers.
        inlier_probability: the chi-square quantile that separates inliers, in (0, 1).
        gnc_iterations: cap on the outer iterations of each GNC (the translation step's and
            GTSAM's).
        pose_graph: the graph's extraction, if the caller has it.

    Raises:
        GraphError: a graph the package cannot work on.
        SolverError: a bad parameter, or a solve that failed.
    """
    began = time.perf_counter()
    if not 0.0 < inlier_probability < 1.0:
        raise SolverError(f"inlier_probability must lie in (0, 1), got {inlier_probability}")
    if gnc_iterations < 1:
        raise SolverError(f"gnc_iterations must be >= 1, got {gnc_iterations}")
    g = pose_graph if pose_graph is not None else PoseGraph2D.from_gtsam(graph, values)
    factor_of_edge = _edge_factor_indices(graph, g.num_edges)
    chain = odometry_edges(g)
    known = chain if trust_odometry else np.zeros(g.num_edges, bool)
    thresholds = {dof: chi2_quantile(inlier_probability, dof) for dof in (1, 2, 3)}
    steps: list[dict[str, Any]] = []

    step_began = time.perf_counter()
    clean = _all_edges(graph, g, thresholds[3])
    steps.append({"step": "all edges", "seconds": time.perf_counter() - step_began,
                  "certified": clean.certified, "worst_edge_chi2": clean.worst,
                  "passed": clean.passed})
    if clean.passed:  # no evidence against any edge: keep them all
        return _result(graph, factor_of_edge, clean.values, np.ones(g.num_edges, bool),
                       np.ones(g.num_edges), known, began, steps, [],
                       "every edge fits: the relaxation of all edges is certified and every "
                       "residual lies within the inlier bound after refinement")

    step_began = time.perf_counter()
    consistency = pairwise_consistency(g, chain, thresholds[3])
    kept, loose = consistency.seed | chain, consistency.supported
    steps.append(_step("consistency", step_began, None, kept, known) |
                 {"pairs": consistency.pairs, "conflicts": consistency.conflicts,
                  "ambiguous": len(consistency.ambiguous)})
    ambiguous = [(sorted(factor_of_edge[k].tolist()), sorted(factor_of_edge[r].tolist()))
                 for k, r in consistency.ambiguous]

    step_began = time.perf_counter()
    seed = replace(g, edges=g.edges[kept], measured=g.measured[kept],
                   information=g.information[kept])
    theta = make_initializer("certified").run(seed).poses[:, 2]
    positions, weights, iterations = robust_positions(g, theta, known, ~kept, thresholds[2],
                                                       gnc_iterations)
    kept &= weights >= REJECTED_BELOW
    poses = np.column_stack([positions, theta])
    steps.append(_step("start", step_began, iterations, kept, known))

    step_began = time.perf_counter()
    poses, kept, rounds, solver_iterations = _verify(graph, g, factor_of_edge, poses, kept, known,
                                                 loose, thresholds[3])
    steps.append(_step("verify", step_began, rounds, kept, known) |
                 {"solver_iterations": solver_iterations})

    step_began = time.perf_counter()
    result, gnc_weights = _gnc_lm(graph, g, factor_of_edge, g.to_values(poses), kept, known,
                                  inlier_probability, gnc_iterations)
    kept &= gnc_weights >= REJECTED_BELOW
    steps.append(_step("gnc", step_began, None, kept, known))

    return _result(graph, factor_of_edge, result, kept, gnc_weights, known, began, steps,
                   ambiguous, "GNC-LM from the consistent set's verified optimum")


def chi2_cdf(x: float, dof: int) -> float:
    """P(X <= x) for X chi-square with ``dof`` (a positive integer) degrees of freedom, in
    closed form: ``1 - exp(-x/2) sum_{k < dof/2} (x/2)^k / k!`` for even ``dof``;
    ``erf(sqrt(x/2)) - exp(-x/2) sum_{k <= (dof-3)/2} (x/2)^(k+1/2) / Gamma(k + 3/2)`` for odd."""
    if x <= 0.0:
        return 0.0
    half = 0.5 * x
    if dof % 2 == 0:
        term, total = 1.0, 1.0
        for k in range(1, dof // 2):
            term *= half / k
            total += term
        return max(0.0, 1.0 - math.exp(-half) * total)
    term, total = math.sqrt(half) / math.gamma(1.5), 0.0
    for k in range((dof - 1) // 2):
        total += term
        term *= half / (k + 1.5)
    return min(1.0, max(0.0, math.erf(math.sqrt(half)) - math.exp(-half) * total))


def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square quantile: x with ``chi2_cdf(x, dof) = probability`` (bisection to
    round-off; scipy.stats's ppf, without the second it takes to import scipy.stats)."""
    low, high = 0.0, float(dof)
    while chi2_cdf(high, dof) < probability:
        low, high = high, 2.0 * high
    for _ in range(200):
        middle = 0.5 * (low + high)
        if middle in (low, high):
            break
        low, high = (middle, high) if chi2_cdf(middle, dof) < probability else (low, middle)
    return high


def _result(graph, factor_of_edge: np.ndarray, values: gtsam.Values, kept: np.ndarray,
            edge_weights: np.ndarray, known: np.ndarray, began: float,
            steps: list[dict[str, Any]], ambiguous: list[tuple[list[int], list[int]]],
            stopped: str) -> RobustResult:
    weights = np.full(graph.size(), np.nan)
    for k in range(graph.size()):
        if graph.at(k) is not None:
            weights[k] = 1.0
    weights[factor_of_edge] = np.where(kept, np.maximum(edge_weights, 0.0), 0.0)
    weights[factor_of_edge[known]] = 1.0
    rejected = sorted(factor_of_edge[~kept].tolist())
    return RobustResult(
        values=values,
        rejected=rejected,
        weights=weights,
        chi2=chi2(_without(graph, rejected), values),
        seconds=time.perf_counter() - began,
        steps=steps,
        trusted=sorted(factor_of_edge[known].tolist()),
        ambiguous=ambiguous,
        stopped=stopped,
    )


@dataclass
class _AllEdges:
    values: gtsam.Values
    certified: bool
    worst: float | None  # None: not computed (no refined optimum to judge the edges at)
    passed: bool


def _all_edges(graph, g: PoseGraph2D, threshold: float) -> _AllEdges:
    """The clean default on every edge: the certified relaxation, then LM to convergence
    (only when certified); it passes when certified and every edge's chi2 (3 dof, whitened)
    lies below ``threshold``. Wrong closures break one or the other.

    The staircase stops at rank 1 (``_ALL_EDGES_RANK``): every shared file certifies there
    in 3-19 trust-region iterations, while on graphs with wrong closures the higher ranks
    are where the time went (the generator's graph with 10% local wrong closures: rank 2
    ran 300 iterations, 24 s CPU, and still ended uncertified). A clean graph that would
    need a higher rank goes on to the steps below, which reject only on evidence."""
    init = make_initializer("certified", max_rank=_ALL_EDGES_RANK).run(g)
    certified = bool(init.certificate is not None and init.certificate.certified)
    if not certified:
        return _AllEdges(init.values, False, None, False)
    params = solver_params("lm", _LM_ITERS)
    params.setRelativeErrorTol(_TOLERANCE)
    refined = refine(graph, init.values, params, pose_graph=g)
    if refined.failure is not None:
        return _AllEdges(init.values, True, None, False)
    worst = float(edge_chi2(g, g.poses_of(refined.values)).max())
    return _AllEdges(refined.values, True, worst, worst < threshold)


def _verify(graph, g: PoseGraph2D, factor_of_edge: np.ndarray, poses: np.ndarray,
            kept: np.ndarray, known: np.ndarray, supported: np.ndarray,
            threshold: float) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Solve on the kept edges, then re-judge every edge by its chi2 at that optimum; repeated.

    The bar falls from ``_ANNEAL[0] x threshold`` to ``threshold``: a true closure left out
    of the start sits in a map bent without it, so its chi2 there is high; let back in under
    the looser bar, it straightens the map and then passes the final one. Closures with
    loose support (``supported``) get a bar ``_SUPPORTED_BAR`` times looser in the early
    rounds: on the generator's graphs (heavy rotation noise, rotations pinned only by the
    translations) the closures the seed missed sat at 15-50x the threshold in the first map,
    while on Intel a few wrong closures sat at 15-80x and, once in, bent the map until they
    fit. Ends once the final bar leaves the decision unchanged. Intermediate rounds run a
    short, loose solve (they need the map's shape). Each round's solve is :func:`_settle`.
    Returns poses, kept, rounds, solver iterations.
    """
    solver_iterations, rounds = 0, 0
    for bar in list(_ANNEAL) + [1.0] * _VERIFY_ROUNDS:
        rounds += 1
        # rounds under a looser bar need the map's shape, not its last digits
        refined = _settle(_without(graph, factor_of_edge[~kept].tolist()), g.to_values(poses),
                          g, _LM_ITERS if bar == 1.0 else _LOOSE_LM_ITERS,
                          _LOOSE_LM_TOLERANCE if bar != 1.0 else _TOLERANCE)
        solver_iterations += refined.iterations
        poses = g.poses_of(refined.values)
        scale = np.where(supported & (bar > 1.0), bar * _SUPPORTED_BAR, bar)
        decided = known | (edge_chi2(g, poses) < scale * threshold)
        if bar == 1.0 and np.array_equal(decided, kept):
            break
        kept = decided
    return poses, kept, rounds, solver_iterations

def _settle(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, g: PoseGraph2D,
            iterations: int, tolerance: float):
    """GTSAM Gauss-Newton (g2o's loop: on through an increase) from ``values``, or LM
    (relative tolerance ``tolerance``) where that does not lower the chi2. From the maps
    ``_verify`` hands it (a few closures away from their optimum) GN converges in a handful
    of steps where LM's damping takes 15-20 (Intel: 4 against 20); LM remains the fallback
    for a start that GN overshoots from."""
    refined = refine(graph, values, "gn", iterations, pose_graph=g)
    if refined.failure is not None or not refined.chi2 <= refined.chi2_trace[0]:
        params = solver_params("lm", iterations)
        params.setRelativeErrorTol(tolerance)
        refined = refine(graph, values, params, pose_graph=g)
    if refined.failure is not None:
        raise SolverError(f"robust initialization: {refined.failure}")
    return refined

def _gnc_lm(graph, g: PoseGraph2D, factor_of_edge: np.ndarray, start: gtsam.Values,
            kept: np.ndarray, known: np.ndarray, inlier_probability: float,
            iterations: int) -> tuple[gtsam.Values, np.ndarray]:
    """GTSAM's GNC-LM (TLS) from ``start`` on the kept edges; returns its values and the
    weight of every edge (0 for edges not kept)."""
    optimized = _without(graph, factor_of_edge[~kept].tolist())
    inliers = [k for k in range(optimized.size()) if optimized.at(k) is not None]
    inliers = sorted(set(inliers) - set(factor_of_edge[~known].tolist()))
    anchor_key = int(g.keys[g.anchor])
    optimized.add(gtsam.PriorFactorPose2(anchor_key, start.atPose2(anchor_key),
                                         gtsam.noiseModel.Isotropic.Sigma(3, _ANCHOR_SIGMA)))
    params = gtsam.GncLMParams(solver_params("lm", _LM_ITERS))
    params.setLossType(gtsam.GncLossType.TLS)
    params.setScheduler(gtsam.GncScheduler.SuperLinear)
    params.maxIterations = iterations  # the setter prints a warning to stdout
    params.setKnownInliers(inliers + [optimized.size() - 1])
    try:
        optimizer = gtsam.GncLMOptimizer(optimized, start, params)
        optimizer.setInlierCostThresholdsAtProbability(inlier_probability)
        result = optimizer.optimize()
    except RuntimeError as error:
        raise SolverError(f"GNC-LM failed: {one_line(error)}") from None
    weights = np.asarray(optimizer.getWeights(), dtype=float).ravel()[factor_of_edge]
    return result, np.where(kept, weights, 0.0)

def _edge_factor_indices(graph: gtsam.NonlinearFactorGraph, num_edges: int) -> np.ndarray:
    """(m,) the factor index of each edge of the graph's extraction (edges are in graph order)."""
    indices = np.array([k for k in range(graph.size())
                        if isinstance(graph.at(k), gtsam.BetweenFactorPose2)], dtype=np.int64)
    if len(indices) != num_edges:
        raise GraphError(f"the graph has {len(indices)} between factors but its extraction has "
                         f"{num_edges} edges")
    return indices

def _without(graph: gtsam.NonlinearFactorGraph, indices: list[int]) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with the factors at ``indices`` removed (their slots left empty)."""
    copy = gtsam.NonlinearFactorGraph(graph)
    for k in indices:
        copy.remove(int(k))
    return copy

def _step(name: str, began: float, iterations: int | None, kept: np.ndarray,
          known: np.ndarray) -> dict[str, Any]:
    judged = ~known
    return {"step": name, "seconds": time.perf_counter() - began, "iterations": iterations,
            "judged": int(judged.sum()), "kept": int((kept & judged).sum()),
            "rejected": int((~kept & judged).sum())}
