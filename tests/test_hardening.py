"""Hardening through the commands: every output checked before work, the model file an input,
model files and option values bounded; each failure one line, nothing written, inputs intact.

(Line-length, signal, training-state and trailing-slash cases are in test_cli_limits.py.)
"""

from __future__ import annotations

import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.evaluate import main as eval_main
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main
from rlpgo_cli.train import main as train_main

from rlpgo_gtsam import generate, read_g2o, write_g2o
from rlpgo_gtsam.rl.agent.checkpoint import load_model, save_model
from rlpgo_gtsam.rl.agent.networks import Actor
from rlpgo_gtsam.rl.episode import PRESETS

REFUSED = "is an input of this run; refusing to overwrite it"


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<dir>"
            for p in sorted(folder.rglob("*"))}


def _one_line_failure(result, code: int, text: str) -> None:
    assert result.exit_code == code, result.output
    assert "Traceback" not in result.output
    assert text in result.stderr, result.stderr
    if code == 1:  # a usage error (2) adds click's usage lines
        assert result.stderr.count("\n") == 1 and result.stdout == ""


@pytest.fixture
def graph_file(tmp_path: Path) -> Path:
    sample = generate(20, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(3))
    path = tmp_path / "g.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


@pytest.fixture
def model_file(tmp_path: Path) -> Path:
    path = tmp_path / "m.zip"
    save_model(path, Actor(8), PRESETS[1], {"test_cycles": 2})
    return path


# --- the model file is an input ---------------------------------------------------------


def test_init_refuses_to_write_over_its_model(tmp_path, graph_file, model_file):
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(init_main, [str(graph_file), "-o", str(model_file), "--method",
                                            "rl", "--model", str(model_file)])
    _one_line_failure(result, 1, f"{model_file}: {REFUSED}")
    assert _snapshot(tmp_path) == before
    load_model(model_file)  # intact


def test_eval_refuses_json_over_its_model(tmp_path, model_file):
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(eval_main, ["--preset", "1", "--model", str(model_file),
                                            "--json", str(model_file), "--graphs", "1"])
    _one_line_failure(result, 1, f"{model_file}: {REFUSED}")
    assert _snapshot(tmp_path) == before


def test_compare_refuses_json_over_its_model(tmp_path, graph_file, model_file):
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [str(graph_file), "--methods", "rl", "--model",
                                               str(model_file), "--json", str(model_file)])
    _one_line_failure(result, 1, f"{model_file}: {REFUSED}")
    assert _snapshot(tmp_path) == before


# --- rlpgo-compare: --plot PNGs and --json checked together, before any work ------------


def test_compare_refuses_a_plot_that_is_an_input(tmp_path, graph_file):
    source = tmp_path / "g.png"  # a g2o file named .png: its plot would be itself
    source.write_bytes(graph_file.read_bytes())
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [str(source), "--methods", "chordal", "--plot",
                                               str(tmp_path)])
    _one_line_failure(result, 1, f"{source}: {REFUSED}")
    assert _snapshot(tmp_path) == before


def test_compare_refuses_json_named_like_a_plot(tmp_path, graph_file):
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [str(graph_file), "--methods", "chordal",
                                               "--plot", str(tmp_path), "--json",
                                               str(tmp_path / "g.png")])
    _one_line_failure(result, 1, "given as two different outputs")
    assert _snapshot(tmp_path) == before


def test_compare_refuses_two_files_whose_plots_collide(tmp_path, graph_file):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "g.g2o").write_bytes(graph_file.read_bytes())
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(compare_main, [str(tmp_path / "a" / "g.g2o"),
                                               str(tmp_path / "b" / "g.g2o"), "--methods",
                                               "chordal", "--plot", str(tmp_path / "plots")])
    _one_line_failure(result, 1, "two FILES have the same name")
    assert _snapshot(tmp_path) == before


def test_compare_plot_folder_name_too_long_creates_nothing(tmp_path, graph_file):
    before = _snapshot(tmp_path)
    plots = tmp_path / "new" / ("p" * 256)
    result = CliRunner().invoke(compare_main, [str(graph_file), "--methods", "chordal",
                                               "--plot", str(plots)])
    _one_line_failure(result, 1, "longer than 255 bytes")
    assert _snapshot(tmp_path) == before


