"""Certify, else search: the staged default on generated graphs."""

import json
import subprocess
import sys
import time

import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import PoseGraph2D, chi2, generate, make_initializer, read_g2o, refine, write_g2o
from rlpgo_gtsam.ranking import refine_until, run_method
from rlpgo_gtsam.staged import DEFAULT_SEARCHES, SEARCHES, staged_initialize


@pytest.fixture(scope="module")
def heavy():
    """100 poses, sigma_R 0.5, noisy measurements: the relaxation is not exact here."""
    return generate(100, 0.5, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)


def test_an_exact_graph_is_certified_and_the_run_stops(small_exact):
    run = staged_initialize(small_exact.graph, small_exact.initial)
    assert run.certified and [r.method for r in run.rows] == ["certified"]
    assert "certified exact" in run.stopped
    assert chi2(small_exact.graph, run.values) < 1e-9


def test_the_default_stops_after_a_failed_certificate_with_its_refined_estimate(heavy):
    """No search is in the default: none lowered the refined chi2 (staged.py's docstring)."""
    assert DEFAULT_SEARCHES == ()
    run = staged_initialize(heavy.graph, heavy.initial)
    assert not run.certified
    assert [r.method for r in run.rows] == ["certified"] and run.best is run.rows[0]
    assert run.stopped == "relaxation not certified; no search after it (none is in the default)"
    assert run.rows[0].init.certificate.suboptimality_bound > 0
    assert run.rows[0].refined_chi2 < run.rows[0].init_chi2
    assert chi2(heavy.graph, run.values) == pytest.approx(run.rows[0].refined_chi2, rel=1e-9)


def test_searches_on_request_escalate_and_keep_the_lowest(heavy):
    run = staged_initialize(heavy.graph, heavy.initial, searches=SEARCHES)
    assert not run.certified
    assert [r.method for r in run.rows] == ["certified", "chordal", "shonan@best", "rl@best"]
    refined = [r.refined_chi2 for r in run.rows]
    ties = [k for k, value in enumerate(refined) if value <= min(refined) * (1 + 1e-6)]
    assert run.best is run.rows[ties[0]]  # the lowest; a tie goes to the earlier stage
    assert chi2(heavy.graph, run.values) == pytest.approx(min(refined), rel=1e-6)
    assert all("not certified" in reason for reason in run.reasons[1:])
    assert all(r.init_seconds > 0 for r in run.rows)


def test_the_budget_stops_the_searches(heavy):
    run = staged_initialize(heavy.graph, heavy.initial, budget_s=0.0, searches=SEARCHES)
    assert [r.method for r in run.rows] == ["certified"]
    assert "time budget of 0 s spent" in run.stopped


def test_a_budget_cut_in_the_certified_stage_hands_over_its_estimate(heavy):
    lines = []
    run = staged_initialize(heavy.graph, heavy.initial, budget_s=0.0,
                            options={"certified": {"progress": lines.append}})
    assert [r.method for r in run.rows] == ["certified"]
    assert run.rows[0].init.certificate.status == "time_limit" and not run.certified
    assert run.stopped.startswith("time budget of 0 s spent during the certified stage: its "
                                  "best estimate so far, not certified; certified: the time "
                                  "limit stopped LM after 0 of 30 iterations")
    assert run.hint is None  # an unfinished estimate's residuals say nothing of the closures
    assert run.best.refined_chi2 == pytest.approx(chi2(heavy.graph, run.values))
    assert lines  # the stage reported progress


@pytest.fixture(scope="module")
def hard():
    """1000 poses, sigma_R 3, a loop closure at every step: the staircase climbs past rank 1,
    still unverified at rank 2 after 3 s."""
    return generate(1000, 3.0, 0.05, 3.0, 1.0, np.random.default_rng(1), noisy_measurements=True)


