"""The one pairwise least-squares system: GTSAM's own linear solve, weights, indeterminacy."""

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam.chordal import chordal_rotations
from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.linear import PairwiseSystem, solve_pairwise
from rlpgo_gtsam.synthetic import generate
from rlpgo_gtsam.translations import TranslationStep, solve_translations


@pytest.fixture(scope="module")
def noisy_graph() -> PoseGraph2D:
    graph = generate(150, 0.05, 0.1, 1.0, 0.5, np.random.default_rng(3), noisy_measurements=True)
    return PoseGraph2D.from_gtsam(graph.graph, graph.initial)


def _gtsam_solve(num_poses, edges, a_i, a_j, b, held, held_values) -> np.ndarray:
    """The same least squares as GTSAM's GaussianFactorGraph of JacobianFactors solves it."""
    value_of = {int(k): v for k, v in zip(held, held_values, strict=True)}
    graph = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create(2)
    for (i, j), block_i, block_j, rhs in zip(edges.tolist(), a_i, a_j, b, strict=True):
        if i in value_of and j in value_of:
            continue
        if i in value_of:
            graph.add(gtsam.JacobianFactor(j, block_j, rhs - block_i @ value_of[i], unit))
        elif j in value_of:
            graph.add(gtsam.JacobianFactor(i, block_i, rhs - block_j @ value_of[j], unit))
        else:
            graph.add(gtsam.JacobianFactor(i, block_i, j, block_j, rhs, unit))
    solution = graph.optimize()
    return np.array([value_of[k] if k in value_of else solution.at(k)
                     for k in range(num_poses)])


def _random_system(g: PoseGraph2D, seed: int = 0):
    rng = np.random.default_rng(seed)
    m = g.num_edges
    a_i = rng.normal(size=(m, 2, 2)) + 2.0 * np.eye(2)
    a_j = rng.normal(size=(m, 2, 2)) - 2.0 * np.eye(2)
    return a_i, a_j, rng.normal(size=(m, 2))


def test_unit_weights_match_gtsams_linear_solve(noisy_graph):
    g = noisy_graph
    a_i, a_j, b = _random_system(g)
    held, held_values = np.array([0, 40, 41]), np.array([[0.0, 0.0], [3.0, -1.0], [2.5, 4.0]])
    expected = _gtsam_solve(g.num_poses, g.edges, a_i, a_j, b, held, held_values)
    system = PairwiseSystem(g.num_poses, g.edges, held)
    for _ in range(2):  # the second solve reuses the cached pattern and ordering
        x = system.solve(a_i, a_j, b, held_values)
        np.testing.assert_allclose(x, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
        assert np.array_equal(x[held], held_values)


def test_a_zero_weight_edge_is_the_edge_removed(noisy_graph):
    g = noisy_graph
    a_i, a_j, b = _random_system(g, seed=1)
    rng = np.random.default_rng(2)
    weights = rng.uniform(0.2, 3.0, g.num_edges)
    closures = np.flatnonzero(np.abs(g.edges[:, 1] - g.edges[:, 0]) > 1)
    dropped = closures[:5]
    weights[dropped[:3]] = 0.0
    weights[dropped[3:]] = 1e-13  # at or below the floor: left out too
    held, held_values = np.array([0]), np.zeros((1, 2))
    x = solve_pairwise(g.num_poses, g.edges, a_i, a_j, b, held, held_values, weights)
    keep = np.ones(g.num_edges, bool)
    keep[dropped] = False
    root = np.sqrt(weights[keep])
    expected = _gtsam_solve(g.num_poses, g.edges[keep], root[:, None, None] * a_i[keep],
                            root[:, None, None] * a_j[keep], root[:, None] * b[keep], held,
                            held_values)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_an_undetermined_pose_is_named():
    edges = np.array([(0, 1), (1, 2), (2, 3), (3, 4)])
    a_i = -np.broadcast_to(np.eye(2), (4, 2, 2))
    a_j = np.broadcast_to(np.eye(2), (4, 2, 2))
    b = np.ones((4, 2))
    held, held_values = np.array([0]), np.zeros((1, 2))
    system = PairwiseSystem(5, edges, held)
    # edge 2-3 left out: poses 3 and 4 hang free
    with pytest.raises(SolverError, match="left pose index 3 undetermined"):
        system.solve(a_i, a_j, b, held_values, np.array([1.0, 1.0, 0.0, 1.0]))
    # edge 1-2 kept at a weight that vanishes against the others: numerically undetermined
    tiny = np.array([1.0, 1e-30, 1.0, 1.0])[:, None, None]
    with pytest.raises(SolverError, match="left pose index 2 undetermined"):
        system.solve(tiny * a_i, tiny * a_j, b, held_values)
    # a pose no edge touches
    with pytest.raises(SolverError, match="left pose index 5 undetermined"):
        solve_pairwise(6, edges, a_i, a_j, b, held, held_values)


def test_solve_translations_matches_gtsams_solve_of_the_translation_system(noisy_graph):
    g = noisy_graph
    theta = chordal_rotations(g)
    a_j, b = TranslationStep(g).whitened(theta)
    held, held_poses = g.held
    expected = _gtsam_solve(g.num_poses, g.edges, -a_j, a_j, b, held, held_poses[:, :2])
    positions = solve_translations(g, theta)
    scale = np.abs(expected).max()
    np.testing.assert_allclose(positions, expected, rtol=0, atol=1e-9 * scale)
    # the cached step (the agent's reward) gives the same positions, solve after solve
    step = TranslationStep(g)
    for _ in range(2):
        np.testing.assert_allclose(step.positions(theta), expected, rtol=0, atol=1e-9 * scale)
