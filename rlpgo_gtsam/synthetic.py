"""The RL-PGO paper's synthetic pose graphs (:func:`generate`): a lawn-mower path with
vertical loop closures, in the plane (``group=SE2``) or stacked in layers in 3D (``group=SE3``).

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
without them. :func:`add_outliers` does the same to any graph (a benchmark file), or adds a
``count`` of wrong closures instead (any number the graph has room for: several per true
closure, as at 90% of all closures wrong). Poses are taken in the order of the odometry
chain (:func:`~rlpgo_gtsam.graph.odometry_edges`: sorted keys on a robot's path), so
"pose i + k" is k steps further along it. Vertigo's four
policies (Suenderhauf and Protzel, switchable constraints, ``generateDataset.py``):

- ``"random"``: a random pose pair;
- ``"local"``: the second pose within ``LOCAL_RANGE`` poses of the first;
- ``"group"``: ``group_size`` consecutive pairs ``(i + k, j + k)``, k < group_size, all with
  one measurement: they agree with each other around every cycle they form;
- ``"localgroup"``: groups whose second pose lies within ``LOCAL_RANGE`` of the first.

Each Vertigo closure measures a small relative pose (translation N(0, 0.3 m) per axis,
rotation N(0, 10 deg): "these two places are the same", what perceptual aliasing gives) with
the information of the graph's first loop closure (the first edge off the chain; the first
edge if there is none). Two more modes:

- ``"uniform"``: a random pose pair with a random relative pose: translation uniform in
  ``[-s, s]^2``, ``s`` the longer side of the map's bounding box, angle uniform in
  ``[-pi, pi)``;
- ``"plausible"``: a random pair of poses at least ``far`` apart (a tenth of the map's
  diagonal, or three times the longest true closure if that is more), measured as a copy of
  a randomly chosen true closure's measurement.

These two get the noise model (information) of a randomly chosen true loop closure (of an
odometry edge if the graph has none). No wrong closure joins two poses adjacent on the chain
or a pair the graph already joins.

3D (``group=SE3``; :func:`add_outliers` reads the group from the graph). The planar path
folded into layers: ``LAYER_ROWS`` rows a layer, layers ``d`` apart, each layer run back
over the one below it, so that the poses fill a 10 x 10 x k lattice, the first layer the
planar path itself. Each pose faces its next motion (x axis along it, z axis up; the pose
that climbs to the next layer looks up). Loop-closure candidates join each pose to every
lattice neighbour earlier on the path but its predecessor: the pose beside it in the
previous row and the one under it in the previous layer (1.7 a pose in a full stack, a grid
like SE-Sync's grid sets). Noise is ``Exp([N(0, sigma_R) x 3, N(0, sigma_t) x 3])`` in
GTSAM's tangent order (rotation first), the information
``diag(1 / sigma_R^2 x 3, 1 / sigma_t^2 x 3)``. The wrong closures are drawn by the same
policies and pairs as in the plane; Vertigo's small relative pose in 3D is a translation
N(0, 0.3 m) per axis and roll, pitch, yaw N(0, 10 deg) each (its ``generateDataset.py``);
``"uniform"`` draws the translation in ``[-s, s]^3`` and the rotation uniformly on SO(3).

Landmarks (:func:`generate_landmarks`, :class:`LandmarkSettings`): the same lawn mower (the
same draws, so a seed gives the pose graph :func:`generate` gives without wrong closures),
then ``count`` points, each placed near a pose drawn uniformly from the path, uniformly in
the shell between the blind zone and the sensor range around it: in the plane with
``group=SE2``, in space with ``group=SE3``. Every pose measures every point between its blind
zone and its sensor range (its nearest ``max_per_pose`` of them when capped) by bearing and
range: GTSAM's ``BearingRangeFactor2D`` / ``BearingRangeFactor3D``, noise model
``diag(sigma_bearing^2 x (d - 1), sigma_range^2)`` in bearing-range coordinates (the bearing's
angle in the plane, the ``Unit3`` tangent plane in 3D, then the range). The blind zone's
radius is the larger of ``MIN_RANGE_FRACTION x sensor_range`` and ``RANGE_SIGMAS x
sigma_range``, so that bearings are well defined and a noisy range is positive. Points are
named ``l0, l1, ...`` in the order the path first sees them (by pose, then nearest first);
a point that no pose sees is dropped. Measurements are exact by default (the ground truth is
the optimum); with ``noisy_measurements=True`` each is perturbed by a draw from its noise
model (``Rot2`` / ``Unit3`` retraction of the bearing, the range plus its noise). The
initial guess puts each point where its first measurement places it from the chained
initial pose. Landmark factors follow every pose-graph factor, by pose, then nearest first.

Ranges (:func:`generate_ranges`, :class:`RangeSettings`; planar): CORA's problem, vehicles
that measure distances (acoustic beacons, UWB). The same lawn mower (the same draws again),
then ``beacons`` fixed points, each uniform in the bounding box of the true path grown by
``margin_m`` on every side, redrawn until at least :data:`MIN_BEACON_RANGES` poses range to
it (one range leaves a beacon anywhere on a circle, two a mirror pair). The poses that
range, every ``pose_stride``-th from pose 0, each measure the distance to every beacon
between the blind zone (``RANGE_SIGMAS x sigma_range``: a range noise of 6 sigmas would be
needed to make a range negative) and ``sensor_range``: GTSAM's ``RangeFactor2D``. Then
``pose_ranges`` distances between pairs of poses (robots meeting, inter-pose UWB):
``RangeFactorPose2``, each pair a pose drawn uniformly, then a partner drawn uniformly among
the other poses between the blind zone and the sensor range from it, no pair twice. Noise model
``Isotropic.Sigma(1, sigma_range)``. Beacons are named ``l0, l1, ...`` in the order they are
placed. Measurements are exact by default; with ``noisy_measurements=True`` each range gets
a Gaussian draw, redrawn in the (1e-9) case that the range comes out non-positive. The
initial guess puts each beacon at the centroid of the chained initial positions of the poses
that range to it: what a robot knows before solving, nothing of the truth. Beacon ranges
follow every pose-graph factor, by pose, then by beacon; the pose-to-pose ranges come last,
by pair.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph, extract_pose_graph, odometry_edges
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.information import MAX_CONDITION, scaled_informations, with_informations
from rlpgo_gtsam.landmarks import landmark_key, relative_point

__all__ = ["SyntheticGraph", "generate", "generate_landmarks", "LandmarkSettings",
           "add_outliers", "scaled_informations", "with_informations", "OUTLIER_MODES",
           "VERTIGO_MODES", "ROW_LENGTH", "LAYER_ROWS", "GROUP_SIZE", "LOCAL_RANGE",
           "MIN_RANGE_FRACTION", "RANGE_SIGMAS", "generate_ranges", "RangeSettings",
           "MIN_BEACON_RANGES", "generate_helix_ranges"]

ROW_LENGTH = 10
LAYER_ROWS = 10  # 3D: rows of a layer
# Vertigo's policies, then the project's own two; the first is the default.
VERTIGO_MODES = ("random", "local", "group", "localgroup")
OUTLIER_MODES = (*VERTIGO_MODES, "uniform", "plausible")
GROUP_SIZE = 5  # closures per group (group, localgroup)
LOCAL_RANGE = 20  # local modes: the second pose within this many poses of the first
_VERTIGO_SIGMA_T_M = 0.3
_VERTIGO_SIGMA_R_RAD = np.deg2rad(10.0)
# Pairs tried per wrong closure before giving up on a graph too small for the request.
_TRIES_PER_OUTLIER = 1000
# The blind zone around a pose, as a fraction of its sensor range: nearer points, whose
# bearing swings with millimetres of motion, are not measured.
MIN_RANGE_FRACTION = 0.05
# ... and in range noise sigmas: a Gaussian range drawn 6 sigmas from the truth (1e-9 a
# measurement) is what it takes for a noisy range to come out negative.
RANGE_SIGMAS = 6.0
# Poses that must range to a beacon: fewer leave it on a circle (one) or a mirror pair (two).
MIN_BEACON_RANGES = 3
# Placements tried per beacon, and draws per pose-to-pose range, before giving up on
# settings that leave too few poses in range.
_TRIES_PER_RANGE = 1000


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
    num_landmarks: int = 0
    """Points in the graph, keyed ``landmark_key(0) ... landmark_key(num_landmarks - 1)``
    (``l0, l1, ...``); 0 for a pose graph."""


@dataclass(frozen=True)
class LandmarkSettings:
    """How :func:`generate_landmarks` places and measures points (see the module docstring)."""

    count: int
    """Points placed (>= 1); those no pose sees are dropped, so the graph may hold fewer."""
    sensor_range_m: float = 10.0
    """The farthest a pose measures a point, metres (> 0)."""
    sigma_bearing_rad: float = 0.05
    """Bearing noise, radians (> 0): the angle in the plane, each tangent axis of the
    ``Unit3`` bearing in 3D."""
    sigma_range_m: float = 0.1
    """Range noise, metres (> 0); at most ``sensor_range_m / RANGE_SIGMAS``, so that the
    blind zone leaves a shell to measure in."""
    max_per_pose: int | None = None
    """Measure only the nearest this many points from each pose (>= 1); None: every point
    in range."""

    def blind_range_m(self) -> float:
        """The blind zone's radius: points nearer than this to a pose are not measured."""
        return max(MIN_RANGE_FRACTION * self.sensor_range_m, RANGE_SIGMAS * self.sigma_range_m)


