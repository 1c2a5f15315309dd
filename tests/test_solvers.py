import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import GraphError, SolverError, chi2, make_initializer, read_g2o, refine
from tests.conftest import dataset


def test_lm30_from_m3500_vertices_matches_gtsam_reference():
    graph, values = read_g2o(dataset("M3500.g2o"))
    result = refine(graph, values, "lm", 30)
    assert result.chi2 == pytest.approx(137.9, rel=0.01)
    assert result.failure is None
    assert result.chi2_trace[0] == pytest.approx(chi2(graph, values))
    assert len(result.chi2_trace) == result.iterations + 1
    assert result.chi2 == pytest.approx(chi2(graph, result.values))


def test_gn_iteration_cap_is_respected(small_exact):
    start = make_initializer("chordal").initialize(small_exact.graph, small_exact.initial)
    result = refine(small_exact.graph, start, "gn", 3)
    assert result.iterations <= 3
    assert result.chi2 < result.chi2_trace[0]


@pytest.mark.parametrize("solver", ["lm", "gn"])
def test_each_iteration_is_told_with_its_chi2_and_changes_nothing(small_noisy, solver):
    """``on_iteration`` (progress lines of a long refinement) is told each iteration once,
    with its chi2; the result is the same without it."""
    seen: list[tuple[int, float]] = []
    told = refine(small_noisy.graph, small_noisy.initial, solver, 10,
                  on_iteration=lambda k, value: seen.append((k, value)))
    plain = refine(small_noisy.graph, small_noisy.initial, solver, 10)
    assert told.iterations >= 2 and [k for k, _ in seen] == list(range(1, told.iterations + 1))
    assert seen[-1][1] == told.chi2
    assert (told.chi2_trace, told.chi2) == (plain.chi2_trace, plain.chi2)


def test_refine_keeps_the_anchor_pose(small_noisy):
    result = refine(small_noisy.graph, small_noisy.initial, "lm", 10)
    before, after = small_noisy.initial.atPose2(0), result.values.atPose2(0)
    assert np.allclose([after.x(), after.y(), after.theta()],
                       [before.x(), before.y(), before.theta()], atol=1e-6)


def test_zero_iterations_returns_the_start(small_noisy):
    result = refine(small_noisy.graph, small_noisy.initial, "lm", 0)
    assert result.iterations == 0
    assert result.chi2 == pytest.approx(chi2(small_noisy.graph, small_noisy.initial))


def test_unknown_solver_is_an_error(small_noisy):
    with pytest.raises(SolverError, match="unknown solver 'dogleg'"):
        refine(small_noisy.graph, small_noisy.initial, "dogleg", 10)


def test_non_finite_start_is_reported_not_raised(small_noisy):
    values = gtsam.Values(small_noisy.initial)
    values.update(5, gtsam.Pose2(1e300, -1e300, 0.0))
    result = refine(small_noisy.graph, values, "gn", 5)
    assert result.failure is not None


