"""Wrong loop closures through the commands: rlpgo-generate --outliers lists them, rlpgo-init
--robust rejects them and lists what it rejected, and the staged default hints at --robust.

Graphs: the generator's 300-pose lawn mower with noisy measurements (sigma_R 0.1, sigma_t
0.05, d 1, lc 0.5, seed 3), written by rlpgo-generate; 15% wrong loop closures where it has
any. Edge lists are compared as entries ``(line, id_i, id_j)``.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner, Result
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import FALSE_REJECTIONS_DEFAULT
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import read_g2o, read_g2o_lines, refine
from rlpgo_gtsam.io import edge_list_text, g2o_text_lines
from rlpgo_gtsam.robust import RobustSettings, robust_initialize
from rlpgo_gtsam.synthetic import generate
from tests.conftest import assert_same_edges, cli_error, cli_ok, dataset

ARGS = (300, 0.1, 0.05, 1.0, 0.5)
SEED = 3
GRAPH_OPTIONS = ["--n", "300", "--sigma-r", "0.1", "--sigma-t", "0.05", "--d", "1", "--lc",
                 "0.5", "--noisy-measurements", "--seed", str(SEED)]
FRACTION = 0.15
SUMMARY = re.compile(
    r"^rejected (?P<rejected>\d+) of (?P<judged>\d+) loop closures as wrong; chi2 (?P<chi2>\S+) "
    r"on the edges kept; \d+\.\d\d s; wrote (?P<output>\S+)(?: and (?P<listed>\S+))?$"
)


def _run(command, *args: str | float | Path) -> Result:
    return CliRunner().invoke(command, [str(a) for a in args])


def _entries(path: Path) -> list[tuple[int, int, int]]:
    """An edge list's entries, (line, id_i, id_j); its one '#' line, first, checked."""
    text = path.read_text().splitlines()
    assert text[0].startswith("# ") and not any(row.startswith("#") for row in text[1:])
    entries = []
    for row in text[1:]:
        tag, line, edge, i, j = row.split()
        assert (tag, edge) == ("line", "EDGE_SE2"), row
        entries.append((int(line), int(i), int(j)))
    return entries


def _usage_error(result: Result, *mentions: str) -> None:
    cli_error(result, code=2)
    for text in mentions:
        assert text in result.stderr


@dataclass
class Generated:
    """A graph rlpgo-generate wrote with wrong closures, and its list of them."""

    mode: str
    graph: Path
    listed: Path
    stdout: str


@pytest.fixture(scope="module", params=("uniform", "plausible", "group"))
def with_outliers(request, tmp_path_factory) -> Generated:
    folder = tmp_path_factory.mktemp(f"outliers-{request.param}")
    graph, listed = folder / "g.g2o", folder / "wrong.txt"
    result = _run(generate_main, *GRAPH_OPTIONS, "--outliers", FRACTION, "--outlier-mode",
                  request.param, "-o", graph, "--outliers-out", listed)
    cli_ok(result)
    return Generated(request.param, graph, listed, result.stdout)


@dataclass
class CleanRuns:
    """A graph without wrong closures, and what the staged default and --robust made of it."""

    graph: Path
    staged: Path
    staged_stdout: str
    robust: Path
    robust_stdout: str


@pytest.fixture(scope="module")
def clean(tmp_path_factory) -> CleanRuns:
    folder = tmp_path_factory.mktemp("clean")
    graph, staged, robust = folder / "g.g2o", folder / "staged.g2o", folder / "robust.g2o"
    cli_ok(_run(generate_main, *GRAPH_OPTIONS, "-o", graph))
    staged_run = _run(init_main, graph, "-o", staged)
    cli_ok(staged_run)
    robust_run = _run(init_main, graph, "-o", robust, "--robust")
    cli_ok(robust_run)
    return CleanRuns(graph, staged, staged_run.stdout, robust, robust_run.stdout)


# --------------------------------------------------------------------------- line numbers