@dataclass(frozen=True)
class RangeSettings:
    """How :func:`generate_ranges` places beacons and measures ranges (see the module
    docstring)."""

    beacons: int
    """Fixed points placed (>= 0), keyed ``landmark_key(0) ...``; each gets at least
    :data:`MIN_BEACON_RANGES` ranges, so the graph holds them all."""
    pose_ranges: int = 0
    """Distances measured between pairs of poses (>= 0)."""
    # the landmarks' range sensor: rlpgo-generate's --sigma-range and --sensor-range serve both
    sigma_range_m: float = LandmarkSettings.sigma_range_m
    """Range noise, metres (> 0); at most ``sensor_range_m / RANGE_SIGMAS``, so that the
    blind zone leaves a ring to measure in."""
    sensor_range_m: float = LandmarkSettings.sensor_range_m
    """The farthest a range reaches, metres (> 0); beyond the map's diagonal, every pose
    that ranges reaches every beacon."""
    pose_stride: int = 1
    """Only every this-many-th pose (poses 0, k, 2k, ...) ranges to the beacons (>= 1)."""
    margin_m: float = 5.0
    """Beacons lie in the true path's bounding box grown by this much on every side, metres
    (>= 0)."""

    def blind_range_m(self) -> float:
        """The blind zone's radius: nearer than this, a pair is not measured."""
        return RANGE_SIGMAS * self.sigma_range_m


