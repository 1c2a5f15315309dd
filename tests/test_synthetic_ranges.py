"""Generated range-aided graphs (planar): the lawn mower ranging to beacons and between
poses, its ground truth, its noise, its seed, its sizes and its initial guess."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.landmarks import landmark_key
from rlpgo_gtsam.synthetic import (
    MIN_BEACON_RANGES,
    RangeSettings,
    SyntheticGraph,
    generate,
    generate_ranges,
)

# n, sigma_r (rad), sigma_t (m), d (m), lc
ARGS = (60, 0.05, 0.05, 3.0, 0.5)
SETTINGS = RangeSettings(6, pose_ranges=20, sigma_range_m=0.05, sensor_range_m=8.0)


def _sample(seed: int = 0, noisy: bool = False, settings: RangeSettings = SETTINGS,
            lc: float = ARGS[-1]) -> SyntheticGraph:
    return generate_ranges(*ARGS[:-1], lc, np.random.default_rng(seed), settings,
                           noisy_measurements=noisy)


def _factors(graph: gtsam.NonlinearFactorGraph, kind: type) -> list:
    return [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), kind)]


def _position(values: gtsam.Values, key: int) -> np.ndarray:
    if key >= landmark_key(0):  # a beacon; poses are 0 ... n - 1
        return values.atPoint2(key)
    return np.asarray(values.atPose2(key).translation(), float)


def _range_factors(graph: gtsam.NonlinearFactorGraph) -> list:
    return _factors(graph, gtsam.RangeFactor2D) + _factors(graph, gtsam.RangeFactorPose2)


def test_exact_measurements_have_the_truth_as_their_optimum():
    sample = _sample()
    assert chi2(sample.graph, sample.ground_truth) < 1e-18
    assert chi2(sample.graph, sample.initial) > 1e3  # only the guess is noisy
    for factor in _range_factors(sample.graph):
        np.testing.assert_allclose(factor.noiseModel().sigmas(), [0.05])


def test_noisy_measurements_give_the_truth_the_chi2_of_the_noise():
    sample = _sample(seed=1, noisy=True)
    # each factor's error at the truth is its whitened noise draw: chi2 ~ chi2(dofs)
    dofs = sum(sample.graph.at(i).dim() for i in range(sample.graph.size()))
    assert abs(chi2(sample.graph, sample.ground_truth) - dofs) < 5 * np.sqrt(2 * dofs)
    # the ranges alone: one degree of freedom each
    ranges = _range_factors(sample.graph)
    range_chi2 = 2 * sum(f.error(sample.ground_truth) for f in ranges)
    assert abs(range_chi2 - len(ranges)) < 5 * np.sqrt(2 * len(ranges))


def test_a_seed_gives_one_graph_and_generate_s_pose_graph():
    def text(sample: SyntheticGraph) -> str:  # GTSAM's serialization: every digit
        return "".join(x.serialize() for x in (sample.graph, sample.initial, sample.ground_truth))

    a, b, c = _sample(4, True), _sample(4, True), _sample(5, True)
    assert text(a) == text(b) != text(c)
    # the ranges come after the pose graph's draws: the same seed's pose graph
    poses = generate(*ARGS, np.random.default_rng(4), noisy_measurements=True)
    assert all(a.graph.at(i).serialize() == poses.graph.at(i).serialize()
               for i in range(poses.graph.size()))
    assert a.graph.size() == poses.graph.size() + len(_range_factors(a.graph))


@pytest.mark.parametrize("noisy", [False, True])
def test_sizes_are_as_asked_and_every_range_is_positive_and_within_reach(noisy):
    sample = _sample(seed=2, noisy=noisy)
    n, beacons = ARGS[0], SETTINGS.beacons
    assert sample.num_landmarks == beacons
    assert sample.initial.size() == sample.ground_truth.size() == n + beacons
    assert {int(k) for k in sample.ground_truth.keys()} == \
        set(range(n)) | {landmark_key(j) for j in range(beacons)}
    to_beacons = _factors(sample.graph, gtsam.RangeFactor2D)
    between_poses = _factors(sample.graph, gtsam.RangeFactorPose2)
    assert len(between_poses) == SETTINGS.pose_ranges
    assert len({tuple(f.keys()) for f in between_poses}) == SETTINGS.pose_ranges  # no pair twice
    per_beacon = np.bincount([f.keys()[1] - landmark_key(0) for f in to_beacons],
                             minlength=beacons)
    assert per_beacon.min() >= MIN_BEACON_RANGES
    for factor in to_beacons + between_poses:
        a, b = factor.keys()
        distance = np.linalg.norm(_position(sample.ground_truth, b)
                                  - _position(sample.ground_truth, a))
        assert SETTINGS.blind_range_m() <= distance <= SETTINGS.sensor_range_m
        assert factor.measured() > 0
    # the beacons start where the poses that range to them start, on average
    for j in range(beacons):
        ranging = [f.keys()[0] for f in to_beacons if f.keys()[1] == landmark_key(j)]
        np.testing.assert_allclose(sample.initial.atPoint2(landmark_key(j)),
                                   np.mean([_position(sample.initial, k) for k in ranging],
                                           axis=0))


def test_a_stride_ranges_every_kth_pose_and_lc_zero_keeps_odometry_alone():
    # a sensor range beyond the map's diagonal: every 5th pose reaches every beacon
    settings = RangeSettings(3, sigma_range_m=1e-3, sensor_range_m=1e3, pose_stride=5)
    sample = _sample(seed=3, settings=settings, lc=0.0)
    assert len(_factors(sample.graph, gtsam.BetweenFactorPose2)) == ARGS[0] - 1
    ranging = sorted({f.keys()[0] for f in _factors(sample.graph, gtsam.RangeFactor2D)})
    assert ranging == list(range(0, ARGS[0], 5))
    assert len(_factors(sample.graph, gtsam.RangeFactor2D)) == 3 * len(ranging)
    assert not _factors(sample.graph, gtsam.RangeFactorPose2)


@pytest.mark.parametrize("noisy", [False, True])
def test_levenberg_marquardt_from_the_truth_does_not_raise_the_cost(noisy):
    sample = _sample(seed=6, noisy=noisy)
    at_truth = chi2(sample.graph, sample.ground_truth)
    result = gtsam.LevenbergMarquardtOptimizer(sample.graph, sample.ground_truth).optimize()
    assert chi2(sample.graph, result) <= at_truth + 1e-12
    if not noisy:  # the truth is the optimum: nothing moves
        for k in range(ARGS[0]):
            assert result.atPose2(k).equals(sample.ground_truth.atPose2(k), 1e-9)


@pytest.mark.parametrize("settings, message", [
    (RangeSettings(0), "at least 1 beacon or 1 pose-to-pose range"),
    (RangeSettings(-1, pose_ranges=3), "must be >= 0"),
    (RangeSettings(3, sigma_range_m=0.0), "must be positive"),
    (RangeSettings(3, sensor_range_m=float("inf")), "must be finite"),
    (RangeSettings(3, sensor_range_m=1.0, sigma_range_m=0.5), "lower sigma_range"),
    (RangeSettings(3, pose_stride=0), "pose_stride must be >= 1"),
    (RangeSettings(3, margin_m=-1.0), "margin must be >= 0"),
    (RangeSettings(3, sensor_range_m=1.0, margin_m=1e4), "could not place beacon 1 of 3"),
    (RangeSettings(0, pose_ranges=10_000), "could not draw pose-to-pose range"),
])
def test_settings_out_of_range_are_refused_by_name(settings, message):
    with pytest.raises(RlpgoError, match=message):
        _sample(settings=settings)
