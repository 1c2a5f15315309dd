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
