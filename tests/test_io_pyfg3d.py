"""CORA's PyFG files in 3D: every 3D line kind read into its GTSAM factor, a generated 3D
range-aided graph written and read back to the same factors, values and cost, the file's
covariance (translation first) meaning what GTSAM's Pose3 noise model (rotation first) means,
each bad 3D line named by file:line, and rlpgo-init on a 3D PyFG file."""

from __future__ import annotations

import re
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import G2oFormatError, OutputError, chi2, read_pyfg, write_pyfg
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.io.pyfg import (
    PyfgTimes,
    check_pyfg_graph,
    pyfg_group,
    pyfg_text,
    read_pyfg_file,
)
from rlpgo_gtsam.landmarks import bearing_range_factor
from tests.conftest import cli_error, cli_ok
from tests.test_pyfg import with_bad_line
from tests.test_ranges import range_aided_3d

# a covariance in PyFG's order (x y z, then rotation), correlated across the two blocks
# (x with the rotation about z): its upper triangle, row by row
COVARIANCE = ("0.04 0.01 0.0 0.0 0.0 0.0001 0.04 0.0 0.0 0.0 0.0 0.09 0.0 0.0 0.0 "
              "0.0001 0.0 0.0 0.0002 0.0 0.0003")
# every 3D line kind, nonzero timestamps, a range named landmark first, one between
# landmarks; the second edge's covariance as CORA's own 3D files write one (with -0.0)
SMALL = f"""\
VERTEX_SE3:QUAT 1.5 A0 0.0 0.0 0.0 0.0 0.0 0.0 1.0
VERTEX_SE3:QUAT 2.25 A1 1.0 0.1 0.05 0.0 0.0 0.05 0.99875
VERTEX_SE3:QUAT 3.125 A2 2.1 0.3 0.1 0.0 0.0 0.1 0.995
VERTEX_SE3:QUAT 4.0 B0 0.5 2.0 1.0 0.0 0.0 -0.15 0.9887
VERTEX_XYZ L0 3.0 4.0 1.0
VERTEX_XYZ L1 -1.0 5.0 2.0
VERTEX_SE3:QUAT:PRIOR 1.5 A0 0.0 0.0 0.0 0.0 0.0 0.0 1.0 {COVARIANCE}
VERTEX_XYZ:PRIOR 0.75 L1 -1.2 5.1 2.1 4.0 0.5 0.0 4.0 0.0 1.0
EDGE_SE3:QUAT 2.25 A0 A1 1.02 0.08 0.04 0.0 0.0 0.0 1.0 {COVARIANCE}
EDGE_SE3:QUAT 3.125 A1 A2 1.1 0.15 0.06 0.0 0.0 0.05 0.99875 0.01 0.0 0.0 0.0 0.0 -0.0 \
0.01 0.0 0.0 0.0 -0.0 0.01 0.0 0.0 -0.0 0.0005 0.0 -0.0 0.0005 -0.0 0.0005
EDGE_SE3_XYZ 3.5 A2 L0 1.3 3.4 0.5 0.01 0.002 0.0 0.02 0.0 0.03
EDGE_RANGE 4.5 A0 L0 5.1 0.25
EDGE_RANGE 5.5 L1 A1 5.2 0.25
EDGE_RANGE 6.5 A2 B0 2.4 0.04
EDGE_RANGE 7.5 L0 L1 4.0 0.5
EDGE_RANGE 8.5 B0 L1 3.4 0.04
"""
# PyFG's 3D pose tangent (translation first) -> GTSAM's Pose3 tangent (rotation first)
TO_GTSAM = np.array([3, 4, 5, 0, 1, 2])


def _file(tmp_path: Path, text: str = SMALL, name: str = "small3d.pyfg") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _upper(text: str, size: int) -> np.ndarray:
    """The symmetric matrix of an upper triangle written row by row."""
    matrix = np.zeros((size, size))
    rows, cols = np.triu_indices(size)
    matrix[rows, cols] = list(map(float, text.split()))
    matrix[cols, rows] = matrix[rows, cols]
    return matrix


def _perturbed(values: gtsam.Values, rng: np.random.Generator) -> gtsam.Values:
    """``values`` moved off where they are: a round trip must keep the cost everywhere."""
    moved = gtsam.Values()
    for key in values.keys():
        try:
            pose = values.atPose3(key)
        except RuntimeError:
            moved.insert(key, values.atPoint3(key) + 0.3 * rng.normal(size=3))
        else:
            moved.insert(key, pose.retract(0.1 * rng.normal(size=6)))
    return moved


