"""Landmark lines in the g2o reader and writer: GTSAM's example files read as
``gtsam.readG2o`` reads them (where it does), the lines it skips or refuses read by their
meaning, every malformed landmark line named by its ``file:line``, and read -> write -> read
giving back the same graph.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam.errors import G2oFormatError, InformationWarning, OutputError
from rlpgo_gtsam.io import (
    file_group,
    g2o_text,
    g2o_text_lines,
    read_g2o,
    read_g2o_extracted,
    read_g2o_lines,
    read_poses,
    write_g2o,
)
from rlpgo_gtsam.landmarks import landmark_key, relative_point

L = landmark_key
INFO_2 = "1 0 0 1 0 1"
INFO_3 = " ".join(["100", "0", "0", "0", "0", "0", "100", "0", "0", "0", "0", "100", "0", "0",
                   "0", "100", "0", "0", "100", "0", "100"])
# EDGE_SE3_TRACKXYZ's information in GTSAM's example files (g2o order, upper triangle)
TRACK_INFO = ("72.57142857142857 -13.71428571428571 -41.14285714285714 93.14285714285714 "
              "-20.57142857142857 38.28571428571429")


def example(name: str) -> Path:
    return Path(gtsam.findExampleDataFile(name))


def chi2(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    return 2.0 * graph.error(values)


def factor_kinds(graph: gtsam.NonlinearFactorGraph) -> dict[str, int]:
    kinds: dict[str, int] = {}
    for index in range(graph.size()):
        name = type(graph.at(index)).__name__
        kinds[name] = kinds.get(name, 0) + 1
    return kinds


def write(folder: Path, text: str, name: str = "graph.g2o") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def assert_same_values(values: gtsam.Values, expected: gtsam.Values, tol: float = 1e-9) -> None:
    assert sorted(values.keys()) == sorted(expected.keys())
    assert values.equals(expected, tol)


def round_trip(folder: Path, graph: gtsam.NonlinearFactorGraph,
               values: gtsam.Values) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    path = folder / "written.g2o"
    write_g2o(path, graph, values)
    return read_g2o(path)


# --------------------------------------------------------------------------- GTSAM's files


@pytest.mark.parametrize("name", ["known_landmark_localization_20.g2o",
                                  "known_landmark_localization_3.g2o",
                                  "edge_se3_trackxyz_example.g2o"])
def test_trackxyz_files_read_as_gtsam_reads_them(name):
    """Poses, landmarks l<j> and EDGE_SE3_TRACKXYZ as BearingRangeFactor3D: the graph error
    and the values are gtsam.readG2o's."""
    path = example(name)
    assert file_group(path).dimension == 3
    graph, values = read_g2o(path)
    expected_graph, expected_values = gtsam.readG2o(str(path), True)
    assert factor_kinds(graph) == factor_kinds(expected_graph)
    assert_same_values(values, expected_values)
    assert chi2(graph, values) == pytest.approx(chi2(expected_graph, expected_values),
                                                rel=1e-9, abs=1e-12)


def test_known_landmark_localization_keys_and_ground_truth():
    path = example("known_landmark_localization_20.g2o")
    graph, values = read_g2o(path)
    assert sorted(values.keys()) == sorted(list(range(20)) + [L(j) for j in range(4)])
    assert values.atPoint3(L(0)).tolist() == [4.0, 1.0, 2.0]  # VERTEX_TRACKXYZ 0 4 1 2
    # read_poses: the poses of the vertex lines; landmark vertices are left out
    assert sorted(read_poses(path).keys()) == list(range(20))