def test_factors_know_their_file_lines(tmp_path):
    path = tmp_path / "in.g2o"
    path.write_text("# a comment\n"
                    "VERTEX_SE2 0 0 0 0\n"
                    "\n"
                    "VERTEX_SE2 1 1 0 0\n"
                    "VERTEX_SE2 2 2 0 0\n"
                    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
                    "FIX 0\n"
                    "# another\n"
                    "EDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n"
                    "EDGE_SE2 0 2 2 0 0 1 0 0 1 0 1\n")
    graph, values, lines = read_g2o_lines(path)
    assert lines == [6, 9, 10, 7]  # the edges in file order, then the FIX prior
    assert isinstance(graph.at(3), gtsam.PriorFactorPose2)
    text, written_lines = g2o_text_lines(graph, values)  # vertices, edges, then FIX
    assert written_lines == [4, 5, 6, 7]
    rows = text.splitlines()
    assert [rows[line - 1].split()[:3] for line in written_lines[:3]] == [
        ["EDGE_SE2", "0", "1"], ["EDGE_SE2", "1", "2"], ["EDGE_SE2", "0", "2"]]
    assert rows[written_lines[3] - 1] == "FIX 0"
    listed = edge_list_text(graph, [2], lines, title="t", g2o_name="in\n.g2o")
    assert listed.splitlines()[1:] == ["line 10 EDGE_SE2 0 2"]
    assert listed.count("\n") == 2  # a line break in the name does not break the header


# --------------------------------------------------------------------------- rlpgo-generate


def test_generate_lists_the_wrong_closures_at_their_lines(with_outliers):
    sample = generate(*ARGS, np.random.default_rng(SEED), noisy_measurements=True,
                      outliers=FRACTION, outlier_mode=with_outliers.mode)
    assert len(sample.outlier_edges) == int(FRACTION * 430) > 0
    _, _, lines = read_g2o_lines(with_outliers.graph)
    expected = [(lines[k], *sample.graph.at(k).keys()) for k in sample.outlier_edges]
    entries = _entries(with_outliers.listed)
    assert entries == expected
    rows = with_outliers.graph.read_text().splitlines()
    for line, i, j in entries:
        assert rows[line - 1].split()[:3] == ["EDGE_SE2", str(i), str(j)]
    grouped = ", groups of 5" if with_outliers.mode == "group" else ""
    assert (f"added {len(entries)} wrong loop closures ({with_outliers.mode}{grouped}); listed "
            f"in {with_outliers.listed}") in with_outliers.stdout


# --------------------------------------------------------------------------- rlpgo-init --robust


def test_robust_rejects_exactly_the_wrong_closures(with_outliers, tmp_path):
    # group: at 0.1 rad per measurement one wrong group (pose 200 "is" pose 180) passes every
    # short-cycle test against the true closures near it (scores 3-20 under the 21.1 bar)
    # and enters the seed; the verify step judges the group as a whole against the map
    # without it, and it goes
    output, rejected = tmp_path / "init.g2o", tmp_path / "rejected.txt"
    result = _run(init_main, with_outliers.graph, "-o", output, "--robust", "--outliers-out",
                  rejected)
    cli_ok(result)
    printed = result.stdout.rstrip("\n").splitlines()
    assert len(printed) >= 2 and all(line.startswith(("step ", "ambiguous: ", "doubtful: "))
                                     for line in printed[:-1])
    summary = SUMMARY.match(printed[-1])
    assert summary, printed[-1]
    assert (summary["output"], summary["listed"]) == (str(output), str(rejected))

    assert _entries(rejected) == _entries(with_outliers.listed)
    assert int(summary["rejected"]) == len(_entries(rejected))
    graph, _ = read_g2o(with_outliers.graph)
    closures = [k for k in range(graph.size()) if abs(np.diff(graph.at(k).keys())[0]) != 1]
    assert int(summary["judged"]) == len(closures)

    assert_same_edges(with_outliers.graph, output)  # every edge written, the wrong ones too
    clean = generate(*ARGS, np.random.default_rng(SEED), noisy_measurements=True)
    lowest = refine(clean.graph, clean.ground_truth, "lm", 100).chi2
    _, guess = read_g2o(output)
    assert 2.0 * clean.graph.error(guess) == pytest.approx(lowest, rel=1e-6)
    assert float(summary["chi2"]) == pytest.approx(lowest, rel=1e-5)  # printed to 6 digits