# --------------------------------------------------------------------------- reading


def test_every_3d_line_kind_reads_into_its_gtsam_factor(tmp_path):
    path = _file(tmp_path)
    read = read_pyfg_file(path)
    assert read.group is SE3 and pyfg_group(path) is SE3
    assert (read.poses, read.landmarks) == (4, 2)
    kinds = [type(read.graph.at(k)).__name__ for k in range(read.graph.size())]
    assert kinds == ["PriorFactorPose3", "PriorFactorPoint3", "BetweenFactorPose3",
                     "BetweenFactorPose3", "BearingRangeFactor3D", "RangeFactor3D",
                     "RangeFactor3D", "RangeFactorPose3", "RangeFactor3", "RangeFactor3D"]
    assert read.lines == list(range(7, 17))
    assert read.times.factors == (1.5, 0.75, 2.25, 3.125, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5)
    assert read.times.vertices[gtsam.symbol("B", 0)] == 4.0
    # a quaternion qx qy qz qw, divided by its length: B0 turned about z by -2 atan2(.15, .9887)
    b0 = read.values.atPose3(gtsam.symbol("B", 0))
    np.testing.assert_allclose(b0.rotation().matrix(),
                               gtsam.Rot3.Yaw(-2 * np.arctan2(0.15, 0.9887)).matrix(),
                               atol=1e-15)
    np.testing.assert_array_equal(b0.translation(), [0.5, 2.0, 1.0])
    np.testing.assert_array_equal(read.values.atPoint3(gtsam.symbol("L", 1)), [-1.0, 5.0, 2.0])
    # the file's translation-first covariance is GTSAM's rotation-first one
    file_covariance = _upper(COVARIANCE, 6)
    for index in (0, 2):
        np.testing.assert_allclose(read.graph.at(index).noiseModel().covariance(),
                                   file_covariance[TO_GTSAM][:, TO_GTSAM], rtol=1e-12,
                                   atol=1e-18)
    # CORA's style of line: translation variance 0.01, rotation 0.0005
    np.testing.assert_allclose(read.graph.at(3).noiseModel().sigmas() ** 2,
                               [0.0005] * 3 + [0.01] * 3, rtol=1e-12)
    # a point prior's covariance as it is (x y z), a range named landmark first pose first
    np.testing.assert_allclose(read.graph.at(1).noiseModel().covariance(),
                               _upper("4.0 0.5 0.0 4.0 0.0 1.0", 3), rtol=1e-12)
    flipped = read.graph.at(6)
    assert list(flipped.keys()) == [gtsam.symbol("A", 1), gtsam.symbol("L", 1)]
    assert flipped.noiseModel().sigmas()[0] == pytest.approx(0.5, rel=1e-15)
    seen = read.graph.at(4).measured()  # the landmark (1.3, 3.4, 0.5) in A2's frame
    assert seen.range() == pytest.approx(np.linalg.norm([1.3, 3.4, 0.5]), rel=1e-15)
    np.testing.assert_allclose(seen.bearing().point3(),
                               np.array([1.3, 3.4, 0.5]) / np.linalg.norm([1.3, 3.4, 0.5]),
                               rtol=1e-15)


def test_the_files_covariance_is_translation_first_as_gtsams_pose3_errors_show(tmp_path):
    """The cost GTSAM gives a between factor read from the file, at poses off its measurement
    by a tangent step, is the quadratic form of the file's own matrix in the file's order."""
    factor = read_pyfg_file(_file(tmp_path)).graph.at(2)  # EDGE_SE3:QUAT A0 A1, correlated
    file_covariance = _upper(COVARIANCE, 6)
    measured = factor.measured()
    rng = np.random.default_rng(4)
    a0, a1 = gtsam.symbol("A", 0), gtsam.symbol("A", 1)
    for step in [np.array([0, 0, 0, 0.2, 0, 0]), np.array([0, 0, 0.02, 0, 0, 0]),
                 *(0.05 * rng.normal(size=(4, 6)))]:  # GTSAM's tangent: rotation first
        values = gtsam.Values()
        values.insert(a0, gtsam.Pose3())
        values.insert(a1, measured.compose(gtsam.Pose3.Expmap(step)))
        in_file_order = np.concatenate([step[3:], step[:3]])
        expected = 0.5 * in_file_order @ np.linalg.solve(file_covariance, in_file_order)
        assert factor.error(values) == pytest.approx(expected, rel=1e-9)


