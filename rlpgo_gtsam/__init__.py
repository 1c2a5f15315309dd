"""rlpgo_gtsam: better initial guesses for planar pose-graph optimization in GTSAM.

Reading graphs and the classical initializers load GTSAM and numpy only; the agent's names
(``RLInitializer``, ``PoseGraphEnv``, ...) load torch or gymnasium on first use. The
environment id ``rlpgo/PoseGraph-v0`` registers when :mod:`rlpgo_gtsam.env` is imported
(``gymnasium.make("rlpgo_gtsam.env:rlpgo/PoseGraph-v0")`` does that itself).
"""

from __future__ import annotations

import importlib
from typing import Any

from rlpgo_gtsam.episode import PRESETS, EnvConfig
from rlpgo_gtsam.errors import (
    G2oFormatError,
    GraphError,
    ModelError,
    OutputError,
    RlpgoError,
    SolverError,
)
from rlpgo_gtsam.g2o import read_g2o, read_g2o_lines, write_g2o
from rlpgo_gtsam.graph import PoseGraph2D, chi2, rotation_weights
from rlpgo_gtsam.initializers import (
    ChordalInitializer,
    Initializer,
    InitResult,
    LagoInitializer,
    OdometryInitializer,
    OrientationInitializer,
    ShonanInitializer,
    initializer_names,
    make_initializer,
    register,
)
from rlpgo_gtsam.robust import RobustResult, robust_initialize
from rlpgo_gtsam.solvers import RefineResult, refine
from rlpgo_gtsam.synthetic import SyntheticGraph, add_outliers, generate
from rlpgo_gtsam.translations import poses_with_orientations, solve_translations

__version__ = "0.1.0"

# Names whose modules import torch or gymnasium: loaded when first used.
_LAZY = {
    "RLInitializer": "rlpgo_gtsam.rl_initializer",
    "PoseGraphEnv": "rlpgo_gtsam.env",
    "ENV_ID": "rlpgo_gtsam.env",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rlpgo_gtsam' has no attribute '{name}'")


__all__ = [
    "ENV_ID",
    "PRESETS",
    "ChordalInitializer",
    "EnvConfig",
    "G2oFormatError",
    "GraphError",
    "InitResult",
    "Initializer",
    "LagoInitializer",
    "ModelError",
    "OdometryInitializer",
    "OrientationInitializer",
    "OutputError",
    "PoseGraph2D",
    "PoseGraphEnv",
    "RLInitializer",
    "RefineResult",
    "RobustResult",
    "RlpgoError",
    "ShonanInitializer",
    "SolverError",
    "SyntheticGraph",
    "add_outliers",
    "chi2",
    "generate",
    "initializer_names",
    "make_initializer",
    "poses_with_orientations",
    "read_g2o",
    "read_g2o_lines",
    "refine",
    "register",
    "robust_initialize",
    "rotation_weights",
    "solve_translations",
    "write_g2o",
]
