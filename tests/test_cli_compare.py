import json

from click.testing import CliRunner
from rlpgo_cli.compare import main

from rlpgo_gtsam import RotationInitializer, SolverError, initializers, register, write_g2o
from tests.conftest import cli_error, dataset

RECORD_KEYS = {"dataset", "poses", "edges", "method", "init_chi2", "init_seconds", "solver",
               "iters", "refined_chi2", "refine_seconds", "failure", "dimension"}


def test_compare_runs_out_of_the_box(tmp_path):
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(
        main, ["--solver", "lm", "--iters", "30", "--methods", "odometry,chordal",
               "--json", str(json_path), "--plot", str(tmp_path / "new" / "plots")]
    )
    assert result.exit_code == 0, result.output
    assert "generated lawn mower (n=300 sigma_r=0.3" in result.output
    records = json.loads(json_path.read_text())
    assert [r["method"] for r in records] == ["odometry", "chordal"]
    assert all(set(r) == RECORD_KEYS | {"accuracy"} for r in records)  # generated: with truth
    assert all(r["refined_chi2"] <= r["init_chi2"] for r in records)
    pngs = list((tmp_path / "new" / "plots").glob("*.png"))  # the folders made
    assert len(pngs) == 1 and pngs[0].stat().st_size > 10_000
    assert pngs[0].read_bytes()[:4] == b"\x89PNG"


def test_compare_on_files_reports_each(tmp_path, small_noisy):
    path = tmp_path / "small.g2o"
    write_g2o(path, small_noisy.graph, small_noisy.initial)
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(
        main, [str(path), str(dataset("MIT.g2o")), "--solver", "gn", "--iters", "10",
               "--methods", "lago,chordal", "--json", str(json_path)]
    )
    assert result.exit_code == 0, result.output
    records = json.loads(json_path.read_text())
    assert [(r["dataset"], r["method"]) for r in records] == [
        ("small.g2o", "lago"), ("small.g2o", "chordal"), ("MIT.g2o", "lago"), ("MIT.g2o", "chordal")
    ]
    assert all(r["solver"] == "gn" and r["iters"] <= 10 for r in records)
    mit = {r["method"]: r for r in records if r["dataset"] == "MIT.g2o"}
    assert (mit["chordal"]["poses"], mit["chordal"]["edges"]) == (808, 827)


def test_unknown_method_is_a_usage_error():
    result = CliRunner().invoke(main, ["--methods", "odometry,magic"])
    cli_error(result, "unknown method 'magic'", code=2)


def test_a_failing_method_is_reported_and_the_others_still_run(tmp_path, monkeypatch):
    """An initializer that raises (registered as users register theirs) is a FAILED row; the
    others still run and the run exits 1."""

    class Failing(RotationInitializer):
        def rotations(self, pose_graph, start=None):
            raise SolverError("indeterminate on purpose")

    monkeypatch.setattr(initializers, "_REGISTRY", dict(initializers._REGISTRY))
    register("failing", Failing)
    lines = [f"VERTEX_SE2 {k} {k}.0 0 0" for k in range(4)]
    lines += [f"EDGE_SE2 {k} {k + 1} 1 0 0.1 1 0 0 1 0 1" for k in range(3)]
    path = tmp_path / "chain.g2o"
    path.write_text("\n".join(lines) + "\n")
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(main, [str(path), "--methods", "odometry,failing,lago",
                                       "--solver", "gn", "--json", str(json_path)])
    assert result.exit_code == 1
    assert result.stderr == ("Error: at least one method failed (see FAILED above) (nothing "
                             "written)\n")
    assert result.stdout.count("FAILED: ") == 1
    assert "indeterminate on purpose" in result.stdout
    assert "Traceback" not in result.output
    rows = [line.split() for line in result.stdout.splitlines()
            if line.split()[:1] in (["odometry"], ["failing"], ["lago"])]
    assert [row[0] for row in rows] == ["odometry", "failing", "lago"]  # every row printed
    assert rows[1][1] == "-" and rows[2][1] != "-"  # no guess from the failing one
    assert not json_path.exists()  # a run that fails writes nothing


