"""Wrong loop closures: the generator's outliers and the robust initializer, on generated graphs."""

from __future__ import annotations

import hashlib

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam.errors import RlpgoError, SolverError
from rlpgo_gtsam.g2o import g2o_text
from rlpgo_gtsam.graph import PoseGraph2D, chi2, edge_chi2
from rlpgo_gtsam.initializers import make_initializer
from rlpgo_gtsam.residuals import outlier_suspicion
from rlpgo_gtsam.robust import robust_initialize
from rlpgo_gtsam.solvers import refine
from rlpgo_gtsam.staged import staged_initialize
from rlpgo_gtsam.synthetic import add_outliers, generate

# A 300-pose lawn mower with noisy measurements: rotation noise 0.1 rad per measurement.
ARGS = (300, 0.1, 0.05, 1.0, 0.5)

# sha256 of g2o_text(graph, initial) + g2o_text(graph, ground_truth) and the rng's next draw,
# produced by the generator before wrong closures existed (commit b6aa194).
BEFORE = [
    ((20, 0.3, 0.01, 3.0, 0.5), 0, False,
     "90ae9da3dcf556c92e2d3ee304cdee5b92aebcac5678f3ca334893c7d2826b6b", 0.0907530456191219),
    ((300, 0.2, 0.1495, 1.0, 0.5), 1, True,
     "d9dbee78d8a8862bccf88a31d952d7b32d5793d7a25512050734490d65e16c84", 0.6470071622065572),
]


def _digest(sample) -> str:
    text = g2o_text(sample.graph, sample.initial) + g2o_text(sample.graph, sample.ground_truth)
    return hashlib.sha256(text.encode()).hexdigest()


@pytest.mark.parametrize(("args", "seed", "noisy", "digest", "next_draw"), BEFORE)
def test_outlier_free_output_is_unchanged(args, seed, noisy, digest, next_draw):
    rng = np.random.default_rng(seed)
    sample = generate(*args, rng, noisy_measurements=noisy, outliers=0.0)
    assert _digest(sample) == digest
    assert rng.random() == next_draw  # nothing more was drawn
    assert sample.outlier_edges == []


def test_wrong_closures_come_after_the_same_graph():
    clean = generate(*ARGS, np.random.default_rng(4), noisy_measurements=True)
    for mode in ("random", "plausible"):
        sample = generate(*ARGS, np.random.default_rng(4), noisy_measurements=True,
                          outliers=0.1, outlier_mode=mode)
        m = clean.graph.size()
        assert sample.outlier_edges == list(range(m, m + int(0.1 * m)))
        assert sample.initial.equals(clean.initial, 0.0)
        assert sample.ground_truth.equals(clean.ground_truth, 0.0)
        g = PoseGraph2D.from_gtsam(sample.graph, sample.ground_truth)
        g_clean = PoseGraph2D.from_gtsam(clean.graph, clean.ground_truth)
        np.testing.assert_array_equal(g.edges[:m], g_clean.edges)
        np.testing.assert_array_equal(g.measured[:m], g_clean.measured)
        pairs = {tuple(sorted(p)) for p in g.edges[:m].tolist()}
        wrong = g.edges[m:]
        assert np.all(np.abs(wrong[:, 1] - wrong[:, 0]) > 1)
        assert not pairs & {tuple(sorted(p)) for p in wrong.tolist()}
        assert len({tuple(sorted(p)) for p in wrong.tolist()}) == len(wrong)
        # every wrong closure really is wrong: far off at the ground truth
        assert edge_chi2(g, g.poses)[m:].min() > 100.0


def test_add_outliers_leaves_its_input_alone_and_checks_arguments():
    sample = generate(*ARGS, np.random.default_rng(4), noisy_measurements=True)
    size = sample.graph.size()
    graph, indices = add_outliers(sample.graph, sample.ground_truth, 0.2,
                                  np.random.default_rng(0), "plausible")
    assert sample.graph.size() == size and graph.size() == size + len(indices)
    with pytest.raises(RlpgoError, match="fraction"):
        add_outliers(sample.graph, sample.ground_truth, 1.0, np.random.default_rng(0))
    with pytest.raises(RlpgoError, match="unknown outlier mode"):
        generate(*ARGS, np.random.default_rng(0), outliers=0.1, outlier_mode="sneaky")


