"""3D pose graphs through the product: rlpgo-init and rlpgo-compare on SE-Sync's 3D files,
the staged default on a Pose3 graph, the file's dimension told from its lines, and the 3D
information rule on parking-garage's and cubicle's real matrices (cubicle's read as
gtsam.readG2o reads them, weighed as SE-Sync reads them)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import CliRunner, Result
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import (
    InformationWarning,
    RlpgoError,
    read_g2o,
    staged_initialize,
    write_g2o,
)
from rlpgo_gtsam.graph import (
    PoseGraph3D,
    extract_pose_graph,
    rotation_weights,
    translation_weights,
)
from rlpgo_gtsam.groups import SE2, SE3
from rlpgo_gtsam.information import (
    INDEFINITE,
    LIFTED,
    information_problem,
    information_problem_6,
    information_rule_3d,
    printed_informations,
)
from rlpgo_gtsam.initializers import initializer_names, make_initializer
from rlpgo_gtsam.io import file_group, write
from rlpgo_gtsam.io.formats import G2O_TO_GTSAM, SPATIAL
from rlpgo_gtsam.ranking import comparison_methods
from rlpgo_gtsam.residuals import outlier_suspicion
from rlpgo_gtsam.solvers import refine
from rlpgo_gtsam.staged import SEARCHES, SEARCHES_3D
from rlpgo_gtsam.synthetic import add_outliers, generate
from tests.conftest import cli_error, cli_ok, dataset

# the 3D method names (the registry's) and rlpgo-compare's 3D rows
SPATIAL_METHODS = tuple(initializer_names(SE3))
COMPARISON_3D = tuple(comparison_methods(SE3))

# SE-Sync's rounded estimate + GTSAM LM30 on these files (datasets/3d/README.md)
SESYNC_LM30 = {"tinyGrid3D": 18.6278, "smallGrid3D": 1035.85}
SUMMARY = re.compile(r"^input chi2 \S+; (?P<method>\S+) \+ LM30: chi2 (?P<chi2>\S+); "
                     r"\d+\.\d\d s; wrote .+$")
_UPPER = np.triu_indices(6)


def run_init(*args: str | Path) -> Result:
    return CliRunner().invoke(init_main, [str(a) for a in args])


def _summary(result: Result) -> re.Match:
    match = SUMMARY.match(result.stdout.rstrip("\n").splitlines()[-1])
    assert match, result.stdout
    return match


def _file_information(line: str) -> np.ndarray:
    """The information of an EDGE_SE3:QUAT line, in GTSAM's order, as the file states it."""
    upper = np.zeros((6, 6))
    upper[_UPPER] = [float(v) for v in line.split()[10:]]
    full = upper + np.triu(upper, 1).T
    return full[G2O_TO_GTSAM][:, G2O_TO_GTSAM]