def _planar_poses(n: int, d: float) -> list[gtsam.Pose2]:
    poses = []
    for k in range(n):
        row, col = divmod(k, ROW_LENGTH)
        x = col if row % 2 == 0 else ROW_LENGTH - 1 - col
        heading = 0.0 if row % 2 == 0 else np.pi
        if col == ROW_LENGTH - 1:  # the turning pose at the end of a row
            heading = np.pi / 2
        poses.append(gtsam.Pose2(x * d, row * d, heading))
    return poses


def _planar_candidates(n: int) -> list[tuple[int, int]]:
    pairs = []
    for k in range(ROW_LENGTH, n):
        col = k % ROW_LENGTH
        if col != ROW_LENGTH - 1:
            pairs.append((k, k - (2 * col + 1)))
    if n >= 2:
        pairs.append((n - 1, n - 2))
    return pairs


def _lattice_path(n: int) -> np.ndarray:
    """(n, 3) integer lattice cells of the 3D path: the planar rows in each layer, every
    other layer run backwards, so that each cell is a neighbour of the one before."""
    layer, rest = np.divmod(np.arange(n), ROW_LENGTH * LAYER_ROWS)
    row, col = np.divmod(rest, ROW_LENGTH)
    x = np.where((layer * LAYER_ROWS + row) % 2 == 0, col, ROW_LENGTH - 1 - col)
    y = np.where(layer % 2 == 0, row, LAYER_ROWS - 1 - row)
    return np.stack([x, y, layer], axis=1)


def _layered_poses(n: int, d: float) -> list[gtsam.Pose3]:
    cells = _lattice_path(n)
    moves = np.diff(cells, axis=0).astype(float)
    x_axis = np.vstack([moves, moves[-1:]])  # the last pose keeps the last motion's direction
    # z up; for a climb (x up) the z axis is x cross the world's y
    z_axis = np.where(x_axis[:, 2:] == 0, [0.0, 0.0, 1.0], np.cross(x_axis, [0.0, 1.0, 0.0]))
    rotations = np.stack([x_axis, np.cross(z_axis, x_axis), z_axis], axis=2)
    positions = d * cells.astype(float)
    return [gtsam.Pose3(gtsam.Rot3(r), t) for r, t in zip(rotations, positions, strict=True)]


def _layered_candidates(n: int) -> list[tuple[int, int]]:
    """(k, m): pose k and each lattice neighbour m earlier on the path than its
    predecessor, by k, then m."""
    cells = _lattice_path(n)
    index = np.full(cells.max(axis=0) + 1, -1, np.int64)
    index[tuple(cells.T)] = np.arange(n)
    pairs = []
    for axis in range(3):
        below = cells.copy()
        below[:, axis] -= 1
        inside = below[:, axis] >= 0
        k = np.flatnonzero(inside)
        m = index[tuple(below[inside].T)]
        for a, b in ((k, m), (m, k)):  # the neighbour on either side of k along the axis
            keep = (b >= 0) & (b < a - 1)
            pairs.append(np.stack([a[keep], b[keep]], axis=1))
    joined = np.concatenate(pairs)
    joined = joined[np.lexsort((joined[:, 1], joined[:, 0]))]
    return [(int(a), int(b)) for a, b in joined]


# Each group's path: its true poses and its loop-closure candidates.
_PATHS: dict[Group, tuple[Callable[[int, float], list], Callable[[int], list[tuple[int, int]]]]] = {
    SE2: (_planar_poses, _planar_candidates), SE3: (_layered_poses, _layered_candidates)}


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
    group: Group = SE2,
) -> SyntheticGraph:
    """Generate one lawn-mower pose graph: planar, or in layers in 3D (see the module
    docstring).

    Args:
        n: number of poses (>= 2).
        sigma_r: rotation noise, radians (> 0), per rotation axis.
        sigma_t: translation noise per axis, metres (> 0).
        d: spacing between neighbouring poses, rows and layers, metres (> 0).
        lc: fraction of the loop-closure candidates to keep, in [0, 1].
        rng: the only source of randomness.
        noisy_measurements: perturb the measurements too (the ground truth is then not the
            optimum); by default measurements are exact and only the initial guess is noisy.
        outliers: wrong loop closures to add, as a fraction of the outlier-free graph's
            edges (``int(outliers x edges)`` of them), in [0, 1); drawn last.
        outlier_mode: how they are drawn, one of :data:`OUTLIER_MODES`.
        group_size: closures per group in the group modes (>= 1).
        group: :data:`~rlpgo_gtsam.groups.SE2` (``Pose2`` values, ``BetweenFactorPose2``
            factors) or :data:`~rlpgo_gtsam.groups.SE3` (``Pose3``, ``BetweenFactorPose3``).
    """
    _check_settings(n, sigma_r, sigma_t, d, lc, outliers, outlier_mode, group_size)
    sample = _pose_graph(n, sigma_r, sigma_t, d, lc, rng, noisy_measurements, group)
    if outliers > 0:
        sample.graph, sample.outlier_edges = add_outliers(
            sample.graph, sample.ground_truth, outliers, rng, outlier_mode, group_size)
    return sample


