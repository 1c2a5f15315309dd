import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import (
    GraphError,
    PoseGraph2D,
    RlpgoError,
    chi2,
    generate,
    initializer_names,
    make_initializer,
    read_g2o,
    refine,
    register,
)
from rlpgo_gtsam.graph import component_labels
from rlpgo_gtsam.initializers import OdometryInitializer
from rlpgo_gtsam.se2 import wrap
from tests.conftest import dataset

LOWEST_KNOWN = {"M3500A.g2o": 912.2, "M3500B.g2o": 2055.4, "Intel.g2o": 212.7, "MIT.g2o": 41.21}


@pytest.mark.parametrize("name", [
    pytest.param(name, marks=[pytest.mark.slow] if name.startswith("M3500") else [])
    for name in sorted(LOWEST_KNOWN)])
def test_chordal_then_lm30_reaches_lowest_known(name):
    graph, values = read_g2o(dataset(name))
    result = refine(graph, make_initializer("chordal").initialize(graph, values), "lm", 30)
    assert result.chi2 <= LOWEST_KNOWN[name] * 1.001


@pytest.mark.parametrize(("name", "bound"), [("Intel.g2o", 213.0), ("MIT.g2o", 771.0)])
def test_lago_works_with_full_gaussian_noise(name, bound):
    graph, values = read_g2o(dataset(name))
    result = refine(graph, make_initializer("lago").initialize(graph, values), "lm", 30)
    assert result.chi2 <= bound


@pytest.mark.parametrize(
    ("method", "tolerance"), [("lago", 1e-6), ("chordal", 1e-6), ("shonan", 1e-2)]
)
def test_classical_initializers_solve_exact_graphs(method, tolerance, small_exact):
    # Shonan's iterative rotation solve stops at its own tolerance, the others are exact.
    initial = make_initializer(method).initialize(small_exact.graph, small_exact.initial)
    assert chi2(small_exact.graph, initial) < tolerance
    assert chi2(small_exact.graph, small_exact.initial) > 1e3


@pytest.mark.parametrize("method", ["odometry", "lago", "chordal", "shonan"])
def test_anchor_pose_is_kept(method, small_noisy):
    initial = make_initializer(method).initialize(small_noisy.graph, small_noisy.initial)
    assert initial.atPose2(0).equals(small_noisy.initial.atPose2(0), 1e-9)
    assert initial.size() == small_noisy.initial.size()


def test_new_initializers_plug_in_by_name(small_noisy):
    register("test-odometry", OdometryInitializer)
    assert "test-odometry" in initializer_names()
    result = make_initializer("test-odometry").initialize(small_noisy.graph, small_noisy.initial)
    assert chi2(small_noisy.graph, result) == chi2(small_noisy.graph, small_noisy.initial)


def test_unknown_method_names_the_choices():
    with pytest.raises(RlpgoError, match="unknown method 'magic'; choose from odometry"):
        make_initializer("magic")