def assert_same_edges_3d(source: Path, output: Path) -> None:
    """``output`` holds the edges of ``source``: same keys in order, measurements to 1e-12,
    information to a relative 1e-12."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InformationWarning)
        graph, _ = read_g2o(source)
        written, _ = read_g2o(output)
    assert written.size() == graph.size()
    for k in range(graph.size()):
        ours, theirs = written.at(k), graph.at(k)
        assert type(ours) is type(theirs) and ours.keys() == theirs.keys()
        if isinstance(ours, gtsam.BetweenFactorPose3):
            np.testing.assert_allclose(ours.measured().matrix(), theirs.measured().matrix(),
                                       atol=1e-12)
            np.testing.assert_allclose(ours.noiseModel().information(),
                                       theirs.noiseModel().information(), rtol=1e-12, atol=0)


# --------------------------------------------------------------------------- rlpgo-init


@pytest.mark.parametrize("name", ["tinyGrid3D", "smallGrid3D"])
def test_default_certifies_and_reaches_sesync_lm30(tmp_path, name):
    source = dataset(f"3d/{name}.g2o")
    output = tmp_path / "out.g2o"
    result = run_init(source, "-o", output)
    cli_ok(result)
    assert "stage certified: " in result.stdout
    assert "  certificate: certified optimal (" in result.stdout
    assert "stopped: the relaxation is certified exact" in result.stdout
    summary = _summary(result)
    assert summary["method"] == "certified"
    assert float(summary["chi2"]) == pytest.approx(SESYNC_LM30[name], rel=1e-4)
    assert_same_edges_3d(source, output)
    graph, values = read_g2o(output)  # the written guess is the reported one
    assert 2 * graph.error(values) == pytest.approx(SESYNC_LM30[name], rel=1e-4)


@pytest.mark.parametrize("method", list(SPATIAL_METHODS))
def test_every_3d_method_by_name(tmp_path, method):
    output = tmp_path / "out.g2o"
    result = run_init(dataset("3d/tinyGrid3D.g2o"), "-o", output, "--method", method)
    cli_ok(result)
    summary = _summary(result)
    assert summary["method"] == method
    # every 3D method reaches the minimum of this 9-pose grid after LM30
    assert float(summary["chi2"]) == pytest.approx(SESYNC_LM30["tinyGrid3D"], rel=1e-4)
    assert ("certificate: certified optimal" in result.stdout) == (method == "certified")
    assert_same_edges_3d(dataset("3d/tinyGrid3D.g2o"), output)


def test_method_all_runs_the_3d_rows_certified_first(tmp_path):
    result = run_init(dataset("3d/tinyGrid3D.g2o"), "-o", tmp_path / "out.g2o",
                      "--method", "all")
    cli_ok(result)
    rows = [line.split()[0] for line in result.stdout.splitlines()
            if line.split() and line.split()[0].partition("@")[0] in SPATIAL_METHODS]
    assert rows == [m if m != "shonan" else "shonan@best" for m in COMPARISON_3D]
    assert _summary(result)["method"] == "certified"  # the six tie: the first row is written


def test_refine_none_writes_the_certified_guess(tmp_path):
    output = tmp_path / "out.g2o"
    result = run_init(dataset("3d/tinyGrid3D.g2o"), "-o", output, "--refine", "none")
    cli_ok(result)
    guess = float(re.search(r"guess chi2 (\S+),", result.stdout)[1])
    graph, values = read_g2o(output)
    assert 2 * graph.error(values) == pytest.approx(guess, rel=1e-5)
    assert guess > SESYNC_LM30["tinyGrid3D"]  # not refined


def test_json_record_of_a_3d_run(tmp_path):
    output, record = tmp_path / "out.g2o", tmp_path / "run.json"
    result = run_init(dataset("3d/smallGrid3D.g2o"), "-o", output, "--json", record)
    cli_ok(result)
    data = json.loads(record.read_text())
    assert {"input", "output", "dimension", "poses", "edges", "method", "input_chi2", "result",
            "refine", "iters", "chi2", "variance_factor", "certified", "status", "stopped",
            "hint", "seconds", "notes", "rows"} == set(data)
    # SE-Sync's smallGrid3D (no FIX): 6 dof over 297 - 125 + 1 independent cycles
    assert data["variance_factor"] == pytest.approx(data["chi2"] / (6 * (297 - 125 + 1)))
    assert (data["dimension"], data["poses"], data["edges"]) == (3, 125, 297)
    assert (data["method"], data["result"], data["refine"], data["iters"]) == \
        ("auto", "certified", "lm", 30)
    assert data["certified"] is True and data["status"] == "certified"
    assert data["chi2"] == pytest.approx(1035.85, rel=1e-4)
    assert data["chi2"] == pytest.approx(float(_summary(result)["chi2"]), rel=1e-5)
    assert data["notes"] == [] and data["hint"] is None
    assert data["output"] == str(output)
    [row] = data["rows"]
    assert row["certificate"]["status"] == "certified" and row["certificate"]["rank"] == 3
    assert row["refined_chi2"] == data["chi2"]


def test_json_record_of_planar_and_robust_runs(tmp_path):
    """--json is the same record on a planar graph; a --robust run records what it rejected."""
    sample = generate(60, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(3), noisy_measurements=True)
    path = tmp_path / "in.g2o"
    write_g2o(path, sample.graph, sample.initial)
    cli_ok(run_init(path, "-o", tmp_path / "out.g2o", "--json", tmp_path / "run.json"))
    data = json.loads((tmp_path / "run.json").read_text())
    assert (data["dimension"], data["poses"], data["result"]) == (2, 60, "certified")
    assert data["certified"] is True and data["rows"][0]["certificate"]["rank"] >= 1
    wrong, _ = add_outliers(sample.graph, sample.ground_truth, 0.1, np.random.default_rng(4))
    write_g2o(path, wrong, sample.initial)
    result = run_init(path, "-o", tmp_path / "robust.g2o", "--robust", "--json",
                      tmp_path / "robust.json")
    cli_ok(result)
    data = json.loads((tmp_path / "robust.json").read_text())
    assert data["method"] == "robust" and data["dimension"] == 2
    assert f"rejected {len(data['rejected'])} of {data['judged']} loop closures" in result.stdout
    assert data["chi2"] == pytest.approx(float(re.search(r"; chi2 (\S+) on the edges kept",
                                                         result.stdout)[1]), rel=1e-5)
    kept = data["edges"] - len(data["rejected"])  # the chi2 is the kept edges'
    assert data["variance_factor"] == pytest.approx(data["chi2"] / (3 * (kept - 60 + 1)))


def test_budget_cuts_the_certified_stage_and_still_writes(tmp_path):
    output = tmp_path / "out.g2o"
    result = run_init(dataset("3d/smallGrid3D.g2o"), "-o", output, "--budget", "0.001")
    cli_ok(result)
    assert "spent during the certified stage" in result.stdout
    assert "(the stages' share of --budget 0.001 s after reading smallGrid3D.g2o" in result.stdout
    assert "certificate: not certified" in result.stdout or \
        "time limit" in result.stdout.split("certificate: ")[1].splitlines()[0]
    graph, values = read_g2o(output)
    assert np.isfinite(2 * graph.error(values))


def test_existing_outputs_are_refused(tmp_path):
    output, record = tmp_path / "out.g2o", tmp_path / "run.json"
    output.write_text("keep")
    cli_error(run_init(dataset("3d/tinyGrid3D.g2o"), "-o", output),
              f"{output}: exists; give --overwrite to replace it")
    assert output.read_text() == "keep"
    record.write_text("keep")
    cli_error(run_init(dataset("3d/tinyGrid3D.g2o"), "-o", tmp_path / "new.g2o", "--json",
                       record), f"{record}: exists; give --overwrite to replace it")
    assert not (tmp_path / "new.g2o").exists()  # the guess and its record, or neither
    cli_ok(run_init(dataset("3d/tinyGrid3D.g2o"), "-o", output, "--overwrite"))
    assert output.read_text().startswith("VERTEX_SE3:QUAT 0 ")


def test_the_agent_and_planar_methods_are_one_line_on_3d(tmp_path):
    source = dataset("3d/tinyGrid3D.g2o")
    output = tmp_path / "out.g2o"
    message = cli_error(run_init(source, "-o", output, "--method", "rl"))
    assert message.startswith(f"{source} holds a 3D pose graph: 'rl': the agent is planar")
    message = cli_error(run_init(source, "-o", output, "--method", "rl@chordal"))
    assert "the agent is planar" in message
    message = cli_error(run_init(source, "-o", output, "--method", "all", "--episodes", "3"))
    assert message == (f"{source} holds a 3D pose graph, and the agent is planar (it runs on "
                       "2D graphs only): --episodes cannot apply")
    message = cli_error(run_init(source, "-o", output, "--method", "lago"))
    assert message == (f"{source} holds a 3D pose graph: 'lago' is a planar method; the 3D "
                       f"methods are {', '.join(SPATIAL_METHODS)}")
    # a 3D name on a planar file: the same kind of line
    planar = dataset("MIT.g2o")
    message = cli_error(run_init(planar, "-o", output, "--method", "initialize_pose3"))
    assert message == (f"{planar} holds a planar pose graph: 'initialize_pose3' is a 3D method; "
                       f"the planar methods are {', '.join(initializer_names(SE2))}")
    cli_error(run_init(source, "-o", output, "--method", "nonsense"), "nonsense", code=2)
    assert not output.exists()


def test_robust_on_3d_is_one_line_or_a_3d_guess(tmp_path):
    """Until the robust path takes 3D graphs its typed error is one line; once it does, the
    guess is a 3D file with every edge of the input."""
    source, output = dataset("3d/tinyGrid3D.g2o"), tmp_path / "out.g2o"
    result = run_init(source, "-o", output, "--robust")
    if result.exit_code:
        assert cli_error(result).startswith(f"--robust on {source} (a 3D pose graph): ")
        assert not output.exists()
    else:
        cli_ok(result)
        assert_same_edges_3d(source, output)


def test_robust_outliers_out_lists_the_3d_edges_the_generator_made_wrong(tmp_path):
    """--outliers-out on a 3D file lists each rejected edge as ``line <L> EDGE_SE3:QUAT i j``
    with its line in the input: on a generated graph with 10% wrong closures (random), the
    list equals the generator's."""
    from rlpgo_cli.generate import main as generate_main

    graph, made = tmp_path / "wrong3d.g2o", tmp_path / "made.txt"
    cli_ok(CliRunner().invoke(generate_main, [
        "--dim", "3", "--n", "200", "--sigma-r", "0.05", "--sigma-t", "0.1", "--d", "1",
        "--lc", "0.5", "--noisy-measurements", "--seed", "3", "--outliers", "0.1",
        "-o", str(graph), "--outliers-out", str(made)]))
    output, listed = tmp_path / "out.g2o", tmp_path / "listed.txt"
    cli_ok(run_init(graph, "-o", output, "--robust", "--outliers-out", listed))

    def entries(path: Path) -> list[str]:
        return sorted(line for line in path.read_text().splitlines()
                      if not line.startswith("#"))

    assert entries(listed) and entries(listed) == entries(made)
    text = graph.read_text().splitlines()
    for entry in entries(listed):
        _, line, tag, i, j = entry.split()
        assert tag == "EDGE_SE3:QUAT"
        assert text[int(line) - 1].split()[:3] == [tag, i, j]