def _pose_graph(n: int, sigma_r: float, sigma_t: float, d: float, lc: float,
                rng: np.random.Generator, noisy_measurements: bool,
                group: Group) -> SyntheticGraph:
    """The lawn mower without wrong closures: the path, its odometry and loop closures, the
    chained initial guess and the ground truth (settings already checked)."""
    true_poses, candidates = _PATHS[group]
    truth = true_poses(n, d)
    sigmas = np.full(group.dof, float(sigma_t))  # in the tangent order of the poses' Expmap
    sigmas[list(group.rotation_axes)] = sigma_r
    expmap = type(truth[0]).Expmap
    noise = gtsam.noiseModel.Diagonal.Sigmas(sigmas)

    def perturb(pose):
        return pose.compose(expmap(rng.normal(0.0, sigmas)))

    odometry = [truth[k].between(truth[k + 1]) for k in range(n - 1)]
    pairs = candidates(n)
    count = int(lc * len(pairs))
    chosen = sorted(rng.choice(len(pairs), size=count, replace=False)) if count else []
    closures = [pairs[c] for c in chosen]

    def measure(between):
        return perturb(between) if noisy_measurements else between

    graph = gtsam.NonlinearFactorGraph()
    measured_odometry = []
    for k, between in enumerate(odometry):
        measured = measure(between)
        measured_odometry.append(measured)
        graph.add(group.between_factor(k, k + 1, measured, noise))
    for i, j in closures:
        graph.add(group.between_factor(i, j, measure(truth[i].between(truth[j])), noise))

    initial, ground_truth = gtsam.Values(), gtsam.Values()
    pose = truth[0]
    initial.insert(0, pose)
    for k, measured in enumerate(measured_odometry):
        step = measured if noisy_measurements else perturb(measured)
        pose = pose.compose(step)
        initial.insert(k + 1, pose)
    for k, true_pose in enumerate(truth):
        ground_truth.insert(k, true_pose)
    return SyntheticGraph(graph, initial, ground_truth)


def generate_landmarks(
    n: int,
    sigma_r: float,
    sigma_t: float,
    d: float,
    lc: float,
    rng: np.random.Generator,
    landmarks: LandmarkSettings,
    noisy_measurements: bool = False,
    group: Group = SE2,
) -> SyntheticGraph:
    """Generate a lawn mower (:func:`generate`'s, without wrong closures) that also measures
    points by bearing and range (see the module docstring).

    Args:
        n, sigma_r, sigma_t, d, lc, rng, group: as for :func:`generate`; the poses are
            integer keys ``0 ... n - 1``.
        landmarks: how the points are placed and measured.
        noisy_measurements: perturb every measurement, odometry, loop closures and
            landmarks, by a draw from its noise model (the ground truth is then not the
            optimum); by default measurements are exact and only the initial guess is noisy.

    Returns:
        The graph (between factors, then bearing-range factors), the initial guess (chained
        odometry; each point from its first measurement) and the ground truth, poses and
        points; ``num_landmarks`` says how many points were seen.

    Raises:
        RlpgoError: settings out of range.
    """
    _check_settings(n, sigma_r, sigma_t, d, lc, 0.0, OUTLIER_MODES[0], GROUP_SIZE)
    _check_landmarks(landmarks)
    sample = _pose_graph(n, sigma_r, sigma_t, d, lc, rng, noisy_measurements, group)
    truth = [group.pose_at(sample.ground_truth, k) for k in range(n)]
    positions = np.array([np.asarray(pose.translation(), float) for pose in truth])
    inner, outer = landmarks.blind_range_m(), landmarks.sensor_range_m
    points = _scatter(positions, landmarks.count, inner, outer, rng)
    sightings = _sightings(positions, points, inner, outer, landmarks.max_per_pose)

    sigmas = np.array([landmarks.sigma_bearing_rad] * (group.d - 1) + [landmarks.sigma_range_m])
    noise = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    errors = rng.normal(0.0, sigmas, size=(len(sightings), len(sigmas))) \
        if noisy_measurements else np.zeros((len(sightings), len(sigmas)))
    factor_type = _BEARING_RANGE_FACTORS[group]
    names: dict[int, int] = {}  # placed point -> its index in the graph, by first sighting
    for (k, j), error in zip(sightings, errors, strict=True):
        bearing = truth[k].bearing(points[j])
        if noisy_measurements:
            bearing = bearing.retract(error[:-1])
        measured_range = truth[k].range(points[j]) + float(error[-1])
        key = landmark_key(names.setdefault(j, len(names)))
        factor = factor_type(k, key, bearing, measured_range, noise)
        sample.graph.add(factor)
        if not sample.initial.exists(key):
            seen_from = group.pose_at(sample.initial, k)
            sample.initial.insert(key, seen_from.transformFrom(relative_point(factor)[0]))
            sample.ground_truth.insert(key, points[j])
    sample.num_landmarks = len(names)
    return sample


# Each group's point measurement.
_BEARING_RANGE_FACTORS: dict[Group, type] = {
    SE2: gtsam.BearingRangeFactor2D, SE3: gtsam.BearingRangeFactor3D}


def _scatter(centres: np.ndarray, count: int, inner: float, outer: float,
             rng: np.random.Generator) -> np.ndarray:
    """(count, dim) points, each uniform in the shell ``inner <= r <= outer`` around a
    centre drawn uniformly from ``centres`` (n, dim)."""
    dim = centres.shape[1]
    anchors = rng.integers(len(centres), size=count)
    directions = rng.normal(size=(count, dim))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # uniform in volume: the radius's dim-th power is uniform between the shell's
    radii = (inner ** dim + rng.uniform(size=count) * (outer ** dim - inner ** dim)) ** (1 / dim)
    return centres[anchors] + radii[:, None] * directions