def test_compare_writes_plots_into_a_new_folder(tmp_path, graph_file):
    result = CliRunner().invoke(compare_main, [str(graph_file), "--methods", "chordal",
                                               "--iters", "2", "--plot",
                                               str(tmp_path / "new" / "plots")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "new" / "plots" / "g.png").read_bytes()[:4] == b"\x89PNG"


# --- model files: bombs, lying headers, config schema, through rlpgo-init -----------------


def _bomb(path: Path, model_file: Path, megabytes: int, declared: int | None = None) -> Path:
    """A model zip whose actor.pt inflates to ``megabytes`` MiB of zeros; with
    ``declared``, its headers claim that many bytes instead (a lying header)."""
    with zipfile.ZipFile(model_file) as zf:
        config = zf.read("config.json")
    chunk = bytes(1 << 20)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("config.json", config)
        with zf.open("actor.pt", "w", force_zip64=True) as member:
            for _ in range(megabytes):
                member.write(chunk)
    if declared is not None:  # actor.pt is the last entry of the central directory
        data = bytearray(path.read_bytes())
        central = data.rfind(b"PK\x01\x02")
        assert data[central + 24:central + 28] == struct.pack("<I", megabytes << 20)
        data[central + 24:central + 28] = struct.pack("<I", declared)
        path.write_bytes(bytes(data))
        with zipfile.ZipFile(path) as zf:
            assert zf.getinfo("actor.pt").file_size == declared
    return path


@pytest.mark.parametrize(("declared", "message"), [
    (None, "member actor.pt is larger than"),
    (50_000, "not a readable model zip (Bad CRC-32"),
], ids=["honest-header", "lying-header"])
def test_a_model_zip_bomb_is_one_line(tmp_path, graph_file, model_file, declared, message):
    bomb = _bomb(tmp_path / "bomb.zip", model_file, 32, declared)
    output = tmp_path / "out.g2o"
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(init_main, [str(graph_file), "-o", str(output), "--method",
                                            "rl", "--model", str(bomb)])
    _one_line_failure(result, 1, f"{bomb}: {message}")
    assert _snapshot(tmp_path) == before


def _with_config(model_file: Path, path: Path, change) -> Path:
    with zipfile.ZipFile(model_file) as zf:
        config = json.loads(zf.read("config.json"))
        weights = zf.read("actor.pt")
    change(config)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("config.json", json.dumps(config))
        zf.writestr("actor.pt", weights)
    return path


@pytest.mark.parametrize(("change", "message"), [
    (lambda c: c.update(cycles=3), 'config field cycles belongs inside "env"'),
    (lambda c: c["env"].update(test_cycles=3), "env field test_cycles belongs at the top level"),
    (lambda c: c.update(test_cycles=10**12), "test_cycles must be an integer in [1, 10000]"),
    (lambda c: c.update(hidden=2048), "hidden size must be an integer in 1..1024"),
    (lambda c: c.update(seed=-1), "config field seed must be an integer"),
    (lambda c: c.update(train_seconds=float("nan")), "train_seconds must be a finite number"),
    (lambda c: c.update(sac={"tau": "x"}), "sac must be an object of finite numbers"),
    (lambda c: c.update(command=7), "command must be a string"),
    (lambda c: c["env"].update(d=1e308), "env.d must be a finite number in [0, 1e+06]"),
], ids=["cycles-at-top", "test-cycles-in-env", "test-cycles-huge", "hidden-wide",
        "seed-negative", "seconds-nan", "sac-str", "command-int", "d-huge"])
def test_model_config_fields_are_checked_against_the_schema(tmp_path, graph_file, model_file,
                                                            change, message):
    broken = _with_config(model_file, tmp_path / "broken.zip", change)
    output = tmp_path / "out.g2o"
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(init_main, [str(graph_file), "-o", str(output), "--method",
                                            "rl", "--model", str(broken)])
    _one_line_failure(result, 1, f"{broken}: ")
    assert message in result.stderr
    assert _snapshot(tmp_path) == before


def test_wider_weights_than_the_config_are_refused_before_unpickling(tmp_path, model_file):
    with zipfile.ZipFile(model_file) as zf:
        config = zf.read("config.json")
    wide = tmp_path / "wide.zip"
    save_model(wide, Actor(256), PRESETS[1], {})
    with zipfile.ZipFile(wide) as zf:
        weights = zf.read("actor.pt")
    mixed = tmp_path / "mixed.zip"
    with zipfile.ZipFile(mixed, "w") as zf:
        zf.writestr("config.json", config)  # hidden 8
        zf.writestr("actor.pt", weights)  # 256 wide: about 3 MB
    from rlpgo_gtsam import ModelError

    with pytest.raises(ModelError, match="member actor.pt is larger than"):
        load_model(mixed)


# --- option values: bounded at parse time, ranges in --help --------------------------------


@pytest.mark.parametrize(("command", "args", "option"), [
    (init_main, ["--episodes", "101"], "--episodes"),
    (init_main, ["--cycles", "nan"], "--cycles"),
    (init_main, ["--budget", "inf"], "--budget"),
    (compare_main, ["--episodes", "1000000"], "--episodes"),
    (compare_main, ["--iters", "-1"], "--iters"),
    (generate_main, ["--n", "1000001"], "--n"),
    (generate_main, ["--lc", "1.5"], "--lc"),
    (generate_main, ["--d", "nan"], "--d"),
    (eval_main, ["--preset", "1", "--seed", "-1"], "--seed"),
    (eval_main, ["--preset", "1", "--graphs", "0"], "--graphs"),
    (train_main, ["--preset", "1", "--hidden", "1025"], "--hidden"),
    (train_main, ["--preset", "1", "--episodes", "2147483648"], "--episodes"),
    (train_main, ["--preset", "9"], "--preset"),
], ids=lambda value: value.name if hasattr(value, "name") else None)
def test_out_of_range_option_values_are_usage_errors(tmp_path, graph_file, command, args,
                                                     option):
    output = tmp_path / "out.g2o"
    extra = {init_main: [str(graph_file), "-o", str(output)], compare_main: [str(graph_file)],
             generate_main: ["-o", str(output)], eval_main: [],
             train_main: ["--out", str(tmp_path / "m")]}[command]
    before = _snapshot(tmp_path)
    result = CliRunner().invoke(command, [*extra, *args])
    _one_line_failure(result, 2, option)
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize(("command", "shown"), [
    (init_main, ["0<=x<=100000", "0<=x<=4294967295", "1<=x<=100", "FLOAT [0, 1e+06]"]),
    (generate_main, ["2<=x<=1000000", "FLOAT [0, 1]", "FLOAT [1e-06, 1e+06]"]),
    (train_main, ["4<=x<=1024", "0<=x<=4294967295"]),
    (eval_main, ["1<=x<=5", "1<=x<=1000000"]),
], ids=["init", "generate", "train", "eval"])
def test_help_shows_the_ranges(command, shown):
    result = CliRunner().invoke(command, ["--help"], terminal_width=200)
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    for range_text in shown:
        assert range_text in text, range_text


# --- rlpgo-train: outputs checked before work ----------------------------------------------


def test_train_refuses_a_stem_whose_names_are_too_long_before_work(tmp_path):
    stem = tmp_path / "new" / ("m" * 250)  # 250 + ".train.pt" > 255
    result = CliRunner().invoke(train_main, ["--preset", "1", "--episodes", "2", "--out",
                                             str(stem)])
    _one_line_failure(result, 1, "file name longer than 255 bytes")
    assert list(tmp_path.iterdir()) == []


def test_train_refuses_an_output_that_is_a_folder(tmp_path):
    (tmp_path / "m.csv").mkdir()
    result = CliRunner().invoke(train_main, ["--preset", "1", "--episodes", "2", "--out",
                                             str(tmp_path / "m")])
    _one_line_failure(result, 1, "m.csv: is a directory")
    assert [p.name for p in tmp_path.iterdir()] == ["m.csv"]


def test_a_new_training_run_replaces_all_earlier_outputs_together(tmp_path):
    from rlpgo_gtsam.rl.agent.config import SacConfig
    from rlpgo_gtsam.rl.train import TrainConfig, train

    sac = SacConfig(hidden=8, batch_size=2, gradient_steps=1, warmup_episodes=1, window=8,
                    burn_in=2)
    out = str(tmp_path / "m")
    train(TrainConfig(preset=1, episodes=2, out=out, sac=sac, checkpoint_every=2))
    first = _snapshot(tmp_path)
    train(TrainConfig(preset=1, episodes=3, seed=1, out=out, sac=sac, checkpoint_every=2))
    second = _snapshot(tmp_path)
    names = {"m.zip", "m.csv", "m.png", "m.train.pt"}
    assert names <= set(first) and names <= set(second)
    assert all(first[name] != second[name] for name in names)  # none is left from run one
    assert second["m.csv"].decode().splitlines()[-1].startswith("3,")
    assert load_model(tmp_path / "m.zip").metadata["episodes"] == 3
    assert not [name for name in second if name.endswith(".tmp")]


def test_generate_within_its_bounds_writes_a_file_its_reader_takes(tmp_path):
    output = tmp_path / "out.g2o"
    result = CliRunner().invoke(generate_main, ["--n", "12", "--d", "1000000", "--sigma-t",
                                                "10000", "--sigma-r", "3.2", "-o",
                                                str(output)])
    assert result.exit_code == 0, result.output
    assert read_g2o(output)[1].size() == 12
    # noise so unbalanced that no method could use the information: refused, nothing written
    refused = tmp_path / "refused.g2o"
    result = CliRunner().invoke(generate_main, ["--n", "12", "--sigma-t", "1000000",
                                                "--sigma-r", "3.2", "-o", str(refused)])
    assert result.exit_code == 1
    assert "condition number above 1e+09" in result.stderr
    assert not refused.exists()