def test_mixed_files_are_an_error_with_the_line(tmp_path):
    tiny = dataset("3d/tinyGrid3D.g2o").read_text().splitlines()
    mixed = tmp_path / "mixed.g2o"
    mixed.write_text("\n".join([*tiny[:12], "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1", *tiny[12:]])
                     + "\n")
    cli_error(run_init(mixed, "-o", tmp_path / "out.g2o"),
              f"{mixed}:13: EDGE_SE2: a planar line in a 3D file (a file holds 2D or 3D "
              "lines, not both)")
    planar = dataset("MIT.g2o").read_text().splitlines()
    mixed.write_text("\n".join([*planar[:5], tiny[0], *planar[5:]]) + "\n")
    cli_error(run_init(mixed, "-o", tmp_path / "out.g2o"),
              f"{mixed}:6: VERTEX_SE3:QUAT: a 3D line in a planar file (a file holds 2D or 3D "
              "lines, not both)")
    assert not (tmp_path / "out.g2o").exists()


def test_dimension_is_told_by_the_first_pose_line(tmp_path):
    assert file_group(dataset("3d/tinyGrid3D.g2o")).dimension == 3
    assert file_group(dataset("MIT.g2o")).dimension == 2
    path = tmp_path / "g.g2o"
    tiny = dataset("3d/tinyGrid3D.g2o").read_text()
    path.write_text("# a comment\n\nFIX 0\n" + tiny)
    assert file_group(path).dimension == 3
    graph, values = read_g2o(path)
    assert isinstance(extract_pose_graph(graph, values), PoseGraph3D)
    path.write_text("FOO 1 2\n" + tiny)
    assert file_group(path).dimension == 2  # the planar reader names the unknown tag
    with pytest.raises(RlpgoError, match=r":1: unknown tag 'FOO'"):
        read_g2o(path)