def test_a_clean_graph_gets_the_same_chi2_with_and_without_robust(clean):
    graph, _ = read_g2o(clean.graph)
    _, staged = read_g2o(clean.staged)
    _, robust = read_g2o(clean.robust)
    assert 2.0 * graph.error(robust) == pytest.approx(2.0 * graph.error(staged), rel=1e-6)
    assert clean.robust_stdout.splitlines()[-1].startswith("rejected 0 of ")
    assert_same_edges(clean.graph, clean.robust)


def test_covariance_scale_tells_the_robust_path_the_noise_is_larger(clean, tmp_path):
    # the clean graph with every information 4x too large (covariances 4x too small): told
    # so, --robust keeps every closure and writes the clean run's map; its chi2 and record
    # are those of the file as written
    graph, values = read_g2o(clean.graph)
    optimistic, output, record = tmp_path / "optimistic.g2o", tmp_path / "o.g2o", \
        tmp_path / "o.json"
    text = []
    for line in clean.graph.read_text().splitlines():
        fields = line.split()
        if fields and fields[0] == "EDGE_SE2":
            fields[6:] = [repr(4.0 * float(v)) for v in fields[6:]]
        text.append(" ".join(fields))
    optimistic.write_text("\n".join(text) + "\n")
    as_stated = _run(init_main, optimistic, "-o", tmp_path / "as_stated.g2o", "--robust",
                     "--json", tmp_path / "as_stated.json")
    cli_ok(as_stated)  # true closures go, and the hint says why that may be
    assert SUMMARY.match(as_stated.stdout.splitlines()[-1])["rejected"] != "0"
    [hint] = [line for line in as_stated.stdout.splitlines() if line.startswith("hint: ")]
    assert "times worse than their covariances say" in hint and "--covariance-scale" in hint
    assert json.loads((tmp_path / "as_stated.json").read_text())["hint"] == hint[len("hint: "):]
    result = _run(init_main, optimistic, "-o", output, "--robust", "--covariance-scale", 4,
                  "--json", record)
    cli_ok(result)
    summary = SUMMARY.match(result.stdout.splitlines()[-1])
    assert summary is not None and summary["rejected"] == "0"
    assert "hint:" not in result.stdout
    _, robust = read_g2o(clean.robust)
    _, written = read_g2o(output)
    assert 2.0 * graph.error(written) == pytest.approx(2.0 * graph.error(robust), rel=1e-6)
    recorded = json.loads(record.read_text())
    assert recorded["covariance_scale"] == 4.0 and recorded["rejected"] == []
    assert recorded["hint"] is None
    assert recorded["chi2"] == pytest.approx(4.0 * 2.0 * graph.error(robust), rel=1e-6)


def test_false_rejections_reaches_the_robust_path(with_outliers, tmp_path):
    # the rate goes to robust_initialize as given (0: the false-rejection bar off, so the
    # verify step reports no unlikely fit) and into the record; --help's default is the
    # library's
    assert FALSE_REJECTIONS_DEFAULT == RobustSettings().false_rejection_rate
    record = tmp_path / "r.json"
    result = _run(init_main, with_outliers.graph, "-o", tmp_path / "o.g2o", "--robust",
                  "--false-rejections", 0, "--json", record)
    cli_ok(result)
    recorded = json.loads(record.read_text())
    assert recorded["false_rejection_rate"] == 0.0
    [verify] = [step for step in recorded["steps"] if step["step"] == "verify"]
    assert verify["unlikely_fits"] == 0
    assert "; unlikely fits 0" in result.stdout
    graph, values = read_g2o(with_outliers.graph)
    assert recorded["rejected"] == robust_initialize(graph, values,
                                                     false_rejection_rate=0.0).rejected


