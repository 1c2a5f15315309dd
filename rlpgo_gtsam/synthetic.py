"""The RL-PGO paper's synthetic pose graphs: a lawn-mower path with vertical loop closures.

Poses run in rows of ten, ``d`` metres apart, rows ``d`` apart, alternating direction; the
motion into the last pose of a row and the one into the first pose of the next each end
with a 90-degree turn. Loop-closure candidates join each pose of a row to the pose right
below it in the previous row (the row's last, turning pose excluded), plus one candidate
between the last two poses, as the paper's code enumerates them; ``int(lc * candidates)``
of them are drawn without replacement. With n = 20, lc = 0.5 this gives 24 edges, with
n = 300 it gives 430, the counts of the paper's graphs.

By default every measurement is exact (the ground truth is the optimum, chi2 = 0) and only
the initial guess is noisy: dead reckoning of the motions, each perturbed by
``Exp([N(0, sigma_t), N(0, sigma_t), N(0, sigma_R)])``, as in the paper's tables. With
``noisy_measurements=True`` every measurement is perturbed that way instead and the initial
guess chains the noisy odometry: graphs whose optimum is not the ground truth.

Wrong loop closures (``outliers > 0``): ``int(outliers x edges)`` extra between factors,
``edges`` the number of between factors of the outlier-free graph (odometry included: 5% of
M3500's 5453 edges is 272 wrong closures), appended after every other factor and drawn from
the same ``rng`` after everything else, so a seed gives the same outlier-free part with or
without them. :func:`add_outliers` does the same to any graph (a benchmark file). Poses are
taken in the order of the odometry chain (:func:`~rlpgo_gtsam.graph.odometry_edges`: sorted
keys on a robot's path), so "pose i + k" is k steps further along it. Vertigo's four
policies (Suenderhauf and Protzel, switchable constraints, ``generateDataset.py``):

- ``"random"``: a random pose pair;
- ``"local"``: the second pose within ``LOCAL_RANGE`` poses of the first;
- ``"group"``: ``group_size`` consecutive pairs ``(i + k, j + k)``, k < group_size, all with
  one measurement: they agree with each other around every cycle they form;
- ``"localgroup"``: groups whose second pose lies within ``LOCAL_RANGE`` of the first.

Each Vertigo closure measures a small relative pose (translation N(0, 0.3 m) per axis,
rotation N(0, 10 deg): "these two places are the same", what perceptual aliasing gives) with
the information of the graph's first loop closure (the first edge off the chain; the first
edge if there is none). Two earlier modes remain:

- ``"uniform"``: a random pose pair with a random relative pose: translation uniform in
  ``[-s, s]^2``, ``s`` the longer side of the map's bounding box, angle uniform in
  ``[-pi, pi)``;
- ``"plausible"``: a random pair of poses at least ``far`` apart (a tenth of the map's
  diagonal, or three times the longest true closure if that is more), measured as a copy of
  a randomly chosen true closure's measurement.

These two get the noise model (information) of a randomly chosen true loop closure (of an
odometry edge if the graph has none). No wrong closure joins two poses adjacent on the chain
or a pair the graph already joins.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import MAX_CONDITION, PoseGraph2D, odometry_edges

__all__ = ["SyntheticGraph", "generate", "add_outliers", "OUTLIER_MODES", "VERTIGO_MODES",
           "ROW_LENGTH", "GROUP_SIZE", "LOCAL_RANGE"]

ROW_LENGTH = 10
# Vertigo's policies, then the project's earlier two; the first is the default.
VERTIGO_MODES = ("random", "local", "group", "localgroup")
OUTLIER_MODES = (*VERTIGO_MODES, "uniform", "plausible")
GROUP_SIZE = 5  # closures per group (group, localgroup)
LOCAL_RANGE = 20  # local modes: the second pose within this many poses of the first
_VERTIGO_SIGMA_T_M = 0.3
_VERTIGO_SIGMA_R_RAD = np.deg2rad(10.0)
# Pairs tried per wrong closure before giving up on a graph too small for the request.
_TRIES_PER_OUTLIER = 1000


@dataclass
class SyntheticGraph:
    """A generated graph: factors, the noisy initial guess and the ground truth, all GTSAM.

    Attributes:
        outlier_edges: factor indices (into ``graph``) of the wrong loop closures, in
            ascending order; empty when the graph has none.
    """

    graph: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    ground_truth: gtsam.Values
    outlier_edges: list[int] = field(default_factory=list)


def _true_poses(n: int, d: float) -> list[gtsam.Pose2]:
    poses = []
    for k in range(n):
        row, col = divmod(k, ROW_LENGTH)
        x = col if row % 2 == 0 else ROW_LENGTH - 1 - col
        heading = 0.0 if row % 2 == 0 else np.pi
        if col == ROW_LENGTH - 1:  # the turning pose at the end of a row
            heading = np.pi / 2
        poses.append(gtsam.Pose2(x * d, row * d, heading))
    return poses


def _candidates(n: int) -> list[tuple[int, int]]:
    pairs = []
    for k in range(ROW_LENGTH, n):
        col = k % ROW_LENGTH
        if col != ROW_LENGTH - 1:
            pairs.append((k, k - (2 * col + 1)))
    if n >= 2:
        pairs.append((n - 1, n - 2))
    return pairs


def _perturb(pose: gtsam.Pose2, sigma_r: float, sigma_t: float, rng: np.random.Generator):
    noise = rng.normal(0.0, [sigma_t, sigma_t, sigma_r])
    return pose.compose(gtsam.Pose2.Expmap(noise))


def generate(
    n: int,
    sigma_r: float,
    sigma_t: float,
    d: float,
    lc: float,
    rng: np.random.Generator,
    noisy_measurements: bool = False,
    outliers: float = 0.0,
    outlier_mode: str = OUTLIER_MODES[0],
    group_size: int = GROUP_SIZE,
) -> SyntheticGraph:
    """Generate one lawn-mower pose graph.

    Args:
        n: number of poses (>= 2).
        sigma_r: rotation noise, radians (> 0).
        sigma_t: translation noise per axis, metres (> 0).
        d: spacing between neighbouring poses and between rows, metres (> 0).
        lc: fraction of the loop-closure candidates to keep, in [0, 1].
        rng: the only source of randomness.
        noisy_measurements: perturb the measurements too (the ground truth is then not the
            optimum); by default measurements are exact and only the initial guess is noisy.
        outliers: wrong loop closures to add, as a fraction of the outlier-free graph's
            edges (``int(outliers x edges)`` of them), in [0, 1); drawn last.
        outlier_mode: how they are drawn, one of :data:`OUTLIER_MODES`.
        group_size: closures per group in the group modes (>= 1).
    """
    if n < 2:
        raise RlpgoError(f"a graph needs at least 2 poses, got n={n}")
    if sigma_r <= 0 or sigma_t <= 0 or d <= 0:
        raise RlpgoError("sigma_r, sigma_t and d must be positive")
    if max(sigma_r, sigma_t) ** 2 > MAX_CONDITION * min(sigma_r, sigma_t) ** 2:
        raise RlpgoError(f"sigma_t = {sigma_t:g} m and sigma_r = {sigma_r:g} rad give an "
                         f"information matrix with a condition number above {MAX_CONDITION:g}, "
                         "which no method can use; bring them closer")
    if not 0.0 <= lc <= 1.0:
        raise RlpgoError(f"lc must lie in [0, 1], got {lc}")
    _check_outliers(outliers, outlier_mode, group_size)
    truth = _true_poses(n, d)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_t, sigma_t, sigma_r]))
    odometry = [truth[k].between(truth[k + 1]) for k in range(n - 1)]
    candidates = _candidates(n)
    count = int(lc * len(candidates))
    chosen = sorted(rng.choice(len(candidates), size=count, replace=False)) if count else []
    closures = [candidates[c] for c in chosen]

    def measure(between: gtsam.Pose2) -> gtsam.Pose2:
        return _perturb(between, sigma_r, sigma_t, rng) if noisy_measurements else between

    graph = gtsam.NonlinearFactorGraph()
    measured_odometry = []
    for k, between in enumerate(odometry):
        measured = measure(between)
        measured_odometry.append(measured)
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, measured, noise))
    for i, j in closures:
        graph.add(gtsam.BetweenFactorPose2(i, j, measure(truth[i].between(truth[j])), noise))

    initial, ground_truth = gtsam.Values(), gtsam.Values()
    pose = truth[0]
    initial.insert(0, pose)
    for k, measured in enumerate(measured_odometry):
        step = measured if noisy_measurements else _perturb(measured, sigma_r, sigma_t, rng)
        pose = pose.compose(step)
        initial.insert(k + 1, pose)
    for k, true_pose in enumerate(truth):
        ground_truth.insert(k, true_pose)
    outlier_edges: list[int] = []
    if outliers > 0:
        graph, outlier_edges = add_outliers(graph, ground_truth, outliers, rng, outlier_mode,
                                            group_size)
    return SyntheticGraph(graph, initial, ground_truth, outlier_edges)


def add_outliers(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    fraction: float,
    rng: np.random.Generator,
    mode: str = OUTLIER_MODES[0],
    group_size: int = GROUP_SIZE,
) -> tuple[gtsam.NonlinearFactorGraph, list[int]]:
    """A copy of ``graph`` with ``int(fraction x edges)`` wrong loop closures appended.

    Args:
        graph: a planar pose graph (what :class:`~rlpgo_gtsam.graph.PoseGraph2D` accepts).
        values: the poses that define the map's geometry (its extent, which poses are far
            apart): the ground truth or the best known solution, not a drifting guess.
        fraction: wrong closures per between factor of ``graph``, in [0, 1).
        rng: the only source of randomness.
        mode: one of :data:`OUTLIER_MODES` (see the module docstring).
        group_size: closures per group in the group modes (the last group may be cut short
            to give exactly ``int(fraction x edges)``).

    Returns:
        The new graph (``graph`` itself is not changed) and the factor indices of the wrong
        closures in it, ascending (they follow every factor of ``graph``).

    Raises:
        RlpgoError: a fraction outside [0, 1), an unknown mode, or a graph with too few
            pose pairs that qualify.
        GraphError: a graph the package cannot read as a planar pose graph.
    """
    _check_outliers(fraction, mode, group_size)
    g = PoseGraph2D.from_gtsam(graph, values)
    count = int(fraction * g.num_edges)
    result = gtsam.NonlinearFactorGraph(graph)
    if count == 0:
        return result, []
    chain = odometry_edges(g)
    order = _chain_order(g, chain)  # pose index at each place along the chain
    place = np.empty(g.num_poses, np.int64)
    place[order] = np.arange(g.num_poses)
    keys = g.keys.astype(np.int64)
    joined = {(min(a, b), max(a, b)) for a, b in place[g.edges].tolist()}
    is_closure = ~chain
    templates = np.flatnonzero(is_closure) if is_closure.any() else np.arange(g.num_edges)
    first_closure = int(templates[0])
    positions = g.poses[:, :2]
    side = float(np.max(positions.max(axis=0) - positions.min(axis=0)))
    side = side if side > 0 else 1.0
    far = max(0.1 * np.hypot(*(positions.max(axis=0) - positions.min(axis=0))),
              3.0 * float(np.max(np.hypot(*g.measured[templates, :2].T))))
    grouped = mode in ("group", "localgroup")
    size = group_size if grouped else 1
    n = g.num_poses
    start = result.size()
    drawn = 0
    while drawn < count:
        members = min(size, count - drawn)
        for _ in range(_TRIES_PER_OUTLIER):
            a = int(rng.integers(0, n - members + 1))
            if mode in ("local", "localgroup"):
                b = a + int(rng.integers(-LOCAL_RANGE, LOCAL_RANGE + 1))
            else:
                b = int(rng.integers(0, n - members + 1))
            if abs(a - b) <= 1 or not 0 <= b <= n - members:
                continue
            pairs = [(a + k, b + k) for k in range(members)]
            if any((min(p), max(p)) in joined for p in pairs):
                continue
            i, j = order[a], order[b]
            if mode == "plausible" and np.hypot(*(positions[i] - positions[j])) < far:
                continue
            break
        else:
            raise RlpgoError(
                f"could not place wrong closure {drawn + 1} of {count} ({mode}) after "
                f"{_TRIES_PER_OUTLIER} tries: the graph has too few pose pairs that qualify")
        if mode in VERTIGO_MODES:
            measured = gtsam.Pose2(*rng.normal(0.0, [_VERTIGO_SIGMA_T_M, _VERTIGO_SIGMA_T_M,
                                                     _VERTIGO_SIGMA_R_RAD]).tolist())
            information = g.information[first_closure]
        else:
            template = int(templates[rng.integers(len(templates))])
            if mode == "uniform":
                dx, dy = rng.uniform(-side, side, size=2).tolist()
                measured = gtsam.Pose2(dx, dy, float(rng.uniform(-np.pi, np.pi)))
            else:
                measured = gtsam.Pose2(*g.measured[template])
            information = g.information[template]
        noise = gtsam.noiseModel.Gaussian.Information(information)
        for p, q in pairs:
            joined.add((min(p, q), max(p, q)))
            result.add(gtsam.BetweenFactorPose2(int(keys[order[p]]), int(keys[order[q]]),
                                                measured, noise))
        drawn += members
    return result, list(range(start, start + count))


def _chain_order(g: PoseGraph2D, chain: np.ndarray) -> np.ndarray:
    """Pose indices in the order a walk along the chain meets them: depth first from the
    anchor, the lower index first (sorted keys on a path)."""
    neighbours: list[list[int]] = [[] for _ in range(g.num_poses)]
    for i, j in g.edges[chain].tolist():
        neighbours[i].append(j)
        neighbours[j].append(i)
    seen = np.zeros(g.num_poses, bool)
    order, stack = [], [g.anchor]
    seen[g.anchor] = True
    while stack:
        a = stack.pop()
        order.append(a)
        for b in sorted(neighbours[a], reverse=True):
            if not seen[b]:
                seen[b] = True
                stack.append(b)
    return np.array(order, dtype=np.int64)


def _check_outliers(fraction: float, mode: str, group_size: int = GROUP_SIZE) -> None:
    if not 0.0 <= fraction < 1.0:
        raise RlpgoError(f"the fraction of wrong loop closures must lie in [0, 1), got {fraction}")
    if mode not in OUTLIER_MODES:
        raise RlpgoError(f"unknown outlier mode '{mode}'; choose from {', '.join(OUTLIER_MODES)}")
    if group_size < 1:
        raise RlpgoError(f"group_size must be >= 1, got {group_size}")
