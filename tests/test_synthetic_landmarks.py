"""Generated landmark graphs (planar and 3D): the lawn mower measuring points by bearing and
range, its ground truth, its noise, its seed, its initial guess, and rlpgo-generate
--landmarks."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.generate import main

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.io import read_g2o
from rlpgo_gtsam.landmarks import landmark_key
from rlpgo_gtsam.synthetic import (
    LandmarkSettings,
    SyntheticGraph,
    generate,
    generate_landmarks,
)
from tests.conftest import cli_error, cli_ok

GROUPS = [SE2, SE3]
# n, sigma_r (rad), sigma_t (m), d (m), lc
ARGS = (60, 0.05, 0.05, 3.0, 0.5)
SETTINGS = LandmarkSettings(40, sensor_range_m=6.0, sigma_bearing_rad=0.02, sigma_range_m=0.05)


def _sample(group: Group, seed: int = 0, noisy: bool = False,
            settings: LandmarkSettings = SETTINGS) -> SyntheticGraph:
    return generate_landmarks(*ARGS, np.random.default_rng(seed), settings,
                              noisy_measurements=noisy, group=group)


def _landmark_factors(graph: gtsam.NonlinearFactorGraph) -> list:
    return [graph.at(i) for i in range(graph.size())
            if isinstance(graph.at(i), (gtsam.BearingRangeFactor2D, gtsam.BearingRangeFactor3D))]


def _position(values: gtsam.Values, key: int, group: Group) -> np.ndarray:
    return np.asarray(group.pose_at(values, key).translation(), float)


def _point(values: gtsam.Values, key: int, group: Group) -> np.ndarray:
    return values.atPoint2(key) if group is SE2 else values.atPoint3(key)


@pytest.mark.parametrize("group", GROUPS)
def test_exact_measurements_have_the_truth_as_their_optimum(group):
    sample = _sample(group)
    assert chi2(sample.graph, sample.ground_truth) < 1e-18
    assert chi2(sample.graph, sample.initial) > 1e3  # only the guess is noisy
    factors = _landmark_factors(sample.graph)
    kind = gtsam.BearingRangeFactor2D if group is SE2 else gtsam.BearingRangeFactor3D
    assert factors and all(isinstance(f, kind) for f in factors)
    # in bearing-range coordinates: the bearing's (d - 1) axes, then the range
    information = factors[0].noiseModel().information()
    np.testing.assert_allclose(np.diag(information),
                               [1 / 0.02**2] * (group.d - 1) + [1 / 0.05**2])


@pytest.mark.parametrize("group", GROUPS)
def test_noisy_measurements_give_the_truth_the_chi2_of_the_noise(group):
    sample = _sample(group, seed=1, noisy=True)
    # each factor's error at the truth is its whitened noise draw: chi2 ~ chi2(dofs)
    dofs = sum(sample.graph.at(i).dim() for i in range(sample.graph.size()))
    assert abs(chi2(sample.graph, sample.ground_truth) - dofs) < 5 * np.sqrt(2 * dofs)
    landmark_dofs = group.d * len(_landmark_factors(sample.graph))
    assert landmark_dofs > dofs / 2  # the landmarks' noise is most of what is tested


@pytest.mark.parametrize("group", GROUPS)
def test_a_seed_gives_one_graph_and_generate_s_pose_graph(group):
    def text(sample: SyntheticGraph) -> str:  # GTSAM's serialization: every digit
        return "".join(x.serialize() for x in (sample.graph, sample.initial, sample.ground_truth))

    a, b, c = _sample(group, 4, True), _sample(group, 4, True), _sample(group, 5, True)
    assert text(a) == text(b) != text(c)
    # the landmarks come after the pose graph's draws: the same seed's pose graph
    poses = generate(*ARGS, np.random.default_rng(4), noisy_measurements=True, group=group)
    assert all(a.graph.at(i).serialize() == poses.graph.at(i).serialize()
               for i in range(poses.graph.size()))
    assert a.graph.size() == poses.graph.size() + len(_landmark_factors(a.graph))


@pytest.mark.parametrize("group", GROUPS)
def test_every_landmark_is_seen_within_the_sensor_range(group):
    sample = _sample(group, seed=2)
    m = sample.num_landmarks
    assert 0 < m <= SETTINGS.count
    keys = {landmark_key(j) for j in range(m)}
    seen = [f.keys()[1] for f in _landmark_factors(sample.graph)]
    assert set(seen) == keys
    # named in the order the path first sees them
    assert list(dict.fromkeys(seen)) == [landmark_key(j) for j in range(m)]
    assert sample.initial.size() == sample.ground_truth.size() == ARGS[0] + m
    for f in _landmark_factors(sample.graph):
        pose, point = f.keys()
        distance = np.linalg.norm(_point(sample.ground_truth, point, group)
                                  - _position(sample.ground_truth, pose, group))
        assert SETTINGS.blind_range_m() <= distance <= SETTINGS.sensor_range_m
    points = np.array([_point(sample.ground_truth, k, group) for k in sorted(keys)])
    assert points.shape == (m, group.d)
    if group is SE3:  # the 60 poses lie in one layer; the points fill the volume around it
        assert np.ptp(points[:, 2]) > SETTINGS.sensor_range_m


def test_a_cap_keeps_each_pose_s_nearest_landmarks_and_drops_the_unseen():
    settings = LandmarkSettings(200, sensor_range_m=6.0, max_per_pose=2)
    sample = _sample(SE2, seed=3, settings=settings)
    per_pose = np.bincount([f.keys()[0] for f in _landmark_factors(sample.graph)],
                           minlength=ARGS[0])
    assert per_pose.max() == 2
    assert sample.num_landmarks < 200  # 60 poses x 2 sightings cannot see them all
    assert sample.ground_truth.size() == ARGS[0] + sample.num_landmarks


@pytest.mark.parametrize("group", GROUPS)
def test_levenberg_marquardt_from_the_initial_guess_reaches_the_optimum(group):
    sample = _sample(group, seed=6, noisy=True)
    start = chi2(sample.graph, sample.initial)
    result = gtsam.LevenbergMarquardtOptimizer(sample.graph, sample.initial).optimize()
    # the optimum is at least as good as the truth, and far better than the guess
    assert chi2(sample.graph, result) <= chi2(sample.graph, sample.ground_truth)
    assert chi2(sample.graph, result) < start / 20


@pytest.mark.parametrize("settings, message", [
    (LandmarkSettings(0), "at least 1 landmark"),
    (LandmarkSettings(5, sigma_range_m=0.0), "must be positive"),
    (LandmarkSettings(5, sensor_range_m=1.0, sigma_range_m=0.5), "lower sigma_range"),
    (LandmarkSettings(5, max_per_pose=0), "max_per_pose must be >= 1"),
])
def test_settings_out_of_range_are_refused_by_name(settings, message):
    with pytest.raises(RlpgoError, match=message):
        _sample(SE2, settings=settings)


def test_landmark_options_need_landmarks_and_exclude_wrong_closures(tmp_path):
    out = str(tmp_path / "g.g2o")
    cli_error(CliRunner().invoke(main, ["--n", "20", "--sensor-range", "5", "-o", out]),
              "--sensor-range: options of the landmarks and the ranges; give --landmarks N, "
              "--ranges N or --pose-ranges K too", code=2)
    cli_error(CliRunner().invoke(main, ["--n", "20", "--landmarks", "5", "--outliers", "0.1",
                                        "-o", out]), "do not combine with --landmarks", code=2)
    assert not (tmp_path / "g.g2o").exists()


@pytest.mark.parametrize("dim", [2, 3])
def test_generate_writes_landmark_graphs(tmp_path, dim):
    out, truth = tmp_path / "g.g2o", tmp_path / "gt.g2o"
    result = CliRunner().invoke(main, [
        "--dim", str(dim), "--n", "40", "--landmarks", "30", "--sensor-range", "6",
        "--seed", "2", "-o", str(out), "--ground-truth", str(truth)])
    cli_ok(result)
    sample = generate_landmarks(40, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(2),
                                LandmarkSettings(30, sensor_range_m=6.0),
                                group=GROUPS[dim - 2])
    assert f"40 poses, {sample.num_landmarks} landmarks" in result.output
    graph, initial = read_g2o(out)
    _, ground_truth = read_g2o(truth)
    assert initial.size() == ground_truth.size() == 40 + sample.num_landmarks
    assert graph.size() == sample.graph.size()
    assert chi2(graph, ground_truth) < 1e-12 < 1e3 < chi2(graph, initial)