def test_disconnected_graph_from_code_is_refused():
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(3)
    graph.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(1, 0, 0), noise))
    graph.add(gtsam.BetweenFactorPose2(2, 3, gtsam.Pose2(1, 0, 0), noise))
    values = gtsam.Values()
    for key in range(4):
        values.insert(key, gtsam.Pose2(float(key), 0.0, 0.0))
    with pytest.raises(GraphError, match=r"2 connected components \(keys 0-1 and keys 2-3\)"):
        make_initializer("chordal").initialize(graph, values)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_component_labels_are_the_components_a_search_finds(seed):
    # a generated graph cut into pieces (a random half of its edges dropped, edges shuffled
    # and turned round): each pose labelled with the smallest pose index of its component
    rng = np.random.default_rng(seed)
    synthetic = generate(300, 0.05, 0.1, 1.0, 0.3, rng)
    edges = PoseGraph2D.from_gtsam(synthetic.graph, synthetic.initial).edges
    edges = edges[rng.permutation(len(edges))[: len(edges) // 2]]
    edges = np.where(rng.random((len(edges), 1)) < 0.5, edges, edges[:, ::-1])
    n = len(synthetic.initial.keys())
    neighbours: dict[int, list[int]] = {k: [] for k in range(n)}
    for i, j in edges.tolist():
        neighbours[i].append(j)
        neighbours[j].append(i)
    expected = np.full(n, -1)
    for start in range(n):  # in index order: the first pose reached is the smallest
        if expected[start] < 0:
            expected[start], frontier = start, [start]
            while frontier:
                for other in neighbours[frontier.pop()]:
                    if expected[other] < 0:
                        expected[other] = start
                        frontier.append(other)
    labels = component_labels(n, edges)
    assert np.array_equal(labels, expected)
    assert len(np.unique(expected)) > 10  # really cut into pieces


def test_non_pose2_factor_is_refused(small_noisy):
    graph = gtsam.NonlinearFactorGraph(small_noisy.graph)
    graph.add(gtsam.PriorFactorPoint2(1, np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
    with pytest.raises(GraphError, match="unsupported factor PriorFactorPoint2"):
        make_initializer("lago").initialize(graph, small_noisy.initial)


def test_lago_matches_gtsams_own_lago_on_a_diagonal_noise_graph():
    """gtsam.lago.initialize also re-solves the angles in its linear pose step, so the two
    guesses differ; the orientation step is the same and LM reaches the same optimum."""
    sample = generate(300, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(4), noisy_measurements=True)
    anchored = gtsam.NonlinearFactorGraph(sample.graph)
    anchored.add(gtsam.PriorFactorPose2(0, sample.initial.atPose2(0),
                                        gtsam.noiseModel.Unit.Create(3)))
    orientations = gtsam.lago.initializeOrientations(anchored)
    pose_graph = PoseGraph2D.from_gtsam(sample.graph, sample.initial)
    ours = make_initializer("lago").run(pose_graph)
    theirs_theta = np.array([orientations.at(k)[0] for k in range(pose_graph.num_poses)])
    assert np.abs(wrap(ours.poses[:, 2] - theirs_theta)).max() < 1e-9
    theirs = gtsam.lago.initialize(anchored)
    assert refine(sample.graph, ours.values, "lm", 50).chi2 == pytest.approx(
        refine(sample.graph, theirs, "lm", 50).chi2, rel=1e-7)


def test_chordal_then_lm_reaches_the_ground_truth_started_optimum():
    """Noisy measurements: the optimum is not the ground truth, but LM from the ground truth
    finds the basin a good initializer must reach."""
    sample = generate(300, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(5), noisy_measurements=True)
    reference = refine(sample.graph, sample.ground_truth, "lm", 100).chi2
    for method in ("chordal", "lago"):
        guess = make_initializer(method).initialize(sample.graph, sample.initial)
        assert refine(sample.graph, guess, "lm", 100).chi2 == pytest.approx(reference, rel=1e-6)


def test_results_carry_chi2_seconds_and_the_start(small_noisy):
    pose_graph = PoseGraph2D.from_gtsam(small_noisy.graph, small_noisy.initial)
    result = make_initializer("chordal").run(pose_graph)
    assert result.method == "chordal" and result.seconds > 0
    assert result.chi2 == pytest.approx(chi2(small_noisy.graph, result.values))
    assert np.allclose(PoseGraph2D.from_gtsam(small_noisy.graph, result.values).poses,
                       result.poses)


def test_unknown_options_are_named():
    with pytest.raises(RlpgoError, match="method 'chordal' does not take episodes"):
        make_initializer("chordal", episodes=3)
    with pytest.raises(RlpgoError, match="'lago@chordal': method lago takes no start"):
        make_initializer("lago@chordal")


@pytest.mark.parametrize(("name", "models"), [("Intel.g2o", None), ("M3500.g2o", 3)])
def test_edge_graphs_keep_each_edges_noise_with_one_model_per_value(name, models):
    """The graphs the LAGO, Shonan and fastsync steps hand to GTSAM hold each edge as
    measured with the noise it gets from its own information (Intel: nearly every edge its
    own), a model made once per distinct value (M3500's 5453 edges: three)."""
    from rlpgo_gtsam.graph import rotation_weights
    from rlpgo_gtsam.initializers import _edge_factors

    g = PoseGraph2D.from_gtsam(*read_g2o(dataset(name)))
    weights = rotation_weights(g)
    factors = _edge_factors(g, weights, lambda w: gtsam.noiseModel.Isotropic.Precision(3, w))
    assert len(factors) == g.num_edges
    for (i, j), z, w, factor in zip(g.edges.tolist(), g.measured, weights, factors,
                                    strict=True):
        alone = gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z),
                                         gtsam.noiseModel.Isotropic.Precision(3, float(w)))
        assert factor.equals(alone, 0.0)
    held = [factor.noiseModel() for factor in factors]  # alive: one wrapper per model
    assert len({id(model) for model in held}) == (models or len(np.unique(weights)))