def test_rlpgo_compare_s_3d_rows_are_the_registry_s_certified_first():
    assert COMPARISON_3D[0] == "certified" and sorted(COMPARISON_3D) == sorted(SPATIAL_METHODS)


_LOADED = ("import sys\n"
           "from rlpgo_cli.init import main\n"
           "try:\n"
           "    main(sys.argv[1:])\n"
           "except SystemExit as stop:\n"
           "    assert not stop.code, stop.code\n"
           "print(' '.join(m for m in sys.modules if m.startswith('rlpgo_gtsam')))\n")
_MODULES_3D = {"rlpgo_gtsam.relaxation.stiefel"}


@pytest.mark.parametrize("name, loaded", [("MIT.g2o", False), ("3d/tinyGrid3D.g2o", True)])
def test_a_planar_command_loads_no_3d_module(tmp_path, name, loaded):
    done = subprocess.run([sys.executable, "-c", _LOADED, str(dataset(name)), "-o",
                           str(tmp_path / "out.g2o")], capture_output=True, text=True,
                          check=True, timeout=120)
    modules = set(done.stdout.splitlines()[-1].split())
    assert "rlpgo_gtsam.io" in modules
    assert (_MODULES_3D <= modules) if loaded else not (_MODULES_3D & modules)


# --------------------------------------------------------------------------- rlpgo-compare