def _sightings(positions: np.ndarray, points: np.ndarray, inner: float, outer: float,
               max_per_pose: int | None) -> list[tuple[int, int]]:
    """(pose, point) pairs within ``[inner, outer]`` of each other: by pose, then nearest
    first (then by point), at most ``max_per_pose`` a pose."""
    from scipy.spatial import cKDTree

    near = cKDTree(points).query_ball_point(positions, outer, return_sorted=True)
    pairs: list[tuple[int, int]] = []
    for k, candidates in enumerate(near):
        seen = np.asarray(candidates, np.int64)
        distances = np.linalg.norm(points[seen] - positions[k], axis=1)
        in_range = (distances >= inner) & (distances <= outer)
        seen, distances = seen[in_range], distances[in_range]
        seen = seen[np.lexsort((seen, distances))][:max_per_pose]
        pairs.extend((k, int(j)) for j in seen)
    return pairs


def _check_landmarks(landmarks: LandmarkSettings) -> None:
    if landmarks.count < 1:
        raise RlpgoError(f"a landmark graph needs at least 1 landmark, got {landmarks.count}")
    if min(landmarks.sensor_range_m, landmarks.sigma_bearing_rad, landmarks.sigma_range_m) <= 0:
        raise RlpgoError("the sensor range, sigma_bearing and sigma_range must be positive")
    if landmarks.blind_range_m() >= landmarks.sensor_range_m:
        raise RlpgoError(f"sigma_range = {landmarks.sigma_range_m:g} m leaves nothing to "
                         f"measure within the sensor range of {landmarks.sensor_range_m:g} m: "
                         f"nearer than {RANGE_SIGMAS:g} sigma_range a range may come out "
                         "negative; lower sigma_range or raise the sensor range")
    if landmarks.max_per_pose is not None and landmarks.max_per_pose < 1:
        raise RlpgoError(f"max_per_pose must be >= 1 (or None), got {landmarks.max_per_pose}")


def generate_ranges(
    n: int,
    sigma_r: float,
    sigma_t: float,
    d: float,
    lc: float,
    rng: np.random.Generator,
    ranges: RangeSettings,
    noisy_measurements: bool = False,
) -> SyntheticGraph:
    """Generate a planar lawn mower (:func:`generate`'s, without wrong closures) that also
    measures ranges to beacons and between poses (see the module docstring).

    Args:
        n, sigma_r, sigma_t, d, lc, rng: as for :func:`generate` (``lc = 0``: odometry
            alone); the poses are integer keys ``0 ... n - 1``, ``Pose2`` values.
        ranges: how the beacons are placed and the ranges measured.
        noisy_measurements: perturb every measurement, odometry, loop closures and ranges,
            by a draw from its noise model (the ground truth is then not the optimum); by
            default measurements are exact and only the initial guess is noisy.

    Returns:
        The graph (between factors, then ``RangeFactor2D`` pose-beacon ranges, then
        ``RangeFactorPose2`` pose-pose ranges), the initial guess (chained odometry; each
        beacon at the centroid of the initial positions of the poses that range to it) and
        the ground truth, poses and beacons (``Point2``); ``num_landmarks`` is the number
        of beacons.

    Raises:
        RlpgoError: settings out of range, or settings that leave a beacon or a pose-to-pose
            range without enough poses in range.
    """
    _check_settings(n, sigma_r, sigma_t, d, lc, 0.0, OUTLIER_MODES[0], GROUP_SIZE)
    _check_ranges(ranges)
    sample = _pose_graph(n, sigma_r, sigma_t, d, lc, rng, noisy_measurements, SE2)
    positions = np.array([np.asarray(sample.ground_truth.atPose2(k).translation(), float)
                          for k in range(n)])
    inner, outer = ranges.blind_range_m(), ranges.sensor_range_m
    beacons, sightings = _place_beacons(positions, ranges, rng)
    pairs = _pose_pairs(positions, ranges.pose_ranges, inner, outer, rng)

    noise = gtsam.noiseModel.Isotropic.Sigma(1, ranges.sigma_range_m)
    beacon_ranges = _measured_ranges(
        np.linalg.norm(beacons[sightings[:, 1]] - positions[sightings[:, 0]], axis=1),
        ranges.sigma_range_m, noisy_measurements, rng)
    pose_ranges = _measured_ranges(
        np.linalg.norm(positions[pairs[:, 1]] - positions[pairs[:, 0]], axis=1),
        ranges.sigma_range_m, noisy_measurements, rng)
    for (k, j), measured in zip(sightings.tolist(), beacon_ranges.tolist(), strict=True):
        sample.graph.add(gtsam.RangeFactor2D(k, landmark_key(j), measured, noise))
    for (a, b), measured in zip(pairs.tolist(), pose_ranges.tolist(), strict=True):
        sample.graph.add(gtsam.RangeFactorPose2(a, b, measured, noise))

    start = np.array([np.asarray(sample.initial.atPose2(k).translation(), float)
                      for k in range(n)])
    for j, beacon in enumerate(beacons):
        ranging = sightings[sightings[:, 1] == j, 0]
        sample.initial.insert(landmark_key(j), start[ranging].mean(axis=0))
        sample.ground_truth.insert(landmark_key(j), beacon)
    sample.num_landmarks = len(beacons)
    return sample


