"""The episode mechanics against from-scratch computations, on generated graphs only."""

import numpy as np
import pytest

from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.rl.episode import (
    BalancingPolicy,
    EdgeWalk,
    OrientationState,
    RandomPolicy,
    rollout,
)
from rlpgo_gtsam.se2 import orientation_cost, wrap
from rlpgo_gtsam.synthetic import generate


@pytest.fixture(scope="module")
def graph_1000() -> PoseGraph2D:
    sample = generate(1000, 0.4, 0.05, 3.0, 0.5, np.random.default_rng(3),
                      noisy_measurements=True)
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial)


def _scratch(graph: PoseGraph2D, theta: np.ndarray) -> dict:
    """Every kept quantity of OrientationState, computed from nothing."""
    i, j = graph.edges[:, 0], graph.edges[:, 1]
    residual = wrap(theta[j] - theta[i] - graph.measured[:, 2])
    slope = 4.0 * np.sin(residual)
    gradient = np.zeros(graph.num_poses)
    np.add.at(gradient, j, slope)
    np.add.at(gradient, i, -slope)
    return {
        "oc": orientation_cost(theta, graph.edges, graph.measured[:, 2]),
        "mean_message": np.sqrt(8.0) * np.abs(np.sin(0.5 * residual)).sum() / graph.num_poses,
        "residual": residual,
        "gradient": gradient,
    }


def test_incremental_state_matches_scratch_after_20000_random_rotations(graph_1000):
    rng = np.random.default_rng(0)
    state = OrientationState(graph_1000, graph_1000.poses[:, 2])
    best_cost, best_theta = state.cost_sq, np.array(state.theta)
    for _ in range(20_000):
        state.rotate(int(rng.integers(graph_1000.num_poses)), float(rng.uniform(-0.3, 0.3)))
        if state.mark_best():
            best_cost, best_theta = state.cost_sq, np.array(state.theta)
    theta = np.array(state.theta)
    expected = _scratch(graph_1000, theta)
    assert state.oc == pytest.approx(expected["oc"], rel=1e-10)
    assert state.mean_message == pytest.approx(expected["mean_message"], rel=1e-10)
    assert np.allclose(state.residual, expected["residual"], atol=1e-12)
    gradients = [state.gradient(k) for k in range(graph_1000.num_poses)]
    assert np.allclose(gradients, expected["gradient"], atol=1e-9)
    assert np.array_equal(state.best_orientations(), best_theta)
    assert state.best_oc == pytest.approx(np.sqrt(best_cost))
    assert state.best_oc == pytest.approx(_scratch(graph_1000, best_theta)["oc"], rel=1e-10)


def test_walk_skips_edges_of_held_poses_and_observes_the_current_edge(graph_1000):
    walk = EdgeWalk(graph_1000)
    assert not np.isin(graph_1000.edges[walk.edges], [graph_1000.anchor]).any()
    assert len(walk) == int((graph_1000.edges != graph_1000.anchor).all(axis=1).sum())
    state = OrientationState(graph_1000, graph_1000.poses[:, 2])
    expected = _scratch(graph_1000, graph_1000.poses[:, 2])
    i, j = graph_1000.edges[walk.edges[5]]
    observed = walk.observe(state, 5 + 2 * len(walk))  # step 5 of the third cycle
    assert observed == pytest.approx(np.float32([
        expected["mean_message"], expected["residual"][walk.edges[5]],
        expected["gradient"][i], expected["gradient"][j]]).tolist())


def test_balancing_rule_zeroes_each_residual_it_visits(graph_1000):
    result = rollout(BalancingPolicy(10.0), graph_1000, graph_1000.poses[:, 2], 1, 10.0,
                     np.zeros((1, 2)))
    assert result.best_oc[0] < result.initial_oc
    # One step of the rule on a fresh state leaves that edge's residual at zero.
    walk, state = EdgeWalk(graph_1000), OrientationState(graph_1000, graph_1000.poses[:, 2])
    observation = np.array([walk.observe(state, 0)])
    action, _ = BalancingPolicy(10.0).step(observation, np.zeros((1, 2)), None)
    walk.act(state, 0, action[0], 10.0)
    assert abs(state.residual[walk.edge_list[0]]) < 1e-6


def test_batched_rollouts_equal_single_ones_and_keep_the_held_pose(graph_1000):
    start = graph_1000.poses[:, 2]
    last = np.array([[0.0, 0.0], [0.5, -0.5]])
    batch = rollout(BalancingPolicy(0.25), graph_1000, start, 2, 0.25, last)
    for b in range(2):
        single = rollout(BalancingPolicy(0.25), graph_1000, start, 2, 0.25, last[b:b + 1])
        assert np.array_equal(single.best_theta[0], batch.best_theta[b])
    assert np.all(batch.best_theta[:, graph_1000.anchor] == wrap(start[graph_1000.anchor]))
    assert np.all(batch.best_oc <= batch.initial_oc)


