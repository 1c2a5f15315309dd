"""Ranges in the relaxation (CORA's formulation: a unit direction per range), planar and 3D:
exact range-aided graphs certified with their truth recovered, noisy ones at or below LM and
never falsely certified, a range the relaxation does not model carried and named."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from rlpgo_gtsam import staged_initialize
from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.graph import extract_pose_graph
from rlpgo_gtsam.synthetic import generate_helix_ranges
from tests.conftest import chi2_of, lm_values


def range_aided(seed: int, noise: float, n: int = 40, beacons: int = 3, pose_ranges: int = 8):
    """A curving planar path with odometry, ranges from every pose to each beacon and a few
    between poses; measurements noisy by ``noise`` times their sigmas; the start chains the
    odometry and puts each beacon 3 m off its truth."""
    rng = np.random.default_rng(seed)
    sigmas, sigma_range = np.array([0.05, 0.05, 0.02]), 0.1
    truth = [gtsam.Pose2(0, 0, 0)]
    for k in range(1, n):
        truth.append(truth[-1].compose(gtsam.Pose2(1.0, 0, 0.1 + 0.15 * np.sin(0.2 * k))))
    beacons_at = rng.uniform(-10, 10, size=(beacons, 2))
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(X(0), truth[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.01)))
    odometry = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    chained = [truth[0]]
    for k in range(n - 1):
        step = truth[k].between(truth[k + 1]).retract(noise * rng.normal(size=3) * sigmas)
        graph.add(gtsam.BetweenFactorPose2(X(k), X(k + 1), step, odometry))
        chained.append(chained[-1].compose(step))
    ranging = gtsam.noiseModel.Isotropic.Sigma(1, sigma_range)
    for k in range(n):
        for b in range(beacons):
            r = np.linalg.norm(truth[k].translation() - beacons_at[b])
            graph.add(gtsam.RangeFactor2D(X(k), L(b), r + noise * sigma_range * rng.normal(),
                                          ranging))
    for _ in range(pose_ranges):
        a, b = (int(k) for k in rng.choice(n, 2, replace=False))
        r = np.linalg.norm(truth[a].translation() - truth[b].translation())
        graph.add(gtsam.RangeFactorPose2(X(a), X(b), r + noise * sigma_range * rng.normal(),
                                         ranging))
    values, ground_truth = gtsam.Values(), gtsam.Values()
    for k in range(n):
        values.insert(X(k), chained[k])
        ground_truth.insert(X(k), truth[k])
    for b in range(beacons):
        values.insert(L(b), gtsam.Point2(*(beacons_at[b] + 3.0 * rng.normal(size=2))))
        ground_truth.insert(L(b), gtsam.Point2(*beacons_at[b]))
    return graph, values, ground_truth


def test_ranges_are_extracted_between_translation_nodes():
    graph, values, _ = range_aided(0, 1.0, n=10, beacons=2, pose_ranges=3)
    g = extract_pose_graph(graph, values)
    assert g.ranges is not None and g.ranges.count == 10 * 2 + 3
    assert g.points is not None and g.points.count == 2 and len(g.points.edges) == 0
    assert not g.carried
    # beacon ranges end at the points' nodes, pose ranges between poses
    assert (g.ranges.nodes[:20, 1] >= g.num_poses).all()
    assert (g.ranges.nodes[20:] < g.num_poses).all()
    np.testing.assert_allclose(g.ranges.weights, 100.0)


@pytest.mark.parametrize("seed", [1, 2])
def test_an_exact_range_aided_graph_is_certified_with_its_truth_recovered(seed):
    graph, values, ground_truth = range_aided(seed, 0.0)
    run = staged_initialize(graph, values, iters=100)
    assert run.certified
    assert "3 landmarks and 128 ranges inside" in run.certificate.describe()
    assert chi2_of(graph, run.values) < 1e-12
    for b in range(3):
        np.testing.assert_allclose(run.values.atPoint2(L(b)), ground_truth.atPoint2(L(b)),
                                   atol=1e-6)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noisy_range_aided_graphs_are_at_or_below_lm_and_never_falsely_certified(seed, dim):
    graph, values, ground_truth = (range_aided if dim == 2 else range_aided_3d)(seed, 1.0)
    run = staged_initialize(graph, values, iters=100)
    assert run.certificate.ranges == (128 if dim == 2 else 68)
    ours = chi2_of(graph, run.values)
    others = [chi2_of(graph, lm_values(graph, start)) for start in (values, ground_truth)]
    assert ours <= min(others) * (1 + 1e-4)
    certificate = run.certificate
    if run.certified:
        assert certificate.suboptimality_bound <= 1e-4 * max(certificate.estimate_cost,
                                                             certificate.lower_bound)


def test_a_range_only_beacon_without_a_value_is_named():
    graph, values, _ = range_aided(0, 1.0, n=6, beacons=1, pose_ranges=0)
    values.erase(L(0))
    with pytest.raises(GraphError, match="landmark l0 is measured by ranges alone"):
        staged_initialize(graph, values)


def range_aided_3d(seed: int, noise: float, n: int = 40, beacons: int = 3,
                   pose_ranges: int = 8):
    sample = generate_helix_ranges(n, np.random.default_rng(seed), beacons=beacons,
                                   pose_ranges=pose_ranges, noise=noise)
    return sample.graph, sample.initial, sample.ground_truth


@pytest.mark.parametrize("seed", [1, 2])
def test_an_exact_3d_range_aided_graph_is_certified_with_its_truth_recovered(seed):
    graph, values, ground_truth = range_aided_3d(seed, 0.0)
    g = extract_pose_graph(graph, values)
    assert g.ranges is not None and g.ranges.count == 20 * 3 + 8 and not g.carried
    run = staged_initialize(graph, values, iters=100)
    assert run.certified, run.certificate.describe()
    assert "3 landmarks and 68 ranges inside" in run.certificate.describe()
    assert chi2_of(graph, run.values) < 1e-10
    for b in range(3):
        np.testing.assert_allclose(run.values.atPoint3(L(b)), ground_truth.atPoint3(L(b)),
                                   atol=1e-5)


def test_a_robust_3d_range_is_carried_and_named():
    graph, values, _ = range_aided_3d(0, 1.0, n=10, beacons=1, pose_ranges=0)
    huber = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0),
                                           gtsam.noiseModel.Isotropic.Sigma(1, 0.1))
    graph.add(gtsam.RangeFactor3D(X(9), L(0), 5.0, huber))
    run = staged_initialize(graph, values)
    assert run.certificate.outside == ("RangeFactor3D x 1",)
    assert run.certificate.ranges == 5
    assert not run.certified
    assert chi2_of(graph, run.values) <= chi2_of(graph, lm_values(graph, values)) * (1 + 1e-6)


def test_a_first_radius_far_too_long_does_not_stall_the_trust_region():
    """Heavy range weights (0.01 m) beside loose odometry (0.05 rad per step) make the first
    trust-region radius 1e5 times too long: its rejected steps shrink it rather than end
    the rank as a stall, and the default reaches LM's best from the truth."""
    sample = generate_helix_ranges(60, np.random.default_rng(1), beacons=3, stride=1,
                                   rotation_sigma=0.05, translation_sigma=0.1,
                                   sigma_range_m=0.01)
    run = staged_initialize(sample.graph, sample.initial, iters=100)
    truth = chi2_of(sample.graph, lm_values(sample.graph, sample.ground_truth))
    assert chi2_of(sample.graph, run.values) <= truth * (1 + 1e-4)