def _place_beacons(positions: np.ndarray, ranges: RangeSettings,
                   rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(beacons, 2) positions, each uniform in the grown bounding box of ``positions``
    (n, 2) until :data:`MIN_BEACON_RANGES` of the ranging poses reach it, and the (pose,
    beacon) pairs that range, (m, 2), by pose, then beacon."""
    from scipy.spatial import cKDTree

    low = positions.min(axis=0) - ranges.margin_m
    high = positions.max(axis=0) + ranges.margin_m
    if ranges.beacons and np.any(high <= low):
        raise RlpgoError("the path is a line and the margin is 0: beacons on the path's line "
                         "cannot be located across it; give a positive margin")
    ranging = np.arange(0, len(positions), ranges.pose_stride)
    tree = cKDTree(positions[ranging])
    inner, outer = ranges.blind_range_m(), ranges.sensor_range_m
    beacons = np.empty((ranges.beacons, 2))
    pairs: list[tuple[int, int]] = []
    for j in range(ranges.beacons):
        for _ in range(_TRIES_PER_RANGE):
            beacon = rng.uniform(low, high)
            near = np.asarray(tree.query_ball_point(beacon, outer), np.int64)
            near = near[np.linalg.norm(positions[ranging[near]] - beacon, axis=1) >= inner]
            if len(near) >= MIN_BEACON_RANGES:
                break
        else:
            raise RlpgoError(
                f"could not place beacon {j + 1} of {ranges.beacons} where at least "
                f"{MIN_BEACON_RANGES} poses range to it after {_TRIES_PER_RANGE} tries: "
                "raise the sensor range, or lower the margin or the pose stride")
        beacons[j] = beacon
        pairs.extend((int(k), j) for k in ranging[near])
    sightings = np.array(pairs, np.int64).reshape(-1, 2)
    return beacons, sightings[np.lexsort((sightings[:, 1], sightings[:, 0]))]


def _pose_pairs(positions: np.ndarray, count: int, inner: float, outer: float,
                rng: np.random.Generator) -> np.ndarray:
    """(count, 2) pose index pairs (a < b), by pair: a pose drawn uniformly, then a partner
    uniformly among the poses between ``inner`` and ``outer`` of it, no pair twice."""
    from scipy.spatial import cKDTree

    if count == 0:
        return np.empty((0, 2), np.int64)
    tree = cKDTree(positions)
    taken: set[tuple[int, int]] = set()
    for drawn in range(count):
        for _ in range(_TRIES_PER_RANGE):
            a = int(rng.integers(len(positions)))
            near = np.asarray(tree.query_ball_point(positions[a], outer), np.int64)
            near = near[np.linalg.norm(positions[near] - positions[a], axis=1) >= inner]
            free = [int(b) for b in near if (min(a, b), max(a, b)) not in taken]
            if free:
                b = free[int(rng.integers(len(free)))]
                taken.add((min(a, b), max(a, b)))
                break
        else:
            raise RlpgoError(
                f"could not draw pose-to-pose range {drawn + 1} of {count} after "
                f"{_TRIES_PER_RANGE} tries: too few pose pairs within the sensor range")
    return np.array(sorted(taken), np.int64).reshape(-1, 2)


def _measured_ranges(distances: np.ndarray, sigma: float, noisy: bool,
                     rng: np.random.Generator) -> np.ndarray:
    """The true ``distances``, or each plus N(0, sigma), redrawn while it is not positive."""
    if not noisy:
        return distances
    measured = distances + rng.normal(0.0, sigma, size=len(distances))
    while (bad := measured <= 0).any():
        measured[bad] = distances[bad] + rng.normal(0.0, sigma, size=int(bad.sum()))
    return measured


def _check_ranges(ranges: RangeSettings) -> None:
    if ranges.beacons < 0 or ranges.pose_ranges < 0:
        raise RlpgoError(f"beacons and pose_ranges must be >= 0, got {ranges.beacons} and "
                         f"{ranges.pose_ranges}")
    if ranges.beacons == 0 and ranges.pose_ranges == 0:
        raise RlpgoError("a range graph needs at least 1 beacon or 1 pose-to-pose range")
    if min(ranges.sensor_range_m, ranges.sigma_range_m) <= 0:
        raise RlpgoError("the sensor range and sigma_range must be positive")
    if not np.isfinite(ranges.sensor_range_m):
        raise RlpgoError("the sensor range must be finite: beyond the map's diagonal, every "
                         "pose that ranges reaches every beacon")
    if ranges.blind_range_m() >= ranges.sensor_range_m:
        raise RlpgoError(f"sigma_range = {ranges.sigma_range_m:g} m leaves nothing to "
                         f"measure within the sensor range of {ranges.sensor_range_m:g} m: "
                         f"nearer than {RANGE_SIGMAS:g} sigma_range a range may come out "
                         "negative; lower sigma_range or raise the sensor range")
    if ranges.pose_stride < 1:
        raise RlpgoError(f"pose_stride must be >= 1, got {ranges.pose_stride}")
    if not ranges.margin_m >= 0:
        raise RlpgoError(f"the beacons' margin must be >= 0 m, got {ranges.margin_m}")


def add_outliers(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    fraction: float | None,
    rng: np.random.Generator,
    mode: str = OUTLIER_MODES[0],
    group_size: int = GROUP_SIZE,
    *,
    count: int | None = None,
) -> tuple[gtsam.NonlinearFactorGraph, list[int]]:
    """A copy of ``graph`` with ``int(fraction x edges)`` wrong loop closures appended, or
    ``count`` of them.

    Args:
        graph: a planar or 3D pose graph (what
            :func:`~rlpgo_gtsam.graph.extract_pose_graph` accepts); the wrong closures are
            its group's between factors.
        values: the poses that define the map's geometry (its extent, which poses are far
            apart): the ground truth or the best known solution, not a drifting guess.
        fraction: wrong closures per between factor of ``graph``, in [0, 1); None when
            ``count`` is given.
        rng: the only source of randomness.
        mode: one of :data:`OUTLIER_MODES` (see the module docstring).
        group_size: closures per group in the group modes (the last group may be cut short
            to give exactly the number asked for).
        count: the number of wrong closures instead of a fraction (>= 0, any number the
            graph has room for: more wrong closures than edges, as at 90% of all closures
            wrong); ``fraction`` must then be None. The draws are those of the fraction that
            gives the same number, so ``count=int(fraction x edges)`` gives the same graph.

    Returns:
        The new graph (``graph`` itself is not changed) and the factor indices of the wrong
        closures in it, ascending (they follow every factor of ``graph``).

    Raises:
        RlpgoError: a fraction outside [0, 1), a negative count, both or neither given, an
            unknown mode, or a graph with too few pose pairs that qualify.
        GraphError: a graph the package cannot read as a pose graph.
    """
    if (fraction is None) == (count is None):
        raise RlpgoError("add_outliers takes a fraction of the edges or a count of wrong "
                         "closures: one of them, not both")
    if count is not None and (isinstance(count, bool) or int(count) != count or count < 0):
        raise RlpgoError(f"the count of wrong loop closures must be an integer >= 0, got {count}")
    _check_outliers(0.0 if fraction is None else fraction, mode, group_size)
    g = extract_pose_graph(graph, values)
    wanted = int(fraction * g.num_edges) if fraction is not None else int(count or 0)
    group = g.group
    measured = group.measured(g)
    draw = _WRONG_MEASUREMENTS[group]

    def measure(source: int, side: float):
        if mode == "plausible":
            return group.gtsam_pose(measured[source])
        return draw(mode, side, rng)

    return _add_wrong_closures(graph, g, group.translations(g.poses),
                               group.translations(measured), wanted, rng, mode, group_size,
                               group.between_factor, measure)


def _wrong_pose2(mode: str, side: float, rng: np.random.Generator) -> gtsam.Pose2:
    """A planar wrong closure's measurement: Vertigo's small relative pose, or ``"uniform"``'s."""
    if mode in VERTIGO_MODES:
        return gtsam.Pose2(*rng.normal(0.0, [_VERTIGO_SIGMA_T_M, _VERTIGO_SIGMA_T_M,
                                             _VERTIGO_SIGMA_R_RAD]).tolist())
    dx, dy = rng.uniform(-side, side, size=2).tolist()
    return gtsam.Pose2(dx, dy, float(rng.uniform(-np.pi, np.pi)))