def test_missing_landmark_vertex_starts_at_its_first_sighting():
    """GTSAM's edge_se3_trackxyz_missing_vertex.g2o (gtsam.readG2o refuses it): landmark 9
    has no vertex line and starts where pose 7 sees it."""
    graph, values = read_g2o(example("edge_se3_trackxyz_missing_vertex.g2o"))
    pose = gtsam.Pose3(gtsam.Rot3.Quaternion(0.7071067811865475, 0, 0, 0.7071067811865475),
                       np.array([1.0, -2.0, 0.5]))
    np.testing.assert_allclose(values.atPoint3(L(9)), pose.transformFrom(np.array([2.0, 1, 3])),
                               atol=1e-12)
    assert chi2(graph, values) < 1e-20  # the measurement made the value


def test_nonidentity_offset_is_the_body_frame_measurement(tmp_path):
    """edge_se3_trackxyz_nonidentity_offset.g2o: sensor 1 sits 0.1 m along the body's x, so
    the point (2, 1, 3) seen by the sensor is (2.1, 1, 3) in the body frame with the same
    information (no rotation): the graph of that identity-offset file, which gtsam.readG2o
    reads."""
    path = example("edge_se3_trackxyz_nonidentity_offset.g2o")
    graph, values = read_g2o(path)
    with pytest.raises(Exception, match="identity PARAMS_SE3OFFSET"):
        gtsam.readG2o(str(path), True)
    point, information = relative_point(graph.at(0))
    np.testing.assert_allclose(point, [2.1, 1.0, 3.0], rtol=1e-14)
    upper = np.array(TRACK_INFO.split(), dtype=float)
    np.testing.assert_allclose(information[np.triu_indices(3)], upper, rtol=1e-12)
    by_hand = write(tmp_path, path.read_text().replace("PARAMS_SE3OFFSET 1 0.1 0 0",
                                                       "PARAMS_SE3OFFSET 1 0 0 0")
                    .replace("EDGE_SE3_TRACKXYZ 7 9 1 2 1 3", "EDGE_SE3_TRACKXYZ 7 9 1 2.1 1 3"))
    expected_graph, expected_values = gtsam.readG2o(str(by_hand), True)
    assert_same_values(values, expected_values)
    assert chi2(graph, values) == pytest.approx(chi2(expected_graph, expected_values), rel=1e-9)
    assert chi2(graph, values) > 0.5  # the 0.1 m offset is what the pose does not explain