def test_the_record_names_the_false_rejection_rate_used_when_none_is_given(with_outliers,
                                                                          tmp_path):
    record = tmp_path / "r.json"
    cli_ok(_run(init_main, with_outliers.graph, "-o", tmp_path / "o.g2o", "--robust",
                "--json", record))
    assert (json.loads(record.read_text())["false_rejection_rate"]
            == RobustSettings().false_rejection_rate)


def test_doubtful_closures_are_named_and_recorded(with_outliers, tmp_path):
    # the closures kept that fit poorly: one line naming them, and the record lists them with
    # their p-values as the library found them
    record = tmp_path / "r.json"
    result = _run(init_main, with_outliers.graph, "-o", tmp_path / "o.g2o", "--robust",
                  "--json", record)
    cli_ok(result)
    graph, values = read_g2o(with_outliers.graph)
    found = robust_initialize(graph, values)
    recorded = json.loads(record.read_text())["doubtful"]
    assert recorded == [{"factor": k, "p_value": p} for k, p in found.doubtful]
    # the generator's covariances state its noise: about 1 in 20 true closures fits this
    # poorly (6 of the 116 kept on each of these graphs)
    assert found.doubtful
    [line] = [line for line in result.stdout.splitlines() if line.startswith("doubtful: ")]
    kept = len(found.weights[~np.isnan(found.weights)]) - len(found.trusted) - len(
        found.rejected)
    assert line.startswith(f"doubtful: {len(found.doubtful)} of the {kept} loop closures "
                           "kept fit the map poorly (p < 0.05")
    assert f"factors {found.doubtful[0][0]}" in line and "in --json" in line


def test_robust_with_refine_none_writes_the_same_guess(clean, tmp_path):
    output = tmp_path / "none.g2o"
    cli_ok(_run(init_main, clean.graph, "-o", output, "--robust", "--refine", "none"))
    assert output.read_bytes() == clean.robust.read_bytes()


# --------------------------------------------------------------------------- the staged default


def test_the_staged_default_hints_at_robust_when_closures_are_wrong(with_outliers, tmp_path):
    output = tmp_path / "init.g2o"
    result = _run(init_main, with_outliers.graph, "-o", output)
    cli_ok(result)
    assert "NOT certified" in result.stdout
    hints = [line for line in result.stdout.splitlines() if line.startswith("hint: ")]
    assert len(hints) == 1 and "--robust" in hints[0]


def test_the_staged_default_gives_no_hint_on_a_certified_graph(clean):
    assert "certificate: certified optimal" in clean.staged_stdout
    assert "hint" not in clean.staged_stdout


# --------------------------------------------------------------------------- errors


def test_outliers_out_without_robust_is_a_usage_error(clean, tmp_path):
    output, listed = tmp_path / "init.g2o", tmp_path / "rejected.txt"
    result = _run(init_main, clean.graph, "-o", output, "--outliers-out", listed)
    _usage_error(result, "--outliers-out", "--robust")
    assert not output.exists() and not listed.exists()


def test_outliers_out_may_not_be_the_input(clean, tmp_path):
    before = clean.graph.read_bytes()
    output = tmp_path / "init.g2o"
    result = _run(init_main, clean.graph, "-o", output, "--robust", "--outliers-out",
                  clean.graph)
    cli_error(result, f"{clean.graph}: is an input of this run; refusing to overwrite it")
    assert clean.graph.read_bytes() == before
    assert not output.exists()


@pytest.mark.parametrize(("command", "args", "mentions"), [
    (init_main, ["--robust", "--method", "chordal"], ["--robust", "--method chordal"]),
    (init_main, ["--robust", "--budget", "5", "--refine", "gn"], ["--budget", "--refine gn"]),
    (init_main, ["--no-trust-odometry"], ["--robust"]),
    (init_main, ["--covariance-scale", "4"], ["--covariance-scale", "--robust"]),
    (init_main, ["--robust", "--covariance-scale", "0"], ["--covariance-scale", "(0, 1e+06]"]),
    (init_main, ["--false-rejections", "0.01"], ["--false-rejections", "--robust"]),
    (init_main, ["--robust", "--false-rejections", "1"], ["--false-rejections", "[0, 1)"]),
    (generate_main, ["--outliers", "1"], ["--outliers", "[0, 1)"]),
    (generate_main, ["--outlier-mode", "sneaky"], ["--outlier-mode"]),
], ids=["method", "staged_options", "trust_without_robust", "scale_without_robust",
        "scale_zero", "rate_without_robust", "rate_one", "outliers_one", "mode"])