def test_compare_on_3d_and_2d_files_gives_each_its_rows(tmp_path):
    record = tmp_path / "rows.json"
    tiny = dataset("3d/tinyGrid3D.g2o")
    planar = tmp_path / "planar.g2o"
    planar.write_text(dataset("MIT.g2o").read_text())
    result = CliRunner().invoke(compare_main, [str(tiny), str(planar), "--methods",
                                               "odometry,chordal,certified", "--json",
                                               str(record)])
    cli_ok(result)
    rows = json.loads(record.read_text())
    assert [(r["dataset"], r["dimension"], r["method"]) for r in rows] == [
        ("tinyGrid3D.g2o", 3, "odometry"), ("tinyGrid3D.g2o", 3, "chordal"),
        ("tinyGrid3D.g2o", 3, "certified"), ("planar.g2o", 2, "odometry"),
        ("planar.g2o", 2, "chordal"), ("planar.g2o", 2, "certified")]
    assert rows[2]["certificate"]["status"] == "certified"
    for r in rows[:3]:
        assert r["refined_chi2"] == pytest.approx(SESYNC_LM30["tinyGrid3D"], rel=1e-4)


def test_compare_default_rows_on_a_3d_file(tmp_path):
    record = tmp_path / "rows.json"
    result = CliRunner().invoke(compare_main, [str(dataset("3d/tinyGrid3D.g2o")), "--json",
                                               str(record)])
    cli_ok(result)
    assert [r["method"] for r in json.loads(record.read_text())] == \
        [m if m != "shonan" else "shonan@best" for m in COMPARISON_3D]
    assert "= 6 methods tie for the lowest refined chi2" in result.stdout
    header = next(line for line in result.stdout.splitlines() if "init chi2" in line)
    row = next(line for line in result.stdout.splitlines() if "initialize_pose3" in line)
    assert header.index("init chi2") + len("init chi2") == \
        row.index(row.split()[1]) + len(row.split()[1])  # the wider name keeps the columns


def test_compare_refuses_planar_options_on_3d_files(tmp_path):
    tiny = dataset("3d/tinyGrid3D.g2o")
    for extra in (["--methods", "odometry,lago"], ["--plot", str(tmp_path / "plots")]):
        message = cli_error(CliRunner().invoke(compare_main, [str(tiny), *extra]))
        assert message.startswith(f"{tiny} holds a 3D pose graph: ")
    assert not (tmp_path / "plots").exists()


# --------------------------------------------------------------------------- the library


def test_staged_checks_searches_against_the_dimension():
    graph, values = read_g2o(dataset("3d/tinyGrid3D.g2o"))
    with pytest.raises(RlpgoError, match="'rl': the agent is planar"):
        staged_initialize(graph, values, searches=SEARCHES)
    run = staged_initialize(graph, values, searches=SEARCHES_3D)
    assert run.certified and [row.method for row in run.rows] == ["certified"]
    assert run.best.refined_chi2 == pytest.approx(SESYNC_LM30["tinyGrid3D"], rel=1e-4)


def test_outlier_hint_on_a_corrupted_3d_graph():
    """smallGrid3D's residuals are Gaussian; with 20 loop closures turned by 90 degrees
    the refined result's are not, and the hint names the 6-dof bound."""
    graph, values = read_g2o(dataset("3d/smallGrid3D.g2o"))
    g = PoseGraph3D.from_gtsam(graph, values)
    clean = refine(graph, make_initializer("certified").run(g).values, pose_graph=g)
    assert outlier_suspicion(g, clean.values) is None
    corrupted = gtsam.NonlinearFactorGraph()
    turn = gtsam.Pose3(gtsam.Rot3.Rz(np.pi / 2), np.array([2.0, 0.0, 0.0]))
    closures = 0
    for k in range(graph.size()):
        factor = graph.at(k)
        i, j = factor.keys()
        if abs(i - j) > 1 and closures < 20 and k % 5 == 0:
            closures += 1
            factor = gtsam.BetweenFactorPose3(i, j, factor.measured().compose(turn),
                                              factor.noiseModel())
        corrupted.add(factor)
    assert closures == 20
    g = PoseGraph3D.from_gtsam(corrupted, values)
    result = refine(corrupted, make_initializer("chordal").run(g).values, pose_graph=g)
    hint = outlier_suspicion(g, result.values)
    assert hint is not None and "edges fit with chi2 > 22.458" in hint, hint


