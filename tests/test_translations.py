import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import PoseGraph2D, chi2, read_g2o, solve_translations
from tests.conftest import dataset


def _poses(values: gtsam.Values) -> np.ndarray:
    return np.array(
        [[p.x(), p.y(), p.theta()] for p in (values.atPose2(k) for k in sorted(values.keys()))]
    )


def test_exact_orientations_recover_ground_truth(small_exact):
    graph = PoseGraph2D.from_gtsam(small_exact.graph, small_exact.initial)
    truth = _poses(small_exact.ground_truth)
    positions = solve_translations(graph, truth[:, 2])
    assert np.abs(positions - truth[:, :2]).max() < 1e-9


def test_paper_graph_ground_truth_recovered_from_its_orientations():
    graph, values = read_g2o(dataset("paper_sigma_t_sweep/sigma_t_0.1.g2o"))
    _, truth_values = read_g2o(dataset("paper_sigma_t_sweep/sigma_t_0.1.gt.g2o"))
    truth = _poses(truth_values)
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    positions = solve_translations(pose_graph, truth[:, 2])
    solved = pose_graph.to_values(np.column_stack([positions, truth[:, 2]]))
    # The published ground truth is rounded to 6 digits: its own cost is the floor here.
    assert chi2(graph, solved) <= chi2(graph, truth_values) + 1e-9


def test_correlated_information_is_used(small_noisy):
    """With xy-correlated information the solve must beat the one that drops correlations."""
    graph = gtsam.NonlinearFactorGraph()
    rng = np.random.default_rng(3)
    for index in range(small_noisy.graph.size()):
        factor = small_noisy.graph.at(index)
        information = np.diag([400.0, 25.0, 25.0])
        information[0, 1] = information[1, 0] = 80.0 * rng.choice([-1, 1])
        graph.add(
            gtsam.BetweenFactorPose2(
                *factor.keys(),
                factor.measured(),
                gtsam.noiseModel.Gaussian.Information(information),
            )
        )
    pose_graph = PoseGraph2D.from_gtsam(graph, small_noisy.initial)
    theta = _poses(small_noisy.ground_truth)[:, 2]
    full = pose_graph.to_values(np.column_stack([solve_translations(pose_graph, theta), theta]))
    diagonal_only = PoseGraph2D(
        keys=pose_graph.keys,
        poses=pose_graph.poses,
        edges=pose_graph.edges,
        measured=pose_graph.measured,
        information=pose_graph.information * np.eye(3),
        anchor=pose_graph.anchor,
    )
    dropped = pose_graph.to_values(
        np.column_stack([solve_translations(diagonal_only, theta), theta])
    )
    assert chi2(graph, full) < chi2(graph, dropped)


def test_translation_step_chi2_is_gtsams_chi2_of_the_translation_step(small_noisy):
    """The real-cost reward's chi2 (scipy, cached pattern) is GTSAM's chi2 of
    poses_with_rotations, to rounding, away from the optimum and near it."""
    from rlpgo_gtsam import poses_with_rotations
    from rlpgo_gtsam.translations import TranslationStep

    graph = PoseGraph2D.from_gtsam(small_noisy.graph, small_noisy.initial)
    step = TranslationStep(graph)
    rng = np.random.default_rng(0)
    truth = _poses(small_noisy.ground_truth)[:, 2]
    for theta in (graph.poses[:, 2], truth + rng.normal(0.0, 0.3, graph.num_poses), truth):
        poses = poses_with_rotations(graph, theta)
        expected = chi2(graph.graph, graph.to_values(poses))
        assert step.chi2(theta) == pytest.approx(expected, rel=1e-10)
        assert np.abs(step.positions(theta) - poses[:, :2]).max() < 1e-8


def _fresh_positions(pose_graph: PoseGraph2D, theta: np.ndarray) -> np.ndarray:
    """The translation step with a system of its own (nothing kept between calls)."""
    from rlpgo_gtsam.translations import TranslationStep

    return TranslationStep(pose_graph).positions(theta, gauge=False)


def test_a_graph_keeps_one_factorization_for_isotropic_translation_information():
    """M3500's translation information is isotropic: the normal matrix does not depend on
    the orientations, and every translation step on the graph after the first solves with
    the first one's factorization. The positions are those of a fresh solve (to rounding),
    for orientations far from the first ones as well."""
    from rlpgo_gtsam import linear
    from rlpgo_gtsam.translations import TranslationStep

    graph, values = read_g2o(dataset("M3500.g2o"))
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    factorized = []
    original = linear._factorize
    linear._factorize = lambda *args, **kw: factorized.append(1) or original(*args, **kw)
    try:
        rng = np.random.default_rng(4)
        thetas = [pose_graph.poses[:, 2], rng.uniform(-np.pi, np.pi, pose_graph.num_poses)]
        shared = [solve_translations(pose_graph, theta) for theta in thetas]
        assert len(factorized) == 1
    finally:
        linear._factorize = original
    assert TranslationStep.shared(pose_graph).system.fixed_matrix
    for theta, positions in zip(thetas, shared, strict=True):
        fresh = _fresh_positions(pose_graph, theta)
        assert np.abs(positions - fresh).max() <= 1e-9 * max(1.0, np.abs(fresh).max())


def test_anisotropic_translation_information_keeps_no_factorization():
    """Intel's translation information is not isotropic: the matrix turns with the
    orientations, so each step factorizes its own and matches a fresh solve (to the
    rounding of the kept ordering: random orientations make this system ill-conditioned)."""
    from rlpgo_gtsam.translations import TranslationStep

    graph, values = read_g2o(dataset("Intel.g2o"))
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    theta = np.random.default_rng(5).uniform(-np.pi, np.pi, pose_graph.num_poses)
    solve_translations(pose_graph, pose_graph.poses[:, 2])
    assert not TranslationStep.shared(pose_graph).system.fixed_matrix
    fresh = _fresh_positions(pose_graph, theta)
    assert np.abs(solve_translations(pose_graph, theta) - fresh).max() <= 1e-6 * np.abs(fresh).max()


def test_the_chordal_rotations_a_graph_keeps_are_handed_out_as_copies():
    from rlpgo_gtsam.chordal import chordal_rotations

    graph, values = read_g2o(dataset("M3500.g2o"))
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    first = chordal_rotations(pose_graph)
    first[:] = 0.0
    second = chordal_rotations(pose_graph)
    assert np.abs(second).max() > 0.1
    assert np.array_equal(second, chordal_rotations(pose_graph))
