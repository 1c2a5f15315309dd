"""rlpgo-generate --dim 3 --ranges N: a 3D range-aided graph (a climbing helix ranging to
beacons and between poses) written as PyFG, read back whole, and certified by rlpgo-init."""

from __future__ import annotations

from pathlib import Path

import gtsam
import pytest
from click.testing import CliRunner
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import chi2, read_pyfg
from rlpgo_gtsam.io.pyfg import read_pyfg_file
from tests.conftest import cli_error, cli_ok

POSES, BEACONS, POSE_RANGES = 40, 3, 5


def _generate(folder: Path, *options: str) -> tuple[Path, Path, str]:
    out, truth = folder / "g.pyfg", folder / "gt.pyfg"
    result = CliRunner().invoke(generate_main, [
        "--dim", "3", "--n", str(POSES), "--ranges", str(BEACONS), "--pose-ranges",
        str(POSE_RANGES), "--sigma-range", "0.2", "--seed", "3", *options,
        "-o", str(out), "--ground-truth", str(truth)])
    cli_ok(result)
    return out, truth, result.stdout


@pytest.fixture(scope="module")
def exact(tmp_path_factory) -> tuple[Path, Path, str]:
    """A 40-pose helix with exact measurements and its ground truth."""
    return _generate(tmp_path_factory.mktemp("helix"))


def test_the_written_graph_reads_back_as_3d_with_its_truth_at_zero(exact):
    out, truth, stdout = exact
    assert stdout.startswith(f"{out}: {POSES} poses, {BEACONS} beacons, ")
    read = read_pyfg_file(out)
    assert (read.poses, read.landmarks) == (POSES, BEACONS)
    assert read.count(gtsam.RangeFactorPose3) == POSE_RANGES
    assert read.count(gtsam.RangeFactor3D) == BEACONS * ((POSES + 1) // 2)  # every 2nd pose
    assert read.count(gtsam.BetweenFactorPose3) == POSES - 1
    graph, values = read_pyfg(out)
    _, ground_truth = read_pyfg(truth)
    assert gtsam.utilities.allPose3s(values).size() == POSES
    assert chi2(graph, ground_truth) < 1e-12 < 1e3 < chi2(graph, values)


def test_init_certifies_the_written_graph(tmp_path, exact):
    out, truth, _ = exact
    result_path = tmp_path / "out.pyfg"
    result = CliRunner().invoke(init_main, [str(out), "-o", str(result_path)])
    cli_ok(result)
    assert "certificate: certified optimal" in result.stdout
    assert f"with {BEACONS} landmarks and " in result.stdout
    graph, found = read_pyfg(result_path)
    assert chi2(graph, found) < 1e-6


def test_noisy_measurements_move_the_optimum_off_the_truth(tmp_path):
    out, truth, _ = _generate(tmp_path, "--noisy-measurements")
    graph, _ = read_pyfg(out)
    _, ground_truth = read_pyfg(truth)
    assert chi2(graph, ground_truth) > 1.0


@pytest.mark.parametrize(("args", "message"), [
    (["--ranges", "3", "-o", "r.g2o"], "r.g2o: a graph with ranges is written as PyFG"),
    (["--ranges", "3", "--d", "2", "-o", "r.pyfg"], "--d: not used by the 3D range graph"),
    (["--pose-ranges", "3", "--lc", "0.2", "--sensor-range", "9", "-o", "r.pyfg"],
     "--lc, --sensor-range: not used by the 3D range graph"),
    (["--ranges", "3", "--landmarks", "4", "-o", "r.pyfg"], "--landmarks: not used with"),
])
def test_refuses_what_the_3d_range_graph_cannot_take(tmp_path, args, message):
    args = [str(tmp_path / arg) if arg.startswith("r.") else arg for arg in args]
    result = CliRunner().invoke(generate_main, ["--dim", "3", "--n", "40", *args])
    cli_error(result, message, code=2)
    assert not list(tmp_path.iterdir())
