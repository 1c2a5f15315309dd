"""The 3D generator (the lawn mower in layers), its wrong loop closures by Vertigo's policies,
and rlpgo-generate --dim 3; the 2D output pinned byte for byte."""

from __future__ import annotations

import hashlib

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.generate import main

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph3D, chi2, edge_chi2
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.initializers import make_initializer
from rlpgo_gtsam.io import g2o_text, read_g2o
from rlpgo_gtsam.se3 import between, rotation_angles
from rlpgo_gtsam.synthetic import LOCAL_RANGE, OUTLIER_MODES, add_outliers, generate
from tests.conftest import cli_error, cli_ok

# n, sigma_r (rad), sigma_t (m), d (m), lc
ARGS = (300, 0.05, 0.1, 2.0, 0.5)


def _relative(g: PoseGraph3D, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
    """Every pose in the frame of pose 0: the poses with the gauge taken out."""
    poses = g.poses_of(values)
    r, t = poses[:, :, :3], poses[:, :, 3]
    return between(np.repeat(r[:1], len(r), 0), np.repeat(t[:1], len(t), 0), r, t)


def test_the_path_fills_layers_and_closes_loops_to_its_lattice_neighbours():
    sample = generate(1000, *ARGS[1:], np.random.default_rng(0), group=SE3)
    g = PoseGraph3D.from_gtsam(sample.graph, sample.ground_truth)
    cells = g.translations / 2.0
    np.testing.assert_allclose(cells, np.round(cells), atol=1e-12)
    assert np.ptp(cells, axis=0).tolist() == [9, 9, 9]  # a 10 x 10 x 10 cube, 10 layers
    assert len({tuple(c) for c in np.round(cells).astype(int).tolist()}) == 1000
    # 999 odometry edges, then int(0.5 x 1701) closures, each between lattice neighbours
    assert g.num_edges == 999 + 850
    steps = np.linalg.norm(g.translations[g.edges[:, 1]] - g.translations[g.edges[:, 0]], axis=1)
    np.testing.assert_allclose(steps, 2.0)
    np.testing.assert_array_equal(g.edges[:999], np.arange(999)[:, None] + [0, 1])
    assert np.all(np.abs(g.edges[999:, 0] - g.edges[999:, 1]) > 1)
    # each pose faces its next motion: its x axis points at the next pose
    heading = g.rotations[:-1, :, 0]
    np.testing.assert_allclose(heading, np.diff(g.translations, axis=0) / 2.0, atol=1e-12)


def test_exact_measurements_have_the_truth_as_a_certified_optimum():
    sample = generate(*ARGS, np.random.default_rng(1), group=SE3)
    assert chi2(sample.graph, sample.ground_truth) < 1e-18
    assert chi2(sample.graph, sample.initial) > 1e4  # only the guess is noisy
    g = PoseGraph3D.from_gtsam(sample.graph, sample.initial)
    result = make_initializer("certified").run(g)
    assert result.certificate.certified and result.certificate.rank == 3
    assert result.chi2 < 1e-12
    true_r, true_t = _relative(g, sample.ground_truth)
    found_r, found_t = _relative(g, result.values)
    assert rotation_angles(found_r.transpose(0, 2, 1) @ true_r).max() < 1e-9
    np.testing.assert_allclose(found_t, true_t, atol=1e-9)


def test_noisy_measurements_give_the_truth_the_chi2_of_the_noise():
    sample = generate(*ARGS, np.random.default_rng(2), noisy_measurements=True, group=SE3)
    m = sample.graph.size()
    # each edge's error at the truth is minus its noise vector, whitened: chi2 ~ chi2(6m)
    assert abs(chi2(sample.graph, sample.ground_truth) - 6 * m) < 4 * np.sqrt(12 * m)
    information = sample.graph.at(0).noiseModel().information()  # GTSAM's order
    np.testing.assert_allclose(information, np.diag([400.0] * 3 + [100.0] * 3))


def test_a_seed_gives_one_graph():
    def text(seed: int) -> str:
        sample = generate(120, 0.1, 0.1, 1.0, 0.5, np.random.default_rng(seed),
                          noisy_measurements=True, outliers=0.1, outlier_mode="group",
                          group=SE3)
        return g2o_text(sample.graph, sample.initial) + \
            g2o_text(sample.graph, sample.ground_truth)

    assert text(3) == text(3) != text(4)


@pytest.mark.parametrize("mode", OUTLIER_MODES)
def test_each_policy_places_its_wrong_closures(mode):
    clean = generate(*ARGS, np.random.default_rng(5), noisy_measurements=True, group=SE3)
    sample = generate(*ARGS, np.random.default_rng(5), noisy_measurements=True, outliers=0.1,
                      outlier_mode=mode, group_size=4, group=SE3)
    m = clean.graph.size()
    assert sample.outlier_edges == list(range(m, m + int(0.1 * m)))
    assert sample.initial.equals(clean.initial, 0.0)  # the same graph, closures after it
    g = PoseGraph3D.from_gtsam(sample.graph, sample.ground_truth)
    wrong = g.edges[m:]
    pairs = {tuple(sorted(p)) for p in g.edges[:m].tolist()}
    assert np.all(np.abs(wrong[:, 1] - wrong[:, 0]) > 1)
    assert not pairs & {tuple(sorted(p)) for p in wrong.tolist()}
    assert len({tuple(sorted(p)) for p in wrong.tolist()}) == len(wrong)
    assert np.median(edge_chi2(g, g.poses)[m:]) > 100.0  # wrong at the truth
    measured_r, measured_t = g.measured_rotations[m:], g.measured_translations[m:]
    if "local" in mode:
        assert np.all(np.abs(wrong[:, 1] - wrong[:, 0]) <= LOCAL_RANGE)
    if "group" in mode:  # runs of 4 consecutive pairs (i + k, j + k), one measurement
        for start in range(0, len(wrong), 4):
            run = slice(start, start + 4)
            np.testing.assert_array_equal(wrong[run] - wrong[start],
                                          np.arange(len(wrong[run]))[:, None] * [1, 1])
            assert np.all(measured_r[run] == measured_r[start])
            assert np.all(measured_t[run] == measured_t[start])
    first_closure = np.flatnonzero(np.abs(np.diff(g.edges[:m])) != 1)[0]
    if mode in ("uniform", "plausible"):
        assert any(np.all(g.information[k] == g.information[first_closure]) for k in range(m))
        return
    # Vertigo: a small relative pose with the first loop closure's information
    assert np.all(g.information[m:] == g.information[first_closure])
    assert np.all(np.abs(measured_t) < 1.5) and 0.15 < np.std(measured_t) < 0.45
    assert rotation_angles(measured_r).max() < np.deg2rad(60)


def test_add_outliers_checks_its_arguments_and_leaves_the_graph_alone():
    sample = generate(40, 0.1, 0.1, 1.0, 0.5, np.random.default_rng(0), group=SE3)
    size = sample.graph.size()
    graph, added = add_outliers(sample.graph, sample.ground_truth, 0.2,
                                np.random.default_rng(1), "localgroup", 3)
    assert sample.graph.size() == size and graph.size() == size + len(added) == size + 10
    with pytest.raises(Exception, match="unknown outlier mode 'sneaky'"):
        add_outliers(sample.graph, sample.ground_truth, 0.1, np.random.default_rng(1),
                     "sneaky")


@pytest.mark.parametrize("group", [SE2, SE3])
def test_a_count_of_wrong_closures_may_exceed_the_edges_and_matches_its_fraction(group):
    sample = generate(60, 0.1, 0.1, 1.0, 0.5, np.random.default_rng(0), group=group)
    size = sample.graph.size()

    def text(graph) -> str:
        return g2o_text(graph, sample.ground_truth)

    # the count a fraction gives draws the same graph as that fraction
    by_fraction, added = add_outliers(sample.graph, sample.ground_truth, 0.3,
                                      np.random.default_rng(1), "group")
    by_count, same = add_outliers(sample.graph, sample.ground_truth, None,
                                  np.random.default_rng(1), "group", count=int(0.3 * size))
    assert same == added and text(by_count) == text(by_fraction)
    # 90% of all closures wrong: nine per true closure, more than the graph's edges
    closures = size - 59
    many, wrong = add_outliers(sample.graph, sample.ground_truth, None,
                               np.random.default_rng(1), "localgroup", count=9 * closures)
    assert wrong == list(range(size, size + 9 * closures)) and 9 * closures > size
    assert many.size() == size + 9 * closures and sample.graph.size() == size
    assert add_outliers(sample.graph, sample.ground_truth, None, np.random.default_rng(1),
                        count=0)[1] == []
    for fraction, count, message in [(0.1, 5, "one of them, not both"),
                                     (None, None, "one of them, not both"),
                                     (None, -1, "integer >= 0"), (None, 2.5, "integer >= 0"),
                                     (1.0, None, r"in \[0, 1\)")]:
        with pytest.raises(RlpgoError, match=message):
            add_outliers(sample.graph, sample.ground_truth, fraction,
                         np.random.default_rng(1), count=count)


def test_the_command_writes_3d_files_and_lists_real_edges(tmp_path):
    out, truth, listed = tmp_path / "g.g2o", tmp_path / "gt.g2o", tmp_path / "wrong.txt"
    args = ["--dim", "3", "--n", "200", "--sigma-r", "0.05", "--sigma-t", "0.1", "--d", "2",
            "--noisy-measurements", "--outliers", "0.05", "--outlier-mode", "group",
            "--group-size", "3", "--seed", "4", "-o", str(out), "--ground-truth", str(truth),
            "--outliers-out", str(listed)]
    result = CliRunner().invoke(main, args)
    cli_ok(result)
    graph, initial = read_g2o(out)
    _, ground_truth = read_g2o(truth)
    assert initial.size() == 200 and isinstance(graph.at(0), gtsam.BetweenFactorPose3)
    assert f"ground-truth chi2 {chi2(graph, ground_truth):.6g}" in result.stdout
    text = out.read_text().splitlines()
    rows = listed.read_text().splitlines()
    # 199 odometry edges and int(0.5 x 261) closures (81 in each layer, 99 between them)
    assert rows[0].startswith("# wrong loop closures") and len(rows) == 1 + int(0.05 * 329)
    keys = {tuple(graph.at(k).keys()) for k in range(graph.size())}
    for row in rows[1:]:
        _, line, tag, i, j = row.split()
        assert tag == "EDGE_SE3:QUAT" and text[int(line) - 1].split()[:3] == [tag, i, j]
        assert (int(i), int(j)) in keys
    again = CliRunner().invoke(main, args)
    cli_error(again, f"{out}: exists; give --overwrite to replace it")


# sha256 (first 32 hex digits) of the graph, ground truth and outlier list rlpgo-generate
# writes for these arguments: the planar output is pinned, so that a change made for 3D to the
# shared generator cannot move it.
PLANAR = [
    (["--n", "120", "--seed", "3", "--noisy-measurements", "--outliers", "0.1",
      "--outlier-mode", "localgroup", "--group-size", "4"],
     ["65cecc3f3213668161dcbe5585684935", "4d5820e26747ad7a0bcaf7f0c0d1723b",
      "45848bda915e3aa5ea2249e71360e89a"]),
    (["--n", "120", "--seed", "5", "--noisy-measurements", "--outliers", "0.08",
      "--outlier-mode", "plausible"],
     ["97f8acdb0b1533249144d1c2cc4efff8", "c7f57794d58a4c6575fa3872fb3d00c1",
      "294113e393c349145a146c35f205495c"]),
    (["--n", "57", "--seed", "2", "--lc", "0.8", "--sigma-r", "0.1", "--sigma-t", "0.2",
      "--d", "1.5"],
     ["b88cc5d147566408b88f67dc9cd981a2", "e051a60fc89cc59944597c8cb877e7c1",
      "bd64cd5f9cc22637b4cbfe3bbe50654c"]),
]


@pytest.mark.parametrize(("args", "digests"), PLANAR)
def test_planar_output_is_pinned_byte_for_byte(tmp_path, args, digests):
    files = [tmp_path / name for name in ("g.g2o", "gt.g2o", "wrong.txt")]
    cli_ok(CliRunner().invoke(main, [*args, "-o", str(files[0]),
                                                     "--ground-truth", str(files[1]),
                                                     "--outliers-out", str(files[2])]))
    assert [hashlib.sha256(f.read_bytes()).hexdigest()[:32] for f in files] == digests
