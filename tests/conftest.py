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
