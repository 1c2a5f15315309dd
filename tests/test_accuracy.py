"""Trajectory errors against ground truth: the same figures as evo's APE and RPE, on generated
planar and 3D graphs (exact, noisy, refined); what a ground truth needs (a pose for each of the
estimate's keys, nothing else); and the compare command's APE/RPE columns."""

from __future__ import annotations

import json

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.generate import main as generate_main

from rlpgo_gtsam import (
    G2oFormatError,
    GraphError,
    TrajectoryErrors,
    generate,
    refine,
    trajectory_errors,
    write_g2o,
)
from rlpgo_gtsam.accuracy import check_ground_truth
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.io import read_poses

RELATIVE = 1e-6


def _graphs():
    """(name, estimate, ground truth) of generated graphs: the exact-measurement graph's noisy
    guess, a noisy-measurement graph's guess, and that guess after LM; all near enough to
    their truth that evo's alignment keeps them upright (see the mirror test)."""
    exact = generate(40, 0.05, 0.05, 3.0, 0.5, np.random.default_rng(3))
    noisy = generate(50, 0.1, 0.1, 2.0, 0.5, np.random.default_rng(4), noisy_measurements=True)
    refined = refine(noisy.graph, noisy.initial, "lm", 20).values
    return [("exact", exact.initial, exact.ground_truth),
            ("noisy", noisy.initial, noisy.ground_truth),
            ("noisy + LM", refined, noisy.ground_truth)]


GRAPHS = _graphs()


def _graphs_3d():
    """(name, estimate, ground truth) of generated 3D graphs (the lawn mower in layers):
    a noisy guess, and a noisy-measurement graph's guess after LM."""
    exact = generate(60, 0.05, 0.05, 3.0, 0.5, np.random.default_rng(5), group=SE3)
    noisy = generate(60, 0.1, 0.1, 2.0, 0.5, np.random.default_rng(6), noisy_measurements=True,
                     group=SE3)
    refined = refine(noisy.graph, noisy.initial, "lm", 20).values
    return [("3D exact", exact.initial, exact.ground_truth),
            ("3D noisy + LM", refined, noisy.ground_truth)]


GRAPHS_3D = _graphs_3d()


def _is_3d(values: gtsam.Values) -> bool:
    try:
        values.atPose3(values.keys()[0])
    except RuntimeError:
        return False
    return True


def _evo_trajectory(values: gtsam.Values, keys: list[int]):
    """An evo PoseTrajectory3D of the Pose2 values at ``keys``: z = 0, a rotation about z,
    timestamps the key index."""
    from evo.core.trajectory import PoseTrajectory3D

    poses = [values.atPose2(key) for key in keys]
    xyz = np.array([[p.x(), p.y(), 0.0] for p in poses])
    half = np.array([p.theta() / 2 for p in poses])
    wxyz = np.column_stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), np.sin(half)])
    return PoseTrajectory3D(xyz, wxyz, np.arange(len(keys), dtype=float))


def _evo_trajectory_3d(values: gtsam.Values, keys: list[int]):
    """An evo PoseTrajectory3D of the Pose3 values at ``keys``, timestamps the key index."""
    from evo.core.trajectory import PoseTrajectory3D

    poses = [values.atPose3(key) for key in keys]
    xyz = np.array([p.translation() for p in poses])
    quaternions = [p.rotation().toQuaternion() for p in poses]
    wxyz = np.array([[q.w(), q.x(), q.y(), q.z()] for q in quaternions])
    return PoseTrajectory3D(xyz, wxyz, np.arange(len(keys), dtype=float))


