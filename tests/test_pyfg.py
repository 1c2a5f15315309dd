"""CORA's PyFG files: GTSAM's goats files read as their lines say, every line kind written back
to the same graph, each bad line named by file:line, the Plaza logs as GTSAM's example builds
them, and the commands on range-aided graphs (rlpgo-generate --ranges, rlpgo-init and
rlpgo-compare on .pyfg files)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import G2oFormatError, OutputError, chi2, read_pyfg, write_pyfg
from rlpgo_gtsam.io.plaza import read_plaza
from rlpgo_gtsam.io.pyfg import PyfgTimes, check_pyfg_graph, pyfg_text, read_pyfg_file
from rlpgo_gtsam.synthetic import RangeSettings, generate_ranges
from tests.conftest import cli_error, cli_ok

GOATS = {"goats_15.pyfg": (473, 3, 472, 786), "goats_16.pyfg": (201, 4, 200, 572)}
# every planar line kind, nonzero timestamps, a range named landmark first, one between
# landmarks, a correlated covariance
SMALL = """\
VERTEX_SE2 1.5 A0 0.0 0.0 0.0
VERTEX_SE2 2.25 A1 1.0 0.1 0.05
VERTEX_SE2 3.125 A2 2.1 0.3 0.1
VERTEX_SE2 4.0 B0 0.5 2.0 -0.3
VERTEX_XY L0 3.0 4.0
VERTEX_XY L1 -1.0 5.0
VERTEX_SE2:PRIOR 1.5 A0 0.0 0.0 0.0 0.01 0.0 0.0 0.01 0.0 0.001
VERTEX_XY:PRIOR 0.75 L1 -1.2 5.1 4.0 0.5 4.0
EDGE_SE2 2.25 A0 A1 1.02 0.08 0.04 0.0004 0.0001 0.0 0.0004 0.0 0.000004
EDGE_SE2 3.125 A1 A2 1.1 0.15 0.06 0.0004 0.0 0.0 0.0004 0.0 0.000004
EDGE_SE2_XY 3.5 A2 L0 1.3 3.4 0.01 0.002 0.02
EDGE_RANGE 4.5 A0 L0 5.1 0.25
EDGE_RANGE 5.5 L1 A1 5.2 0.25
EDGE_RANGE 6.5 A2 B0 2.4 0.04
EDGE_RANGE 7.5 L0 L1 4.0 0.5
EDGE_RANGE 8.5 B0 L1 3.4 0.04
"""


def _goats(name: str) -> Path:
    return Path(gtsam.findExampleDataFile(name))


def _small(tmp_path: Path, text: str = SMALL, name: str = "small.pyfg") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _by_hand(path: Path) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The goats lines (poses, landmarks, odometry, ranges) made into GTSAM factors directly."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()

    def key(name: str) -> int:
        return gtsam.symbol(name[0], int(name[1:]))

    for line in path.read_text().splitlines():
        tag, *f = line.split()
        if tag == "VERTEX_SE2":
            values.insert(key(f[1]), gtsam.Pose2(*map(float, f[2:5])))
        elif tag == "VERTEX_XY":
            values.insert(key(f[0]), gtsam.Point2(*map(float, f[1:3])))
        elif tag == "EDGE_SE2":
            c = list(map(float, f[6:12]))
            cov = np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])
            graph.add(gtsam.BetweenFactorPose2(key(f[1]), key(f[2]),
                                               gtsam.Pose2(*map(float, f[3:6])),
                                               gtsam.noiseModel.Gaussian.Covariance(cov)))
        else:
            assert tag == "EDGE_RANGE"
            graph.add(gtsam.RangeFactor2D(key(f[1]), key(f[2]), float(f[3]),
                                          gtsam.noiseModel.Isotropic.Sigma(
                                              1, math.sqrt(float(f[4])))))
    return graph, values


# --------------------------------------------------------------------------- reading


@pytest.mark.parametrize("name", sorted(GOATS))
def test_goats_files_read_as_their_lines_say(name):
    path = _goats(name)
    tags = [line.split()[0] for line in path.read_text().splitlines()]
    poses, landmarks, odometry, ranges = GOATS[name]
    assert (tags.count("VERTEX_SE2"), tags.count("VERTEX_XY"), tags.count("EDGE_SE2"),
            tags.count("EDGE_RANGE")) == GOATS[name]
    read = read_pyfg_file(path)
    assert (read.poses, read.landmarks) == (poses, landmarks)
    assert read.count(gtsam.BetweenFactorPose2) == odometry
    assert read.count(gtsam.RangeFactor2D) == ranges == read.graph.size() - odometry
    assert read.values.exists(gtsam.symbol("A", poses - 1))
    assert read.values.exists(gtsam.symbol("L", landmarks - 1))
    graph, values = _by_hand(path)
    assert values.equals(read.values, 0.0)
    assert chi2(read.graph, read.values) == pytest.approx(chi2(graph, values), rel=1e-12)


def test_every_line_kind_reads_into_its_gtsam_factor(tmp_path):
    read = read_pyfg_file(_small(tmp_path))
    kinds = [type(read.graph.at(k)).__name__ for k in range(read.graph.size())]
    assert kinds == ["PriorFactorPose2", "PriorFactorPoint2", "BetweenFactorPose2",
                     "BetweenFactorPose2", "BearingRangeFactor2D", "RangeFactor2D",
                     "RangeFactor2D", "RangeFactorPose2", "RangeFactor2", "RangeFactor2D"]
    assert read.lines == list(range(7, 17))
    assert read.times.factors == (1.5, 0.75, 2.25, 3.125, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5)
    assert read.times.vertices[gtsam.symbol("B", 0)] == 4.0
    # a covariance, upper triangle by rows: the information is its inverse
    between = read.graph.at(2)
    covariance = np.array([[4e-4, 1e-4, 0], [1e-4, 4e-4, 0], [0, 0, 4e-6]])
    np.testing.assert_allclose(between.noiseModel().information(), np.linalg.inv(covariance),
                               rtol=1e-12)
    # a range named landmark first is GTSAM's pose-first factor, variance 0.25: sigma 0.5
    flipped = read.graph.at(6)
    assert list(flipped.keys()) == [gtsam.symbol("A", 1), gtsam.symbol("L", 1)]
    assert flipped.noiseModel().sigmas()[0] == pytest.approx(0.5, rel=1e-15)
    # the landmark measured in the pose's frame: bearing and range of (1.3, 3.4)
    seen = read.graph.at(4).measured()
    assert seen.range() == pytest.approx(math.hypot(1.3, 3.4), rel=1e-15)
    assert seen.bearing().theta() == pytest.approx(math.atan2(3.4, 1.3), rel=1e-15)


def test_comments_and_blank_lines_are_skipped(tmp_path):
    plain = read_pyfg(_small(tmp_path))
    text = "# a comment\n\n" + SMALL.replace("VERTEX_XY L0", "\nVERTEX_XY L0")
    commented = read_pyfg(_small(tmp_path, text))
    assert chi2(*commented) == chi2(*plain) and commented[1].equals(plain[1], 0.0)


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", sorted(GOATS))
def test_goats_round_trip(tmp_path, name):
    read = read_pyfg_file(_goats(name))
    out = tmp_path / name
    write_pyfg(out, read.graph, read.values, read.times)
    again = read_pyfg_file(out)
    assert again.values.equals(read.values, 0.0)
    assert chi2(again.graph, again.values) == pytest.approx(chi2(read.graph, read.values),
                                                            rel=1e-9)
    assert again.lines == read.lines  # every vertex first, then the edges in file order
    assert pyfg_text(again.graph, again.values, again.times) == out.read_text()


def test_every_line_kind_and_timestamp_round_trips(tmp_path):
    read = read_pyfg_file(_small(tmp_path))
    text = pyfg_text(read.graph, read.values, read.times)
    again = read_pyfg_file(_small(tmp_path, text, "again.pyfg"))
    assert again.values.equals(read.values, 0.0)
    assert again.times.factors == read.times.factors
    assert again.times.vertices == read.times.vertices
    for values in (read.values, _shifted(read.values)):
        assert chi2(again.graph, values) == pytest.approx(chi2(read.graph, values), rel=1e-9)
    # what was read is what is written back, the flipped range and landmark lines aside
    written = text.splitlines()
    assert written[0] == "VERTEX_SE2 1.5 A0 0.0 0.0 0.0"
    assert "EDGE_RANGE 5.5 A1 L1 5.2 0.25" in written
    assert "EDGE_SE2 2.25 A0 A1 1.02 0.08 0.04 0.0004 0.0001 0.0 0.0004 0.0 4e-06" in written
    assert "VERTEX_XY:PRIOR 0.75 L1 -1.2 5.1 4.0 0.5 4.0" in written


def _shifted(values: gtsam.Values) -> gtsam.Values:
    """``values`` moved off the file's values: a round trip must keep the cost everywhere."""
    moved = gtsam.Values()
    for key in values.keys():
        try:
            moved.insert(key, values.atPose2(key).compose(gtsam.Pose2(0.3, -0.2, 0.1)))
        except RuntimeError:
            moved.insert(key, values.atPoint2(key) + np.array([0.5, -0.4]))
    return moved


