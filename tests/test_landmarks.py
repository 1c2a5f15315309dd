"""Landmarks and carried factors: the relaxation certifies poses and points together, never a
graph it does not model, and no other method beats a certified result."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import L, X

from rlpgo_gtsam import robust_initialize, staged_initialize
from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.graph import extract_pose_graph
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.landmarks import bearing_range_factor, place_points, relative_point
from rlpgo_gtsam.ranking import compare_methods, comparison_methods
from rlpgo_gtsam.synthetic import LandmarkSettings, generate_landmarks
from tests.conftest import chi2_of, lm_values


def planar_slam_example():
    """GTSAM's PlanarSLAMExample: three poses, two landmarks seen by bearing and range, a
    prior on the first pose; the initial values are the example's perturbed ones."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(X(1), gtsam.Pose2(0, 0, 0),
                                     gtsam.noiseModel.Diagonal.Sigmas([0.3, 0.3, 0.1])))
    odometry = gtsam.noiseModel.Diagonal.Sigmas([0.2, 0.2, 0.1])
    graph.add(gtsam.BetweenFactorPose2(X(1), X(2), gtsam.Pose2(2, 0, 0), odometry))
    graph.add(gtsam.BetweenFactorPose2(X(2), X(3), gtsam.Pose2(2, 0, 0), odometry))
    sensor = gtsam.noiseModel.Diagonal.Sigmas([0.1, 0.2])
    graph.add(gtsam.BearingRangeFactor2D(X(1), L(1), gtsam.Rot2.fromDegrees(45), np.sqrt(8),
                                         sensor))
    graph.add(gtsam.BearingRangeFactor2D(X(2), L(1), gtsam.Rot2.fromDegrees(90), 2.0, sensor))
    graph.add(gtsam.BearingRangeFactor2D(X(3), L(2), gtsam.Rot2.fromDegrees(90), 2.0, sensor))
    values = gtsam.Values()
    values.insert(X(1), gtsam.Pose2(-0.25, 0.20, 0.15))
    values.insert(X(2), gtsam.Pose2(2.30, 0.10, -0.20))
    values.insert(X(3), gtsam.Pose2(4.10, 0.10, 0.10))
    values.insert(L(1), gtsam.Point2(1.80, 2.10))
    values.insert(L(2), gtsam.Point2(4.10, 1.80))
    return graph, values


def _landmark_graph(group, n=120, count=40, seed=3, sigma_r=0.05):
    return generate_landmarks(n, sigma_r, 0.05, 3.0, 0.3, np.random.default_rng(seed),
                              LandmarkSettings(count), noisy_measurements=True, group=group)


@pytest.mark.parametrize("point", [np.array([3.0, -1.0]), np.array([1.0, 2.0, -0.5])])
def test_a_position_measurement_round_trips_through_bearing_and_range(point):
    d = len(point)
    information = np.diag(np.arange(1.0, d + 1.0)) + 0.3
    factor = bearing_range_factor(0, int(L(4)), point, information)
    back, back_information = relative_point(factor)
    np.testing.assert_allclose(back, point, atol=1e-12)
    np.testing.assert_allclose(back_information, information, rtol=1e-9)


def test_the_conversion_is_gtsams_own_for_trackxyz_lines():
    """gtsam.readG2o turns EDGE_SE3_TRACKXYZ into a BearingRangeFactor3D: ours, made from the
    same position and information, charges the same error."""
    path = gtsam.findExampleDataFile("known_landmark_localization_20.g2o")
    graph, values = gtsam.readG2o(path, True)
    theirs = [graph.at(k) for k in range(graph.size())
              if isinstance(graph.at(k), gtsam.BearingRangeFactor3D)]
    assert len(theirs) == 80
    for factor in theirs[:10]:
        point, information = relative_point(factor)
        ours = bearing_range_factor(factor.keys()[0], factor.keys()[1], point, information)
        assert ours.error(values) == pytest.approx(factor.error(values), rel=1e-9)


def test_planar_slam_example_is_certified_at_its_optimum():
    graph, values = planar_slam_example()
    run = staged_initialize(graph, values)
    assert run.certified
    assert run.certificate.points == 2
    assert "2 landmarks inside" in run.certificate.describe()
    assert chi2_of(graph, run.values) <= chi2_of(graph, lm_values(graph, values)) + 1e-9


