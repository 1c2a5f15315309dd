"""Shared fixtures: the shared benchmark folder and small generated graphs."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rlpgo_gtsam.synthetic import SyntheticGraph, generate

DATASETS = Path(
    os.environ.get("RLPGO_DATASETS", Path(__file__).resolve().parents[2] / "shared" / "datasets")
)


def dataset(name: str) -> Path:
    """Path of a shared benchmark file; the test is skipped where ../shared is absent."""
    path = DATASETS / name
    if not path.exists():
        pytest.skip(f"{path} not found (set RLPGO_DATASETS)")
    return path


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

    from rlpgo_gtsam.agent.checkpoint import save_model
    from rlpgo_gtsam.agent.networks import Actor
    from rlpgo_gtsam.episode import PRESETS

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