def test_random_policy_is_seeded(graph_1000):
    runs = [rollout(RandomPolicy(np.random.default_rng(seed)), graph_1000,
                    graph_1000.poses[:, 2], 1, 0.25, np.zeros((1, 2))).final_oc[0]
            for seed in (1, 1, 2)]
    assert runs[0] == runs[1] != runs[2]


# --- the rich observation and keeping the lowest real cost (issue 11) ---------------------


@pytest.fixture(scope="module")
def graph_60() -> PoseGraph2D:
    sample = generate(60, 0.4, 0.05, 3.0, 0.5, np.random.default_rng(5),
                      noisy_measurements=True)
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial)


def _frozen_costs(graph: PoseGraph2D, theta: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """e^T Lambda e per edge with positions ``xy`` held, from nothing."""
    from rlpgo_gtsam.se2 import rotation_matrices

    i, j = graph.edges[:, 0], graph.edges[:, 1]
    r_i_t = np.transpose(rotation_matrices(theta[i]), (0, 2, 1))
    r_m_t = np.transpose(rotation_matrices(graph.measured[:, 2]), (0, 2, 1))
    local = np.einsum("eab,eb->ea", r_i_t, xy[j] - xy[i]) - graph.measured[:, :2]
    error = np.column_stack([np.einsum("eab,eb->ea", r_m_t, local),
                             wrap(theta[j] - theta[i] - graph.measured[:, 2])])
    return np.einsum("ea,eab,eb->e", error, graph.information, error)


def test_rich_state_keeps_the_real_cost_of_each_edge_and_its_slopes(graph_60):
    from rlpgo_gtsam.rl.episode import make_state

    state = make_state(graph_60, graph_60.poses[:, 2], "rich")
    xy = np.array(state.xy)
    rng = np.random.default_rng(0)
    for _ in range(500):
        state.rotate(int(rng.integers(1, graph_60.num_poses)), float(rng.uniform(-0.3, 0.3)))
    theta = np.array(state.theta)
    assert np.allclose(state.edge_cost, _frozen_costs(graph_60, theta, xy), rtol=1e-9)
    for pose in (3, 17, 42):  # slopes against central differences of the summed costs
        bumped = [theta.copy(), theta.copy()]
        bumped[0][pose] += 1e-6
        bumped[1][pose] -= 1e-6
        numeric = (_frozen_costs(graph_60, bumped[0], xy).sum()
                   - _frozen_costs(graph_60, bumped[1], xy).sum()) / 2e-6
        assert state.real_slope(pose) == pytest.approx(numeric, rel=1e-5, abs=1e-4)
    state.recompute()  # a cycle's end: positions from the translation step of the new angles
    from rlpgo_gtsam.translations import TranslationStep

    assert state.chi2 == pytest.approx(TranslationStep(graph_60).chi2(theta), rel=1e-12)


def test_rich_observation_extends_the_paper_observation(graph_60):
    from rlpgo_gtsam.rl.episode import OBSERVATION_SIZES, make_state

    paper_walk, rich_walk = EdgeWalk(graph_60), EdgeWalk(graph_60, "rich", cycles=3)
    paper = OrientationState(graph_60, graph_60.poses[:, 2])
    rich = make_state(graph_60, graph_60.poses[:, 2], "rich")
    for step in range(0, 3 * len(rich_walk), 7):
        short, full = paper_walk.observe(paper, step), rich_walk.observe(rich, step)
        assert len(short) == OBSERVATION_SIZES["paper"]
        assert len(full) == OBSERVATION_SIZES["rich"]
        assert full[:4] == short
        assert 0.0 <= full[-2] < 1.0 and full[-1] == pytest.approx(step / (3 * len(rich_walk)))


def test_rollout_keeping_chi2_hands_over_the_lowest_real_cost_of_its_cycles(graph_60):
    from rlpgo_gtsam.translations import TranslationStep

    step = TranslationStep(graph_60)
    start = graph_60.poses[:, 2]
    last = np.zeros((2, 2))
    kept = rollout(BalancingPolicy(0.25), graph_60, start, 3, 0.25, last, keep="chi2",
                   observation="rich")
    ends = [step.chi2(_final(graph_60, cycles_run)) for cycles_run in (1, 2, 3)]
    assert kept.best_chi2[0] == pytest.approx(min(ends), rel=1e-12)  # the lowest cycle end
    assert kept.best_chi2[0] == pytest.approx(step.chi2(kept.best_theta[0]), rel=1e-12)
    # The paper's keep is untouched by the new options' existence.
    default = rollout(BalancingPolicy(0.25), graph_60, start, 3, 0.25, last)
    assert default.best_chi2 is None


def _final(graph: PoseGraph2D, cycles: int) -> np.ndarray:
    """The orientations after ``cycles`` passes of the balancing rule."""
    walk, state = EdgeWalk(graph), OrientationState(graph, graph.poses[:, 2])
    policy = BalancingPolicy(0.25)
    for step in range(cycles * len(walk)):
        action, _ = policy.step(np.array([walk.observe(state, step)]), np.zeros((1, 2)), None)
        walk.act(state, step, action[0], 0.25)
    return np.array(state.theta)
