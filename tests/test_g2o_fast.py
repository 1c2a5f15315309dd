"""The fast g2o reader and writer agree with the careful, line-by-line ones.

``read_g2o`` parses a regular file a chunk at a time and hands anything unusual to the
careful reader; ``g2o_text_lines`` formats in bulk and hands anything unusual to the careful
writer. On generated graphs, the shared datasets and files the fast reader declines, both
paths must give the same graph, values and factor lines, and the same text.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from rlpgo_gtsam import io
from rlpgo_gtsam.errors import OutputError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.io import formats, read, scan, write
from rlpgo_gtsam.io.formats import PLANAR
from rlpgo_gtsam.synthetic import generate
from tests.conftest import DATASETS


def _rows(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> tuple[list, list]:
    """Every factor and value as exact numbers (information as bytes: bit for bit)."""
    factors = []
    for index in range(graph.size()):
        factor = graph.at(index)
        model = factor.noiseModel()
        if isinstance(factor, gtsam.BetweenFactorPose2):
            z = factor.measured()
            factors.append(("between", tuple(factor.keys()), (z.x(), z.y(), z.theta()),
                            model.information().tobytes()))
        else:
            p = factor.prior()
            factors.append(("prior", tuple(factor.keys()), (p.x(), p.y(), p.theta()),
                            type(model).__name__))
    poses = [(key, values.atPose2(key).x(), values.atPose2(key).y(), values.atPose2(key).theta())
             for key in values.keys()]
    return factors, poses


def _text_fast(graph, values):
    return write.text_fast(graph, values, PLANAR)


def _text_careful(graph, values):
    return write.text_careful(graph, values, PLANAR)


def _text_of_extraction(graph, values, made):
    return write.text_of_extraction(graph, values, made, PLANAR)


def _careful_read(path: Path):
    return read.build(path, read.read_table(path, PLANAR, fast=False), PLANAR, extract=True)


def _assert_same_extraction(made: PoseGraph2D, graph: gtsam.NonlinearFactorGraph,
                            values: gtsam.Values) -> None:
    """The reader's extraction is extraction's own, every array bit for bit (dtype, shape)."""
    walked = PoseGraph2D.from_gtsam(graph, values)
    assert made.graph is graph
    for name in ("keys", "poses", "edges", "measured", "information", "fixed", "fixed_poses",
                 "anchor_pose"):
        mine, theirs = getattr(made, name), getattr(walked, name)
        assert (mine.dtype, mine.shape) == (theirs.dtype, theirs.shape), name
        assert mine.tobytes() == theirs.tobytes(), name
    assert made.anchor == walked.anchor and type(made.anchor) is type(walked.anchor)


def _assert_same_read(path: Path) -> None:
    graph, values, lines, made = io.read_g2o_extracted(path)
    graph2, values2, lines2, made2 = _careful_read(path)
    assert lines == lines2
    assert _rows(graph, values) == _rows(graph2, values2)
    _assert_same_extraction(made, graph, values)
    _assert_same_extraction(made2, graph2, values2)


def _fast_scan_accepts(path: Path) -> bool:
    with path.open("rb") as handle:
        return scan.scan(handle, PLANAR) is not None


@pytest.mark.parametrize("n, seed, noisy, fixed", [
    (200, 1, True, False), (1500, 2, False, True), (1000, 3, True, True),
])
def test_generated_graphs_read_and_write_the_same_both_ways(tmp_path, n, seed, noisy, fixed):
    sample = generate(n, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(seed),
                      noisy_measurements=noisy)
    graph, values = sample.graph, sample.initial
    if fixed:
        for key in (0, n // 2):
            graph.add(gtsam.PriorFactorPose2(key, values.atPose2(key),
                                             gtsam.noiseModel.Constrained.All(3)))
    # _text_fast must take this graph, and write what the careful writer writes
    written = _text_fast(graph, values)
    assert written is not None
    assert written == _text_careful(graph, values)
    path = tmp_path / "g.g2o"
    path.write_text(written[0])
    assert _fast_scan_accepts(path)  # the speed comes from here: it must not fall back
    _assert_same_read(path)
    # what was read writes the same text again, on both paths
    graph2, values2 = io.read_g2o(path)
    assert _text_fast(graph2, values2) == _text_careful(graph2, values2) == written


def test_edge_only_file_chains_the_same_both_ways(tmp_path):
    sample = generate(300, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(4),
                      noisy_measurements=True)
    text = io.g2o_text(sample.graph, sample.initial)
    path = tmp_path / "edges.g2o"
    path.write_text("".join(line + "\n" for line in text.splitlines()
                            if line.startswith("EDGE_SE2")))
    assert _fast_scan_accepts(path)
    _assert_same_read(path)


@pytest.mark.parametrize("name", ["Intel.g2o", "MIT.g2o", "M3500.g2o"])  # MIT, Intel: a
def test_datasets_read_and_write_the_same_both_ways(name):  # distinct information per edge
    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    _assert_same_read(path)
    graph, values = io.read_g2o(path)
    assert _text_fast(graph, values) == _text_careful(graph, values)
    # a graph from gtsam.readG2o: one noise model object per edge, no FIX
    graph, values = gtsam.readG2o(str(path), False)
    assert _text_fast(graph, values) == _text_careful(graph, values)


BASE = [
    "VERTEX_SE2 0 0 0 0",
    "VERTEX_SE2 1 1 0 0.1",
    "VERTEX_SE2 2 2 0.5 0.2",
    "EDGE_SE2 0 1 1 0 0.1 500 0 0 500 0 2000",
    "EDGE_SE2 1 2 1 0.5 0.1 400 10 0 500 0 2000",
    "EDGE_SE2 0 2 2 0.5 0.2 500 0 0 500 0 2000",
    "FIX 0",
]


@pytest.mark.parametrize("lines, fast", [
    pytest.param(BASE, True, id="plain"),
    pytest.param([" " + line.replace(" ", "\t") for line in BASE], True, id="tabs"),
    pytest.param(["# caf\u00e9 \u00e9t\u00e9", *BASE], True, id="utf8_comment"),
    pytest.param([line.replace(" ", "\u00a0", 1) for line in BASE], True, id="nbsp"),
    pytest.param([*BASE[:3], "EDGE_SE2 0 1 1 0 0.1 500 0 0 500 0 2000\r\r", *BASE[4:]], False,
                 id="two_crs"),
    pytest.param(["VERTEX_SE2 " + "0" * 30 + " 0 0 0", *BASE[1:]], False, id="zero_padded_id"),
    pytest.param(["VERTEX_SE2 18446744073709551615 3 0 0",
                  "EDGE_SE2 2 18446744073709551615 1 -0.5 0 1 0 0 1 0 1", *BASE], True,
                 id="largest_id"),
])
def test_unusual_but_valid_files_read_the_same(tmp_path, lines, fast):
    path = tmp_path / "odd.g2o"
    path.write_bytes(("\n".join(lines) + "\n").encode())
    assert _fast_scan_accepts(path) == fast
    _assert_same_read(path)


def test_a_file_across_chunks_keeps_its_line_numbers(tmp_path, monkeypatch):
    """Lines split over chunk boundaries (tiny chunks) still come back whole, numbered."""
    sample = generate(120, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(5))
    path = tmp_path / "g.g2o"
    path.write_text("# header\n\n" + io.g2o_text(sample.graph, sample.initial))
    whole = io.read_g2o_lines(path)
    monkeypatch.setattr(scan, "_CHUNK_BYTES", 97)
    assert _fast_scan_accepts(path)
    chunked = io.read_g2o_lines(path)
    assert chunked[2] == whole[2]
    assert _rows(*chunked[:2]) == _rows(*whole[:2])
    _assert_same_read(path)


def test_values_built_by_gtsam_are_the_values_inserted_one_by_one(tmp_path):
    """Where GTSAM's parser builds the vertices (a memfd on Linux), its Pose2 values are the
    ones ``Pose2(x, y, theta)`` gives for the numbers this reader read, bit for bit (cos and
    sin included); without memfd the reader inserts them itself."""
    sample = generate(500, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(6),
                      noisy_measurements=True)
    path = tmp_path / "g.g2o"
    path.write_text("\n".join(line.replace(" ", "\t", 2) if k % 7 == 0 else line
                              for k, line in enumerate(io.g2o_text(sample.graph,
                                                                    sample.initial).splitlines()))
                    + "\n")
    table = read.read_table(path, PLANAR)
    assert table.vertex_text is not None
    order = np.argsort(table.vertex_keys)
    keys, poses = table.vertex_keys[order], table.vertex_numbers[order]
    values = formats._values_by_gtsam(table.vertex_text, keys, poses)
    if not hasattr(__import__("os"), "memfd_create"):
        assert values is None
        return
    assert values is not None
    assert list(values.keys()) == keys.tolist()
    for key, (x, y, theta) in zip(keys.tolist(), poses.tolist(), strict=True):
        assert values.atPose2(key).matrix().tobytes() == gtsam.Pose2(x, y, theta).matrix().tobytes()


def test_gtsam_reads_every_number_the_checks_pass_as_float_does(tmp_path):
    """GTSAM's parse of the vertex lines is compared with this reader's on a sample only:
    that rests on the C library reading every field that ``float()`` takes (plain ASCII,
    finite) to the same double. Here 3000 vertices (three times the sample) hold numbers
    written every way a file may write them (signs, bare points, exponents, 25 significant
    digits, halfway cases, subnormals, underflow to zero, 1e300 in a position), and every value
    GTSAM built is the reader's Pose2, bit for bit."""
    rng = np.random.default_rng(11)
    forms = [
        lambda v: repr(v), lambda v: f"{v:.3f}", lambda v: f"{v:+.6e}", lambda v: f"{v:.25g}",
        lambda v: f"{v:E}", lambda v: f"{v:.0f}.", lambda v: f"{v:.2e}".replace("e-0", "e-"),
        lambda v: (f"{v:.4f}".lstrip("0") or "0") if 0 <= v < 1 else repr(v),
        lambda v: "00" + repr(abs(v)), lambda v: f"{v * 1e-310!r}", lambda v: f"{v}e-400",
        lambda v: "0.1000000000000000055511151231257827", lambda v: "2.2250738585072011e-308",
    ]
    # positions only: an angle this large wraps in numpy and in GTSAM's cos and sin apart
    # by more than the 1e-9 rad the comparison allows (the reader then inserts the values)
    large = [lambda v: f"{v * 1e300:.17g}", lambda v: "9007199254740993"]
    n = 3000
    numbers = rng.normal(0.0, 50.0, (n, 3))
    numbers[:, 2] /= 20.0
    lines = []
    for k in range(n):
        fields = [(forms + large if c < 2 else forms)[(3 * k + c) % (len(forms) + 2 * (c < 2))](
            float(numbers[k, c])) for c in range(3)]
        lines.append(f"VERTEX_SE2 {k} {' '.join(fields)}")
    lines += [f"EDGE_SE2 {k} {k + 1} 1 0 0 1 0 0 1 0 1" for k in range(n - 1)]
    path = tmp_path / "forms.g2o"
    path.write_text("\n".join(lines) + "\n")
    table = read.read_table(path, PLANAR)
    assert table.vertex_text is not None  # the fast reader took every line
    if not hasattr(__import__("os"), "memfd_create"):
        pytest.skip("GTSAM's parser builds the values through a memfd (Linux) only")
    order = np.argsort(table.vertex_keys)
    values = formats._values_by_gtsam(table.vertex_text, table.vertex_keys[order],
                                      table.vertex_numbers[order])
    assert values is not None and values.size() == n
    for k, line in enumerate(lines[:n]):
        x, y, theta = map(float, line.split()[2:])
        built = values.atPose2(k).matrix().tobytes()
        assert built == gtsam.Pose2(x, y, theta).matrix().tobytes(), line