def _wrong_pose3(mode: str, side: float, rng: np.random.Generator) -> gtsam.Pose3:
    """A 3D wrong closure's measurement: Vertigo's small relative pose (roll, pitch, yaw),
    or ``"uniform"``'s (the rotation uniform on SO(3))."""
    if mode in VERTIGO_MODES:
        x, y, z, roll, pitch, yaw = rng.normal(0.0, [_VERTIGO_SIGMA_T_M] * 3
                                               + [_VERTIGO_SIGMA_R_RAD] * 3).tolist()
        return gtsam.Pose3(gtsam.Rot3.Ypr(yaw, pitch, roll), np.array([x, y, z]))
    t = rng.uniform(-side, side, size=3)
    q = rng.normal(size=4)  # a uniform rotation: a uniform unit quaternion
    q /= np.linalg.norm(q)
    return gtsam.Pose3(gtsam.Rot3.Quaternion(*q.tolist()), t)


_WRONG_MEASUREMENTS: dict[Group, Callable[[str, float, np.random.Generator], object]] = {
    SE2: _wrong_pose2, SE3: _wrong_pose3}


def _add_wrong_closures(graph: gtsam.NonlinearFactorGraph, g: PoseGraph,
                        positions: np.ndarray, moves: np.ndarray, count: int,
                        rng: np.random.Generator, mode: str, group_size: int, factor: type,
                        measure: Callable[[int, float], object]):
    """The policies of both dimensions: ``count`` wrong closures. ``positions`` (n, dim) are
    the poses' positions, ``moves`` (m, dim) each edge's measured translation;
    ``measure(source, side)`` draws one group's measurement, ``source`` the edge whose
    information it takes (the one ``"plausible"`` copies), ``side`` the map's longest side."""
    result = gtsam.NonlinearFactorGraph(graph)
    if count == 0:
        return result, []
    start = result.size()
    keys = g.keys.astype(np.int64)
    extent = positions.max(axis=0) - positions.min(axis=0)
    side = float(np.max(extent))
    side = side if side > 0 else 1.0
    for pairs, source in _wrong_pairs(g, positions, moves, count, mode, group_size, rng):
        measured = measure(source, side)
        noise = gtsam.noiseModel.Gaussian.Information(g.information[source])
        for i, j in pairs:
            result.add(factor(int(keys[i]), int(keys[j]), measured, noise))
    return result, list(range(start, start + count))