def test_rows_stream_and_a_method_named_runs_as_named(tmp_path, small_noisy):
    """Each row is printed as soon as its method is done: the rows before Shonan come before
    Shonan's progress line. Shonan named in --methods runs from its own start (in the
    default rows it starts from the best so far: shonan@best)."""
    path = tmp_path / "small.g2o"
    write_g2o(path, small_noisy.graph, small_noisy.initial)
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(main, [str(path), "--methods", "odometry,lago,shonan",
                                       "--json", str(json_path)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    header = next(k for k, line in enumerate(lines) if line.split()[:1] == ["method"])
    row = {line.split()[0]: k for k, line in enumerate(lines) if line.startswith("  ")
           and not line.startswith("    ")}
    progress = next(k for k, line in enumerate(lines) if line.startswith("    shonan: run 1 of"))
    assert header < row["odometry"] < row["lago"] < progress < row["shonan"]
    assert lines[row["shonan"] + 1].startswith(("* lowest refined chi2: ", "= "))
    records = json.loads(json_path.read_text())
    assert [r["method"] for r in records] == ["odometry", "lago", "shonan"]
    shonan = records[2]
    assert "started_from" not in shonan["details"]  # its own starts, not the best row
    assert shonan["init_seconds"] >= shonan["details"]["runs"][0]["seconds"] > 0


def test_the_default_rows_stream_from_the_console_script(tmp_path):
    """``rlpgo-compare FILE`` as a user runs it (the console script's launcher, stdout a
    pipe): the default rows are the classical ones and certified, fastsync one name away;
    each row arrives as its method finishes (at least half its own seconds after the row
    before it), every row reports its seconds, and the JSON is complete."""
    import itertools
    import os
    import subprocess
    import sys
    import time

    from rlpgo_cli.compare import DEFAULT_METHODS, LEFT_OUT

    assert "fastsync" in LEFT_OUT and "fastsync" not in DEFAULT_METHODS.split(",")
    json_path = tmp_path / "rows.json"
    script = "import sys; from rlpgo_cli.launch import compare; sys.argv[0] = 'rlpgo-compare'; " \
             "compare()"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    began = time.monotonic()
    with subprocess.Popen([sys.executable, "-c", script, str(dataset("MIT.g2o")), "--json",
                           str(json_path)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                          text=True, env=env) as process:
        arrived = [(time.monotonic() - began, line) for line in process.stdout]
    assert process.returncode == 0
    records = json.loads(json_path.read_text())
    assert [r["method"] for r in records] == ["odometry", "lago", "chordal", "shonan@best",
                                             "certified"]
    rows = [(t, line.split()[0]) for t, line in arrived
            if line.startswith("  ") and not line.startswith("    ")
            and line.split()[0] in {r["method"] for r in records}]
    assert [method for _, method in rows] == [r["method"] for r in records]
    for ((before, _), (after, _)), record in zip(itertools.pairwise(rows), records[1:],
                                                strict=True):
        seconds = record["init_seconds"] + record["refine_seconds"]
        assert seconds > 0 and after - before >= 0.5 * seconds
    result = CliRunner().invoke(main, [str(dataset("MIT.g2o")), "--methods", "chordal,fastsync"])
    assert result.exit_code == 0, result.output
    assert "  fastsync " in result.output


def test_in_the_default_rows_shonan_starts_from_the_best_so_far(small_noisy):
    """compare_methods' default (FROM_BEST): Shonan runs once, from the lowest refined chi2
    before it, and ends no higher."""
    from rlpgo_gtsam.ranking import compare_methods

    rows = compare_methods(small_noisy.graph, small_noisy.initial, ["odometry", "lago", "shonan"])
    assert [r.method for r in rows] == ["odometry", "lago", "shonan@best"]
    lowest = min(r.refined_chi2 for r in rows[:2])
    best = next(r for r in rows[:2] if r.refined_chi2 <= lowest * (1 + 1e-6))  # ties: first
    shonan = rows[2]
    assert shonan.init.details["started_from"] == best.method
    assert len(shonan.init.details["runs"]) == 1  # one run, from the best; no random starts
    assert shonan.refined_chi2 <= best.refined_chi2 * (1 + 1e-6)