def test_the_reader_extracts_shuffled_ids_and_wrapped_angles_as_extraction_does(tmp_path):
    """Ids in shuffled order with gaps, FIX lines naming several poses (the first is the
    anchor), measured angles beyond pi: the reader's extraction is the walk's, bit for bit."""
    sample = generate(150, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(7),
                      noisy_measurements=True)
    rng = np.random.default_rng(8)
    ids = (rng.permutation(150) * 10 + 7).tolist()
    vertices, edges = [], []
    for line in io.g2o_text(sample.graph, sample.initial).splitlines():
        tag, *fields = line.split()
        if tag == "VERTEX_SE2":
            vertices.append(" ".join([tag, str(ids[int(fields[0])]), *fields[1:]]))
        else:
            angle = float(fields[4]) + 2 * np.pi * int(rng.integers(-3, 4))
            edges.append(" ".join([tag, str(ids[int(fields[0])]), str(ids[int(fields[1])]),
                                   *fields[2:4], repr(angle), *fields[5:]]))
    rng.shuffle(vertices)
    path = tmp_path / "shuffled.g2o"
    path.write_text("\n".join([*vertices, *edges, f"FIX {ids[40]} {ids[3]}", f"FIX {ids[9]}"])
                    + "\n")
    _assert_same_read(path)
    graph, values, _, made = io.read_g2o_extracted(path)
    assert made.anchor == int(np.searchsorted(made.keys, ids[40])) and len(made.fixed) == 3


