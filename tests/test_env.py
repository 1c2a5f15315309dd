import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import rlpgo_gtsam  # noqa: F401  (registers the environment id)
from rlpgo_gtsam import PRESETS, PoseGraphEnv, chi2, read_g2o, write_g2o
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.synthetic import generate
from tests.conftest import dataset


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_check_env_passes_for_every_preset(preset):
    check_env(gym.make("rlpgo/PoseGraph-v0", preset=preset).unwrapped, skip_render_check=True)


def test_check_env_passes_for_a_wrapped_g2o_file(tmp_path, small_noisy):
    path = tmp_path / "g.g2o"
    write_g2o(path, small_noisy.graph, small_noisy.initial)
    graph, values = read_g2o(path)
    check_env(PoseGraphEnv(graph=graph, values=values), skip_render_check=True)


def test_make_registers_the_id_on_first_use():
    env = gym.make("rlpgo_gtsam.rl.env:rlpgo/PoseGraph-v0", preset=2)
    assert env.unwrapped.config == PRESETS[2]


def _episode(env, seed):
    observation, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    trace = [observation]
    done = False
    while not done:
        observation, reward, done, truncated, info = env.step(rng.uniform(-1, 1, 2))
        assert not truncated
        trace.append(np.append(observation, reward))
    return trace, info


def test_same_seed_same_episode():
    first, info = _episode(PoseGraphEnv(preset=3), seed=11)
    second, _ = _episode(PoseGraphEnv(preset=3), seed=11)
    other, _ = _episode(PoseGraphEnv(preset=3), seed=12)
    assert all(np.array_equal(a, b) for a, b in zip(first, second, strict=True))
    assert not np.array_equal(first[0], other[0])


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_episode_length_is_cycles_times_non_anchor_edges(preset):
    env = PoseGraphEnv(preset=preset)
    env.reset(seed=0)
    edges = env.pose_graph.edges
    non_anchor = int(np.sum((edges[:, 0] != 0) & (edges[:, 1] != 0)))
    trace, info = _episode(env, 0)
    assert len(trace) - 1 == non_anchor * PRESETS[preset].cycles
    assert info["cycle"] == PRESETS[preset].cycles


def test_step_touches_only_the_two_poses():
    env = PoseGraphEnv(preset=1)
    env.reset(seed=3)
    before = np.array(env.state.theta)
    i, j = env.pose_graph.edges[env.walk.edges[0]]
    env.step(np.array([0.5, -0.5], np.float32))
    after = np.array(env.state.theta)
    changed = np.flatnonzero(before != after)
    assert set(changed) == {i, j}
    assert after[i] == pytest.approx(before[i] + 0.5 * PRESETS[1].action_range_rad)


def test_reward_and_bonus():
    env = PoseGraphEnv(preset=1)
    _, info = env.reset(seed=5)
    # The edge-balancing rule zeroes each residual it visits; OC falls below a tenth soon.
    rewards, infos = [], []
    for _ in range(env.steps_per_episode):
        observation = env._observation()
        r = observation[1] / PRESETS[1].action_range_rad / 2
        _, reward, done, _, info = env.step(np.clip([r, -r], -1, 1))
        rewards.append(reward)
        infos.append(info)
    base = [100.0 / (i["oc"] + 1.0) for i in infos]
    bonuses = np.round(np.array(rewards) - np.array(base), 9)
    assert set(bonuses) <= {0.0, 25.0}
    expected = int(math.floor(math.log10(infos[0]["initial_oc"] / min(i["oc"] for i in infos))))
    assert int(np.sum(bonuses == 25.0)) == expected >= 1


def test_best_values_use_the_best_orientations(small_exact):
    env = PoseGraphEnv(graph=small_exact.graph, values=small_exact.initial)
    env.reset(seed=0, options={"orientations": PoseGraph2D.from_gtsam(
        small_exact.graph, small_exact.ground_truth).poses[:, 2]})
    assert env.state.oc < 1e-9
    env.step(np.array([1.0, 1.0], np.float32))  # moves away from the optimum
    assert env.state.oc > 0.1
    assert chi2(small_exact.graph, env.best_values()) < 1e-9


def test_bad_parameters_are_refused():
    with pytest.raises(rlpgo_gtsam.RlpgoError, match="preset must be one of"):
        PoseGraphEnv(preset=9)
    with pytest.raises(rlpgo_gtsam.RlpgoError, match="unknown environment parameter"):
        PoseGraphEnv(preset=1, sigma=0.3)


@pytest.mark.parametrize(("n", "edges"), [(20, 24), (300, 430)])
def test_generator_reproduces_the_paper_edge_counts(n, edges):
    sample = generate(n, 0.3, 0.01, 3.0, 0.5, np.random.default_rng(0))
    assert sample.graph.size() == edges
    assert chi2(sample.graph, sample.ground_truth) < 1e-20


def test_generator_layout_matches_the_paper_graphs():
    _, paper_truth = read_g2o(dataset("paper_sigma_t_sweep/sigma_t_0.05.gt.g2o"))
    sample = generate(300, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(0))
    ours = PoseGraph2D.from_gtsam(sample.graph, sample.ground_truth).poses
    theirs = PoseGraph2D.from_gtsam(sample.graph, paper_truth).poses
    # The published ground truth drifts by rounding (about 1e-4 m per row).
    assert np.abs(ours[:, :2] - theirs[:, :2]).max() < 1e-2
    assert np.abs(np.angle(np.exp(1j * (ours[:, 2] - theirs[:, 2])))).max() < 1e-3


def test_noisy_measurements_move_the_optimum_off_the_ground_truth():
    sample = generate(100, 0.1, 0.05, 3.0, 0.5, np.random.default_rng(0), noisy_measurements=True)
    assert chi2(sample.graph, sample.ground_truth) > 10.0