def test_a_small_budget_cuts_inside_the_certified_stage_and_bounds_the_whole_run(hard):
    """The deadline bites inside the stage (trust region, CG, factorizations, the
    verification) and leaves the translations and the refinement their time: the run ends
    within 1.2 x its budget with the lowest estimate reached, and says it was cut."""
    import rlpgo_gtsam.relaxation.circles  # noqa: F401  (scipy's first import is not the run's time)

    lines: list[str] = []
    run = staged_initialize(hard.graph, hard.initial, budget_s=2.0,
                            options={"certified": {"progress": lines.append}})
    assert run.seconds <= 1.2 * 2.0
    assert [r.method for r in run.rows] == ["certified"] and not run.certified
    assert run.rows[0].init.certificate.status == "time_limit"
    assert run.stopped.startswith("time budget of 2 s spent during the certified stage: its "
                                  "best estimate so far, not certified")
    assert run.best.refined_chi2 == pytest.approx(chi2(hard.graph, run.values))
    assert run.best.refined_chi2 < chi2(hard.graph, hard.initial) / 100  # a guess
    assert lines and "lambda_min nan" in " ".join(lines)  # progress; nothing verified


def test_refine_until_with_time_to_spare_is_one_refine_exactly(heavy):
    """A refinement the time left holds four times over (as reckoned before an iteration is
    timed) runs as one ``refine``: a budget that is not reached changes nothing."""
    values = make_initializer("chordal").initialize(heavy.graph, heavy.initial)
    whole = refine(heavy.graph, values, iters=30)
    spared, cut = refine_until(heavy.graph, values, "lm", 30, time.perf_counter() + 600.0)
    assert cut is None
    assert (spared.iterations, spared.chi2_trace) == (whole.iterations, whole.chi2_trace)


def test_refine_until_ends_by_its_deadline(heavy):
    values = make_initializer("chordal").initialize(heavy.graph, heavy.initial)
    spent, cut = refine_until(heavy.graph, values, "lm", 30, time.perf_counter() - 1.0)
    assert (spent.iterations, spent.chi2_trace) == (0, [chi2(heavy.graph, values)])
    assert cut == "the time limit stopped LM after 0 of 30 iterations"
    whole = refine(heavy.graph, values, "lm", 30)
    ample, cut = refine_until(heavy.graph, values, "lm", 30, time.perf_counter() + 600.0)
    assert cut is None and 1 <= ample.iterations <= 30
    assert ample.chi2 == pytest.approx(whole.chi2, rel=1e-6)  # chunks restart LM's damping
    assert ample.chi2_trace[-1] == ample.chi2 and len(ample.chi2_trace) == ample.iterations + 1


def test_a_failed_initializer_reports_the_seconds_it_spent(heavy):
    """Shonan with max_p 2 does not converge on this graph (after 0.01-0.3 s, by host): the
    failure names the seconds the row measured, not 0.00 (it once did after 4 s)."""
    pose_graph = PoseGraph2D.from_gtsam(heavy.graph, heavy.initial)
    row = run_method(heavy.graph, pose_graph, "shonan", options={"max_p": 2, "starts": 1})
    assert row.init is None and "failed from every start (1 run, " in row.failure
    told = float(row.failure.split("(1 run, ")[1].split(" s)")[0])
    assert row.init_seconds > 0.0
    assert abs(told - row.init_seconds) <= 0.02  # the message rounds to 0.01 s
    assert row.record()["init_seconds"] == row.init_seconds


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


def test_rlpgo_init_auto_reports_the_stage_and_why_it_stopped(tmp_path, heavy):
    path, output = tmp_path / "in.g2o", tmp_path / "out.g2o"
    write_g2o(path, heavy.graph, heavy.initial)
    result = CliRunner().invoke(init_main, [str(path), "-o", str(output)])
    assert result.exit_code == 0, result.output
    stages = [line.split()[1].rstrip(":") for line in result.stdout.splitlines()
              if line.startswith("stage ")]
    assert stages == ["certified"]
    assert "NOT certified" in result.stdout
    assert "stopped: relaxation not certified; no search after it" in result.stdout


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
    lines = result.stdout.splitlines()
    rows = {line.split()[0]: line for line in lines
            if line[2:].split()[:1] in (["odometry"], ["chordal"], ["certified"])}
    # after the rows (printed as each is done): the lowest chi2, or every row of a tie for it
    tie = "= 2 methods tie for the lowest refined chi2 (within a relative 1e-06): chordal, " \
          "certified"
    assert lines.index(tie) == lines.index(rows["certified"]) + 1
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