@pytest.mark.parametrize("group", [SE2, SE3])
def test_landmark_graphs_are_certified_at_or_below_lm_from_truth_and_odometry(group):
    sample = _landmark_graph(group)
    graph = sample.graph
    run = staged_initialize(graph, sample.initial)
    assert run.certified
    assert run.certificate.points == sample.num_landmarks
    ours = chi2_of(graph, run.values)
    for start in (sample.ground_truth, sample.initial):
        assert ours <= chi2_of(graph, lm_values(graph, start)) * (1 + 1e-4)


def test_points_are_placed_where_their_measurements_agree():
    """With exact measurements and the true poses, placement puts every point at its truth."""
    sample = generate_landmarks(30, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(1),
                                LandmarkSettings(10))  # exact measurements, noisy start
    g = extract_pose_graph(sample.graph, sample.ground_truth)
    points = g.points
    assert points is not None
    poses = g.poses_of(sample.ground_truth)
    placed = place_points(points, SE2.rotation_matrices(SE2.rotations(poses)),
                          SE2.translations(poses))
    truth = np.array([sample.ground_truth.atPoint2(int(key)) for key in points.keys])
    np.testing.assert_allclose(placed, truth, atol=1e-9)


def _with_fix_and_priors(sample, group):
    """The sample's graph with two FIXed poses, a soft pose prior and a point prior, each at
    a value off the truth so that they pull against the measurements."""
    graph = gtsam.NonlinearFactorGraph(sample.graph)
    truth = sample.ground_truth
    if group is SE2:
        shift = gtsam.Pose2(0.3, -0.2, 0.05)
        pose, prior, point_prior = (truth.atPose2, gtsam.PriorFactorPose2,
                                    gtsam.PriorFactorPoint2)
    else:
        shift = gtsam.Pose3(gtsam.Rot3.Rz(0.05), np.array([0.3, -0.2, 0.1]))
        pose, prior, point_prior = (truth.atPose3, gtsam.PriorFactorPose3,
                                    gtsam.PriorFactorPoint3)
    constrained = gtsam.noiseModel.Constrained.All(group.dof)
    graph.add(prior(0, pose(0), constrained))
    graph.add(prior(40, pose(40).compose(shift), constrained))
    graph.add(prior(80, pose(80).compose(shift), gtsam.noiseModel.Isotropic.Sigma(group.dof,
                                                                                 0.05)))
    key = int(L(3))
    at = truth.atPoint2(key) if group is SE2 else truth.atPoint3(key)
    graph.add(point_prior(key, np.asarray(at) + 0.4, gtsam.noiseModel.Isotropic.Sigma(group.d,
                                                                                      0.1)))
    values = gtsam.Values(sample.initial)
    # the FIXed poses start where they are held, as a g2o FIX line holds its vertex
    values.update(40, pose(40).compose(shift))
    values.update(0, pose(0))
    return graph, values


@pytest.mark.parametrize("group", [SE2, SE3])
def test_a_certified_whole_graph_is_not_beaten_by_any_method(group):
    """FIX lines, a soft prior and a point prior inside: the certificate covers them, and no
    initializer + LM of the comparison gets lower."""
    sample = _landmark_graph(group, n=100, count=30, seed=5)
    graph, values = _with_fix_and_priors(sample, group)
    run = staged_initialize(graph, values, iters=100)
    certificate = run.certificate
    assert certificate.fixed_poses == 2 and certificate.priors == 2
    rows = compare_methods(graph, values, comparison_methods(group), iters=100)
    others = [row.refined_chi2 for row in rows if row.failure is None]
    assert len(others) >= 3
    ours = chi2_of(graph, run.values)
    assert run.certified
    assert ours <= min(others) * (1 + 1e-4)
    for start in (values, sample.ground_truth):
        assert ours <= chi2_of(graph, lm_values(graph, start)) * (1 + 1e-4)


