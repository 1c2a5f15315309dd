"""Shared fixtures and helpers: the shared benchmark folder, small generated graphs, checks of
command runs."""

from __future__ import annotations

import os
from pathlib import Path

import gtsam
import numpy as np
import pytest
from click.testing import Result

from rlpgo_gtsam.io import read_g2o
from rlpgo_gtsam.synthetic import SyntheticGraph, generate

DATASETS = Path(
    os.environ.get("RLPGO_DATASETS", Path(__file__).resolve().parents[2] / "shared" / "datasets")
)


def with_factors(graph: gtsam.NonlinearFactorGraph, *factors) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with ``factors`` appended (``graph`` itself unchanged)."""
    grown = gtsam.NonlinearFactorGraph(graph)
    for factor in factors:
        grown.add(factor)
    return grown


def lm_values(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              iters: int = 100) -> gtsam.Values:
    """GTSAM's LM from ``values``, capped at ``iters`` iterations: the plain anchor."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iters)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def chi2_of(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """g2o chi2: 2 x GTSAM's error."""
    return 2.0 * graph.error(values)


def dataset(name: str) -> Path:
    """Path of a shared benchmark file; the test is skipped where ../shared is absent."""
    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    return path


@pytest.fixture
def hessian_products(monkeypatch) -> list[int]:
    """A one-element counter of the Hessian products the staircase's truncated CG takes,
    counted from here on (reset it by assigning ``[0]``)."""
    import rlpgo_gtsam.relaxation.trust_region as trust_region

    products = [0]
    truncated_cg = trust_region.truncated_cg

    def counted(grad, hess, pre, radius, *args):
        def product(v):
            products[0] += 1
            return hess(v)
        return truncated_cg(grad, product, pre, radius, *args)

    monkeypatch.setattr(trust_region, "truncated_cg", counted)
    return products


@pytest.fixture
def small_exact() -> SyntheticGraph:
    """n = 60 lawn mower, exact measurements, noisy initial guess."""
    return generate(60, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(7))


@pytest.fixture
def small_noisy() -> SyntheticGraph:
    """n = 60 lawn mower with noisy measurements."""
    return generate(60, 0.2, 0.05, 3.0, 0.5, np.random.default_rng(8), noisy_measurements=True)


def model_with_config(folder: Path, edit, metadata: dict | None = None) -> Path:
    """A real 8-unit model saved in ``folder``, rewritten with ``edit(config)`` applied to its
    config.json (the weights kept): the fuzz tests' way to make odd model files."""
    import json
    import zipfile

    from rlpgo_gtsam.rl.agent.checkpoint import save_model
    from rlpgo_gtsam.rl.agent.networks import Actor
    from rlpgo_gtsam.rl.episode import PRESETS

    path = folder / "m.zip"
    save_model(path, Actor(8), PRESETS[1], metadata or {})
    with zipfile.ZipFile(path) as zf:
        config = json.loads(zf.read("config.json"))
        weights = zf.read("actor.pt")
    edit(config)
    broken = folder / "broken.zip"
    with zipfile.ZipFile(broken, "w") as zf:
        zf.writestr("config.json", json.dumps(config))
        zf.writestr("actor.pt", weights)
    return broken


def cli_ok(result: Result) -> None:
    """A command run that succeeded: exit code 0, no exception, nothing on stderr."""
    assert result.exception is None, repr(result.exception)
    assert result.exit_code == 0, result.output
    assert result.stderr == ""


def cli_error(result: Result, message: str | None = None, code: int = 1) -> str:
    """A command run that failed cleanly: exit ``code``, no traceback, and for a run error
    (1) exactly one line ``Error: <message>`` on stderr and nothing on stdout; for a usage
    error (2) click's usage lines and ``message`` somewhere on stderr. Returns the message
    of a run error."""
    # CliRunner swallows an uncaught exception: it would be a traceback in a real run.
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(
        result.exception)
    assert "Traceback" not in result.output
    assert result.exit_code == code, (result.exit_code, result.output)
    if code == 2:
        assert message is None or message in result.stderr, result.stderr
        return ""
    assert result.stdout == ""
    assert result.stderr.startswith("Error: ") and result.stderr.count("\n") == 1, result.stderr
    if message is not None:
        assert result.stderr == f"Error: {message}\n"
    return result.stderr[len("Error: "):-1]


def factor_rows(graph: gtsam.NonlinearFactorGraph) -> list:
    """Each factor as ``(kind, keys, measured (x, y, theta) or None, information or None)``,
    kind "between" or "prior": what a g2o file says about the graph."""
    rows = []
    for index in range(graph.size()):
        factor = graph.at(index)
        if isinstance(factor, gtsam.BetweenFactorPose2):
            z = factor.measured()
            rows.append(("between", tuple(factor.keys()), (z.x(), z.y(), z.theta()),
                         factor.noiseModel().information()))
        else:
            assert isinstance(factor, gtsam.PriorFactorPose2), type(factor)
            rows.append(("prior", tuple(factor.keys()), None, None))
    return rows


def assert_same_factors(graph: gtsam.NonlinearFactorGraph, graph2: gtsam.NonlinearFactorGraph,
                        kinds: tuple[str, ...] = ("between", "prior")) -> None:
    """The same factors of ``kinds`` in the same order: keys and measurements exact,
    information to 1e-12 relative."""
    rows = [row for row in factor_rows(graph) if row[0] in kinds]
    rows2 = [row for row in factor_rows(graph2) if row[0] in kinds]
    assert [row[:3] for row in rows2] == [row[:3] for row in rows]
    for row, row2 in zip(rows, rows2, strict=True):
        if row[3] is not None:
            np.testing.assert_allclose(row2[3], row[3], rtol=1e-12, atol=0)


def assert_same_edges(source: Path, output: Path) -> None:
    """``output`` holds the very edges of ``source``: the same EDGE_SE2 lines, in order."""
    edges = [line for line in source.read_text().splitlines() if line.startswith("EDGE_SE2")]
    written = [line for line in output.read_text().splitlines() if line.startswith("EDGE_SE2")]
    assert written == edges  # same count and the very same text
    assert_same_factors(read_g2o(source)[0], read_g2o(output)[0], kinds=("between",))