def test_the_dimension_is_told_by_the_files_lines(tmp_path):
    ranges_first = "EDGE_RANGE 0.0 A0 A1 1.0 0.1\n" + SMALL
    assert pyfg_group(_file(tmp_path, ranges_first)) is SE3
    planar = ("VERTEX_SE2 0.0 A0 0.0 0.0 0.0\nVERTEX_SE2 0.0 A1 1.0 0.0 0.0\n"
              "EDGE_RANGE 0.0 A0 A1 1.0 0.1\n")
    assert pyfg_group(_file(tmp_path, planar, "planar.pyfg")) is SE2
    assert read_pyfg_file(tmp_path / "planar.pyfg").group is SE2


# --------------------------------------------------------------------------- round trips


def _generated() -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """A 3D range-aided graph (Pose3 odometry with rotation and translation sigmas apart, a
    pose prior, ranges to beacons and between poses) with one factor of each other kind a 3D
    PyFG line holds: a correlated loop closure, a point prior, a landmark seen from a pose,
    a range between two landmarks."""
    graph, values, truth = range_aided_3d(1, 1.0, n=20, beacons=2, pose_ranges=4)
    x, l0, l1 = (lambda k: gtsam.symbol("x", k)), gtsam.symbol("l", 0), gtsam.symbol("l", 1)
    gtsam_order = _upper(COVARIANCE, 6)[TO_GTSAM][:, TO_GTSAM]
    graph.add(gtsam.BetweenFactorPose3(x(0), x(5), truth.atPose3(x(0)).between(
        truth.atPose3(x(5))), gtsam.noiseModel.Gaussian.Covariance(gtsam_order)))
    graph.add(gtsam.PriorFactorPoint3(l0, truth.atPoint3(l0) + 0.1,
                                      gtsam.noiseModel.Gaussian.Covariance(
                                          _upper("4.0 0.5 0.0 4.0 0.2 1.0", 3))))
    seen = truth.atPose3(x(3)).transformTo(truth.atPoint3(l1))
    graph.add(bearing_range_factor(x(3), l1, seen, np.diag([4.0, 9.0, 16.0])))
    graph.add(gtsam.RangeFactor3(l0, l1, float(np.linalg.norm(
        truth.atPoint3(l0) - truth.atPoint3(l1))), gtsam.noiseModel.Isotropic.Sigma(1, 0.2)))
    return graph, values


def test_a_generated_3d_range_graph_round_trips_to_the_same_factors_values_and_cost(tmp_path):
    graph, values = _generated()
    out = tmp_path / "g.pyfg"
    write_pyfg(out, graph, values)
    text = out.read_text()
    assert text.startswith("VERTEX_SE3:QUAT 0.0 x0 0.0 0.0 0.0 0.0 0.0 0.0 1.0\n")
    assert "\nVERTEX_XYZ l1 " in text
    read = read_pyfg_file(out)
    assert read.group is SE3 and (read.poses, read.landmarks) == (20, 2)
    assert read.graph.size() == graph.size()
    for k in range(graph.size()):
        original, again = graph.at(k), read.graph.at(k)
        assert type(again) is type(original)
        assert list(again.keys()) == list(original.keys())
    assert read.values.size() == values.size()
    assert read.values.equals(values, 1e-12)
    for key in values.keys():  # positions exactly
        try:
            position = values.atPose3(key).translation()
            again = read.values.atPose3(key).translation()
        except RuntimeError:
            position, again = values.atPoint3(key), read.values.atPoint3(key)
        np.testing.assert_array_equal(again, position)
    rng = np.random.default_rng(5)
    for at in (values, *(_perturbed(values, rng) for _ in range(3))):
        assert chi2(read.graph, at) == pytest.approx(chi2(graph, at), rel=1e-9)
        for k in range(graph.size()):
            assert read.graph.at(k).error(at) == pytest.approx(graph.at(k).error(at), rel=1e-8,
                                                               abs=1e-12)
    # what was read writes the same text again, but for a quaternion's 15th digit, which
    # moves through a rotation matrix and back (as the g2o writer's does)
    _assert_same_text_to_quaternion_rounding(text, pyfg_text(read.graph, read.values))