def test_carried_factors_make_the_certificate_not_applicable():
    graph, values = planar_slam_example()
    graph.add(gtsam.BearingFactor2D(X(3), L(1), gtsam.Rot2.fromDegrees(135),
                                    gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    run = staged_initialize(graph, values)
    certificate = run.certificate
    assert not run.certified and not certificate.certified
    assert str(certificate.status) == "not_applicable"
    assert certificate.outside == ("BearingFactor2D x 1",)
    assert certificate.relaxed == "certified"
    assert "not applicable: BearingFactor2D x 1 outside the relaxation" in certificate.describe()
    assert "certified optimal" not in certificate.describe()
    assert "does not apply" in run.stopped
    # LM refined the whole graph, the range included
    assert chi2_of(graph, run.values) <= chi2_of(graph, lm_values(graph, values)) + 1e-9


def test_a_carried_factor_with_its_own_variable_keeps_the_users_value():
    """A GPS-like prior on a separate Point2 tied to a pose by a bearing: the other variable
    keeps its value, LM refines everything."""
    graph, values = planar_slam_example()
    other = int(gtsam.symbol("g", 0))
    graph.add(gtsam.PriorFactorPoint2(other, gtsam.Point2(4.0, 0.0),
                                      gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    graph.add(gtsam.BearingFactor2D(X(3), other, gtsam.Rot2.fromDegrees(-90),
                                    gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    values.insert(other, gtsam.Point2(4.2, 0.3))
    g = extract_pose_graph(graph, values)
    assert [item.kind for item in g.carried] == ["PriorFactorPoint2", "BearingFactor2D"]
    start = g.to_values(g.poses)
    assert np.allclose(start.atPoint2(other), [4.2, 0.3])
    run = staged_initialize(graph, values)
    assert not run.certified
    assert chi2_of(graph, run.values) <= chi2_of(graph, lm_values(graph, values)) * (1 + 1e-6)


def test_a_carried_factor_on_a_variable_without_a_value_names_both():
    graph, values = planar_slam_example()
    graph.add(gtsam.BearingFactor2D(X(3), int(gtsam.symbol("b", 7)), gtsam.Rot2(0.3),
                                    gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    with pytest.raises(GraphError, match="BearingFactor2D on x3 b7: key b7 has no value"):
        staged_initialize(graph, values)


def test_a_landmark_without_a_value_starts_at_its_first_sighting():
    graph, values = planar_slam_example()
    values.erase(L(2))
    g = extract_pose_graph(graph, values)
    run = staged_initialize(graph, values)
    assert run.certified
    assert g.points is not None and g.points.count == 2
    full_graph, full_values = planar_slam_example()
    anchor = chi2_of(full_graph, lm_values(full_graph, full_values))
    assert chi2_of(graph, run.values) <= anchor + 1e-9


def test_the_robust_path_refuses_a_graph_with_landmarks_by_name():
    graph, values = planar_slam_example()
    with pytest.raises(GraphError, match="robust path judges pose graphs.*2 landmarks"):
        robust_initialize(graph, values)


def test_bearing_only_range_only_point_betweens_and_robust_sightings_are_carried():
    """What the relaxation does not model is named, and LM still refines it with the rest."""
    graph, values = planar_slam_example()
    sensor = gtsam.noiseModel.Diagonal.Sigmas([0.1, 0.2])
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                            sensor)
    graph.add(gtsam.BearingFactor2D(X(3), L(1), gtsam.Rot2.fromDegrees(135),
                                    gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    graph.add(gtsam.BetweenFactorPoint2(L(1), L(2), gtsam.Point2(2.0, 0.0),
                                       gtsam.noiseModel.Isotropic.Sigma(2, 0.1)))
    graph.add(gtsam.BearingRangeFactor2D(X(2), L(2), gtsam.Rot2.fromDegrees(45), np.sqrt(8),
                                         robust))
    run = staged_initialize(graph, values)
    assert run.certificate.outside == ("BearingFactor2D x 1", "BetweenFactorPoint2 x 1",
                                       "BearingRangeFactor2D x 1")
    assert not run.certified
    assert chi2_of(graph, run.values) <= chi2_of(graph, lm_values(graph, values)) * (1 + 1e-6)


@pytest.mark.parametrize("group", [SE2, SE3])
def test_rlpgo_init_on_a_landmark_file_writes_the_landmarks_back(tmp_path, group):
    from click.testing import CliRunner
    from rlpgo_cli.init import main as init_main

    from rlpgo_gtsam import read_g2o, write_g2o

    sample = _landmark_graph(group, n=60, count=20, seed=4)
    path, output = tmp_path / "in.g2o", tmp_path / "out.g2o"
    write_g2o(path, sample.graph, sample.initial)
    done = CliRunner().invoke(init_main, [str(path), "-o", str(output)])
    assert done.exit_code == 0, done.output
    assert f"with {sample.num_landmarks} landmarks inside" in done.output
    graph, values = read_g2o(output)
    assert values.size() == sample.initial.size()
    read_graph, _ = read_g2o(path)
    ours = chi2_of(read_graph, values)
    assert ours <= chi2_of(read_graph, lm_values(read_graph, sample.initial)) * (1 + 1e-4)