def test_options_that_do_not_go_together_are_usage_errors(clean, tmp_path, command, args,
                                                          mentions):
    output = tmp_path / "out.g2o"
    inputs = [clean.graph] if command is init_main else []
    _usage_error(_run(command, *inputs, "-o", output, *args), *mentions)
    assert not output.exists()


# --------------------------------------------------------------------------- hostile input


def _appended(source: Path, folder: Path, *lines: str) -> Path:
    """A copy of ``source`` in ``folder`` with ``lines`` appended."""
    path = folder / f"{source.stem}-hostile.g2o"
    path.write_text(source.read_text() + "".join(f"{line}\n" for line in lines))
    return path


@pytest.mark.parametrize("length", ["1e20", "1e300"])
def test_robust_rejects_a_closure_no_map_can_fit_and_writes_the_clean_map(length, tmp_path):
    graph = _appended(dataset("MIT.g2o"), tmp_path, f"EDGE_SE2 1 500 {length} 0 0 1 0 0 1 0 1")
    out, listed = tmp_path / "out.g2o", tmp_path / "wrong.txt"
    result = _run(init_main, graph, "-o", out, "--robust", "--outliers-out", listed)
    cli_ok(result)
    assert "step reach: kept 827 of 828 edges judged, rejected 1" in result.stdout
    summary = SUMMARY.match(result.stdout.splitlines()[-1])
    assert summary is not None and summary["rejected"] == "1" and summary["judged"] == "21"
    assert float(summary["chi2"]) == pytest.approx(41.2069, rel=1e-5)  # MIT's own optimum
    assert _entries(listed) == [(len(graph.read_text().splitlines()), 1, 500)]


def test_robust_keeps_fixed_poses_where_the_file_holds_them(tmp_path):
    graph = _appended(dataset("3d/smallGrid3D.g2o"), tmp_path, "FIX 0 40 80",
                      "EDGE_SE3:QUAT 0 20 1e300 0 0 0 0 0 1 100 0 0 0 0 0 100 0 0 0 0 100 0 0 0 "
                      "25 0 0 25 0 25")
    out = tmp_path / "out.g2o"
    cli_ok(_run(init_main, graph, "-o", out, "--robust"))
    _, given = read_g2o(graph)
    _, written = read_g2o(out)
    for key in (0, 40, 80):
        assert written.atPose3(key).equals(given.atPose3(key), 1e-9)


def test_robust_on_a_graph_with_every_pose_fixed_writes_the_held_poses(tmp_path):
    source = dataset("3d/tinyGrid3D.g2o")
    ids = [row.split()[1] for row in source.read_text().splitlines()
           if row.startswith("VERTEX")]
    graph = _appended(source, tmp_path, "FIX " + " ".join(ids))
    out = tmp_path / "out.g2o"
    result = _run(init_main, graph, "-o", out, "--robust")
    cli_ok(result)
    assert "step held: " in result.stdout
    _, given = read_g2o(graph)
    _, written = read_g2o(out)
    for key in given.keys():
        assert written.atPose3(key).equals(given.atPose3(key), 1e-9)


def test_robust_refuses_a_bridge_too_long_for_the_arithmetic_on_one_line(tmp_path):
    graph = _appended(dataset("MIT.g2o"), tmp_path, "VERTEX_SE2 5000 0 0 0",
                      "EDGE_SE2 1 5000 1e300 0 0 1 0 0 1 0 1")
    message = cli_error(_run(init_main, graph, "-o", tmp_path / "out.g2o", "--robust"))
    assert message.startswith("between factor 1-5000 measures 1e+300 m, ")
    assert not (tmp_path / "out.g2o").exists()