def _assert_same_text_to_quaternion_rounding(text: str, again: str) -> None:
    """Every field of ``again`` is the one of ``text`` (the same characters), but for the
    quaternions' fields, which are within 1e-14 of them."""
    lines, lines_again = text.splitlines(), again.splitlines()
    assert len(lines) == len(lines_again)
    for line, line_again in zip(lines, lines_again, strict=True):
        fields, fields_again = line.split(), line_again.split()
        assert len(fields) == len(fields_again)
        # a pose line's quaternion: after the tag, timestamp, names and x y z
        first = {"VERTEX_SE3:QUAT": 6, "VERTEX_SE3:QUAT:PRIOR": 6, "EDGE_SE3:QUAT": 7}.get(
            fields[0])
        quaternion = range(first, first + 4) if first is not None else range(0)
        for k, (field, field_again) in enumerate(zip(fields, fields_again, strict=True)):
            if k in quaternion:
                assert abs(float(field) - float(field_again)) <= 1e-14, (line, line_again)
            else:
                assert field == field_again, (line, line_again)


def test_every_3d_line_kind_and_timestamp_round_trips(tmp_path):
    read = read_pyfg_file(_file(tmp_path))
    text = pyfg_text(read.graph, read.values, read.times)
    again = read_pyfg_file(_file(tmp_path, text, "again.pyfg"))
    assert again.values.equals(read.values, 1e-15)
    assert again.times.factors == read.times.factors
    assert again.times.vertices == read.times.vertices
    rng = np.random.default_rng(6)
    for values in (read.values, _perturbed(read.values, rng)):
        assert chi2(again.graph, values) == pytest.approx(chi2(read.graph, values), rel=1e-9)
    # what was read is what is written back, the flipped range aside
    written = text.splitlines()
    assert written[0] == "VERTEX_SE3:QUAT 1.5 A0 0.0 0.0 0.0 0.0 0.0 0.0 1.0"
    assert written[4] == "VERTEX_XYZ L0 3.0 4.0 1.0"
    assert f"EDGE_SE3:QUAT 2.25 A0 A1 1.02 0.08 0.04 0.0 0.0 0.0 1.0 {COVARIANCE}" in written
    assert f"VERTEX_SE3:QUAT:PRIOR 1.5 A0 0.0 0.0 0.0 0.0 0.0 0.0 1.0 {COVARIANCE}" in written
    assert "VERTEX_XYZ:PRIOR 0.75 L1 -1.2 5.1 2.1 4.0 0.5 0.0 4.0 0.0 1.0" in written
    assert "EDGE_RANGE 5.5 A1 L1 5.2 0.25" in written
    assert "EDGE_RANGE 7.5 L0 L1 4.0 0.5" in written


def _pose3s(*keys: int) -> gtsam.Values:
    values = gtsam.Values()
    for k, key in enumerate(keys):
        values.insert(key, gtsam.Pose3(gtsam.Rot3(), np.array([k, 0.0, 0.0])))
    return values


