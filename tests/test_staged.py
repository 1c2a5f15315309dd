"""Certify, else search: the staged default on generated graphs."""

import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import chi2, generate, read_g2o, write_g2o
from rlpgo_gtsam.staged import staged_initialize


@pytest.fixture(scope="module")
def heavy():
    """100 poses, sigma_R 0.5, noisy measurements: the relaxation is not exact here."""
    return generate(100, 0.5, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)


def test_an_exact_graph_is_certified_and_the_run_stops(small_exact):
    run = staged_initialize(small_exact.graph, small_exact.initial)
    assert run.certified and [r.method for r in run.rows] == ["certified"]
    assert "certified exact" in run.stopped
    assert chi2(small_exact.graph, run.values) < 1e-9


def test_a_failed_certificate_escalates_and_keeps_the_lowest(heavy):
    run = staged_initialize(heavy.graph, heavy.initial)
    assert not run.certified
    assert [r.method for r in run.rows] == ["certified", "chordal", "shonan@best", "rl@best"]
    assert run.rows[0].init.certificate.suboptimality_bound > 0
    refined = [r.refined_chi2 for r in run.rows]
    ties = [k for k, value in enumerate(refined) if value <= min(refined) * (1 + 1e-6)]
    assert run.best is run.rows[ties[0]]  # the lowest; a tie goes to the earlier stage
    assert chi2(heavy.graph, run.values) == pytest.approx(min(refined), rel=1e-6)
    assert all("not certified" in reason for reason in run.reasons[1:])


def test_the_budget_stops_the_searches(heavy):
    run = staged_initialize(heavy.graph, heavy.initial, budget_s=0.0)
    assert [r.method for r in run.rows] == ["certified"]
    assert run.stopped == "time budget of 0 s spent"


def test_rlpgo_init_prints_the_certificate_and_loads_no_torch(tmp_path, small_exact):
    path, output = tmp_path / "in.g2o", tmp_path / "out.g2o"
    write_g2o(path, small_exact.graph, small_exact.initial)
    script = ("import sys; from rlpgo_cli.init import main\n"
              "try:\n    main([sys.argv[1], '-o', sys.argv[2]])\n"
              "except SystemExit as exit:\n    assert exit.code in (0, None), exit.code\n"
              "assert 'torch' not in sys.modules and 'gymnasium' not in sys.modules\n")
    done = subprocess.run([sys.executable, "-c", script, str(path), str(output)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "certificate: certified optimal" in done.stdout
    assert "stopped: the relaxation is certified exact" in done.stdout
    assert chi2(*read_g2o(output)) < 1e-9


def test_rlpgo_init_auto_reports_each_stage(tmp_path, heavy):
    path, output = tmp_path / "in.g2o", tmp_path / "out.g2o"
    write_g2o(path, heavy.graph, heavy.initial)
    result = CliRunner().invoke(init_main, [str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    stages = [line.split()[1].rstrip(":") for line in result.stdout.splitlines()
              if line.startswith("stage ")]
    assert stages == ["certified", "chordal", "shonan@best", "rl@best"]
    assert "NOT certified" in result.stdout


def test_compare_marks_the_best_row_and_shows_certificates(tmp_path, small_exact):
    path = tmp_path / "in.g2o"
    write_g2o(path, small_exact.graph, small_exact.initial)
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(compare_main, [str(path), "--methods",
                                               "odometry,chordal,certified", "--json",
                                               str(json_path)])
    assert result.exit_code == 0, result.output
    records = {r["method"]: r for r in json.loads(json_path.read_text())}
    assert records["certified"]["certificate"]["certified"] is True
    assert records["certified"]["certificate"]["suboptimality_bound"] < 1e-6
    assert "certificate" not in records["chordal"]
    rows = {line[2:].split()[0]: line for line in result.stdout.splitlines()
            if line[2:].split()[:1] in (["odometry"], ["chordal"], ["certified"])}
    # the lowest chi2 is marked "*", or "=" on every row of a tie for it
    marked = [name for name, line in rows.items() if line[0] in "*="]
    assert marked == ["chordal", "certified"] and all(rows[m][0] == "=" for m in marked)
    assert rows["certified"].rstrip().endswith("yes")
    assert rows["odometry"].rstrip().endswith("-")


def test_ties_go_to_the_earlier_cheaper_row():
    from rlpgo_gtsam.ranking import MethodResult, best_of

    def row(method, value):
        return MethodResult("g", 2, 1, method, None, "lm", refined_chi2=value)

    rows = [row("cheap", 100.00005), row("dear", 100.0), row("failed", 1.0)]
    rows[2].failure = "boom"
    assert best_of(rows).method == "cheap"  # within 1e-6 relative: a tie
    assert best_of([row("a", 101.0), row("b", 100.0)]).method == "b"
