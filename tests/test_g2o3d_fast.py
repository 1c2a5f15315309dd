"""The fast 3D g2o reader and writer agree with the careful, line-by-line ones.

``read_g2o`` parses a regular 3D file a chunk at a time and hands anything unusual to the
careful reader; ``g2o_text_lines`` formats in bulk and hands anything unusual to the careful
writer. On generated graphs, SE-Sync's files and files the fast reader declines, both paths
must give the same graph and values, bit for bit, and the same text.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import io
from rlpgo_gtsam.errors import G2oFormatError
from rlpgo_gtsam.groups import SE3
from rlpgo_gtsam.io import read, scan, write
from rlpgo_gtsam.io.formats import SPATIAL
from rlpgo_gtsam.synthetic import generate
from tests.conftest import DATASETS


def _rows(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> tuple[list, list]:
    """Every factor and value as exact numbers (matrices as bytes: bit for bit)."""
    factors = []
    for index in range(graph.size()):
        factor = graph.at(index)
        model = factor.noiseModel()
        if isinstance(factor, gtsam.BetweenFactorPose3):
            factors.append(("between", tuple(factor.keys()), factor.measured().matrix().tobytes(),
                            model.information().tobytes()))
        else:
            factors.append(("prior", tuple(factor.keys()), factor.prior().matrix().tobytes(),
                            type(model).__name__))
    poses = [(key, values.atPose3(key).matrix().tobytes()) for key in values.keys()]
    return factors, poses


def _text_fast(graph, values):
    return write.text_fast(graph, values, SPATIAL)


def _text_careful(graph, values):
    return write.text_careful(graph, values, SPATIAL)


def _careful_read(path: Path):
    return read.build(path, read.read_table(path, SPATIAL, fast=False), SPATIAL)[:2]


def _assert_same_read(path: Path) -> None:
    assert _rows(*io.read_g2o(path)) == _rows(*_careful_read(path))


def _fast_scan_accepts(path: Path) -> bool:
    with path.open("rb") as handle:
        return scan.scan(handle, SPATIAL) is not None


def _generated(n: int, seed: int, fixed: bool) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    sample = generate(n, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(seed),
                      noisy_measurements=True, group=SE3)
    graph, values = sample.graph, sample.initial
    if fixed:
        for key in (0, n // 2):
            graph.add(gtsam.PriorFactorPose3(key, values.atPose3(key),
                                             gtsam.noiseModel.Constrained.All(6)))
    return graph, values


@pytest.mark.parametrize("n, seed, fixed", [(300, 1, False), (1200, 2, True)])
def test_generated_graphs_read_and_write_the_same_both_ways(tmp_path, n, seed, fixed):
    graph, values = _generated(n, seed, fixed)
    written = _text_fast(graph, values)
    assert written is not None  # the speed comes from here: it must not fall back
    assert written == _text_careful(graph, values)
    path = tmp_path / "g.g2o"
    path.write_text(written[0])
    assert _fast_scan_accepts(path)
    _assert_same_read(path)
    # what was read writes the same text on both paths (not always the text it was read
    # from: a quaternion through a rotation matrix and back can move in its 15th digit)
    graph2, values2 = io.read_g2o(path)
    assert _text_fast(graph2, values2) == _text_careful(graph2, values2)


@pytest.mark.parametrize("name", ["torus3D.g2o", "sphere2500.g2o", "smallGrid3D.g2o"])
def test_datasets_read_and_write_the_same_both_ways(name):
    path = DATASETS / "3d" / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    assert _fast_scan_accepts(path)  # a distinct information text per edge, spaces padded
    _assert_same_read(path)
    graph, values = io.read_g2o(path)
    assert _text_fast(graph, values) == _text_careful(graph, values)
    graph, values = gtsam.readG2o(str(path), True)  # one noise model object per edge
    assert _text_fast(graph, values) == _text_careful(graph, values)


_INFO = "1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1"
BASE = [
    "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1",
    "VERTEX_SE3:QUAT 1 1 0 0 0 0 0.1 1",
    "VERTEX_SE3:QUAT 2 2 0.5 0 0.1 0 0 2",
    "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.1 1 " + _INFO,
    "EDGE_SE3:QUAT 1 2 1 0.5 0 0.1 0 -0.1 1 " + _INFO.replace("1 0 0 0 0 0", "2 0.5 0 0 0 0", 1),
    "EDGE_SE3:QUAT 0 2 2 0.5 0 0.1 0 0 1e0 " + _INFO,
    "FIX 0",
]


@pytest.mark.parametrize("lines, fast", [
    pytest.param(BASE, True, id="plain"),
    pytest.param([" " + line.replace(" ", "\t") + " \r" for line in BASE], True, id="tabs_crlf"),
    pytest.param(["# caf\u00e9", "", *BASE[:3], "# edges", *BASE[3:]], True, id="comments"),
    pytest.param([line.replace(" ", "\u00a0", 1) for line in BASE], True, id="nbsp"),
    pytest.param(BASE[3:6] + ["FIX 1 2"], True, id="edges_only"),
    pytest.param(["VERTEX_SE3:QUAT 18446744073709551615 3 0 0 0 0 0 1",
                  "EDGE_SE3:QUAT 2 18446744073709551615 1 -0.5 0 0 0 0 1 " + _INFO, *BASE], True,
                 id="largest_id"),
    pytest.param([BASE[0], "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 1e-9", *BASE[2:]], False,
                 id="nearly_zero_quaternion"),
])
def test_unusual_but_valid_files_read_the_same(tmp_path, lines, fast):
    path = tmp_path / "odd.g2o"
    path.write_bytes(("\n".join(lines) + "\n").encode())
    assert _fast_scan_accepts(path) == fast
    _assert_same_read(path)


@pytest.mark.parametrize("line, reason", [
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0", "needs 30 numbers after the tag, found 11"),
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1_0 " + _INFO, "field 9 is not a number: '1_0'"),
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 0 " + _INFO, "is zero: it names no rotation"),
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 -" + _INFO, "not positive definite"),
    ("EDGE_SE3:QUAT 1 1 1 0 0 0 0 0 1 " + _INFO, "joins vertex 1 to itself"),
    ("EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 inf " + _INFO, "field 9 is not finite"),
    ("VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1", "id 1 defined twice (first on line 2)"),
    ("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", "a planar line in a 3D file"),
])
def test_an_error_in_a_long_file_names_its_line(tmp_path, monkeypatch, line, reason):
    """A bad line deep in a file the fast reader reads in small chunks: the careful reader,
    which it hands the file to, names that line."""
    monkeypatch.setattr(scan, "_CHUNK_BYTES", 301)
    lines = BASE[:6] + [BASE[3]] * 50
    lines.insert(40, line)
    path = tmp_path / "bad.g2o"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(G2oFormatError) as caught:
        io.read_g2o(path)
    assert str(caught.value).startswith(f"{path}:41: ")
    assert reason in str(caught.value)


def test_a_file_across_chunks_keeps_its_line_numbers(tmp_path, monkeypatch):
    graph, values = _generated(150, 5, fixed=True)
    path = tmp_path / "g.g2o"
    path.write_text("# header\n\n" + io.g2o_text(graph, values))
    whole = _rows(*io.read_g2o(path))
    monkeypatch.setattr(scan, "_CHUNK_BYTES", 301)
    assert _fast_scan_accepts(path)
    assert _rows(*io.read_g2o(path)) == whole
    _assert_same_read(path)


@pytest.mark.parametrize("name", ["cubicle.g2o", "parking-garage.g2o"])
def test_matrices_the_rule_changes_read_and_warn_the_same_both_ways(name):
    """The 3D information rule on real matrices (cubicle's indefinite couplings, parking
    garage's ill-conditioned ones): the same matrices used and the same warnings."""
    path = DATASETS / "3d" / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    assert _fast_scan_accepts(path)
    with warnings.catch_warnings(record=True) as fast:
        warnings.simplefilter("always")
        rows = _rows(*io.read_g2o(path))
    with warnings.catch_warnings(record=True) as careful:
        warnings.simplefilter("always")
        table = read.read_table(path, SPATIAL, fast=False)
        read.warn_changes(path, SPATIAL, table.changed)
        assert rows == _rows(*read.build(path, table, SPATIAL)[:2])
    assert [str(w.message) for w in fast] == [str(w.message) for w in careful]


def test_cubicle_is_gtsam_read_g2o_graph_and_writes_its_printed_matrices(tmp_path):
    """The whole cubicle: the reader's graph is gtsam.readG2o's (the same noise models, the
    same error to 1e-9 at either's values), and the writer writes the printed matrices of
    GTSAM's partial factors, which read back to the same models."""
    path = DATASETS / "3d" / "cubicle.g2o"
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        graph, values = io.read_g2o(path)
    theirs, their_values = gtsam.readG2o(str(path), True)
    assert graph.size() == theirs.size() == 16869
    assert all(np.array_equal(graph.at(k).noiseModel().R(), theirs.at(k).noiseModel().R())
               for k in range(graph.size()))
    for at in (values, their_values):
        assert graph.error(at) == pytest.approx(theirs.error(at), rel=1e-9)
    written = _text_fast(theirs, their_values)
    assert written is not None  # the careful writer agrees: tests/test_cli_3d.py, on its head
    out = tmp_path / "out.g2o"
    out.write_text(written[0])
    back, back_values = gtsam.readG2o(str(out), True)
    for k in range(0, back.size(), 7):
        np.testing.assert_allclose(back.at(k).noiseModel().R(), theirs.at(k).noiseModel().R(),
                                   rtol=1e-9, atol=1e-6)
    assert back.error(back_values) == pytest.approx(theirs.error(their_values), rel=1e-9)