def _evo_errors(estimate: gtsam.Values, truth: gtsam.Values,
                delta: int = 1) -> tuple[dict[str, float], bool]:
    """evo's own figures: APE (translation part) after its Umeyama SE(3) alignment, RPE
    (translation part and rotation angle in degrees) over consecutive pairs ``delta`` frames
    apart; and whether the alignment kept the estimate upright (z up)."""
    from evo.core import metrics

    keys = sorted(estimate.keys())
    trajectory = _evo_trajectory_3d if _is_3d(estimate) else _evo_trajectory
    reference, estimated = trajectory(truth, keys), trajectory(estimate, keys)
    rotation, _, _ = estimated.align(reference, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimated))
    figures = {f"ape_{name}_m": ape.get_statistic(getattr(metrics.StatisticsType, name))
               for name in ("rmse", "mean", "median", "max")}
    for relation, name in [(metrics.PoseRelation.translation_part, "rpe_rmse_m"),
                           (metrics.PoseRelation.rotation_angle_deg, "rpe_rmse_deg")]:
        rpe = metrics.RPE(relation, delta=delta, delta_unit=metrics.Unit.frames, all_pairs=False)
        rpe.process_data((reference, estimated))
        figures[name] = rpe.get_statistic(metrics.StatisticsType.rmse)
    return figures, bool(rotation[2, 2] > 0)


@pytest.mark.parametrize("delta", [1, 7])
@pytest.mark.parametrize("name, estimate, truth", GRAPHS + GRAPHS_3D,
                         ids=[g[0] for g in GRAPHS + GRAPHS_3D])
def test_the_figures_are_evos(name, estimate, truth, delta):
    pytest.importorskip("evo")
    ours = trajectory_errors(estimate, truth, rpe_delta=delta)
    theirs, upright = _evo_errors(estimate, truth, delta)
    assert upright
    for field, value in theirs.items():
        assert getattr(ours, field) == pytest.approx(value, rel=RELATIVE), field
    assert ours.ape_rmse_m > 0.01 and ours.rpe_rmse_deg > 0.1  # the cases are not trivial
    assert ours.poses == len(estimate.keys()) and ours.aligned and ours.rpe_delta == delta


def test_refinement_lowers_the_error():
    (_, initial, truth), (_, refined, _) = GRAPHS[1:]
    assert trajectory_errors(refined, truth).ape_rmse_m < trajectory_errors(initial,
                                                                            truth).ape_rmse_m


@pytest.mark.parametrize("align", [True, False])
def test_the_ground_truth_has_no_error(align):
    _, _, truth = GRAPHS[0]
    errors = trajectory_errors(truth, truth, align=align)
    assert errors.ape_max_m < 1e-12 and errors.rpe_rmse_m < 1e-12 and errors.rpe_rmse_deg < 1e-9


def test_a_rigid_motion_of_the_estimate_changes_nothing_when_aligned():
    _, estimate, truth = GRAPHS[1]
    motion = gtsam.Pose2(40.0, -7.0, 2.5)
    moved = gtsam.Values()
    for key in estimate.keys():
        moved.insert(key, motion.compose(estimate.atPose2(key)))
    before, after = trajectory_errors(estimate, truth), trajectory_errors(moved, truth)
    for field, value in before.record().items():
        assert getattr(after, field) == pytest.approx(value, rel=1e-9, abs=1e-12), field
    unaligned = trajectory_errors(moved, truth, align=False)
    assert unaligned.ape_rmse_m > 10 * before.ape_rmse_m  # the motion shows without alignment
    assert unaligned.rpe_rmse_m == pytest.approx(before.rpe_rmse_m, rel=1e-9)


def test_a_mirror_image_is_not_folded_back():
    """The one difference from evo: its SE(3) alignment may turn a planar estimate upside
    down (a half turn about an axis in the plane) when the estimate's mirror image fits the
    truth better; a planar motion cannot, so the APE keeps the error. RPE never aligns."""
    pytest.importorskip("evo")
    _, _, truth = GRAPHS[0]
    mirrored = gtsam.Values()
    for key in truth.keys():
        pose = truth.atPose2(key)
        mirrored.insert(key, gtsam.Pose2(pose.x(), -pose.y(), -pose.theta()))
    theirs, upright = _evo_errors(mirrored, truth)
    ours = trajectory_errors(mirrored, truth)
    assert not upright and theirs["ape_rmse_m"] < 1e-9 < 1.0 < ours.ape_rmse_m
    assert ours.rpe_rmse_deg == pytest.approx(theirs["rpe_rmse_deg"], rel=RELATIVE)
    # ours is the best planar fit: no rotation on a 0.1-degree grid (each with its best
    # translation) brings the mirror closer
    keys = sorted(truth.keys())
    a = np.array([[p.x(), p.y()] for p in map(mirrored.atPose2, keys)])
    b = np.array([[p.x(), p.y()] for p in map(truth.atPose2, keys)])
    a, b = a - a.mean(axis=0), b - b.mean(axis=0)
    turns = np.radians(np.arange(0.0, 360.0, 0.1))
    c, s = np.cos(turns)[:, None], np.sin(turns)[:, None]
    grid = np.sqrt(((c * a[:, 0] - s * a[:, 1] - b[:, 0]) ** 2
                    + (s * a[:, 0] + c * a[:, 1] - b[:, 1]) ** 2).mean(axis=1))
    assert ours.ape_rmse_m <= grid.min() * (1 + 1e-12)
    assert grid.min() == pytest.approx(ours.ape_rmse_m, rel=1e-5)


