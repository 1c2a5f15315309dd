"""rlpgo_gtsam: better initial guesses for planar pose-graph optimization in GTSAM."""

import gymnasium

from rlpgo_gtsam.env import ENV_ID, PRESETS, EnvConfig, PoseGraphEnv
from rlpgo_gtsam.errors import (
    G2oFormatError,
    GraphError,
    ModelError,
    OutputError,
    RlpgoError,
    SolverError,
)
from rlpgo_gtsam.g2o import read_g2o, write_g2o
from rlpgo_gtsam.graph import PoseGraph2D, chi2
from rlpgo_gtsam.initializers import (
    ChordalInitializer,
    LagoInitializer,
    OdometryInitializer,
    ShonanInitializer,
    initializer_names,
    make_initializer,
    register,
)
from rlpgo_gtsam.rl_initializer import RLInitializer
from rlpgo_gtsam.solvers import RefineResult, refine
from rlpgo_gtsam.synthetic import SyntheticGraph, generate
from rlpgo_gtsam.translations import solve_translations

__version__ = "0.1.0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="rlpgo_gtsam.env:PoseGraphEnv")

__all__ = [
    "ENV_ID",
    "PRESETS",
    "ChordalInitializer",
    "EnvConfig",
    "PoseGraphEnv",
    "RLInitializer",
    "SyntheticGraph",
    "generate",
    "G2oFormatError",
    "GraphError",
    "LagoInitializer",
    "ModelError",
    "OdometryInitializer",
    "OutputError",
    "PoseGraph2D",
    "RefineResult",
    "RlpgoError",
    "ShonanInitializer",
    "SolverError",
    "chi2",
    "initializer_names",
    "make_initializer",
    "read_g2o",
    "refine",
    "register",
    "solve_translations",
    "write_g2o",
]