# --------------------------------------------------------------------------- the information rule


def test_parking_garage_is_read_with_its_matrices_as_they_are():
    """Three edges have a condition number above the planar 1e9 (the worst 2.67e9, line
    3594): the 3D rule (up to 1e12) takes them unchanged, without a warning."""
    path = dataset("3d/parking-garage.g2o")
    with warnings.catch_warnings():
        warnings.simplefilter("error", InformationWarning)
        graph, values = read_g2o(path)
    lines = path.read_text().splitlines()
    first_edge = next(n for n, line in enumerate(lines) if line.startswith("EDGE_SE3:QUAT"))
    worst = _file_information(lines[3594 - 1])
    eigenvalues = np.linalg.eigvalsh(worst)
    assert eigenvalues[-1] / eigenvalues[0] == pytest.approx(2.67e9, rel=0.01)
    assert information_problem(worst, 6) is not None  # the planar rule refuses it
    np.testing.assert_allclose(graph.at(3594 - 1 - first_edge).noiseModel().information(),
                               worst, rtol=1e-9, atol=1e-15)
    assert PoseGraph3D.from_gtsam(graph, values).num_edges == 6275


def _cubicle_head(tmp_path: Path, poses: int = 60) -> Path:
    """cubicle.g2o's first ``poses`` vertices and the edges among them, lines as they are."""
    lines = dataset("3d/cubicle.g2o").read_text().splitlines()
    kept = [line for line in lines if line.startswith("VERTEX") and int(line.split()[1]) < poses
            or line.startswith("EDGE") and max(map(int, line.split()[1:3])) < poses]
    path = tmp_path / "cubicle_head.g2o"
    path.write_text("\n".join(kept) + "\n")
    return path


