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


def _real_chi2(env: PoseGraphEnv) -> float:
    """GTSAM's chi2 of the env's orientations with the translation step's positions."""
    from rlpgo_gtsam import poses_with_orientations

    g = env.pose_graph
    return chi2(g.graph, g.to_values(poses_with_orientations(g, np.array(env.state.theta))))


def test_real_cost_reward_is_the_chi2_decrease_through_gtsam():
    """reward="chi2": each step's reward is 100 x the decrease of the log of GTSAM's chi2
    of the translation step, so the return is 100 log(chi2_start / chi2_end)."""
    env = PoseGraphEnv(1, n=30, sigma_t=0.05, noisy_measurements=True, cycles=1,
                       reward="chi2", observation="rich")
    env.reset(seed=4)
    start = _real_chi2(env)
    rng = np.random.default_rng(0)
    previous, total, done = start, 0.0, False
    while not done:
        _, reward, done, _, info = env.step(rng.uniform(-1.0, 1.0, 2))
        now = _real_chi2(env)
        assert reward == pytest.approx(100.0 * math.log(previous / now), rel=1e-7, abs=1e-9)
        assert info["chi2"] == pytest.approx(now, rel=1e-10)
        previous, total = now, total + reward
    assert total == pytest.approx(100.0 * math.log(start / previous), rel=1e-6)
    assert info["best_chi2"] <= min(start, previous) + 1e-9


def test_real_cost_reward_with_oc_shaping_adds_the_paper_reward():
    plain = PoseGraphEnv(1, n=20, cycles=1, reward="chi2")
    shaped = PoseGraphEnv(1, n=20, cycles=1, reward="chi2", oc_shaping=0.5)
    paper = PoseGraphEnv(1, n=20, cycles=1)
    for env in (plain, shaped, paper):
        env.reset(seed=2)
    action = np.array([0.3, -0.2])
    r_plain, r_shaped, r_paper = (env.step(action)[1] for env in (plain, shaped, paper))
    assert r_shaped == pytest.approx(r_plain + 0.5 * r_paper)


def test_rich_observation_env_passes_check_env_and_sees_the_horizon():
    env = PoseGraphEnv(1, n=20, cycles=2, observation="rich")
    check_env(env, skip_render_check=True)
    observation, _ = env.reset(seed=0)
    assert observation.shape == (12,) and env.observation_space.contains(observation)
    steps = env.steps_per_episode
    for _ in range(steps - 1):
        observation, *_ = env.step(np.zeros(2))
    assert observation[-1] == pytest.approx((steps - 1) / steps)  # the episode's fraction
    assert observation[-2] == pytest.approx((steps // 2 - 1) / (steps // 2))  # the cycle's


def test_pool_episodes_start_from_the_classical_optimum(tmp_path):
    """An arena-matched environment: graphs from a cached pool, each episode starting from
    certified + LM's orientations; the cache is reused."""
    from rlpgo_gtsam.rl.episode import EnvConfig
    from rlpgo_gtsam.rl.pool import build_pool
    from rlpgo_gtsam.translations import TranslationStep

    config = EnvConfig(n=30, sigma_r=0.3, sigma_r_max=0.6, sigma_t=0.05,
                       noisy_measurements=True)
    cache = tmp_path / "pool.npz"
    pool = build_pool(config, [1, 2], cache)
    assert cache.is_file()
    assert len({entry.sigma_r for entry in pool}) == 2
    assert all(0.3 <= entry.sigma_r <= 0.6 for entry in pool)
    for entry in pool:  # the start is an LM optimum: its translation-step chi2 is its chi2
        assert TranslationStep(entry.pose_graph).chi2(entry.start_theta) == pytest.approx(
            entry.start_chi2, rel=1e-3)
    again = build_pool(config, [1, 2], cache)
    assert all(np.array_equal(a.start_theta, b.start_theta)
               for a, b in zip(pool, again, strict=True))
    env = PoseGraphEnv(1, pool=pool, n=30, cycles=1, reward="chi2")
    env.reset(seed=0)
    starts = [entry.start_theta for entry in pool]
    assert any(np.allclose(env.state.theta, theta) for theta in starts)
    assert env.initial_chi2 == pytest.approx(min(
        (e.start_chi2 for e in pool), key=lambda c: abs(c - env.initial_chi2)), rel=1e-3)
