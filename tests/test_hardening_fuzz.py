"""Fuzzing the options of rlpgo-compare, rlpgo-eval and rlpgo-train, and every top-level
model-config field: a usage error or a one-line error, never a traceback.

(test_fuzz_options.py covers rlpgo-init, rlpgo-generate and the env fields.) Each command is
given an output in a folder that does not exist, so a value that parses ends in the
output check, before any work: the examples stay fast.
"""

from __future__ import annotations

from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rlpgo_cli.compare import main as compare_main
from rlpgo_cli.evaluate import main as eval_main
from rlpgo_cli.train import main as train_main

from rlpgo_gtsam import ModelError
from rlpgo_gtsam.rl.agent.checkpoint import load_model
from tests.conftest import model_with_config

VALUES = st.one_of(
    st.integers(-2**70, 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e308", "-0", "0x10", "", " ", "1_0", "abc", "٣",
                     "2147483648", "4294967296", "9" * 400, "--help", "a\nb"]),
)
SETTINGS = settings(max_examples=100, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


def _no_traceback(result) -> None:
    assert result.exit_code in (1, 2) or (result.exit_code == 0 and "--help" in
                                          result.output), (result.exit_code, result.output)
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception)


@SETTINGS
@given(option=st.sampled_from(["--iters", "--seed", "--episodes", "--cycles", "--solver",
                               "--methods", "--start"]), value=VALUES)
def test_rlpgo_compare_options(tmp_path_factory, option, value):
    folder = tmp_path_factory.mktemp("compare")
    result = CliRunner().invoke(compare_main, [option, value, "--json",
                                               str(folder / "absent" / "x.json")])
    _no_traceback(result)
    assert list(folder.iterdir()) == []


@SETTINGS
@given(option=st.sampled_from(["--preset", "--graphs", "--seed"]), value=VALUES)
def test_rlpgo_eval_options(tmp_path_factory, option, value):
    folder = tmp_path_factory.mktemp("eval")
    args = [option, value] if option == "--preset" else ["--preset", "1", option, value]
    result = CliRunner().invoke(eval_main, [*args, "--json", str(folder / "absent" / "x.json")])
    _no_traceback(result)
    assert list(folder.iterdir()) == []


@SETTINGS
@given(option=st.sampled_from(["--preset", "--episodes", "--seed", "--hidden", "--batch-size",
                               "--gradient-steps", "--validation-graphs", "--env",
                               "--pool-graphs", "--reward-scale", "--validation",
                               "--initial-last-action"]),
       value=VALUES | st.sampled_from(["n=nan", "n=0", "sigma_r=1e308", "sigma_r=9",
                                       "observation=rich", "reward=x", "keep=", "=1",
                                       "noisy_measurements=2", "cycles=99999999999"]))
def test_rlpgo_train_options(tmp_path_factory, option, value):
    folder = tmp_path_factory.mktemp("train")
    stem = folder / "absent" / ("m" * 250)  # every output name is too long: refused before work
    args = [option, value] if option == "--preset" else ["--preset", "1", option, value]
    result = CliRunner().invoke(train_main, [*args, "--out", str(stem)])
    _no_traceback(result)
    assert list(folder.iterdir()) == []


JSON_VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
    st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=3), st.floats(),
                                                         max_size=2),
)
TOP_FIELDS = ["format", "hidden", "test_cycles", "preset", "seed", "episodes", "train_seconds",
              "validation_best_oc_ratio", "selected_episode", "package_version",
              "torch_version", "command", "sac", "env", "cycles", "n", "note"]


@settings(max_examples=150, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(changes=st.dictionaries(st.sampled_from(TOP_FIELDS), JSON_VALUES, min_size=1,
                               max_size=3))
def test_top_level_model_config_fields(tmp_path_factory, changes):
    broken = model_with_config(tmp_path_factory.mktemp("model"),
                               lambda config: config.update(changes),
                               {"test_cycles": 14, "seed": 0})
    try:
        model = load_model(broken)
    except ModelError as error:
        assert "\n" not in str(error) and str(error).startswith(f"{broken}: ")
    else:
        cycles = model.metadata.get("test_cycles", 1)
        assert type(cycles) is int and 1 <= cycles <= 10_000