@pytest.mark.parametrize("name", ["MIT.g2o", "M3500.g2o"])
def test_text_from_the_extraction_is_the_walks_text(name):
    """Given the graph's extraction, the writer takes measurements, informations and FIXed
    ids from its arrays: the same text as the walk over the factors (the file's own values
    and a refined guess); an extraction of another graph is not used."""
    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    graph, values, _, made = io.read_g2o_extracted(path)
    moved = gtsam.Values()
    for key in values.keys():
        pose = values.atPose2(key)
        moved.insert(key, gtsam.Pose2(pose.x() + 0.1, pose.y() - 1e-7, pose.theta() + 3.0))
    for guess in (values, moved):
        assert _text_of_extraction(graph, guess, made) == io.g2o_text(graph, guess)
    assert _text_of_extraction(gtsam.NonlinearFactorGraph(graph), values, made) is None


def test_text_from_the_extraction_with_fix_and_a_soft_prior(tmp_path):
    sample = generate(120, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(9),
                      noisy_measurements=True)
    graph, values = sample.graph, sample.initial
    for key in (7, 3, 7):
        graph.add(gtsam.PriorFactorPose2(key, values.atPose2(key),
                                         gtsam.noiseModel.Constrained.All(3)))
    made = PoseGraph2D.from_gtsam(graph, values)
    written = io.g2o_text(graph, values, made)
    assert _text_of_extraction(graph, values, made) == written == io.g2o_text(graph, values)
    assert written.endswith("FIX 7 3 7\n")
    # a soft prior: a g2o file cannot hold it, with the extraction or without
    graph.add(gtsam.PriorFactorPose2(5, values.atPose2(5), gtsam.noiseModel.Isotropic.Sigma(3, 1)))
    made = PoseGraph2D.from_gtsam(graph, values)
    assert _text_of_extraction(graph, values, made) is None
    for extraction in (None, made):
        with pytest.raises(OutputError, match="prior"):
            io.g2o_text(graph, values, extraction)


@pytest.mark.parametrize("name", ["MIT.g2o", "3d/smallGrid3D.g2o"])
def test_a_pipe_is_read_once_as_its_file_reads(tmp_path, name):
    """A FIFO (``<(cat file)``) can be read once: the reader finds the file's group and
    reads its graph from the same stream, the careful reader's way."""
    import os
    import threading

    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    fifo = tmp_path / "graph.g2o"
    os.mkfifo(fifo)
    writer = threading.Thread(target=fifo.write_bytes, args=(path.read_bytes(),), daemon=True)
    writer.start()
    graph, values, lines = io.read_g2o_lines(fifo)
    writer.join(timeout=10)
    assert (io.g2o_text(graph, values), lines) == (io.g2o_text(*io.read_g2o(path)),
                                                   io.read_g2o_lines(path)[2])
