"""The certified relaxation on generated graphs: exact graphs certified and recovered, wrong
estimates refused, heavy noise not certified, and the small or odd graphs handled."""

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import GraphError, PoseGraph2D, generate, make_initializer, refine
from rlpgo_gtsam.relaxation import certify, relaxation_cost, synchronize
from rlpgo_gtsam.se2 import wrap


def _graph(sample) -> PoseGraph2D:
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial)


def test_an_exact_graph_is_certified_and_its_ground_truth_recovered():
    sample = generate(300, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(21))
    graph = _graph(sample)
    theta, certificate = synchronize(graph)
    truth = PoseGraph2D.from_gtsam(sample.graph, sample.ground_truth).poses[:, 2]
    assert np.abs(wrap(theta - truth)).max() < 1e-6
    assert certificate.certified and certificate.min_eigenvalue >= -certificate.tolerance
    assert certificate.suboptimality_bound == pytest.approx(0.0, abs=1e-6)
    assert certificate.estimate_cost == pytest.approx(0.0, abs=1e-8)
    result = make_initializer("certified").run(graph)
    assert result.chi2 < 1e-9 and result.certificate.certified
    assert result.details == {}  # the certificate is recorded once, as the certificate


def test_the_odometry_guess_of_a_loopy_graph_is_refused():
    sample = generate(300, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(22))
    graph = _graph(sample)
    certificate = certify(graph, graph.poses[:, 2])
    assert not certificate.certified
    assert certificate.min_eigenvalue < -certificate.tolerance
    assert certificate.suboptimality_bound > 0
    assert certificate.estimate_cost == pytest.approx(relaxation_cost(graph, graph.poses[:, 2]))
    # ... while the optimum of the same graph passes the same test.
    theta, _ = synchronize(graph)
    assert certify(graph, theta).certified


def test_heavy_rotation_noise_is_not_certified_and_has_a_positive_bound():
    sample = generate(100, 0.5, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)
    graph = _graph(sample)
    theta, certificate = synchronize(graph)
    assert not certificate.certified
    assert certificate.suboptimality_bound > 1.0
    assert certificate.lower_bound <= certificate.estimate_cost
    assert certificate.rank >= 2  # the staircase climbed
    # The bound is a bound: no orientation estimate we find costs less than it.
    for start in (graph.poses[:, 2], theta):
        assert relaxation_cost(graph, start) >= certificate.lower_bound - 1e-6


def _tiny(edges, poses=None):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    for i, j, z in edges:
        graph.add(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z), noise))
    keys = sorted({k for i, j, _ in edges for k in (i, j)}) if poses is None else poses
    for k in keys:
        values.insert(k, gtsam.Pose2(0.3 * k, 0.1, 0.2 * k))
    return graph, values


def test_two_poses_and_parallel_edges_are_solved_exactly():
    graph, values = _tiny([(0, 1, (1.0, 0.5, 0.3))])
    result = make_initializer("certified").run(PoseGraph2D.from_gtsam(graph, values))
    assert result.certificate.certified and result.chi2 < 1e-12
    # The same pair twice (once reversed) and a third pose: consistent, so still exact.
    between = gtsam.Pose2(1.0, 0.5, 0.3)
    inverse = between.inverse()
    graph, values = _tiny([(0, 1, (1.0, 0.5, 0.3)), (1, 0, (inverse.x(), inverse.y(),
                                                             inverse.theta())),
                           (1, 2, (0.5, -0.2, -0.4)), (0, 1, (1.0, 0.5, 0.3))])
    result = make_initializer("certified").run(PoseGraph2D.from_gtsam(graph, values))
    assert result.certificate.certified and result.chi2 < 1e-12
    assert refine(graph, result.values).chi2 < 1e-12


def test_one_pose_and_disconnected_graphs_are_clear_errors():
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(0, gtsam.Pose2())
    with pytest.raises(GraphError, match="no BetweenFactorPose2"):
        make_initializer("certified").initialize(graph, values)
    graph, values = _tiny([(0, 1, (1.0, 0.0, 0.1)), (2, 3, (1.0, 0.0, 0.1))])
    with pytest.raises(GraphError, match="2 connected components"):
        make_initializer("certified").initialize(graph, values)
