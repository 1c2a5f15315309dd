"""rlpgo_gtsam: better initial guesses for planar pose-graph optimization in GTSAM.

The default is :func:`staged_initialize`: certify with the SE(2) synchronization relaxation,
else search. Reading graphs, the classical initializers, the default and the robust path load
GTSAM, numpy and scipy only; the agent's names (``RLInitializer``, ``PoseGraphEnv``,
``EnvConfig``, ``PRESETS``) load on first use from :mod:`rlpgo_gtsam.rl` (torch or gymnasium
where they need them). The environment id ``rlpgo/PoseGraph-v0`` registers when
:mod:`rlpgo_gtsam.rl.env` is imported (``gymnasium.make("rlpgo_gtsam.rl.env:rlpgo/PoseGraph-v0")``
does that itself).
"""

from __future__ import annotations

import importlib
from typing import Any

from rlpgo_gtsam.accuracy import TrajectoryErrors, trajectory_errors
from rlpgo_gtsam.certified import Certificate, Status
from rlpgo_gtsam.errors import (
    G2oFormatError,
    GraphError,
    InputNotFoundError,
    ModelError,
    OutputError,
    RlpgoError,
    SolverError,
)
from rlpgo_gtsam.g2o import read_g2o, read_g2o_lines, write_g2o
from rlpgo_gtsam.g2o3d import read_g2o3d, write_g2o3d
from rlpgo_gtsam.graph import PoseGraph2D, chi2, rotation_weights
from rlpgo_gtsam.graph3d import PoseGraph3D
from rlpgo_gtsam.initializers import (
    CertifiedInitializer,
    ChordalInitializer,
    FastSyncInitializer,
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
from rlpgo_gtsam.ranking import MethodResult, best_of, compare_methods
from rlpgo_gtsam.robust import RobustResult, robust_initialize
from rlpgo_gtsam.solvers import RefineResult, refine
from rlpgo_gtsam.staged import StagedResult, staged_initialize
from rlpgo_gtsam.synthetic import SyntheticGraph, add_outliers, generate
from rlpgo_gtsam.translations import poses_with_orientations, solve_translations

__version__ = "0.1.0"

# Names whose modules import torch or gymnasium: loaded when first used.
_LAZY = {
    "RLInitializer": "rlpgo_gtsam.rl.initializer",
    "PoseGraphEnv": "rlpgo_gtsam.rl.env",
    "ENV_ID": "rlpgo_gtsam.rl.env",
    "EnvConfig": "rlpgo_gtsam.rl.episode",
    "PRESETS": "rlpgo_gtsam.rl.episode",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rlpgo_gtsam' has no attribute '{name}'")


__all__ = [
    "staged_initialize",
    "StagedResult",
    "robust_initialize",
    "RobustResult",
    "ENV_ID",
    "PRESETS",
    "Certificate",
    "CertifiedInitializer",
    "ChordalInitializer",
    "EnvConfig",
    "FastSyncInitializer",
    "G2oFormatError",
    "GraphError",
    "InitResult",
    "InputNotFoundError",
    "Initializer",
    "LagoInitializer",
    "MethodResult",
    "ModelError",
    "OdometryInitializer",
    "OrientationInitializer",
    "OutputError",
    "PoseGraph2D",
    "PoseGraph3D",
    "PoseGraphEnv",
    "RLInitializer",
    "RefineResult",
    "RlpgoError",
    "ShonanInitializer",
    "SolverError",
    "Status",
    "SyntheticGraph",
    "TrajectoryErrors",
    "add_outliers",
    "best_of",
    "chi2",
    "compare_methods",
    "generate",
    "initializer_names",
    "make_initializer",
    "poses_with_orientations",
    "read_g2o",
    "read_g2o_lines",
    "read_g2o3d",
    "refine",
    "register",
    "rotation_weights",
    "solve_translations",
    "trajectory_errors",
    "write_g2o",
    "write_g2o3d",
]