def test_a_key_missing_from_the_ground_truth_is_named():
    _, estimate, truth = GRAPHS[0]
    partial = gtsam.Values()
    for key in sorted(truth.keys())[:-3]:
        partial.insert(key, truth.atPose2(key))
    with pytest.raises(GraphError, match="key 37 of the estimate has no pose in the ground"):
        trajectory_errors(estimate, partial)
    # the ground truth may hold more poses than the estimate
    subset = gtsam.Values()
    subset.insert(0, estimate.atPose2(0))
    subset.insert(5, estimate.atPose2(5))
    assert isinstance(trajectory_errors(subset, truth), TrajectoryErrors)
    single = gtsam.Values()
    single.insert(0, estimate.atPose2(0))
    with pytest.raises(GraphError, match="at least 2 poses"):
        trajectory_errors(single, truth)


def test_record_and_describe():
    _, estimate, truth = GRAPHS[2]
    errors = trajectory_errors(estimate, truth)
    assert json.loads(json.dumps(errors.record())) == errors.record()
    text = errors.describe()
    assert "\n" not in text and text.startswith("APE ") and "50 poses" in text


def test_compare_reports_ape_and_rpe_with_a_ground_truth(tmp_path):
    graph, truth, out = tmp_path / "g.g2o", tmp_path / "gt.g2o", tmp_path / "out.json"
    made = CliRunner().invoke(generate_main, ["--n", "30", "--seed", "2", "--output", str(graph),
                                              "--ground-truth", str(truth)])
    assert made.exit_code == 0, made.output
    result = CliRunner().invoke(compare_main, [str(graph), "--ground-truth", str(truth),
                                               "--methods", "odometry,chordal", "--json",
                                               str(out)])
    assert result.exit_code == 0, result.output
    assert "APE m     RPE m" in result.output
    records = json.loads(out.read_text())
    assert [set(r["accuracy"]) for r in records] == [set(TrajectoryErrors.__annotations__)] * 2
    # exact measurements: refined from the chordal start, the map is the ground truth
    assert records[1]["accuracy"]["ape_rmse_m"] < 1e-4
    for files in ([str(graph), str(graph)], []):  # one FILE, or the generated graph's own
        wrong = CliRunner().invoke(compare_main, [*files, "--ground-truth", str(truth)])
        assert wrong.exit_code == 2 and "--ground-truth needs exactly one FILE" in wrong.output
    short = tmp_path / "short.g2o"  # a ground truth without the last poses: named before a run
    CliRunner().invoke(generate_main, ["--n", "20", "--output", str(tmp_path / "x.g2o"),
                                       "--ground-truth", str(short)])
    result = CliRunner().invoke(compare_main, [str(graph), "--ground-truth", str(short)])
    assert result.exit_code == 1
    assert result.stderr == (f"Error: {short}: key 20 of the estimate has no pose in the "
                             "ground truth (nor have 9 more of its 30)\n")


# --------------------------------------------------------------------------- what a ground truth is


def _vertex_lines(path, kept: str) -> str:
    """The lines of the g2o file at ``path`` whose tag starts with ``kept``."""
    return "".join(line for line in path.read_text().splitlines(keepends=True)
                   if line.startswith(kept))