@pytest.mark.parametrize("mode", ["random", "plausible"])
def test_wrong_closures_are_rejected_and_the_map_recovered(mode):
    sample = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True, outliers=0.2,
                      outlier_mode=mode)
    clean = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True)
    lowest = refine(clean.graph, clean.ground_truth, "lm", 100).chi2

    result = robust_initialize(sample.graph, sample.initial)

    assert result.rejected == sample.outlier_edges
    assert np.all(result.weights[sample.outlier_edges] == 0.0)
    assert chi2(clean.graph, result.values) == pytest.approx(lowest, rel=1e-6)
    assert result.chi2 == pytest.approx(lowest, rel=1e-6)
    assert [step["step"] for step in result.steps] == ["consistency", "start", "verify", "gnc"]


def test_a_clean_graph_comes_out_as_the_staged_default_leaves_it():
    clean = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True)
    robust = robust_initialize(clean.graph, clean.initial)
    staged = staged_initialize(clean.graph, clean.initial)
    converged = refine(clean.graph, staged.values, "lm", 100).chi2
    assert robust.rejected == []
    assert robust.chi2 == pytest.approx(converged, rel=1e-6)


def test_without_trusted_odometry_the_same_closures_go():
    sample = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True, outliers=0.1)
    result = robust_initialize(sample.graph, sample.initial, trust_odometry=False)
    assert result.rejected == sample.outlier_edges
    assert result.trusted == []


def test_bad_parameters_are_one_line_errors():
    sample = generate(20, 0.1, 0.05, 1.0, 0.5, np.random.default_rng(0))
    with pytest.raises(SolverError, match="inlier_probability"):
        robust_initialize(sample.graph, sample.initial, inlier_probability=1.0)


def test_edge_chi2_is_gtsams():
    sample = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True, outliers=0.1)
    g = PoseGraph2D.from_gtsam(sample.graph, sample.initial)
    ours = edge_chi2(g, g.poses)
    theirs = [2.0 * sample.graph.at(k).error(sample.initial) for k in range(sample.graph.size())
              if isinstance(sample.graph.at(k), gtsam.BetweenFactorPose2)]
    np.testing.assert_allclose(ours, theirs, rtol=1e-9, atol=1e-9)


def test_outlier_suspicion_points_to_robust_only_when_the_tail_is_heavy():
    clean = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True)
    sample = generate(*ARGS, np.random.default_rng(3), noisy_measurements=True, outliers=0.05)
    for graph, expect in ((clean.graph, None), (sample.graph, "--robust")):
        g = PoseGraph2D.from_gtsam(graph, clean.initial)
        start = make_initializer("chordal").run(g).values
        hint = outlier_suspicion(g, refine(graph, start, "lm", 100, pose_graph=g).values)
        if expect is None:
            assert hint is None
        else:
            assert hint is not None and expect in hint and "\n" not in hint


def test_heavy_rotation_noise_keeps_the_true_closures():
    # 0.2 rad per measurement: the chain alone bends by radians over a few rows. Scored
    # with crude cycle covariances, half the true closures found no informative support,
    # and the thinned seed's optimum was a folded map (chi2 87517 on the clean graph
    # against 1376.45); the propagated covariances keep them.
    args = (1000, 0.2, 0.05, 1.0, 0.5)
    sample = generate(*args, np.random.default_rng(7), noisy_measurements=True, outliers=0.1)
    clean = generate(*args, np.random.default_rng(7), noisy_measurements=True)
    lowest = refine(clean.graph, clean.ground_truth, "lm", 1000).chi2

    result = robust_initialize(sample.graph, sample.initial)

    assert result.rejected == sample.outlier_edges
    assert chi2(clean.graph, result.values) == pytest.approx(lowest, rel=1e-6)
