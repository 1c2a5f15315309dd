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
from rlpgo_gtsam.groups import SE2, SE3
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
    with pytest.raises(GraphError, match="PriorFactorPoint2 on 1: GTSAM cannot evaluate it"):
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
    from rlpgo_gtsam.initializers import _edge_factors, _shared_models

    g = PoseGraph2D.from_gtsam(*read_g2o(dataset(name)))
    weights = rotation_weights(g)
    factors = _edge_factors(g, _shared_models(
        weights, lambda w: gtsam.noiseModel.Isotropic.Precision(3, w)))
    assert len(factors) == g.num_edges
    for (i, j), z, w, factor in zip(g.edges.tolist(), g.measured, weights, factors,
                                    strict=True):
        alone = gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z),
                                         gtsam.noiseModel.Isotropic.Precision(3, float(w)))
        assert factor.equals(alone, 0.0)
    held = [factor.noiseModel() for factor in factors]  # alive: one wrapper per model
    assert len({id(model) for model in held}) == (models or len(np.unique(weights)))


# --------------------------------------------------------------------------- both groups

def _both_groups_graphs():
    """A small generated planar graph and a 3D one, odometry noisy enough that the guess
    from the vertices is far from the optimum."""
    return {"planar": generate(60, 0.1, 0.05, 2.0, 0.5, np.random.default_rng(1),
                               noisy_measurements=True),
            "3D": generate(60, 0.1, 0.05, 2.0, 0.5, np.random.default_rng(1),
                           noisy_measurements=True, group=SE3)}


BOTH = [name for name in initializer_names(SE2) if name in initializer_names(SE3)]


@pytest.mark.parametrize("kind", ["planar", "3D"])
@pytest.mark.parametrize("name", BOTH)
def test_every_initializer_of_both_groups_takes_pose2_and_pose3_graphs(name, kind):
    """``make_initializer(name).initialize(graph, values)`` on a Pose2 and a Pose3 graph
    alike: values of the graph's pose type, a finite chi2, and every method but the odometry
    itself at most the odometry guess's chi2 (each minimizes a relaxation or a part of the
    cost from a start that ignores the drifted vertices)."""
    sample = _both_groups_graphs()[kind]
    values = make_initializer(name).initialize(sample.graph, sample.initial)
    pose = gtsam.Pose2 if kind == "planar" else gtsam.Pose3
    assert values.size() == sample.initial.size()
    assert all(isinstance(_pose_at(values, key, pose), pose) for key in values.keys())
    found = chi2(sample.graph, values)
    assert np.isfinite(found)
    assert found <= chi2(sample.graph, make_initializer("odometry").initialize(
        sample.graph, sample.initial))


def _pose_at(values, key, pose):
    return values.atPose2(key) if pose is gtsam.Pose2 else values.atPose3(key)


def test_the_certified_guess_is_the_lowest_in_both_groups_and_carries_its_certificate():
    from rlpgo_gtsam.graph import extract_pose_graph

    for kind, sample in _both_groups_graphs().items():
        g = extract_pose_graph(sample.graph, sample.initial)
        results = {name: make_initializer(name).run(g) for name in BOTH}
        certified = results["certified"]
        assert certified.certificate.certified, (kind, certified.certificate.describe())
        assert certified.poses.shape == ((60, 3) if kind == "planar" else (60, 3, 4))
        assert certified.chi2 == min(result.chi2 for result in results.values()), kind


def test_a_method_of_one_group_names_the_other_groups_methods():
    samples = _both_groups_graphs()
    with pytest.raises(RlpgoError, match=r"^'lago' is a planar method; the 3D methods are "
                                         r"odometry, chordal"):
        make_initializer("lago").initialize(samples["3D"].graph, samples["3D"].initial)
    with pytest.raises(RlpgoError, match=r"^'initialize_pose3' is a 3D method; the planar "
                                         r"methods are odometry, lago"):
        make_initializer("initialize_pose3").initialize(samples["planar"].graph,
                                                        samples["planar"].initial)
    assert "rl" in initializer_names(SE2) and "rl" not in initializer_names(SE3)
    assert "initialize_pose3" in initializer_names(SE3)
    assert set(initializer_names()) == set(initializer_names(SE2)) | set(initializer_names(SE3))


@pytest.mark.parametrize("kind", ["planar", "3D"])
def test_the_staged_runs_certificate_is_its_certified_rows(kind):
    from rlpgo_gtsam import staged_initialize

    sample = _both_groups_graphs()[kind]
    run = staged_initialize(sample.graph, sample.initial)
    assert run.rows[0].method == "certified"
    assert run.certificate is run.rows[0].init.certificate
    assert run.certificate.certified == run.certified


def test_shonan_on_a_chain_returns_its_exact_rotations():
    """A graph without cycles: the chained rotations are the optimum at zero cost (GTSAM's
    Shonan fails its eigenvalue check on a 1000-pose chain)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    rng = np.random.default_rng(2)
    pose = gtsam.Pose2()
    values.insert(0, pose)
    for k in range(1, 300):
        step = gtsam.Pose2(1.0, 0.1 * rng.normal(), 0.3 * rng.normal())
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, step, gtsam.noiseModel.Unit.Create(3)))
        pose = pose.compose(step)
        values.insert(k, gtsam.Pose2(pose.x() + rng.normal(), pose.y(), pose.theta() + 1.0))
    run = make_initializer("shonan").run(PoseGraph2D.from_gtsam(graph, values))
    assert run.details["tree"] and run.details["runs"] == []
    assert graph.error(run.values) < 1e-12
