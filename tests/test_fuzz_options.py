"""Fuzzing the commands' option values and the model config: never a traceback."""


import numpy as np
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rlpgo_cli.generate import main as generate_main
from rlpgo_cli.init import main as init_main

from rlpgo_gtsam import ModelError, generate, read_g2o, write_g2o
from rlpgo_gtsam.rl.agent.checkpoint import load_model
from tests.conftest import model_with_config

NUMBERS = st.one_of(
    st.integers(-2**70, 2**70).map(str), st.floats(allow_nan=True, allow_infinity=True).map(str),
    st.sampled_from(["nan", "-inf", "1e308", "-0", "0x10", "", " ", "1_0", "abc", "٣"]),
)
SETTINGS = settings(max_examples=120, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])


def _no_traceback(result) -> None:
    assert result.exit_code in (0, 1, 2), (result.exit_code, result.output)
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception)


@SETTINGS
@given(option=st.sampled_from(["--iters", "--seed", "--budget", "--episodes", "--cycles"]),
       value=NUMBERS)
def test_rlpgo_init_options(tmp_path_factory, option, value):
    folder = tmp_path_factory.mktemp("init")
    sample = generate(12, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(0))
    write_g2o(folder / "in.g2o", sample.graph, sample.initial)
    result = CliRunner().invoke(init_main, [str(folder / "in.g2o"), "-o", str(folder / "o.g2o"),
                                            "--method", "chordal", option, value])
    _no_traceback(result)
    if result.exit_code == 0:
        assert read_g2o(folder / "o.g2o")[1].size() == 12


@SETTINGS
@given(option=st.sampled_from(["--sigma-r", "--sigma-t", "--d", "--lc", "--seed"]),
       value=NUMBERS)
def test_rlpgo_generate_options(tmp_path_factory, option, value):
    folder = tmp_path_factory.mktemp("generate")
    result = CliRunner().invoke(generate_main, ["--n", "12", "-o", str(folder / "g.g2o"),
                                                option, value])
    _no_traceback(result)
    if result.exit_code == 0:
        assert read_g2o(folder / "g.g2o")[1].size() == 12  # what it writes, it reads


JSON_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12),
                        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
                        st.lists(st.integers(), max_size=2))


@settings(max_examples=120, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(env=st.dictionaries(st.sampled_from(["n", "sigma_r", "sigma_t", "d", "lc", "cycles",
                                            "action_range_rad", "noisy_measurements",
                                            "observation", "reward", "oc_shaping", "keep",
                                            "sigma_r_max", "start", "other"]),
                           JSON_VALUES | st.sampled_from(["rich", "chi2", "paper", "oc"]),
                           max_size=3),
       extra=st.dictionaries(st.sampled_from(["test_cycles", "hidden", "format"]), JSON_VALUES,
                             max_size=2))
def test_model_configs(tmp_path_factory, env, extra):
    def edit(config):
        config["env"] = {**config["env"], **env}
        config.update(extra)

    broken = model_with_config(tmp_path_factory.mktemp("model"), edit)
    try:
        model = load_model(broken)
    except ModelError as error:
        assert "\n" not in str(error)
    else:
        assert model.env_config.cycles >= 1