def test_the_writer_refuses_what_a_3d_pyfg_file_cannot_hold(tmp_path):
    a0, a1 = gtsam.symbol("A", 0), gtsam.symbol("A", 1)
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.BetweenFactorPose3(a0, a1, gtsam.Pose3(), noise))
    check_pyfg_graph(graph)  # a 3D graph is one a PyFG file holds
    mixed = _pose3s(a0, a1)
    mixed.insert(gtsam.symbol("B", 0), gtsam.Pose2())
    planar_factor = gtsam.NonlinearFactorGraph(graph)
    planar_factor.add(gtsam.BetweenFactorPose2(a0, a1, gtsam.Pose2(),
                                               gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    robust = gtsam.NonlinearFactorGraph()
    robust.add(gtsam.BetweenFactorPose3(a0, a1, gtsam.Pose3(), gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(1.0), noise)))
    cases = [
        (graph, _pose3s(a0), "factor 0 (BetweenFactorPose3 on A0 A1): key A1 has no Pose3 or "
                             "Point3 value"),
        (graph, mixed, "value B0 is a Pose2 among Pose3 or Point3 values: a PyFG file is "
                       "planar or 3D"),
        (planar_factor, _pose3s(a0, a1), "factor 1 (BetweenFactorPose2 on A0 A1): a 3D PyFG "
                                         "file has no line for it"),
        (robust, _pose3s(a0, a1), "factor 0 (BetweenFactorPose3 on A0 A1): a Robust noise "
                                  "model; a PyFG line holds a Gaussian covariance"),
    ]
    for graph_, values, message in cases:
        with pytest.raises(OutputError) as caught:
            write_pyfg(tmp_path / "x.pyfg", graph_, values)
        assert str(caught.value) == message
    with pytest.raises(OutputError, match=re.escape(
            "factor 1 (BetweenFactorPose2 on A0 A1): a 3D PyFG file has no line for it")):
        check_pyfg_graph(planar_factor)
    assert not (tmp_path / "x.pyfg").exists()


# --------------------------------------------------------------------------- bad lines

EDGE = "EDGE_SE3:QUAT 2.25 A0 A1 1.02 0.08 0.04 0.0 0.0 0.0 1.0"
BAD_LINES = [
    (f"{EDGE} {COVARIANCE.rsplit(' ', 1)[0]}",
     "EDGE_SE3:QUAT needs 31 fields after the tag (t a b dx dy dz qx qy qz qw and 21 "
     "covariance entries), found 30"),
    ("VERTEX_XYZ L0 3.0 4.0", "VERTEX_XYZ needs 4 fields after the tag (name x y z), found 3"),
    ("VERTEX_SE3:QUAT 9.0 A7 0.0 0.0 0.0 0.0 0.0 0.0", "VERTEX_SE3:QUAT needs 9 fields after "
     "the tag (t name x y z qx qy qz qw), found 8"),
    ("VERTEX_SE3:QUAT 9.0 A7 0.0 inf 0.0 0.0 0.0 0.0 1.0",
     "VERTEX_SE3:QUAT field 4 is not finite: 'inf'"),
    (f"EDGE_SE3:QUAT 2.25 A0 A1 1.02 0.08 0.04 0.0 nan 0.0 1.0 {COVARIANCE}",
     "EDGE_SE3:QUAT field 8 is not finite: 'nan'"),
    ("VERTEX_SE3:QUAT 9.0 A7 0.0 0.0 0.0 0.0 0.0 0.0 0.0",
     "VERTEX_SE3:QUAT quaternion (0.0, 0.0, 0.0, 0.0) is zero: it names no rotation"),
    (f"EDGE_SE3:QUAT 2.25 A0 A1 1.02 0.08 0.04 0.0 0.0 0.0 0.0 {COVARIANCE}",
     "EDGE_SE3:QUAT quaternion (0.0, 0.0, 0.0, 0.0) is zero: it names no rotation"),
    (f"{EDGE} {COVARIANCE.replace('0.0002', '-0.0002')}",
     f"EDGE_SE3:QUAT covariance is not positive definite "
     f"({COVARIANCE.replace('0.0002', '-0.0002')})"),
    ("VERTEX_XYZ:PRIOR 0.75 L1 -1.2 5.1 2.1 4.0 0.5 0.0 4.0 0.0 0.0",
     "VERTEX_XYZ:PRIOR covariance is not positive definite (4.0 0.5 0.0 4.0 0.0 0.0)"),
    ("EDGE_RANGE 4.5 A0 L7 5.1 0.25",
     "EDGE_RANGE names L7, which no vertex line (VERTEX_SE3:QUAT, VERTEX_XYZ) defines"),
    ("EDGE_RANGE 4.5 A0 L0 -5.1 0.25", "EDGE_RANGE range must be >= 0, found -5.1"),
    ("EDGE_RANGE 4.5 A0 L0 nan 0.25", "EDGE_RANGE field 4 is not finite: 'nan'"),
    ("EDGE_RANGE 4.5 A0 L0 5.1 0", "EDGE_RANGE variance must be positive, found 0"),
    ("EDGE_SE3_XYZ 3.5 A2 B0 1.3 3.4 0.5 0.01 0.002 0.0 0.02 0.0 0.03",
     "EDGE_SE3_XYZ: B0 is a pose (its vertex is on line 4); EDGE_SE3_XYZ takes a landmark there"),
    ("EDGE_SE3_XYZ 3.5 A2 L0 0.0 0.0 0.0 0.01 0.002 0.0 0.02 0.0 0.03",
     "EDGE_SE3_XYZ: a landmark measurement at range 0: its bearing is undefined"),
    ("VERTEX_XYZ A1 0.0 0.0 0.0", "vertex A1 defined twice (first on line 2)"),
    ("VERTEX_XY L5 0.0 0.0", "VERTEX_XY is a planar PyFG line; this file is 3D "
     "(VERTEX_SE3:QUAT on line 1)"),
    ("EDGE_SE2 2.25 A0 A1 1.0 0.0 0.0 1.0 0.0 0.0 1.0 0.0 1.0", "EDGE_SE2 is a planar PyFG line; "
     "this file is 3D (VERTEX_SE3:QUAT on line 1)"),
    ("EDGE_SE3 0 A0 A1 1.0", "unknown PyFG line 'EDGE_SE3' (3D PyFG: VERTEX_SE3:QUAT, "
     "VERTEX_XYZ, VERTEX_SE3:QUAT:PRIOR, VERTEX_XYZ:PRIOR, EDGE_SE3:QUAT, EDGE_SE3_XYZ, "
     "EDGE_RANGE)"),
]


@pytest.mark.parametrize(("bad", "reason"), BAD_LINES)
def test_a_bad_3d_line_is_named_with_its_reason(tmp_path, bad, reason):
    text, line = with_bad_line(SMALL, bad)
    path = _file(tmp_path, text)
    with pytest.raises(G2oFormatError) as caught:
        read_pyfg(path)
    assert str(caught.value) == f"{path}:{line}: {reason}"


def test_a_3d_line_in_a_planar_file_is_named_at_its_line(tmp_path):
    text = ("VERTEX_SE2 0.0 A0 0.0 0.0 0.0\nEDGE_RANGE 0.0 A0 L0 1.0 0.1\n"
            "VERTEX_XYZ L0 1.0 0.0 0.0\n")
    path = _file(tmp_path, text, "mixed.pyfg")
    with pytest.raises(G2oFormatError) as caught:
        read_pyfg(path)
    assert str(caught.value) == (f"{path}:3: VERTEX_XYZ is a 3D PyFG line; this file is "
                                 "planar (VERTEX_SE2 on line 1)")


def test_a_3d_vertex_nothing_measures_is_named(tmp_path):
    path = _file(tmp_path, SMALL.replace("VERTEX_XYZ L1 -1.0 5.0 2.0\n",
                                         "VERTEX_XYZ L1 -1.0 5.0 2.0\nVERTEX_XYZ L9 0 0 0\n"))
    with pytest.raises(G2oFormatError, match=re.escape(
            f"{path}:7: VERTEX_XYZ L9: no factor line names it (GTSAM's optimizers need each "
            "variable in a factor)")):
        read_pyfg(path)


# --------------------------------------------------------------------------- rlpgo-init


def test_init_writes_a_3d_pyfg_guess_with_the_inputs_timestamps(tmp_path):
    graph, values, _ = range_aided_3d(2, 1.0, n=30, beacons=3, pose_ranges=6)
    poses = [key for key in values.keys() if gtsam.Symbol(key).chr() == ord("x")]
    times = PyfgTimes({key: 0.5 * k for k, key in enumerate(poses)},
                      tuple(0.25 * k for k in range(graph.size())))
    source = tmp_path / "in.pyfg"
    write_pyfg(source, graph, values, times)
    out = tmp_path / "out.pyfg"
    result = CliRunner().invoke(init_main, [str(source), "-o", str(out)])
    cli_ok(result)
    assert "certificate: " in result.stdout and "ranges inside" in result.stdout
    written = float(re.search(r"chi2 (\S+); [\d.]+ s; wrote", result.stdout).group(1))
    read = read_pyfg_file(out)
    assert read.group is SE3 and (read.poses, read.landmarks) == (30, 3)
    assert chi2(read.graph, read.values) == pytest.approx(written, rel=1e-5)  # as printed
    assert written < 0.01 * chi2(graph, values)
    assert read.times.factors == times.factors and read.times.vertices == times.vertices
    assert chi2(read.graph, values) == pytest.approx(chi2(graph, values), rel=1e-9)


def test_init_names_a_bad_3d_pyfg_line(tmp_path):
    path = _file(tmp_path, SMALL.replace("EDGE_RANGE 4.5 A0 L0 5.1 0.25",
                                         "EDGE_RANGE 4.5 A0 L0 5.1 0.0"))
    cli_error(CliRunner().invoke(init_main, [str(path), "-o", str(tmp_path / "o.pyfg")]),
              f"{path}:12: EDGE_RANGE variance must be positive, found 0.0")