def _sesync_weights(information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SE-Sync's kappa and tau (d = 3) from the diagonal blocks of (m, 6, 6) informations."""
    return (1.5 / np.trace(np.linalg.inv(information[:, :3, :3]), axis1=1, axis2=2),
            3.0 / np.trace(np.linalg.inv(information[:, 3:, 3:]), axis1=1, axis2=2))


def test_cubicle_indefinite_matrices_are_read_as_gtsam_reads_them(tmp_path):
    """cubicle's indefinite matrices (eigenvalues down to -0.47 x the largest: not rounding)
    have positive definite rotation and translation blocks. The reader's graph is
    gtsam.readG2o's (the same noise models, the same error), says so once naming the first
    line, and the relaxation weighs those edges by the printed blocks, as SE-Sync."""
    path = _cubicle_head(tmp_path)
    lines = path.read_text().splitlines()
    edges = [n for n, line in enumerate(lines, 1) if line.startswith("EDGE_SE3:QUAT")]
    stated = np.array([_file_information(lines[n - 1]) for n in edges])
    eigenvalues = np.linalg.eigvalsh(stated)
    indefinite = eigenvalues[:, 0] < 0
    assert indefinite.sum() == 40
    assert np.all(eigenvalues[indefinite, 0] < -1e-3 * eigenvalues[indefinite, -1])  # not 1e-5
    with pytest.warns(InformationWarning) as caught:
        graph, values = read_g2o(path)
    [warning] = caught
    first = edges[int(np.flatnonzero(indefinite)[0])]
    assert str(warning.message) == (
        f"{path}: 40 EDGE_SE3:QUAT information matrices (first on line {first}) are "
        "indefinite through their rotation-translation coupling alone: kept as printed, as "
        "gtsam.readG2o keeps them (chi2 is GTSAM's model of each, a Cholesky factor stopped at "
        "the indefinite pivot); the relaxation weighs them by their printed rotation and "
        "translation blocks, as SE-Sync does, where that factor's own information is beyond "
        "use")
    theirs, their_values = gtsam.readG2o(str(path), True)
    assert theirs.size() == graph.size() == len(edges)
    for k in range(graph.size()):
        ours, model = graph.at(k).noiseModel(), theirs.at(k).noiseModel()
        assert type(ours) is type(model)
        np.testing.assert_array_equal(ours.R(), model.R())
    for at in (values, their_values):
        assert graph.error(at) == pytest.approx(theirs.error(at), rel=1e-9)
    # GTSAM's model of an indefinite one weighs translation z far above the printed 10
    used = np.array([graph.at(k).noiseModel().information() for k in range(graph.size())])
    assert np.all(used[indefinite, 5, 5] > 1e4 * stated[indefinite, 5, 5])
    np.testing.assert_allclose(used[~indefinite], stated[~indefinite], rtol=1e-12)
    # the weights: the printed blocks where GTSAM's information is beyond rule 1 (all but a
    # few whose factor's information is usable, and is taken at its word), from either graph
    beyond = np.array([information_problem_6(m) is not None for m in used])
    assert beyond.sum() >= 35 and not beyond[~indefinite].any()
    for source in ((graph, values), (theirs, their_values)):
        pose_graph = PoseGraph3D.from_gtsam(*source)
        np.testing.assert_array_equal(pose_graph.information, used)
        expected = np.where(beyond[:, None, None], stated, used)
        for weights, wanted in zip((rotation_weights(pose_graph),
                                    translation_weights(pose_graph)),
                                   _sesync_weights(expected), strict=True):
            np.testing.assert_allclose(weights, wanted, rtol=1e-9)
    # both writers write the printed matrices of GTSAM's partial factors
    assert write.text_fast(theirs, their_values, SPATIAL) == write.text_careful(
        theirs, their_values, SPATIAL)
    result = run_init(path, "-o", tmp_path / "out.g2o", "--json", tmp_path / "run.json")
    cli_ok(result)
    assert result.stdout.startswith(f"note: {warning.message}\n")
    data = json.loads((tmp_path / "run.json").read_text())
    assert data["notes"] == [str(warning.message)] and data["certified"] is True
    # the output holds the printed matrices: it reads back to the same models
    assert_same_edges_3d(path, tmp_path / "out.g2o")
    out_lines = (tmp_path / "out.g2o").read_text().splitlines()
    written = np.array([_file_information(line) for line in out_lines
                        if line.startswith("EDGE_SE3:QUAT")])
    np.testing.assert_allclose(written, stated, rtol=1e-12, atol=1e-9)
    assert 2 * theirs.error(gtsam.readG2o(str(tmp_path / "out.g2o"), True)[1]) == \
        pytest.approx(data["chi2"], rel=1e-9)


def test_cubicle_from_gtsam_read_g2o_is_weighed_as_sesync_reads_it():
    """The API path: a user's graph from gtsam.readG2o(cubicle) (the noise models alone
    carry the printed matrices) is extracted with the relaxation's weights equal to SE-Sync's
    rule on the file's blocks wherever GTSAM's information is beyond use."""
    path = dataset("3d/cubicle.g2o")
    graph, values = gtsam.readG2o(str(path), True)
    stated = np.array([_file_information(line) for line in path.read_text().splitlines()
                       if line.startswith("EDGE_SE3:QUAT")])
    pose_graph = PoseGraph3D.from_gtsam(graph, values)
    beyond = np.array([information_problem_6(m) is not None for m in pose_graph.information])
    assert beyond.sum() == 4849 and (np.linalg.eigvalsh(stated)[:, 0] < 0).sum() == 5021
    np.testing.assert_allclose(pose_graph.weighed[beyond], stated[beyond], rtol=1e-9,
                               atol=1e-6)
    np.testing.assert_array_equal(pose_graph.weighed[~beyond], pose_graph.information[~beyond])
    kappa, tau = _sesync_weights(stated[beyond])
    np.testing.assert_allclose(rotation_weights(pose_graph)[beyond], kappa, rtol=1e-9)
    np.testing.assert_allclose(translation_weights(pose_graph)[beyond], tau, rtol=1e-9)
    # a subgraph made by dataclasses.replace (the robust path's) keeps its edges' weights
    kept = np.arange(1, pose_graph.num_edges, 3)
    part = replace(pose_graph, edges=pose_graph.edges[kept],
                   measured_rotations=pose_graph.measured_rotations[kept],
                   measured_translations=pose_graph.measured_translations[kept],
                   information=pose_graph.information[kept])
    np.testing.assert_array_equal(translation_weights(part), translation_weights(pose_graph)[kept])


def test_printed_matrices_are_read_back_only_from_partial_factors():
    """printed_informations: GTSAM's partial factor of an indefinite matrix gives the matrix
    back; a definite matrix's factor, the product R^T R and False."""
    coupled = np.diag([10.0, 10.0, 9e4, 2e4, 3e6, 10.0])
    coupled[0, 5] = coupled[5, 0] = 8.4e4  # cubicle's pattern: z coupled to roll
    definite = np.diag([4.0, 5.0, 6.0, 7.0, 8.0, 9.0])
    definite[0, 5] = definite[5, 0] = 1.0
    factors = np.array([gtsam.noiseModel.Gaussian.Information(m).R()
                        for m in (coupled, definite)])
    printed, found = printed_informations(factors)
    assert found.tolist() == [True, False]
    np.testing.assert_allclose(printed[0], coupled, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(printed[1], definite, rtol=1e-12)
    assert np.linalg.eigvalsh(factors[0].T @ factors[0])[-1] > 7e8  # what GTSAM charges


def test_rule_lifts_rounding_and_refuses_real_indefiniteness():
    rotated = np.linalg.qr(np.random.default_rng(0).normal(size=(6, 6)))[0]

    def matrix(*eigenvalues: float) -> np.ndarray:
        product = rotated @ np.diag(eigenvalues) @ rotated.T
        return 0.5 * (product + product.T)

    good = matrix(1e-10, 1, 2, 3, 4, 10)  # condition 1e11: as it is
    rounding = matrix(-1e-6, 1, 2, 3, 4, 10)  # -1e-7 x the largest: rounding
    steep = matrix(1e-13, 1, 2, 3, 4, 10)  # condition 1e14: lifted
    indefinite = np.diag([-1e-3, 1, 2, 3, 4, 10])  # -1e-4 x the largest, in a block: refused
    nan = np.eye(6)
    nan[2, 2] = np.nan
    used, problems, changes = information_rule_3d(np.stack([good, rounding, steep, indefinite,
                                                            nan]))
    assert changes == [(), (LIFTED,), (LIFTED,), (), ()]
    assert problems[:3] == [None, None, None]
    assert problems[3].startswith("information matrix is not positive definite (eigenvalues "
                                  "-0.001 .. 10)")
    assert problems[4] == "information matrix is not a finite 6x6 matrix"
    np.testing.assert_array_equal(used[0], good)
    for k in (1, 2):
        eigenvalues = np.linalg.eigvalsh(used[k])
        assert eigenvalues[0] == pytest.approx(1e-10, rel=1e-3)  # the largest / 1e11
        assert np.abs(used[k] - (rounding, steep)[k - 1]).max() < 2e-6
    # indefinite through the coupling alone (both blocks positive definite): kept as
    # printed; an indefinite block is refused
    coupled = np.eye(6)
    coupled[0, 3] = coupled[3, 0] = 5.0
    blocks_bad = coupled.copy()
    blocks_bad[0, 1] = blocks_bad[1, 0] = 5.0
    turned = matrix(-1e-3, 1, 2, 3, 4, 10)  # its blocks happen to be positive definite
    assert all(np.linalg.eigvalsh(turned[b, b])[0] > 0 for b in (slice(0, 3), slice(3, 6)))
    used, problems, changes = information_rule_3d(np.stack([coupled, blocks_bad, turned]))
    assert changes == [(INDEFINITE,), (), (INDEFINITE,)] and problems[0] is None
    np.testing.assert_array_equal(used[0], coupled)
    assert problems[1].startswith("information matrix is not positive definite")
    np.testing.assert_array_equal(used[2], turned)


def test_reader_refuses_real_indefiniteness_with_the_line(tmp_path):
    tiny = dataset("3d/tinyGrid3D.g2o").read_text().splitlines()
    k = next(n for n, line in enumerate(tiny) if line.startswith("EDGE_SE3:QUAT"))
    fields = tiny[k].split()
    bad = fields[:10] + ["-" + fields[10]] + fields[11:]  # I_11 negative: a block indefinite
    path = tmp_path / "bad.g2o"
    path.write_text("\n".join([*tiny[:k], " ".join(bad), *tiny[k + 1:]]) + "\n")
    cli_error(run_init(path, "-o", tmp_path / "out.g2o"),
              f"{path}:{k + 1}: EDGE_SE3:QUAT information matrix is not positive definite "
              f"(eigenvalues -{float(fields[10]):g} .. 100)")
    fields[12] = "nan"
    path.write_text("\n".join([*tiny[:k], " ".join(fields), *tiny[k + 1:]]) + "\n")
    message = cli_error(run_init(path, "-o", tmp_path / "out.g2o"))
    assert message.startswith(f"{path}:{k + 1}: ") and "not finite" in message