def test_rotated_offset_rotates_point_and_information(tmp_path):
    """A sensor turned 90 degrees about z, 0.5 m ahead: the sensor's (x, y, z) is the body's
    (-y, x, z) + (0.5, 0, 0), and its information's axes turn alike. Worked out by hand, the
    body-frame line is one gtsam.readG2o reads."""
    pose = "VERTEX_SE3:QUAT 0 1 2 3 0 0 0 1\nVERTEX_TRACKXYZ 4 0 0 0\n"
    # sensor information [[4, 1, 2], [1, 5, 3], [2, 3, 6]]
    sensor = write(tmp_path, pose + "PARAMS_SE3OFFSET 2 0.5 0 0 0 0 0.7071067811865476 "
                   "0.7071067811865476\nEDGE_SE3_TRACKXYZ 0 4 2 1 -2 3 4 1 2 5 3 6\n", "s.g2o")
    # body: point (2 + 0.5, 1, 3); information [[5, -1, -3], [-1, 4, 2], [-3, 2, 6]]
    body = write(tmp_path, pose + "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n"
                 "EDGE_SE3_TRACKXYZ 0 4 0 2.5 1 3 5 -1 -3 4 2 6\n", "b.g2o")
    graph, values = read_g2o(sensor)
    point, information = relative_point(graph.at(0))
    np.testing.assert_allclose(point, [2.5, 1.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(information, [[5, -1, -3], [-1, 4, 2], [-3, 2, 6]], atol=1e-9)
    expected_graph, expected_values = gtsam.readG2o(str(body), True)
    assert chi2(graph, values) == pytest.approx(chi2(expected_graph, expected_values), rel=1e-9)
    assert chi2(graph, values) > 1.0


@pytest.mark.parametrize(("name", "consecutive_m"), [("victoriaPark_reduced_1k.g2o", 0.15),
                                                     ("cityTrees_reduced_1k.g2o", 0.3)])
def test_landmark2_is_a_point_in_the_pose_frame(name, consecutive_m):
    """LANDMARK2 i j dx dy a b c: landmark j at (dx, dy) in pose i's frame, information
    [[a, b], [b, c]]. gtsam.readG2o skips these lines: its graph is the odometry alone, which
    ours holds too. Read this way, consecutive sightings of a landmark chained through the
    odometry agree to decimetres; read as range and bearing they would miss by metres."""
    path = example(name)
    graph, values, lines = read_g2o_lines(path)
    text = path.read_text().splitlines()
    sightings = [line for line in text if line.startswith("LANDMARK2")]
    assert factor_kinds(graph) == {"BetweenFactorPose2": 999,
                                   "BearingRangeFactor2D": len(sightings)}
    # the odometry: gtsam.readG2o's factors, the same error at its values
    odometry, odometry_values = gtsam.readG2o(str(path), False)
    ours = gtsam.NonlinearFactorGraph()
    for index in range(graph.size()):
        if isinstance(graph.at(index), gtsam.BetweenFactorPose2):
            ours.add(graph.at(index))
    assert chi2(ours, odometry_values) == pytest.approx(chi2(odometry, odometry_values),
                                                        rel=1e-9, abs=1e-15)
    first: dict[int, np.ndarray] = {}
    apart, apart_bearing_range = [], []
    last: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for index in range(graph.size()):
        factor = graph.at(index)
        if not isinstance(factor, gtsam.BearingRangeFactor2D):
            continue
        fields = text[lines[index] - 1].split()
        assert fields[0] == "LANDMARK2"
        i, j = int(fields[1]), int(fields[2])
        dx, dy, a, b, c = map(float, fields[3:8])
        assert tuple(factor.keys()) == (i, L(j))  # landmark ids are their own: l<j>
        point, information = relative_point(factor)
        np.testing.assert_allclose(point, [dx, dy], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(information, [[a, b], [b, c]], rtol=1e-9, atol=1e-9 * a)
        pose = values.atPose2(i)
        seen = pose.transformFrom(np.array([dx, dy]))
        first.setdefault(j, seen)
        as_bearing_range = pose.transformFrom(dx * np.array([np.cos(dy), np.sin(dy)]))
        if j in last:
            apart.append(np.linalg.norm(seen - last[j][0]))
            apart_bearing_range.append(np.linalg.norm(as_bearing_range - last[j][1]))
        last[j] = (seen, as_bearing_range)
    for j, seen in first.items():  # no VERTEX_XY: each landmark starts at its first sighting
        np.testing.assert_allclose(values.atPoint2(L(j)), seen, atol=1e-9)
    assert np.median(apart) < consecutive_m
    assert np.median(apart_bearing_range) > 10 * consecutive_m


def test_bearing_range_and_landmark_lines_read_as_gtsam_reads_them(tmp_path):
    """BR: bearing and range with diagonal sigmas; LANDMARK: (dx, dy) as bearing and range,
    sigmas sqrt(v1 / 10) and sqrt(v1) where v1 == v3, else 1 and 1 (a warning). The graph
    and values are gtsam.readG2o's: VERTEX_XY where given, else the first sighting."""
    path = write(tmp_path, "\n".join([
        "VERTEX_SE2 0 0 0 0",
        "VERTEX_SE2 1 1 0.2 0.5",
        f"EDGE_SE2 0 1 1 0 0.5 {INFO_2}",
        "VERTEX_XY 3 4.5 1.2",
        "BR 0 3 0.3 5.0 0.1 0.2",
        "BR 1 3 0.05 3.5 0.1 0.2",
        "LANDMARK 1 4 2.0 1.0 0.5 0.1 0.5",
        "LANDMARK 0 4 3.1 2.4 0.5 0 0.5",
        "LANDMARK 1 5 -2.0 1.5 0.5 0 0.7",
        "BR 0 5 2.1 2.2 0.2 0.3",
    ]) + "\n")
    with pytest.warns(InformationWarning,
                      match=r"1 LANDMARK line \(first on line 9\) has v1 and v3 apart"):
        graph, values = read_g2o(path)
    expected_graph, expected_values = gtsam.readG2o(str(path), False)
    assert factor_kinds(graph) == factor_kinds(expected_graph)
    assert_same_values(values, expected_values, 1e-12)
    assert chi2(graph, values) == pytest.approx(chi2(expected_graph, expected_values), rel=1e-9)
    for index in range(1, graph.size()):
        ours, theirs = graph.at(index), expected_graph.at(index)
        assert ours.keys() == theirs.keys()
        np.testing.assert_allclose(ours.noiseModel().sigmas(), theirs.noiseModel().sigmas(),
                                   rtol=1e-12)


def test_edge_se2_xy_reads_and_round_trips(tmp_path):
    """g2o's EDGE_SE2_XY: pose i sees landmark j at (dx, dy) in its frame; a landmark id may
    be a pose id (its key is l<j>)."""
    path = write(tmp_path, "\n".join([
        "VERTEX_SE2 0 0 0 0",
        "VERTEX_SE2 1 1 0 1.5707963267948966",
        "VERTEX_XY 0 2 1",
        f"EDGE_SE2 0 1 1 0 1.5707963267948966 {INFO_2}",
        "EDGE_SE2_XY 0 0 2 1 10 2 20",
        "EDGE_SE2_XY 1 0 1.1 -1 10 0 10",
        "FIX 0",
    ]) + "\n")
    graph, values, lines = read_g2o_lines(path)
    assert lines == [4, 5, 6, 7]  # edges, then measurements, then FIX priors
    assert factor_kinds(graph) == {"BetweenFactorPose2": 1, "BearingRangeFactor2D": 2,
                                   "PriorFactorPose2": 1}
    assert sorted(values.keys()) == [0, 1, L(0)]
    point, information = relative_point(graph.at(1))
    np.testing.assert_allclose(point, [2, 1], atol=1e-12)
    np.testing.assert_allclose(information, [[10, 2], [2, 20]], rtol=1e-12)
    # pose 1 sees l0 at (1.1, -1): 0.1 m off along its x, i.e. along the world's y
    assert chi2(graph, values) == pytest.approx(0.1 ** 2 * 10, rel=0.05)
    text, written_lines = g2o_text_lines(graph, values)
    assert text.splitlines()[3:] == ["EDGE_SE2 0 1 1.0 0.0 1.5707963267949 1.0 0.0 0.0 1.0 "
                                     "0.0 1.0", "EDGE_SE2_XY 0 0 2.0 1.0 10.0 2.0 20.0",
                                     "EDGE_SE2_XY 1 0 1.1 -1.0 10.0 0.0 10.0", "FIX 0"]
    again, again_values, again_lines = read_g2o_lines(write(tmp_path, text, "again.g2o"))
    assert again_lines == written_lines
    assert_same_values(again_values, values)
    assert chi2(again, again_values) == pytest.approx(chi2(graph, values), rel=1e-9)


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", ["victoriaPark_reduced_1k.g2o", "cityTrees_reduced_1k.g2o",
                                  "known_landmark_localization_20.g2o",
                                  "edge_se3_trackxyz_example.g2o",
                                  "edge_se3_trackxyz_nonidentity_offset.g2o"])
def test_round_trip_keeps_graph_and_values(tmp_path, name):
    """read -> write -> read: the same factors, the same error to 1e-9 and the same values
    (LANDMARK2 and sensor-frame lines come back as EDGE_SE2_XY and identity-offset
    EDGE_SE3_TRACKXYZ lines)."""
    graph, values = read_g2o(example(name))
    again, again_values = round_trip(tmp_path, graph, values)
    assert factor_kinds(again) == factor_kinds(graph)
    assert_same_values(again_values, values)
    assert chi2(again, again_values) == pytest.approx(chi2(graph, values), rel=1e-9, abs=1e-20)
    text = (tmp_path / "written.g2o").read_text()
    if file_group(example(name)).dimension == 3:
        assert text.count("PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n") == 1
        assert "EDGE_SE3_TRACKXYZ" in text and "VERTEX_TRACKXYZ" in text
    else:
        assert "EDGE_SE2_XY" in text and "VERTEX_XY" in text and "LANDMARK2" not in text


def test_round_trip_of_bearing_range_lines(tmp_path):
    """A BR line's diagonal bearing-range noise comes back, through EDGE_SE2_XY's full
    information, as the same factor."""
    path = write(tmp_path, "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
                 f"EDGE_SE2 0 1 1 0 0 {INFO_2}\nBR 0 7 0.7 12.5 0.01 0.3\nBR 1 7 0.8 11 0.02 "
                 "0.2\n")
    graph, values = read_g2o(path)
    again, again_values = round_trip(tmp_path, graph, values)
    assert_same_values(again_values, values)
    assert chi2(again, again_values) == pytest.approx(chi2(graph, values), rel=1e-9)
    for index in (1, 2):
        np.testing.assert_allclose(again.at(index).noiseModel().information(),
                                   graph.at(index).noiseModel().information(), rtol=1e-9,
                                   atol=1e-9)


def test_extraction_is_the_callers_for_a_landmark_file():
    graph, values, lines, extracted = read_g2o_extracted(example("victoriaPark_reduced_1k.g2o"))
    assert extracted is None and len(lines) == graph.size()


# --------------------------------------------------------------------------- broken files

PLANAR = f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 {INFO_2}\n"  # lines 1-3
SPATIAL = ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
           f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 {INFO_3}\n")  # lines 1-3
OFFSET = "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\n"


@pytest.mark.parametrize(("text", "line", "reason"), [
    # zero range
    (PLANAR + "EDGE_SE2_XY 0 5 0 0 1 0 1\n", 4,
     "EDGE_SE2_XY sees landmark 5 from pose 0 at range 0.0: a bearing needs a positive, "
     "finite range"),
    (PLANAR + "BR 1 5 0.3 0 0.1 0.1\n", 4,
     "BR sees landmark 5 from pose 1 at range 0.0: a bearing needs a positive, finite range"),
    (PLANAR + "LANDMARK 1 5 0 0 0.5 0 0.5\n", 4,
     "LANDMARK sees landmark 5 from pose 1 at range 0.0: a bearing needs a positive, finite "
     "range"),
    # the sensor's 1 m offset puts the point at the body's origin
    (SPATIAL + "PARAMS_SE3OFFSET 0 1 0 0 0 0 0 1\nEDGE_SE3_TRACKXYZ 0 5 0 -1 0 0 1 0 0 1 0 1\n",
     5, "EDGE_SE3_TRACKXYZ sees landmark 5 from pose 0 at range 0.0: a bearing needs a "
     "positive, finite range"),
    # a pose without a vertex (the file has vertex lines)
    (PLANAR + "EDGE_SE2_XY 2 5 1 0 1 0 1\n", 4,
     "EDGE_SE2_XY refers to pose 2, which no VERTEX_SE2 line defines"),
    (SPATIAL + OFFSET + "EDGE_SE3_TRACKXYZ 7 5 0 1 0 0 1 0 0 1 0 1\n", 5,
     "EDGE_SE3_TRACKXYZ refers to pose 7, which no VERTEX_SE3:QUAT line defines"),
    (f"EDGE_SE2 0 1 1 0 0 {INFO_2}\nBR 2 5 0.3 4 0.1 0.1\n", 2,
     "BR refers to pose 2, which no VERTEX_SE2 or EDGE_SE2 line names"),
    # a landmark vertex that nothing measures
    (PLANAR + "VERTEX_XY 3 1 1\n", 4,
     "VERTEX_XY 3: no line measures landmark 3 (an initializer needs a connected graph)"),
    # an unknown sensor offset: named at its edge, wherever the offsets are
    (SPATIAL + OFFSET + "EDGE_SE3_TRACKXYZ 0 5 1 1 0 0 1 0 0 1 0 1\n", 5,
     "EDGE_SE3_TRACKXYZ names sensor offset 1, which no PARAMS_SE3OFFSET line defines"),
    (SPATIAL + "EDGE_SE3_TRACKXYZ 0 5 1 1 0 0 1 0 0 1 0 1\n" + OFFSET, 4,
     "EDGE_SE3_TRACKXYZ names sensor offset 1, which no PARAMS_SE3OFFSET line defines"),
    # wrong number counts
    (PLANAR + "VERTEX_XY 3 1\n", 4, "VERTEX_XY needs 3 numbers after the tag, found 2"),
    (PLANAR + "EDGE_SE2_XY 0 5 1 0 1 0\n", 4,
     "EDGE_SE2_XY needs 7 numbers after the tag, found 6"),
    (PLANAR + "LANDMARK2 0 5 1 0 1 0 1 0\n", 4,
     "LANDMARK2 needs 7 numbers after the tag, found 8"),
    (PLANAR + "BR 0 5 1 2 3\n", 4, "BR needs 6 numbers after the tag, found 5"),
    (PLANAR + "LANDMARK 0 5 1 2 3\n", 4, "LANDMARK needs 7 numbers after the tag, found 5"),
    (SPATIAL + "VERTEX_TRACKXYZ 5 1 2\n", 4,
     "VERTEX_TRACKXYZ needs 4 numbers after the tag, found 3"),
    (SPATIAL + "EDGE_SE3_TRACKXYZ 0 5 0 1 0 0 1 0 0 1 0\n", 4,
     "EDGE_SE3_TRACKXYZ needs 12 numbers after the tag, found 11"),
    (SPATIAL + "PARAMS_SE3OFFSET 0 0 0 0 0 0 1\n", 4,
     "PARAMS_SE3OFFSET needs 8 numbers after the tag, found 7"),
    # planar and 3D tags mixed
    (SPATIAL + "VERTEX_XY 3 1 1\n", 4,
     "VERTEX_XY: a planar line in a 3D file (a file holds 2D or 3D lines, not both)"),
    (SPATIAL + "LANDMARK2 0 5 1 0 1 0 1\n", 4,
     "LANDMARK2: a planar line in a 3D file (a file holds 2D or 3D lines, not both)"),
    (SPATIAL + "EDGE_SE2_XY 0 5 1 0 1 0 1\n", 4,
     "EDGE_SE2_XY: a planar line in a 3D file (a file holds 2D or 3D lines, not both)"),
    (PLANAR + OFFSET, 4,
     "PARAMS_SE3OFFSET: a 3D line in a planar file (a file holds 2D or 3D lines, not both)"),
    (PLANAR + "VERTEX_TRACKXYZ 5 1 2 3\n", 4,
     "VERTEX_TRACKXYZ: a 3D line in a planar file (a file holds 2D or 3D lines, not both)"),
    (OFFSET + PLANAR, 2,  # the offset makes the file 3D
     "VERTEX_SE2: a planar line in a 3D file (a file holds 2D or 3D lines, not both)"),
    # other malformed lines
    (PLANAR + "VERTEX_XY 3 1 1\nVERTEX_XY 3 2 2\n", 5,
     "VERTEX_XY id 3 defined twice (first on line 4)"),
    (PLANAR + "EDGE_SE2_XY 0 5 1 0 1 2 1\n", 4,
     "EDGE_SE2_XY information matrix is not positive definite"),
    (PLANAR + "BR 0 5 0.3 4 0 0.1\n", 4,
     "BR standard deviations must be positive, found 0.0 and 0.1"),
    (PLANAR + "LANDMARK 0 5 1 2 -0.5 0 -0.5\n", 4, "LANDMARK variance must be positive, "
     "found -0.5"),
    (PLANAR + f"EDGE_SE2_XY 0 {2**56} 1 0 1 0 1\n", 4,
     f"landmark id {2**56} is too large: GTSAM's key l<id> holds ids up to 2^56 - 1"),
    (PLANAR + "EDGE_SE2_XY 0 5 1 x 1 0 1\n", 4, "EDGE_SE2_XY field 4 is not a number: 'x'"),
    (SPATIAL + "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 0\n", 4,
     "PARAMS_SE3OFFSET quaternion (0.0, 0.0, 0.0, 0.0) is zero: it names no rotation"),
    (SPATIAL + OFFSET + OFFSET, 5, "PARAMS_SE3OFFSET id 0 defined twice (first on line 4)"),
    (PLANAR.replace("VERTEX_SE2 1", f"VERTEX_SE2 {L(5)}").replace("EDGE_SE2 0 1",
                                                                   f"EDGE_SE2 0 {L(5)}")
     + "EDGE_SE2_XY 0 5 1 0 1 0 1\n", 4,
     f"pose id {L(5)} is the GTSAM key of landmark 5 (l5): the two would be one variable"),
], ids=lambda value: value if isinstance(value, int) else None)
def test_broken_landmark_lines_name_their_line(tmp_path, text, line, reason):
    path = write(tmp_path, text)
    with pytest.raises(G2oFormatError) as raised:
        read_g2o(path)
    assert str(raised.value) == f"{path}:{line}: {reason}"


def test_gtsam_zero_range_file_names_its_line():
    path = example("edge_se3_trackxyz_zero_range.g2o")
    with pytest.raises(G2oFormatError) as raised:
        read_g2o(path)
    assert str(raised.value) == (f"{path}:4: EDGE_SE3_TRACKXYZ sees landmark 9 from pose 7 at "
                                 "range 0.0: a bearing needs a positive, finite range")


def test_file_group_reads_landmark_tags():
    """A landmark tag first decides the group as a pose tag would."""
    assert file_group(example("edge_se3_trackxyz_example.g2o")).dimension == 3  # EDGE first
    assert file_group(example("victoriaPark_reduced_1k.g2o")).dimension == 2


def test_landmark_measurements_alone_make_a_graph(tmp_path):
    """Poses joined through landmarks only: connected, so read."""
    path = write(tmp_path, "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 1 0\nEDGE_SE2_XY 0 2 3 0 1 0 1\n"
                 "EDGE_SE2_XY 1 2 3 -1 1 0 1\n")
    graph, values = read_g2o(path)
    assert factor_kinds(graph) == {"BearingRangeFactor2D": 2}
    assert chi2(graph, values) < 1e-20
    disconnected = write(tmp_path, "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 1 0\n"
                         "EDGE_SE2_XY 0 2 3 0 1 0 1\nEDGE_SE2_XY 1 3 3 -1 1 0 1\n", "d.g2o")
    with pytest.raises(G2oFormatError, match=r"d\.g2o: graph has 2 connected components"):
        read_g2o(disconnected)


# --------------------------------------------------------------------------- the writer


def test_writer_refuses_points_it_cannot_name(tmp_path):
    graph, values = read_g2o(write(tmp_path, PLANAR + "EDGE_SE2_XY 0 5 1 0 1 0 1\n"))
    stray = gtsam.Values(values)
    stray.insert(9, point2=np.array([1.0, 2.0]))  # a point whose key is no l<j>
    with pytest.raises(OutputError, match="a Point2 value has key 9: a g2o file names a "
                                          "landmark l<j> by its id j"):
        g2o_text(graph, stray)
    unmeasured = gtsam.Values(values)
    unmeasured.insert(L(6), point2=np.array([1.0, 2.0]))
    with pytest.raises(OutputError, match="landmark l6 has a value but no factor measures it"):
        g2o_text(graph, unmeasured)
