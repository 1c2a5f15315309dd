"""Wrong loop closures: find them, say which they were, and hand over the right start.

One wrong loop closure bends the chordal estimate, costs the relaxation its certificate and
leads LM to a wrong map; GTSAM's graduated non-convexity (``GncLMOptimizer``) rejects wrong
closures but needs a start near the right map. :func:`robust_initialize` builds that start
and lets GTSAM's GNC-LM (truncated least squares) finish from it:

1. ``consistency``: every pair of loop closures whose ends lie within ``_WINDOW`` steps of
   each other along the odometry chain closes a short cycle through it, whose covariance
   is propagated to first order from its measurements; a closure that agrees with at least
   two neighbours in tests that a wrong closure would pass by chance less than 1% of the
   time, or with at least three in any test, joins the seed (see
   :func:`_consistent_closures`). Wrong closures join random poses and agree with nothing.
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

Trusted edges: with ``trust_odometry=True`` (the default) every edge between consecutive keys
(k, k+1) is a known inlier in every step; without it those edges are judged like closures in
steps 2-4 (step 1 still uses the chain). The anchor (and any FIXed pose) keeps its pose.

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
from rlpgo_gtsam.graph import PoseGraph2D, chi2, edge_chi2, logmap_translation
from rlpgo_gtsam.initializers import make_initializer
from rlpgo_gtsam.rotations import wrap
from rlpgo_gtsam.solvers import refine, solver_params
from rlpgo_gtsam.translations import whitened_system

__all__ = [
    "RobustResult",
    "robust_initialize",
    "outlier_suspicion",
    "odometry_edges",
    "DEFAULT_INLIER_PROBABILITY",
    "SUSPICION_CHI2",
]

# An inlier's residual lies below the chi-square quantile at this probability.
DEFAULT_INLIER_PROBABILITY = 0.9999
# outlier_suspicion: per-edge chi2 (3 dof) above this has probability 0.001 under Gaussian noise.
SUSPICION_CHI2 = 16.266
_SUSPICION_P = 0.001
REJECTED_BELOW = 0.5  # a GNC weight below this is a rejection
_MAX_GNC_ITERATIONS = 100
_MU_STEP = 1.4
_MU_MIN = 1e-6
_WEIGHTS_TOL = 1e-4
_WEIGHT_FLOOR = 1e-12  # weights at or below this leave an edge out of a linear solve
# verify: a closure is let in while its chi2 is below the inlier threshold times these, ...
_ANNEAL = (10.0, 3.0, 1.0)
# ... times this for closures with loose support (at least _LOOSE_SUPPORT agreeing
# neighbours in any test, informative or not) except at the final bar.
_SUPPORTED_BAR = 10.0
_LOOSE_SUPPORT = 3
# The consistency step: closures whose ends lie this many chain steps apart are compared, ...
_WINDOW = 15
# ... a closure needs this many agreeing neighbours, ...
_MIN_SUPPORT = 2
# ... and a pair agrees below this many times the median score (or the chi-square threshold).
_DATA_SCALE = 20.0
# ... and a pair counts only where a wrong closure would agree by chance less often than this.
_CHANCE = 1e-2
_VERIFY_ROUNDS = 4  # final-bar rounds at most
_LM_ITERS = 100
_LOOSE_LM_ITERS = 4
_LOOSE_LM_TOLERANCE = 1e-4
_ANCHOR_SIGMA = 1e-8
_TOLERANCE = 1e-10  # the final rounds' relative error tolerance (the project's)


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
    """

    values: gtsam.Values
    rejected: list[int]
    weights: np.ndarray
    chi2: float
    seconds: float
    steps: list[dict[str, Any]] = field(default_factory=list)
    trusted: list[int] = field(default_factory=list)

    def record(self) -> dict[str, Any]:
        """JSON-ready summary: rejected indices, chi2, seconds, steps."""
        return {"rejected": self.rejected, "chi2": self.chi2, "seconds": self.seconds,
                "steps": self.steps, "trusted": len(self.trusted)}


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
    from scipy.stats import chi2 as chi2_distribution  # scipy: loaded when first used

    g = pose_graph if pose_graph is not None else PoseGraph2D.from_gtsam(graph, values)
    factor_of_edge = _edge_factor_indices(graph, g.num_edges)
    chain = odometry_edges(g)
    known = chain if trust_odometry else np.zeros(g.num_edges, bool)
    thresholds = {dof: float(chi2_distribution.ppf(inlier_probability, dof)) for dof in (1, 2, 3)}
    steps: list[dict[str, Any]] = []

    step_began = time.perf_counter()
    kept, loose, pairs = _consistent_closures(g, chain, thresholds[3])
    kept |= loose | chain
    steps.append(_step("consistency", step_began, None, kept, known) | {"pairs": pairs})

    step_began = time.perf_counter()
    seed = replace(g, edges=g.edges[kept], measured=g.measured[kept],
                   information=g.information[kept])
    theta = make_initializer("certified").run(seed).poses[:, 2]
    positions, weights, iterations = _robust_positions(g, theta, known, ~kept, thresholds[2],
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

    weights = np.full(graph.size(), np.nan)
    for k in range(graph.size()):
        if graph.at(k) is not None:
            weights[k] = 1.0
    weights[factor_of_edge] = np.where(kept, np.maximum(gnc_weights, 0.0), 0.0)
    weights[factor_of_edge[known]] = 1.0
    rejected = sorted(factor_of_edge[~kept].tolist())
    return RobustResult(
        values=result,
        rejected=rejected,
        weights=weights,
        chi2=chi2(_without(graph, rejected), result),
        seconds=time.perf_counter() - began,
        steps=steps,
        trusted=sorted(factor_of_edge[known].tolist()),
    )


def odometry_edges(pose_graph: PoseGraph2D) -> np.ndarray:
    """(m,) bool: the edges that join consecutive keys (k, k+1), in either direction."""
    keys = pose_graph.keys.astype(np.int64)[pose_graph.edges]
    return np.abs(keys[:, 1] - keys[:, 0]) == 1


def outlier_suspicion(pose_graph: PoseGraph2D, values: gtsam.Values) -> str | None:
    """A one-line hint when ``values`` (a refined result) fits the edges with a heavier tail
    than Gaussian noise allows; None when the residuals look Gaussian.

    Each edge's chi2 (3 dof) is compared with :data:`SUSPICION_CHI2`, which Gaussian noise
    exceeds with probability 0.001. The hint fires when more edges exceed it than a Gaussian
    model makes plausible (its expected count plus four standard deviations, and at least
    three edges).
    """
    g = pose_graph
    residuals = edge_chi2(g, g.poses_of(values))
    high = residuals > SUSPICION_CHI2
    count, expected = int(high.sum()), _SUSPICION_P * g.num_edges
    if count < 3 or count <= expected + 4.0 * math.sqrt(expected):
        return None
    worst = np.argsort(-residuals, kind="stable")[:3]
    shown = ", ".join(f"{g.keys[a]}-{g.keys[b]}" for a, b in g.edges[worst].tolist())
    return (f"{count} of {g.num_edges} edges fit with chi2 > {SUSPICION_CHI2:g} (Gaussian noise "
            f"gives about {expected:.0f}; worst: edges {shown}): wrong loop closures are likely; "
            "try --robust")


# ---------------------------------------------------------------------------------------------
# the steps


def _consistent_closures(g: PoseGraph2D, chain_mask: np.ndarray,
                         threshold: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(m,) bool twice, then the number of pairs tested: the closures that agree with at
    least ``_MIN_SUPPORT`` nearby closures in informative tests (the seed), and those that
    agree with at least ``_LOOSE_SUPPORT`` in any test (loose support).

    Two closures ``e = (i, j)`` and ``f = (k, l)`` whose ends are at most ``_WINDOW``
    chain steps apart (``|i - k|``, ``|j - l|``) close a short cycle through the odometry
    chain: ``Z_e^-1 D(i, k) Z_f D(l, j)`` is the identity up to noise (``D(a, b)`` the
    chained odometry from pose a to pose b). Its error (the cycle's Logmap) is scored, 3
    dof, against the cycle's covariance propagated to first order from every measurement in
    it: each factor's covariance moved into the cycle's end frame by the adjoint of the
    rest of the cycle; a chain segment's covariance comes from prefix sums of the steps'
    covariances in the chain's origin frame, so every pair costs the same whatever its
    length. A score below ``min(threshold, _DATA_SCALE x median score)`` is agreement: the
    nominal covariances of real data often overstate the noise by an order of magnitude, so
    the scores' own median sets the scale there (most pairs join two true closures, which
    come in runs). A test is informative where a wrong closure (translation uniform over a
    square of the chain's extent, any angle) would land inside the agreement ellipsoid with
    probability below ``_CHANCE``: over long cycles with heavy rotation noise the ellipsoid
    grows until anything agrees. Pairs across a break in the chain are not tested.
    """
    n = g.num_poses
    cov = np.linalg.inv(g.information)
    closures = np.flatnonzero(~chain_mask)
    chain_edges = np.flatnonzero(chain_mask)
    consistent = np.zeros(g.num_edges, bool)
    if len(closures) < 2 or len(chain_edges) == 0:
        return consistent, consistent.copy(), 0
    # one odometry step per consecutive pair (the first edge found), chained from pose 0,
    # with its covariance in the step's own (right) frame
    steps = np.zeros((n - 1, 3))
    step_cov = np.zeros((n - 1, 3, 3))
    linked = np.zeros(n - 1, bool)
    lower, first_edge = np.unique(g.edges[chain_edges].min(axis=1), return_index=True)
    used = chain_edges[first_edge]
    steps[lower], step_cov[lower] = _oriented(g.measured[used], cov[used],
                                              g.edges[used, 1] < g.edges[used, 0])
    linked[lower] = True
    segment = np.concatenate([[0], np.cumsum(~linked)])
    chain = _chain(steps)
    chain_adjoint = _adjoint(chain)
    chain_adjoint_inverse = np.linalg.inv(chain_adjoint)
    # prefix[m]: the covariance of steps 0..m-1 moved into the origin frame, summed
    prefix = np.zeros((n, 3, 3))
    prefix[1:] = np.cumsum(_sandwich(chain_adjoint[1:], step_cov), axis=0)

    def between(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(a, b) for index arrays, and its covariance in its right frame."""
        lower, upper = np.minimum(a, b), np.maximum(a, b)
        forward = _compose(_inverse(chain[lower]), chain[upper])
        covariance = _sandwich(chain_adjoint_inverse[upper], prefix[upper] - prefix[lower])
        return _oriented(forward, covariance, a > b)

    i, j = g.edges[closures, 0].copy(), g.edges[closures, 1].copy()
    flip = i > j
    measured, closure_cov = _oriented(g.measured[closures], cov[closures], flip)
    i[flip], j[flip] = j[flip], i[flip].copy()
    order = np.argsort(i, kind="stable")
    first = np.searchsorted(i[order], i - _WINDOW)
    last = np.searchsorted(i[order], i + _WINDOW + 1)
    a_list, b_list = [], []
    for a, (lo, hi) in enumerate(zip(first.tolist(), last.tolist(), strict=True)):
        near = order[lo:hi]
        near = near[(np.abs(j[near] - j[a]) <= _WINDOW) & (near != a)]
        a_list.append(np.full(len(near), a))
        b_list.append(near)
    a_idx, b_idx = np.concatenate(a_list), np.concatenate(b_list)
    same = (segment[i[a_idx]] == segment[i[b_idx]]) & (segment[j[a_idx]] == segment[j[b_idx]])
    a_idx, b_idx = a_idx[same], b_idx[same]
    if len(a_idx) == 0:
        return consistent, consistent.copy(), 0

    # the cycle A B C D = Z_e^-1 D(i, k) Z_f D(l, j); a factor's error reaches the cycle's
    # end frame through the adjoint of the inverse of the factors after it
    factors = [_oriented(measured[a_idx], closure_cov[a_idx], np.ones(len(a_idx), bool)),
               between(i[a_idx], i[b_idx]), (measured[b_idx], closure_cov[b_idx]),
               between(j[b_idx], j[a_idx])]
    after = factors[-1][0]
    total = factors[-1][1].copy()
    for pose, covariance in factors[-2::-1]:
        total += _sandwich(_adjoint(_inverse(after)), covariance)
        after = _compose(pose, after)
    error = np.column_stack([logmap_translation(after[:, :2], after[:, 2]), after[:, 2]])
    score = np.einsum("ea,ea->e", error, np.linalg.solve(total, error[..., None])[..., 0])
    bar = min(threshold, _DATA_SCALE * float(np.median(score)))
    # the chance that a wrong closure agrees anyway: the agreement ellipsoid's volume over
    # that of the wrong closures' distribution (a square of the chain's extent, 2 pi)
    side = max(float(np.ptp(chain[:, 0])), float(np.ptp(chain[:, 1])), 1e-9)
    volume = 4.0 / 3.0 * np.pi * bar ** 1.5 * np.sqrt(np.maximum(np.linalg.det(total), 0.0))
    chance = volume / (4.0 * side ** 2 * 2.0 * np.pi)
    agree = score < bar
    informative = agree & (chance < _CHANCE)
    loose = consistent.copy()
    consistent[closures] = np.bincount(a_idx[informative], minlength=len(closures)) >= \
        _MIN_SUPPORT
    loose[closures] = np.bincount(a_idx[agree], minlength=len(closures)) >= _LOOSE_SUPPORT
    return consistent, loose, int(len(a_idx))


def _adjoint(poses: np.ndarray) -> np.ndarray:
    """(k, 3, 3) GTSAM's Pose2 adjoint maps of (k, 3) poses (tangent order x, y, theta)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    adjoint = np.zeros((len(poses), 3, 3))
    adjoint[:, 0, 0], adjoint[:, 0, 1], adjoint[:, 0, 2] = c, -s, poses[:, 1]
    adjoint[:, 1, 0], adjoint[:, 1, 1], adjoint[:, 1, 2] = s, c, -poses[:, 0]
    adjoint[:, 2, 2] = 1.0
    return adjoint


def _sandwich(a: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Row-wise a C a^T."""
    return a @ covariance @ np.transpose(a, (0, 2, 1))


def _oriented(poses: np.ndarray, covariance: np.ndarray,
              reverse: np.ndarray | bool) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) relative poses and their right-frame covariances, inverted where ``reverse``:
    ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``."""
    reverse = np.broadcast_to(np.asarray(reverse, bool), (len(poses),))
    poses, covariance = poses.copy(), covariance.copy()
    covariance[reverse] = _sandwich(_adjoint(poses[reverse]), covariance[reverse])
    poses[reverse] = _inverse(poses[reverse])
    return poses, covariance


def _chain(steps: np.ndarray) -> np.ndarray:
    """(n, 3) poses of a chain of relative steps (n - 1, 3), starting at the origin."""
    theta = np.concatenate([[0.0], np.cumsum(steps[:, 2])])
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    moves = np.column_stack([c * steps[:, 0] - s * steps[:, 1], s * steps[:, 0] + c * steps[:, 1]])
    return np.column_stack([np.vstack([[0.0, 0.0], np.cumsum(moves, axis=0)]), wrap(theta)])


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a * b of (k, 3) poses."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([a[:, 0] + c * b[:, 0] - s * b[:, 1],
                            a[:, 1] + s * b[:, 0] + c * b[:, 1], wrap(a[:, 2] + b[:, 2])])


def _inverse(a: np.ndarray) -> np.ndarray:
    """Row-wise inverse of (k, 3) poses."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack([-c * a[:, 0] - s * a[:, 1], s * a[:, 0] - c * a[:, 1], -a[:, 2]])


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


# ---------------------------------------------------------------------------------------------
# GNC with truncated least squares on the translation step


def _robust_positions(g: PoseGraph2D, theta: np.ndarray, known: np.ndarray,
                      excluded: np.ndarray, threshold: float,
                      iterations: int) -> tuple[np.ndarray, np.ndarray, int]:
    """GNC-TLS on the translation step with ``theta`` fixed: positions, weights, solves.

    The residuals are those of :func:`~rlpgo_gtsam.translations.whitened_system`
    (whitened, 2 dof); known edges keep weight 1, excluded edges 0.
    """
    i, j = g.edges[:, 0], g.edges[:, 1]
    a_j, b, _ = whitened_system(g, theta)
    held, held_poses = g.held

    def solve(w: np.ndarray) -> np.ndarray:
        return _solve_weighted(g.num_poses, g.edges, -a_j, a_j, b, w, held, held_poses[:, :2])

    def residuals(t: np.ndarray) -> np.ndarray:
        r = np.einsum("eab,eb->ea", a_j, t[j] - t[i]) - b
        return np.einsum("ea,ea->e", r, r)

    return _gnc_tls(solve, residuals, known, excluded, threshold, iterations)


def _gnc_tls(solve, residuals, known: np.ndarray, excluded: np.ndarray, threshold: float,
             iterations: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Graduated non-convexity, TLS loss (Yang et al. 2020), GTSAM's super-linear schedule.

    ``solve(weights) -> x`` minimizes the weighted squares; ``residuals(x) -> (m,)`` squared
    whitened residuals, compared with ``threshold``. Known edges keep weight 1, excluded
    ones 0. Returns x, the weights it was solved with and the number of solves.
    """
    weights = np.where(excluded, 0.0, 1.0)
    x = solve(weights)
    unknown = ~known & ~excluded
    r2 = residuals(x)
    worst = float(r2[unknown].max(initial=0.0))
    if 2.0 * worst <= threshold:
        return x, weights, 1
    mu = max(threshold / (2.0 * worst - threshold), _MU_MIN)
    count = 1
    while count <= iterations:
        count += 1
        weights = _tls_weights(r2, threshold, mu)
        weights[known] = 1.0
        weights[excluded] = 0.0
        x = solve(weights)
        if np.all(np.minimum(weights, 1.0 - weights) <= _WEIGHTS_TOL):
            break
        r2 = residuals(x)
        mu = math.sqrt(mu) * _MU_STEP if mu < 1.0 else mu * _MU_STEP
    return x, weights, count


def _tls_weights(r2: np.ndarray, threshold: float, mu: float) -> np.ndarray:
    """The GNC-TLS weights (Yang et al. 2020, eq. 14) of squared residuals ``r2``."""
    with np.errstate(divide="ignore"):
        weights = np.sqrt(threshold * mu * (mu + 1.0) / r2) - mu
    weights[r2 <= mu / (mu + 1.0) * threshold] = 1.0
    weights[r2 >= (mu + 1.0) / mu * threshold] = 0.0
    return np.clip(weights, 0.0, 1.0)


def _solve_weighted(num_poses: int, edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                    b: np.ndarray, weights: np.ndarray, held: np.ndarray,
                    held_values: np.ndarray) -> np.ndarray:
    """Minimize sum_e w_e ||A_i x_i + A_j x_j - b_e||^2 with some x held; returns (n, 2).

    :func:`~rlpgo_gtsam.linear.solve_pairwise` with per-edge weights, through one sparse
    factorization of the normal equations (scipy): GNC solves the same pattern many times,
    and building GTSAM factors edge by edge would dominate.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    # edges of weight 0 are left out: even at a tiny weight a wrong closure joins two
    # random poses, and such joins ruin the factorization's fill (City10K: 0.1 s -> 20 s)
    used = weights > _WEIGHT_FLOOR
    w = weights[used][:, None, None]
    edges, a_i, a_j, b = edges[used], a_i[used], a_j[used], b[used]
    i, j = edges[:, 0], edges[:, 1]
    a_i_t = np.transpose(a_i, (0, 2, 1))
    a_j_t = np.transpose(a_j, (0, 2, 1))
    blocks = [(i, i, w * a_i_t @ a_i), (j, j, w * a_j_t @ a_j), (i, j, w * a_i_t @ a_j),
              (j, i, w * a_j_t @ a_i)]
    rows = np.concatenate([(2 * p[:, None] + [0, 0, 1, 1]).ravel() for p, _, _ in blocks])
    cols = np.concatenate([(2 * q[:, None] + [0, 1, 0, 1]).ravel() for _, q, _ in blocks])
    data = np.concatenate([block.reshape(-1) for _, _, block in blocks])
    size = 2 * num_poses
    normal = sp.csr_matrix((data, (rows, cols)), shape=(size, size))
    gradient = np.zeros(size)
    np.add.at(gradient, 2 * i[:, None] + [0, 1], w[..., 0] * np.einsum("eba,eb->ea", a_i, b))
    np.add.at(gradient, 2 * j[:, None] + [0, 1], w[..., 0] * np.einsum("eba,eb->ea", a_j, b))
    x = np.zeros(size)
    held_index = (2 * np.asarray(held)[:, None] + [0, 1]).ravel()
    x[held_index] = np.asarray(held_values, dtype=float).ravel()
    free = np.ones(size, bool)
    free[held_index] = False
    rhs = gradient[free] - normal[free][:, ~free] @ x[~free]
    try:
        # symmetric mode without pivoting: the normal matrix is positive definite
        factor = splu(normal[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A",
                      diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        x[free] = factor.solve(rhs)
    except RuntimeError as error:
        raise SolverError(f"weighted linear solve failed ({one_line(error)}): the edges kept "
                          "leave part of the graph unconstrained") from None
    if not np.all(np.isfinite(x)):
        raise SolverError("weighted linear solve gave non-finite values")
    return x.reshape(num_poses, 2)


# ---------------------------------------------------------------------------------------------
# helpers


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