def test_a_generated_range_graph_round_trips_with_pyfg_names(tmp_path):
    sample = generate_ranges(30, 0.1, 0.05, 3.0, 0.5, np.random.default_rng(3),
                             RangeSettings(2, 4), noisy_measurements=True)
    out = tmp_path / "g.pyfg"
    write_pyfg(out, sample.graph, sample.initial)
    text = out.read_text()
    assert text.startswith("VERTEX_SE2 0.0 A0 ") and "\nVERTEX_XY l1 " in text
    graph, values = read_pyfg(out)
    assert graph.size() == sample.graph.size()
    assert chi2(graph, values) == pytest.approx(chi2(sample.graph, sample.initial), rel=1e-9)


def _poses(*keys: int) -> gtsam.Values:
    values = gtsam.Values()
    for k, key in enumerate(keys):
        values.insert(key, gtsam.Pose2(k, 0, 0))
    return values


def test_the_writer_refuses_what_a_pyfg_file_cannot_hold(tmp_path):
    a0, a1, a2 = (gtsam.symbol("A", k) for k in range(3))
    noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.BetweenFactorPose2(a0, a1, gtsam.Pose2(1, 0, 0), noise))
    cases = [
        (graph, _poses(0, a0, a1), "keys 0 and A0 would both be written as A0"),
        (graph, _poses(a0), "factor 0 (BetweenFactorPose2 on A0 A1): key A1 has no Pose2 or "
                            "Point2 value"),
        (graph, _poses(a0, a1, a2), "value A2 is named by no factor: a PyFG reader refuses a "
                                    "variable that nothing measures"),
    ]
    robust = gtsam.NonlinearFactorGraph()
    robust.add(gtsam.BetweenFactorPose2(a0, a1, gtsam.Pose2(), gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.0), noise)))
    cases.append((robust, _poses(a0, a1), "factor 0 (BetweenFactorPose2 on A0 A1): a Robust "
                                          "noise model; a PyFG line holds a Gaussian covariance"))
    for graph_, values, message in cases:
        with pytest.raises(OutputError) as caught:
            write_pyfg(tmp_path / "x.pyfg", graph_, values)
        assert str(caught.value) == message
    spatial = gtsam.NonlinearFactorGraph(graph)
    spatial.add(gtsam.PriorFactorPose3(a0, gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
    with pytest.raises(OutputError, match=re.escape(
            "factor 1 (PriorFactorPose3 on A0): a planar PyFG file has no line for it")):
        check_pyfg_graph(spatial)
    assert not (tmp_path / "x.pyfg").exists()


# --------------------------------------------------------------------------- bad lines

BAD_LINES = [
    ("EDGE_SE2 2.25 A0 A1 1.02 0.08 0.04 0.0004 0.0 0.0 0.0004 0.0",
     "EDGE_SE2 needs 12 fields after the tag (t a b dx dy dtheta and 6 covariance entries), "
     "found 11"),
    ("VERTEX_XY L0 3.0", "VERTEX_XY needs 3 fields after the tag (name x y), found 2"),
    ("EDGE_RANGE 4.5 A0 L0 5.1x 0.25", "EDGE_RANGE field 4 is not a number: '5.1x'"),
    ("EDGE_RANGE 4.5 A0 L0 -5.1 0.25", "EDGE_RANGE range must be >= 0, found -5.1"),
    ("EDGE_RANGE 4.5 A0 L0 nan 0.25", "EDGE_RANGE field 4 is not finite: 'nan'"),
    ("EDGE_RANGE 4.5 A0 L0 5.1 0", "EDGE_RANGE variance must be positive, found 0"),
    ("EDGE_RANGE 4.5 A0 L0 5.1 -0.25", "EDGE_RANGE variance must be positive, found -0.25"),
    ("EDGE_RANGE 4.5 A0 L7 5.1 0.25",
     "EDGE_RANGE names L7, which no vertex line (VERTEX_SE2, VERTEX_XY) defines"),
    ("EDGE_RANGE 4.5 A0 A0 5.1 0.25", "EDGE_RANGE joins A0 to itself"),
    ("EDGE_RANGE 4.5 A0 L00 5.1 0.25", "EDGE_RANGE field 3 is not a PyFG name (a letter and an "
     "index without leading zeros, A12 or L0): 'L00'"),
    ("EDGE_SE2_XY 3.5 A2 B0 1.3 3.4 0.01 0.002 0.02",
     "EDGE_SE2_XY: B0 is a pose (its vertex is on line 4); EDGE_SE2_XY takes a landmark there"),
    ("EDGE_SE2 2.25 A0 A1 1.02 0.08 0.04 0.0004 0.0 0.0 -0.0004 0.0 0.000004",
     "EDGE_SE2 covariance is not positive definite (0.0004 0.0 0.0 -0.0004 0.0 0.000004)"),
    ("VERTEX_SE2 9.0 A1 0.0 0.0 0.0", "vertex A1 defined twice (first on line 2)"),
    ("VERTEX_XY A1 0.0 0.0", "vertex A1 defined twice (first on line 2)"),
    ("EDGE_SE3:QUAT 0 A0 A1 1 0 0 0 0 0 1", "EDGE_SE3:QUAT is a 3D PyFG line; this file is "
     "planar (VERTEX_SE2 on line 1)"),
    ("EDGE_BEARING 0 A0 L0 1.0", "unknown PyFG line 'EDGE_BEARING' (planar PyFG: VERTEX_SE2, "
     "VERTEX_XY, VERTEX_SE2:PRIOR, VERTEX_XY:PRIOR, EDGE_SE2, EDGE_SE2_XY, EDGE_RANGE)"),
    ("VERTEX_SE2 t A9 0.0 0.0 0.0", "VERTEX_SE2 field 1 is not a number: 't'"),
]


def with_bad_line(text: str, bad: str) -> tuple[str, int]:
    """``text`` with the line ``bad`` in it, and its line number: a factor line replaces the
    first of its tag; a vertex line or a new tag goes in third."""
    lines = text.splitlines()
    same = [k for k, line in enumerate(lines) if line.split()[0] == bad.split()[0]
            and not bad.startswith("VERTEX")]
    at = same[0] if same else 2
    if same:
        lines[at] = bad
    else:
        lines.insert(at, bad)
    return "\n".join(lines) + "\n", at + 1


@pytest.mark.parametrize(("bad", "reason"), BAD_LINES)
def test_a_bad_line_is_named_with_its_reason(tmp_path, bad, reason):
    text, line = with_bad_line(SMALL, bad)
    path = _small(tmp_path, text)
    with pytest.raises(G2oFormatError) as caught:
        read_pyfg(path)
    assert str(caught.value) == f"{path}:{line}: {reason}"


def test_a_vertex_nothing_measures_is_named(tmp_path):
    path = _small(tmp_path, SMALL.replace("VERTEX_XY L1 -1.0 5.0\n",
                                          "VERTEX_XY L1 -1.0 5.0\nVERTEX_XY L9 0.0 0.0\n"))
    with pytest.raises(G2oFormatError, match=re.escape(
            f"{path}:7: VERTEX_XY L9: no factor line names it (GTSAM's optimizers need each "
            "variable in a factor)")):
        read_pyfg(path)


def test_a_missing_or_empty_file_is_one_line(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_pyfg(tmp_path / "none.pyfg")
    with pytest.raises(G2oFormatError, match="is a directory, not a PyFG file$"):
        read_pyfg(tmp_path)
    with pytest.raises(G2oFormatError, match="holds no VERTEX_SE2 or VERTEX_XY line"):
        read_pyfg(_small(tmp_path, "# nothing\n"))


# --------------------------------------------------------------------------- Plaza


def test_plaza2_is_built_as_gtsams_range_example_builds_it():
    dr, td = (Path(gtsam.findExampleDataFile(f"Plaza2_{k}.txt")) for k in ("DR", "TD"))
    graph, values = read_plaza(dr, td)
    steps = len(dr.read_text().split("\n")) - 1
    kinds = [type(graph.at(k)).__name__ for k in range(graph.size())]
    assert kinds.count("BetweenFactorPose2") == steps == 4090
    assert kinds.count("RangeFactor2D") == 1816 and kinds.count("PriorFactorPose2") == 1
    beacons = [gtsam.symbol("L", j) for j in (0, 1, 5, 6)]
    assert values.size() == steps + 1 + len(beacons)
    assert all(values.exists(key) for key in beacons)
    first = graph.at(1)  # pose 0 to 1: the first dead-reckoning step, Pose2(d, 0, dtheta)
    line = dr.read_text().split()[:3]
    assert first.measured().equals(gtsam.Pose2(float(line[1]), 0.0, float(line[2])), 1e-15)
    np.testing.assert_allclose(first.noiseModel().sigmas(), [0.05, 0.01, 0.1])
    assert graph.at(steps + 1).noiseModel().sigmas()[0] == 100.0
    assert math.isfinite(chi2(graph, values))


def test_a_bad_plaza_line_is_named(tmp_path):
    dr, td = tmp_path / "x_DR.txt", tmp_path / "x_TD.txt"
    dr.write_text("1.0 0.1 0.0\n2.0 0.1 0.01\n")
    td.write_text("1.5 2 5 10.0\n1.7 2 5.5 10.0\n")
    with pytest.raises(G2oFormatError, match=re.escape(
            f"{td}:2: beacon id 5.5 is not a non-negative integer")):
        read_plaza(dr, td)
    dr.write_text("1.0 0.1 0.0\n1.0 0.1 0.01\n")
    with pytest.raises(G2oFormatError, match=re.escape(
            f"{dr}:2: time 1.0 s does not follow the line before (1.0 s)")):
        read_plaza(dr, td)


# --------------------------------------------------------------------------- commands


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> Path:
    """A 60-pose range-aided lawn mower written by rlpgo-generate --ranges."""
    path = tmp_path_factory.mktemp("ranges") / "r.pyfg"
    result = CliRunner().invoke(generate_main, [
        "--n", "60", "--ranges", "3", "--pose-ranges", "5", "--sigma-range", "0.2",
        "--noisy-measurements", "--seed", "2", "-o", str(path)])
    cli_ok(result)
    assert result.stdout.startswith(f"{path}: 60 poses, 3 beacons, ")
    return path


def test_generate_writes_a_range_graph_as_pyfg(generated):
    read = read_pyfg_file(generated)
    assert (read.poses, read.landmarks) == (60, 3)
    assert read.count(gtsam.RangeFactorPose2) == 5 and read.count(gtsam.RangeFactor2D) > 9


@pytest.mark.parametrize(("args", "message"), [
    (["--ranges", "3", "-o", "r.g2o"], "r.g2o: a graph with ranges is written as PyFG"),
    (["--ranges", "3", "--landmarks", "4", "-o", "r.pyfg"], "--landmarks: not used with"),
    (["--pose-ranges", "3", "--max-sightings", "2", "-o", "r.pyfg"], "--max-sightings: not"),
    (["--ranges", "3", "--outliers", "0.1", "-o", "r.pyfg"], "--outliers: not used with"),
    (["--sigma-range", "0.2", "-o", "r.g2o"], "--sigma-range: options of the landmarks and "
     "the ranges"),
    (["--sigma-bearing", "0.2", "-o", "r.g2o"], "--sigma-bearing: options of the landmarks; "),
])
def test_generate_refuses_ranges_it_cannot_write(tmp_path, args, message):
    args = [str(tmp_path / arg) if arg.startswith("r.") else arg for arg in args]
    result = CliRunner().invoke(generate_main, ["--n", "40", *args])
    cli_error(result, message, code=2)
    assert not list(tmp_path.iterdir())


def test_init_writes_a_pyfg_guess_with_the_inputs_timestamps(tmp_path, generated):
    graph, values = read_pyfg(generated)
    source = tmp_path / "in.pyfg"
    poses = [key for key in values.keys() if gtsam.Symbol(key).chr() == ord("A")]
    times = PyfgTimes({key: 0.5 * k for k, key in enumerate(poses)},
                      tuple(0.25 * k for k in range(graph.size())))
    write_pyfg(source, graph, values, times)
    out = tmp_path / "out.pyfg"
    result = CliRunner().invoke(init_main, [str(source), "-o", str(out)])
    cli_ok(result)
    assert "certificate: " in result.stdout
    written = float(re.search(r"chi2 (\S+); [\d.]+ s; wrote", result.stdout).group(1))
    read = read_pyfg_file(out)
    assert chi2(read.graph, read.values) == pytest.approx(written, rel=1e-5)  # as printed
    assert written < 0.01 * chi2(graph, values)
    assert read.times.factors == times.factors and read.times.vertices == times.vertices
    assert chi2(read.graph, values) == pytest.approx(chi2(graph, values), rel=1e-9)


def test_init_refuses_to_write_ranges_as_g2o(tmp_path, generated):
    out = tmp_path / "out.g2o"
    message = cli_error(CliRunner().invoke(init_main, [str(generated), "-o", str(out)]))
    assert message.startswith(f"{out}: a g2o file has no line for ranges, and the graph holds ")
    assert not out.exists()


def test_init_names_a_bad_pyfg_line(tmp_path):
    path = _small(tmp_path, SMALL.replace("EDGE_RANGE 4.5 A0 L0 5.1 0.25",
                                          "EDGE_RANGE 4.5 A0 L0 5.1 0.0"))
    cli_error(CliRunner().invoke(init_main, [str(path), "-o", str(tmp_path / "o.pyfg")]),
              f"{path}:12: EDGE_RANGE variance must be positive, found 0.0")


def test_compare_runs_on_a_pyfg_file(generated):
    result = CliRunner().invoke(compare_main, [str(generated), "--methods",
                                               "odometry,certified"])
    cli_ok(result)
    assert f"{generated.name}: 60 poses" in result.stdout
    assert "certificate (certified): " in result.stdout