def _wrong_pairs(g: PoseGraph, positions: np.ndarray, moves: np.ndarray,
                 count: int, mode: str, group_size: int,
                 rng: np.random.Generator) -> Iterator[tuple[list[tuple[int, int]], int]]:
    """The one definition of the policies: per group, the pose index pairs of its wrong
    closures and the edge whose information they take (the graph's first loop closure for
    Vertigo's modes, a random true closure for the others). Pairs and that edge are drawn
    from ``rng`` before each yield; the caller draws the group's measurement before the
    next, so the draws interleave as one sequence."""
    chain = odometry_edges(g)
    order = _chain_order(g, chain)  # pose index at each place along the chain
    place = np.empty(g.num_poses, np.int64)
    place[order] = np.arange(g.num_poses)
    joined = {(min(a, b), max(a, b)) for a, b in place[g.edges].tolist()}
    is_closure = ~chain
    templates = np.flatnonzero(is_closure) if is_closure.any() else np.arange(g.num_edges)
    first_closure = int(templates[0])
    far = max(0.1 * float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0))),
              3.0 * float(np.max(np.linalg.norm(moves[templates], axis=1))))
    size = group_size if mode in ("group", "localgroup") else 1
    n = g.num_poses
    if size > (n - 2) // 2:
        raise RlpgoError(f"groups of {size} wrong closures need at least {2 * size + 2} poses "
                         f"(two runs of {size} that do not overlap), the graph has {n}")
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
            if mode == "plausible" and np.linalg.norm(positions[i] - positions[j]) < far:
                continue
            break
        else:
            raise RlpgoError(
                f"could not place wrong closure {drawn + 1} of {count} ({mode}) after "
                f"{_TRIES_PER_OUTLIER} tries: the graph has too few pose pairs that qualify")
        joined.update((min(p, q), max(p, q)) for p, q in pairs)
        source = first_closure if mode in VERTIGO_MODES else \
            int(templates[rng.integers(len(templates))])
        yield [(int(order[p]), int(order[q])) for p, q in pairs], source
        drawn += members


def _chain_order(g: PoseGraph, chain: np.ndarray) -> np.ndarray:
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


def _check_settings(n: int, sigma_r: float, sigma_t: float, d: float, lc: float,
                    outliers: float, outlier_mode: str, group_size: int) -> None:
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


def _check_outliers(fraction: float, mode: str, group_size: int = GROUP_SIZE) -> None:
    if not 0.0 <= fraction < 1.0:
        raise RlpgoError(f"the fraction of wrong loop closures must lie in [0, 1), got {fraction}")
    if mode not in OUTLIER_MODES:
        raise RlpgoError(f"unknown outlier mode '{mode}'; choose from {', '.join(OUTLIER_MODES)}")
    if group_size < 1:
        raise RlpgoError(f"group_size must be >= 1, got {group_size}")


def generate_helix_ranges(n: int, rng: np.random.Generator, *, beacons: int = 3,
                          pose_ranges: int = 8, stride: int = 2, noise: float = 1.0,
                          rotation_sigma: float = 0.02, translation_sigma: float = 0.05,
                          sigma_range_m: float = 0.1) -> SyntheticGraph:
    """A 3D range-aided graph: a climbing helix of ``n`` poses (1 m steps turning 0.15 rad)
    with Pose3 odometry, a prior on the first pose, ranges (``RangeFactor3D``) from every
    ``stride``-th pose to each of ``beacons`` points placed uniformly in a 12 m cube about
    the origin, and ``pose_ranges`` ranges (``RangeFactorPose3``) between random pairs of
    poses; measurements perturbed by ``noise`` times their sigmas (0: exact).

    Returns:
        The graph, the initial guess (chained odometry; each beacon 3 m off its truth) and
        the ground truth; poses keyed ``x0 ...``, beacons ``l0 ...`` (``Point3``).
    """
    if n < 2 or beacons < 0 or pose_ranges < 0 or stride < 1 or noise < 0:
        raise RlpgoError("generate_helix_ranges needs n >= 2, stride >= 1 and beacons, "
                         "pose_ranges and noise >= 0")
    sigmas = np.array([rotation_sigma] * 3 + [translation_sigma] * 3)
    turn = gtsam.Pose3(gtsam.Rot3.Ypr(0.15, 0.02, 0.01), np.array([1.0, 0.0, 0.1]))
    truth = [gtsam.Pose3()]
    for _ in range(1, n):
        truth.append(truth[-1].compose(turn))
    beacons_at = rng.uniform(-6, 6, size=(beacons, 3))
    graph = gtsam.NonlinearFactorGraph()
    pose_key = functools.partial(gtsam.symbol, "x")
    graph.add(gtsam.PriorFactorPose3(pose_key(0), truth[0],
                                     gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    odometry = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    chained = [truth[0]]
    for k in range(n - 1):
        step = truth[k].between(truth[k + 1]).retract(noise * rng.normal(size=6) * sigmas)
        graph.add(gtsam.BetweenFactorPose3(pose_key(k), pose_key(k + 1), step, odometry))
        chained.append(chained[-1].compose(step))
    ranging = gtsam.noiseModel.Isotropic.Sigma(1, sigma_range_m)
    for k in range(0, n, stride):
        for b in range(beacons):
            r = np.linalg.norm(truth[k].translation() - beacons_at[b])
            graph.add(gtsam.RangeFactor3D(pose_key(k), landmark_key(b),
                                          r + noise * sigma_range_m * rng.normal(), ranging))
    for _ in range(pose_ranges):
        a, b = (int(k) for k in rng.choice(n, 2, replace=False))
        r = np.linalg.norm(truth[a].translation() - truth[b].translation())
        graph.add(gtsam.RangeFactorPose3(pose_key(a), pose_key(b),
                                         r + noise * sigma_range_m * rng.normal(), ranging))
    values, ground_truth = gtsam.Values(), gtsam.Values()
    for k in range(n):
        values.insert(pose_key(k), chained[k])
        ground_truth.insert(pose_key(k), truth[k])
    for b in range(beacons):
        values.insert(landmark_key(b), gtsam.Point3(*(beacons_at[b] + 3.0 * rng.normal(size=3))))
        ground_truth.insert(landmark_key(b), gtsam.Point3(*beacons_at[b]))
    return SyntheticGraph(graph, values, ground_truth, num_landmarks=beacons)