def _degenerate_graph():
    """A chain whose middle edge has information 1e-30: GTSAM would find the system
    indeterminate."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for key in range(4):
        values.insert(key, gtsam.Pose2(float(key), 0.0, 0.0))
    for key in range(3):
        information = np.eye(3) * (1e-30 if key == 1 else 1.0)
        graph.add(gtsam.BetweenFactorPose2(key, key + 1, gtsam.Pose2(1.0, 0.0, 0.1),
                                           gtsam.noiseModel.Gaussian.Information(information)))
    return graph, values


def test_information_no_method_can_use_is_refused_naming_the_factor():
    from rlpgo_gtsam.ranking import compare_methods

    graph, values = _degenerate_graph()
    for call in (lambda: refine(graph, values, "gn", 10),
                 lambda: compare_methods(graph, values, ["odometry", "chordal"], "gn", 10)):
        with pytest.raises(GraphError, match=r"^between factor 1-2: information matrix has "
                           r"eigenvalues 1e-30 \.\. 1e-30, outside the usable"):
            call()


def test_a_soft_prior_on_a_non_anchor_pose_is_honoured_as_gtsam_does(small_noisy):
    graph = gtsam.NonlinearFactorGraph(small_noisy.graph)
    graph.add(gtsam.PriorFactorPose2(0, small_noisy.initial.atPose2(0),
                                     gtsam.noiseModel.Isotropic.Sigma(3, 0.01)))
    graph.add(gtsam.PriorFactorPose2(2, gtsam.Pose2(5.0, -3.0, 0.4),
                                     gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    ours = refine(graph, small_noisy.initial, params)
    theirs = gtsam.LevenbergMarquardtOptimizer(graph, small_noisy.initial, params).optimize()
    assert ours.chi2 == pytest.approx(2.0 * graph.error(theirs), rel=1e-9)
    plain = refine(small_noisy.graph, small_noisy.initial, params)
    assert abs(ours.chi2 - plain.chi2) > 1.0  # the prior changed the result
    assert params.iterationHook is None  # the caller's params come back unchanged


def test_fixed_poses_are_held_by_initializers_and_refinement(tmp_path, small_noisy):
    from rlpgo_gtsam import write_g2o

    path = tmp_path / "fixed.g2o"
    write_g2o(path, small_noisy.graph, small_noisy.initial)
    path.write_text(path.read_text() + "FIX 0 5\n")
    graph, values = read_g2o(path)
    held = values.atPose2(5)
    for method in ("chordal", "lago", "odometry"):
        guess = make_initializer(method).initialize(graph, values)
        result = refine(graph, guess, "lm", 30)
        for poses in (guess, result.values):
            assert poses.atPose2(5).equals(held, 1e-6), method
        assert result.chi2 == pytest.approx(chi2(graph, result.values))


def test_robust_models_and_missing_keys_are_typed_errors(small_noisy):
    from rlpgo_gtsam import GraphError

    robust = gtsam.NonlinearFactorGraph(small_noisy.graph)
    huber = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0),
                                           gtsam.noiseModel.Unit.Create(3))
    robust.add(gtsam.BetweenFactorPose2(0, 7, gtsam.Pose2(), huber))
    with pytest.raises(GraphError, match="between factor 0-7 has a Robust noise model"):
        refine(robust, small_noisy.initial)
    missing = gtsam.NonlinearFactorGraph(small_noisy.graph)
    missing.add(gtsam.PriorFactorPose2(999, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    with pytest.raises(GraphError, match="prior factor on key 999: the key has no value"):
        make_initializer("chordal").initialize(missing, small_noisy.initial)
    with pytest.raises(GraphError, match="key \"999\""):
        chi2(missing, small_noisy.initial)


def test_the_gauge_prior_goes_only_where_the_graph_has_no_prior(small_noisy):
    """refine reads from the extraction that a graph of edges alone has no prior, and walks
    the factors otherwise: a soft prior added to the graph is honoured even when the
    extraction handed in is the plain graph's (another graph)."""
    from rlpgo_gtsam.graph import extract_pose_graph

    plain = extract_pose_graph(small_noisy.graph, small_noisy.initial)
    graph = gtsam.NonlinearFactorGraph(small_noisy.graph)
    graph.add(gtsam.PriorFactorPose2(2, gtsam.Pose2(5.0, -3.0, 0.4),
                                     gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    theirs = gtsam.LevenbergMarquardtOptimizer(graph, small_noisy.initial, params).optimize()
    for pose_graph in (None, plain, extract_pose_graph(graph, small_noisy.initial)):
        ours = refine(graph, small_noisy.initial, params, pose_graph=pose_graph)
        assert ours.chi2 == pytest.approx(2.0 * graph.error(theirs), rel=1e-9)
    anchored = gtsam.NonlinearFactorGraph(small_noisy.graph)  # the gauge prior, by hand
    anchored.add(gtsam.PriorFactorPose2(0, small_noisy.initial.atPose2(0),
                                        gtsam.noiseModel.Isotropic.Sigma(3, 1e-8)))
    gauged = gtsam.LevenbergMarquardtOptimizer(anchored, small_noisy.initial, params).optimize()
    ours = refine(small_noisy.graph, small_noisy.initial, params, pose_graph=plain)
    assert ours.values.equals(gauged, 1e-9)


def test_an_elimination_runs_where_the_stack_holds_it_and_hands_back_what_it_gives(
        small_noisy):
    """What :func:`eliminating_call` promises a caller: a graph the main thread's stack
    holds is eliminated in place; a deeper one on a thread of its own, and a call from
    inside that thread in place; the function's result or its very exception; the
    process-wide default stack size left as it was. (Its purpose, a tree deeper than the
    stack, is tested under a small stack in tests/test_hostile.py.)"""
    import threading

    from rlpgo_gtsam import extract_pose_graph
    from rlpgo_gtsam.numerics import eliminating_call, elimination_stack_bytes

    here = threading.current_thread()
    assert here is threading.main_thread()
    before = threading.stack_size()
    assert eliminating_call(10_000, threading.current_thread) is here  # City10K's poses
    outer = eliminating_call(10**7, lambda: (
        threading.current_thread(), eliminating_call(10, threading.current_thread)))
    assert outer[0] is not here and outer[1] is outer[0]
    assert threading.stack_size() == before
    assert elimination_stack_bytes(10**6) >= 200 * 10**6  # 80-100 bytes a tree level
    with pytest.raises(SolverError, match="inside"):
        eliminating_call(10**7, lambda: (_ for _ in ()).throw(SolverError("inside")))
    # an indeterminate system raised on that thread is still the refinement's failure
    graph = gtsam.NonlinearFactorGraph(small_noisy.graph)
    values = gtsam.Values(small_noisy.initial)
    values.insert(10**6, gtsam.Pose2())

    def flat(_factor, _values, jacobians):  # a residual that no step can change
        if jacobians is not None:
            jacobians[0] = np.zeros((3, 3))
        return np.zeros(3)

    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [10**6], flat))
    result = refine(graph, values, "gn", 5, has_prior=False,
                    pose_graph=extract_pose_graph(small_noisy.graph, small_noisy.initial))
    assert result.failure is not None and "Indeterminate linear system" in result.failure
