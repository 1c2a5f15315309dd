"""rlpgo-init end to end, RLInitializer through the API, and the rl methods of rlpgo-compare.

The agent is a real, untrained model file: ``Actor(16)`` with seeded weights and preset 1,
saved with ``save_model`` (two test cycles keep the rollouts short). Graphs are small
generated lawn mowers (40 poses) written with ``write_g2o``.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import gtsam
import numpy as np
import pytest
import torch
from click.testing import CliRunner, Result
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.init import ALL
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import (
    PRESETS,
    PoseGraph2D,
    RLInitializer,
    RlpgoError,
    chi2,
    make_initializer,
    read_g2o,
    refine,
    write_g2o,
)
from rlpgo_gtsam.rl.agent.checkpoint import save_model
from rlpgo_gtsam.rl.agent.networks import Actor
from rlpgo_gtsam.synthetic import generate
from tests.conftest import assert_same_edges, cli_error, cli_ok

SUMMARY = re.compile(
    r"^input chi2 (?P<input>\S+); (?P<method>\S+)(?: \+ (?P<step>[A-Z]+\d+))?: chi2 "
    r"(?P<result>\S+); \d+\.\d\d s; wrote (?P<output>.+)$"
)
ROW = re.compile(
    r"^(?P<method>[a-z]\S*)\s+(?P<guess>[-\d.e+]+)\s+(?P<result>[-\d.e+]+)\s+"
    r"(?P<seconds>\d+\.\d\d)(?P<tail>.*)$"
)


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def agent(tmp_path_factory) -> Path:
    """A real model file: a seeded, untrained 16-unit actor on preset 1."""
    path = tmp_path_factory.mktemp("model") / "agent.zip"
    torch.manual_seed(0)
    save_model(path, Actor(16), PRESETS[1], {"test_cycles": 2})
    return path


@pytest.fixture
def graph_file(tmp_path) -> Path:
    """40 poses, heavy rotation noise, noisy measurements."""
    sample = generate(40, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(1), noisy_measurements=True)
    path = tmp_path / "in.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


def run_init(*args: str | Path) -> Result:
    return CliRunner().invoke(init_main, [str(a) for a in args])


def _summary(stdout: str) -> re.Match:
    last = stdout.rstrip("\n").splitlines()[-1]
    match = SUMMARY.match(last)
    assert match, last
    return match


def _g6(value: float) -> str:
    return f"{value:.6g}"


def _assert_same_poses(first: gtsam.Values, second: gtsam.Values, atol: float) -> None:
    assert sorted(first.keys()) == sorted(second.keys())
    for key in first.keys():
        a, b = first.atPose2(key), second.atPose2(key)
        np.testing.assert_allclose([a.x(), a.y()], [b.x(), b.y()], rtol=0, atol=atol)
        assert abs(np.angle(np.exp(1j * (a.theta() - b.theta())))) <= atol


# --------------------------------------------------------------------------- rlpgo-init


def test_init_all_streams_every_method_then_ranks_and_writes_the_lowest(tmp_path, graph_file,
                                                                      agent):
    output = tmp_path / "out.g2o"
    result = run_init(graph_file, "-o", output, "--model", agent, "--method", "all")
    cli_ok(result)
    lines = result.stdout.rstrip("\n").splitlines()
    assert lines[0].split() == ["method", "guess", "chi2", "result", "chi2", "seconds"]
    rows = [ROW.match(line) for line in lines if ROW.match(line)]
    # one row per method, in the order they ran, each printed as soon as it was done: the
    # rows before Shonan came before Shonan's own progress line
    shonan = lines.index(next(line for line in lines if line.startswith("  shonan: run 1 of 1")))
    assert [r["method"] for r in rows] == [m if m != "shonan" else "shonan@best" for m in ALL]
    assert all(lines.index(r.string) < shonan for r in rows[:ALL.index("shonan")])
    assert lines.index(rows[ALL.index("shonan")].string) > shonan
    assert all(r["tail"] == "" and float(r["seconds"]) >= 0 for r in rows), "no method may fail"
    # then the ranking: a rank is the number of rows above plus one; ties share it, as "=k"
    ranking = lines[-2]
    assert ranking.startswith("ranking: ")
    ranked = [entry.split() for entry in ranking.removeprefix("ranking: ").split(", ")]
    ranks = [rank for rank, _ in ranked]
    assert sorted(method for _, method in ranked) == sorted(r["method"] for r in rows)
    for rank in ranks:
        assert rank.startswith("=") == (ranks.count(rank) > 1)
        assert int(rank.lstrip("=")) == ranks.index(rank) + 1
    result_of = {r["method"]: float(r["result"]) for r in rows}
    results = [result_of[method] for _, method in ranked]
    assert results == sorted(results)

    summary = _summary(result.stdout)
    graph, values = read_g2o(graph_file)
    assert summary["input"] == _g6(chi2(graph, values))
    assert summary["step"] == "LM30"
    assert summary["method"] == ranked[0][1]
    assert float(summary["result"]) == min(results)
    assert Path(summary["output"]) == output

    assert_same_edges(graph_file, output)
    out_graph, out_values = read_g2o(output)
    assert sorted(out_values.keys()) == sorted(values.keys())
    written_chi2 = chi2(out_graph, out_values)
    assert _g6(written_chi2) == summary["result"]

    chordal = make_initializer("chordal").initialize(graph, values)
    reference = refine(graph, chordal, "lm", 30).chi2
    assert written_chi2 <= reference * (1 + 1e-9) + 1e-9


@pytest.fixture(scope="module")
def hard_1000(tmp_path_factory) -> Path:
    """1000 poses, sigma_R 0.5, noisy measurements: the certified stage needs seconds."""
    sample = generate(1000, 0.5, 0.05, 3.0, 0.5, np.random.default_rng(1),
                      noisy_measurements=True)
    path = tmp_path_factory.mktemp("hard") / "hard.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


def test_init_budget_cuts_the_certified_stage_and_writes_its_estimate(tmp_path, hard_1000):
    output = tmp_path / "out.g2o"
    began = time.perf_counter()
    result = run_init(hard_1000, "-o", output, "--budget", "0.2")
    cli_ok(result)
    assert time.perf_counter() - began < 30  # the stage alone takes 5 s or more
    lines = result.stdout.splitlines()
    assert any(line.startswith("  certified: ") for line in lines)  # its progress
    assert re.search(r"stopped: time budget of [0-9.e-]+ s spent during the certified stage: "
                     r"its best estimate so far, not certified; .*\(the stages' share of "
                     r"--budget 0\.2 s after reading", result.stdout)
    assert "NOT certified: time limit reached" in result.stdout
    assert not any(line.startswith("hint: ") for line in lines)
    assert re.search(r"; certified \+ LM30 \(cut after \d+\): chi2 ", lines[-1])
    graph, values = read_g2o(hard_1000)
    out_graph, out_values = read_g2o(output)
    assert chi2(out_graph, out_values) < chi2(graph, values) / 10  # a guess, not the input


def test_init_rl_without_refinement_writes_the_agents_guess(tmp_path, graph_file, agent):
    output = tmp_path / "out.g2o"
    result = run_init(graph_file, "-o", output, "--model", agent, "--method", "rl",
                      "--start", "odometry", "--refine", "none", "--cycles", "1")
    cli_ok(result)
    assert len(result.stdout.splitlines()) == 1  # one method: no ranking table
    summary = _summary(result.stdout)
    assert summary["method"] == "rl@odometry" and summary["step"] is None

    graph, values = read_g2o(graph_file)
    assert summary["input"] == _g6(chi2(graph, values))
    rl = RLInitializer(model=agent, cycles=1, start="odometry").run(
        PoseGraph2D.from_gtsam(graph, values))
    guess = rl.values
    assert summary["result"] == _g6(rl.chi2)

    assert_same_edges(graph_file, output)
    out_graph, out_values = read_g2o(output)
    _assert_same_poses(out_values, guess, atol=1e-12)
    assert _g6(chi2(out_graph, out_values)) == summary["result"]
    # The agent moved away from odometry: the file is not just the input's vertices.
    assert chi2(out_graph, out_values) != pytest.approx(chi2(graph, values))


def test_init_classical_method_with_gauss_newton(tmp_path, graph_file):
    output = tmp_path / "out.g2o"
    result = run_init(graph_file, "-o", output, "--method", "chordal", "--refine", "gn",
                      "--iters", "5")
    cli_ok(result)
    summary = _summary(result.stdout)
    assert (summary["method"], summary["step"]) == ("chordal", "GN5")

    graph, values = read_g2o(graph_file)
    expected = refine(graph, make_initializer("chordal").initialize(graph, values), "gn", 5)
    assert summary["result"] == _g6(expected.chi2)
    out_graph, out_values = read_g2o(output)
    assert_same_edges(graph_file, output)
    assert _g6(chi2(out_graph, out_values)) == summary["result"]
    assert chi2(out_graph, out_values) < chi2(graph, values)


def test_init_missing_model(tmp_path, graph_file):
    model, output = tmp_path / "nope.zip", tmp_path / "out.g2o"
    result = run_init(graph_file, "-o", output, "--model", model, "--method", "rl")
    assert cli_error(result).endswith(f"{model}: no such model file")
    assert not output.exists()


@pytest.mark.parametrize(("method", "given", "refused"), [
    ([], ["--model", "nope.zip"], "--model"),
    (["--method", "chordal"], ["--episodes", "3", "--seed", "2"], "--episodes, --seed"),
    (["--method", "all"], ["--start", "lago"], "--start"),
    (["--method", "chordal"], ["--budget", "5"], "--budget bounds --method auto"),
], ids=["default", "chordal", "all", "budget"])
def test_init_options_that_change_nothing_are_usage_errors(tmp_path, graph_file, method,
                                                                given, refused):
    """The default runs no agent: its options would change nothing; nor would --budget
    outside the default."""
    output = tmp_path / "out.g2o"
    result = run_init(graph_file, "-o", output, *method, *given)
    cli_error(result, f"Error: {refused}", code=2)
    assert not output.exists()


@pytest.mark.parametrize("method", ["magic", "rl@magic", ""])
def test_init_unknown_method(tmp_path, graph_file, method):
    output = tmp_path / "out.g2o"
    cli_error(run_init(graph_file, "-o", output, "--method", method), "--method", code=2)
    assert not output.exists()


# --------------------------------------------------------------------------- RLInitializer API


def test_rl_initializer_api(graph_file, agent):
    graph, values = read_g2o(graph_file)
    guess = RLInitializer(model=agent, episodes=3, start="chordal").initialize(graph, values)
    assert isinstance(guess, gtsam.Values)
    assert sorted(guess.keys()) == sorted(values.keys())
    assert guess.atPose2(0).equals(values.atPose2(0), 1e-9)

    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    result = RLInitializer(model=agent, episodes=3, start="chordal").run(pose_graph)
    assert result.method == "rl@chordal"
    _assert_same_poses(result.values, guess, atol=0.0)
    costs = result.details["rollout_chi2"]
    assert len(costs) == 3 and result.chi2 == min(costs) == costs[result.details["chosen_rollout"]]
    assert result.chi2 == pytest.approx(chi2(graph, guess))
    assert result.seconds > 0

    single = RLInitializer(model=agent, episodes=1, start="chordal").run(pose_graph)
    assert single.details["rollout_chi2"] == costs[:1]  # episode 0 of both is the same rollout


def test_rl_initializer_is_deterministic(graph_file, agent):
    graph, values = read_g2o(graph_file)
    first = RLInitializer(model=agent, episodes=2, seed=5).initialize(graph, values)
    second = RLInitializer(model=agent, episodes=2, seed=5).initialize(graph, values)
    _assert_same_poses(first, second, atol=0.0)


@pytest.mark.parametrize("options", [
    {"start": "magic"}, {"start": "rl"}, {"episodes": 0}, {"episodes": -1}, {"cycles": 0},
], ids=["start", "start_rl", "episodes_zero", "episodes_negative", "cycles_zero"])
def test_rl_initializer_rejects_bad_arguments(agent, options):
    with pytest.raises(RlpgoError):
        RLInitializer(model=agent, **options)


def test_rl_initializer_missing_model(tmp_path):
    with pytest.raises(RlpgoError, match="no such model file"):
        RLInitializer(model=tmp_path / "nope.zip")


# --------------------------------------------------------------------------- rlpgo-compare


def test_compare_rl_methods(tmp_path, graph_file, agent):
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(compare_main, [
        str(graph_file), "--methods", "chordal,rl,rl@lago", "--model", str(agent),
        "--iters", "10", "--json", str(json_path),
    ])
    cli_ok(result)
    records = json.loads(json_path.read_text())
    assert [r["method"] for r in records] == ["chordal", "rl@odometry", "rl@lago"]
    assert all(r["dataset"] == "in.g2o" and r["poses"] == 40 for r in records)
    assert all(r["refined_chi2"] <= r["init_chi2"] for r in records)


def test_compare_rl_with_an_unknown_start_is_a_usage_error(tmp_path, graph_file):
    json_path = tmp_path / "out.json"
    result = CliRunner().invoke(compare_main, [str(graph_file), "--methods", "rl@magic",
                                               "--json", str(json_path)])
    cli_error(result, "rl@magic", code=2)
    assert not json_path.exists()
