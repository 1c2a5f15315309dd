"""Fuzzing every command's option values and every model-config field: a usage error, a
one-line error or a run whose output reads back, never a traceback.

rlpgo-init and rlpgo-generate run for real on a 12-pose graph (what they write must read);
rlpgo-compare, rlpgo-eval and rlpgo-train are given outputs in a folder that does not exist
(or, for train, names too long), so a value that parses ends in the output check before any
work, and the examples stay fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.evaluate import main as eval_main
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main
from rlpgo_cli.train import main as train_main

from rlpgo_gtsam import ModelError, generate, read_g2o, write_g2o
from rlpgo_gtsam.rl.agent.checkpoint import load_model
from tests.conftest import model_with_config

VALUES = st.one_of(
    st.integers(-2**70, 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-0", "0x10", "", " ", "1_0", "abc", "٣",
                     "2147483648", "4294967296", "9" * 400, "--help", "a\nb"]),
    st.sampled_from(["n=nan", "n=0", "sigma_r=1e308", "sigma_r=9", "=1",  # for --env
                     "noisy_measurements=2", "cycles=99999999999"]),
)
SETTINGS = settings(deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def graph12(tmp_path_factory) -> Path:
    sample = generate(12, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(0))
    path = tmp_path_factory.mktemp("input") / "in.g2o"
    write_g2o(path, sample.graph, sample.initial)
    return path


# command -> (options fuzzed, the other arguments from (folder, graph12), the output written)
COMMANDS = {
    "init": (init_main, ["--iters", "--budget"], lambda f, g: [g, "-o", f / "o.g2o"], "o.g2o"),
    "init-robust": (init_main, ["--covariance-scale"],
                    lambda f, g: [g, "-o", f / "o.g2o", "--robust"], "o.g2o"),
    "init-agent": (init_main, ["--seed", "--episodes", "--cycles"],
                   lambda f, g: [g, "-o", f / "o.g2o", "--method", "rl"], "o.g2o"),
    "generate": (generate_main, ["--sigma-r", "--sigma-t", "--d", "--lc", "--seed"],
                 lambda f, g: ["--n", "12", "-o", f / "g.g2o"], "g.g2o"),
    "compare": (compare_main, ["--iters", "--seed", "--episodes", "--cycles", "--solver",
                               "--methods", "--start"],
                lambda f, g: ["--json", f / "absent" / "x.json"], None),
    "eval": (eval_main, ["--preset", "--graphs", "--seed"],
             lambda f, g: ["--json", f / "absent" / "x.json"], None),
    "train": (train_main, ["--preset", "--episodes", "--seed", "--hidden", "--batch-size",
                           "--gradient-steps", "--validation-graphs", "--env",
                           "--reward-scale"],
              lambda f, g: ["--out", f / "absent" / ("m" * 250)], None),
}
OPTIONS = [(name, option) for name, (_, options, _, _) in COMMANDS.items() for option in options]


@settings(SETTINGS, max_examples=300)
@given(command_option=st.sampled_from(OPTIONS), value=VALUES)
def test_option_values(tmp_path_factory, graph12, command_option, value):
    name, option = command_option
    command, _, arguments, written = COMMANDS[name]
    folder = tmp_path_factory.mktemp(name)
    args = [str(a) for a in arguments(folder, graph12)]
    if name in ("eval", "train") and option != "--preset":
        args += ["--preset", "1"]
    result = CliRunner().invoke(command, [*args, option, value])
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception)
    if result.exit_code == 0 and written is None:
        assert "--help" in result.output
    else:
        assert result.exit_code in (0, 1, 2), (result.exit_code, result.output)
    if written is None:
        assert list(folder.iterdir()) == []
    elif (folder / written).exists():
        assert result.exit_code == 0
        assert read_g2o(folder / written)[1].size() == 12  # what it writes, it reads


JSON_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
    st.lists(st.integers(), max_size=2),
    st.dictionaries(st.text(max_size=3), st.floats(), max_size=2),
)
TOP_FIELDS = ["format", "hidden", "test_cycles", "preset", "seed", "episodes", "train_seconds",
              "validation_best_oc_ratio", "selected_episode", "package_version",
              "torch_version", "command", "sac", "env", "cycles", "n", "note"]
ENV_FIELDS = ["n", "sigma_r", "sigma_t", "d", "lc", "cycles", "action_range_rad",
              "noisy_measurements", "other"]


@settings(SETTINGS, max_examples=200)
@given(top=st.dictionaries(st.sampled_from(TOP_FIELDS), JSON_VALUES, max_size=3),
       env=st.dictionaries(st.sampled_from(ENV_FIELDS), JSON_VALUES, max_size=3))
@example(top={"env": 3}, env={})
def test_model_config_fields(tmp_path_factory, top, env):
    def edit(config):
        config["env"] = {**config["env"], **env}
        config.update(top)

    broken = model_with_config(tmp_path_factory.mktemp("model"), edit,
                               {"test_cycles": 14, "seed": 0})
    try:
        model = load_model(broken)
    except ModelError as error:
        assert "\n" not in str(error) and str(error).startswith(f"{broken}: ")
    else:
        cycles = model.metadata.get("test_cycles", 1)
        assert type(cycles) is int and 1 <= cycles <= 10_000
        assert model.env_config.cycles >= 1