@pytest.mark.parametrize("group", [SE2, SE3], ids=["planar", "3D"])
def test_a_ground_truth_of_vertices_alone_is_read_and_one_of_edges_alone_refused(tmp_path,
                                                                                   group):
    sample = generate(50, 0.1, 0.1, 2.0, 0.5, np.random.default_rng(4), noisy_measurements=True,
                      group=group)
    estimate, truth = sample.initial, sample.ground_truth
    full = tmp_path / "full.g2o"
    write_g2o(full, sample.graph, truth)
    vertices, edges = tmp_path / "vertices.g2o", tmp_path / "edges.g2o"
    vertices.write_text(_vertex_lines(full, "VERTEX"))
    edges.write_text(_vertex_lines(full, "EDGE"))
    # vertices alone give the same poses as the whole file, and the same figures
    read = read_poses(vertices)
    assert sorted(read.keys()) == sorted(truth.keys())
    assert trajectory_errors(estimate, read) == trajectory_errors(estimate, read_poses(full))
    assert trajectory_errors(estimate, read).ape_rmse_m == pytest.approx(
        trajectory_errors(estimate, truth).ape_rmse_m, rel=1e-9)
    # edges chain into poses, but those are no ground truth: refused, naming the file
    with pytest.raises(G2oFormatError) as excinfo:
        read_poses(edges)
    assert str(excinfo.value) == (f"{edges}: holds no {group.vertex_tag} line: a ground truth "
                                  "needs the true poses as vertex lines")


def test_a_ground_truth_of_the_other_group_is_named():
    (_, planar, planar_truth), (_, spatial, spatial_truth) = GRAPHS[0], GRAPHS_3D[0]
    with pytest.raises(GraphError, match="^key 0 of the ground truth is not a Pose2, as the "
                                         "estimate's poses are$"):
        check_ground_truth(planar, spatial_truth)
    with pytest.raises(GraphError, match="^key 0 of the ground truth is not a Pose3"):
        trajectory_errors(spatial, planar_truth)


@pytest.mark.parametrize("dim", [2, 3])
def test_compare_takes_a_vertices_only_ground_truth_and_refuses_one_without_poses(tmp_path, dim):
    graph, truth = tmp_path / "g.g2o", tmp_path / "gt.g2o"
    made = CliRunner().invoke(generate_main, ["--n", "40", "--dim", str(dim), "--seed", "3",
                                              "--noisy-measurements", "-o", str(graph),
                                              "--ground-truth", str(truth)])
    assert made.exit_code == 0, made.output
    vertices, edges = tmp_path / "v.g2o", tmp_path / "e.g2o"
    vertices.write_text(_vertex_lines(truth, "VERTEX"))
    edges.write_text(_vertex_lines(truth, "EDGE"))
    records = {}
    for name, path in (("full", truth), ("vertices", vertices)):
        out = tmp_path / f"{name}.json"
        result = CliRunner().invoke(compare_main, [str(graph), "--ground-truth", str(path),
                                                   "--methods", "chordal", "--json", str(out)])
        assert result.exit_code == 0, result.output
        records[name] = json.loads(out.read_text())[0]["accuracy"]
    assert records["vertices"] == records["full"]
    assert records["full"]["dimension"] == dim and 1e-6 < records["full"]["ape_rmse_m"] < 10
    tag = "VERTEX_SE3:QUAT" if dim == 3 else "VERTEX_SE2"
    result = CliRunner().invoke(compare_main, [str(graph), "--ground-truth", str(edges)])
    assert result.exit_code == 1 and result.stdout == ""  # refused before any run
    assert result.stderr == (f"Error: {edges}: holds no {tag} line: a ground truth needs the "
                             "true poses as vertex lines\n")
    first_lines = "".join(_vertex_lines(truth, "VERTEX").splitlines(keepends=True)[:25])
    partial = tmp_path / "partial.g2o"
    partial.write_text(first_lines)
    result = CliRunner().invoke(compare_main, [str(graph), "--ground-truth", str(partial)])
    assert result.exit_code == 1 and result.stdout == ""
    assert result.stderr == (f"Error: {partial}: key 25 of the estimate has no pose in the "
                             "ground truth (nor have 14 more of its 40)\n")
