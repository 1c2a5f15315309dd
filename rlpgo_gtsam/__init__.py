"""rlpgo_gtsam: better initial guesses for pose-graph optimization in GTSAM.

The default is :func:`staged_initialize`: certify with the SE(d) synchronization relaxation
(planar or 3D graphs), then refine. Every call takes ``Pose2`` and ``Pose3`` graphs alike:
:func:`extract_pose_graph` makes a :data:`PoseGraph` whose ``group`` (:data:`SE2`,
:data:`SE3`, :mod:`rlpgo_gtsam.groups`) says what differs, and
``make_initializer(name).initialize(graph, values)`` works on both for every method that
has both (:func:`initializer_names` with a group lists them). Every name loads its module
on first use: reading
graphs, the classical initializers, the default and the robust path load GTSAM, numpy and
scipy only; the agent's names (``RLInitializer``, ``PoseGraphEnv``, ``EnvConfig``,
``PRESETS``) load torch or gymnasium from :mod:`rlpgo_gtsam.rl` where they need them. The
environment id ``rlpgo/PoseGraph-v0`` registers when :mod:`rlpgo_gtsam.rl.env` is imported
(``gymnasium.make("rlpgo_gtsam.rl.env:rlpgo/PoseGraph-v0")`` does that itself).
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# Every public name and the module that defines it, imported on first use: `import
# rlpgo_gtsam.errors` (what a command's --help needs) loads nothing else, and the agent's
# names load torch or gymnasium only when used.
_WHERE = {
    "TrajectoryErrors": "rlpgo_gtsam.accuracy",
    "trajectory_errors": "rlpgo_gtsam.accuracy",
    "Certificate": "rlpgo_gtsam.relaxation.certificate",
    "Status": "rlpgo_gtsam.relaxation.certificate",
    "G2oFormatError": "rlpgo_gtsam.errors",
    "GraphError": "rlpgo_gtsam.errors",
    "InformationWarning": "rlpgo_gtsam.errors",
    "InputNotFoundError": "rlpgo_gtsam.errors",
    "ModelError": "rlpgo_gtsam.errors",
    "OutputError": "rlpgo_gtsam.errors",
    "RlpgoError": "rlpgo_gtsam.errors",
    "SolverError": "rlpgo_gtsam.errors",
    "example_file": "rlpgo_gtsam.datasets",
    "example_names": "rlpgo_gtsam.datasets",
    "read_g2o": "rlpgo_gtsam.io",
    "read_g2o_lines": "rlpgo_gtsam.io",
    "write_g2o": "rlpgo_gtsam.io",
    "g2o_text": "rlpgo_gtsam.io",
    "file_group": "rlpgo_gtsam.io",
    "read_pyfg": "rlpgo_gtsam.io.pyfg",
    "write_pyfg": "rlpgo_gtsam.io.pyfg",
    "pyfg_text": "rlpgo_gtsam.io.pyfg",
    "read_plaza": "rlpgo_gtsam.io.plaza",
    "PoseGraph2D": "rlpgo_gtsam.graph",
    "chi2": "rlpgo_gtsam.graph",
    "rotation_weights": "rlpgo_gtsam.graph",
    "Group": "rlpgo_gtsam.groups",
    "SE2": "rlpgo_gtsam.groups",
    "SE3": "rlpgo_gtsam.groups",
    "PoseGraph3D": "rlpgo_gtsam.graph",
    "PoseGraph": "rlpgo_gtsam.graph",
    "extract_pose_graph": "rlpgo_gtsam.graph",
    "CertifiedInitializer": "rlpgo_gtsam.initializers",
    "ChordalInitializer": "rlpgo_gtsam.initializers",
    "FastSyncInitializer": "rlpgo_gtsam.initializers",
    "InitResult": "rlpgo_gtsam.initializers",
    "Initializer": "rlpgo_gtsam.initializers",
    "LagoInitializer": "rlpgo_gtsam.initializers",
    "OdometryInitializer": "rlpgo_gtsam.initializers",
    "RotationInitializer": "rlpgo_gtsam.initializers",
    "InitializePose3": "rlpgo_gtsam.initializers",
    "ShonanInitializer": "rlpgo_gtsam.initializers",
    "initializer_names": "rlpgo_gtsam.initializers",
    "make_initializer": "rlpgo_gtsam.initializers",
    "register": "rlpgo_gtsam.initializers",
    "MethodResult": "rlpgo_gtsam.ranking",
    "best_of": "rlpgo_gtsam.ranking",
    "compare_methods": "rlpgo_gtsam.ranking",
    "ENV_ID": "rlpgo_gtsam.rl.env",
    "PoseGraphEnv": "rlpgo_gtsam.rl.env",
    "EnvConfig": "rlpgo_gtsam.rl.episode",
    "PRESETS": "rlpgo_gtsam.rl.episode",
    "RLInitializer": "rlpgo_gtsam.rl.initializer",
    "RobustResult": "rlpgo_gtsam.robust",
    "RobustSettings": "rlpgo_gtsam.robust",
    "robust_initialize": "rlpgo_gtsam.robust",
    "RefineResult": "rlpgo_gtsam.solvers",
    "refine": "rlpgo_gtsam.solvers",
    "StagedResult": "rlpgo_gtsam.staged",
    "staged_initialize": "rlpgo_gtsam.staged",
    "SyntheticGraph": "rlpgo_gtsam.synthetic",
    "add_outliers": "rlpgo_gtsam.synthetic",
    "generate": "rlpgo_gtsam.synthetic",
    "poses_with_rotations": "rlpgo_gtsam.translations",
    "solve_translations": "rlpgo_gtsam.translations",
}


# Modules reached as attributes (``rlpgo_gtsam.groups.SE3``).
_SUBMODULES = ("datasets", "groups", "initializers")


def __getattr__(name: str) -> Any:
    if name in _SUBMODULES:
        return importlib.import_module(f"rlpgo_gtsam.{name}")
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rlpgo_gtsam' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE) | set(_SUBMODULES))


__all__ = [
    "staged_initialize",
    "StagedResult",
    "robust_initialize",
    "RobustResult",
    "RobustSettings",
    "ENV_ID",
    "PRESETS",
    "Certificate",
    "CertifiedInitializer",
    "ChordalInitializer",
    "EnvConfig",
    "FastSyncInitializer",
    "G2oFormatError",
    "GraphError",
    "InformationWarning",
    "InitResult",
    "InputNotFoundError",
    "Initializer",
    "LagoInitializer",
    "MethodResult",
    "ModelError",
    "OdometryInitializer",
    "RotationInitializer",
    "InitializePose3",
    "OutputError",
    "PoseGraph2D",
    "PoseGraph3D",
    "PoseGraph",
    "Group",
    "SE2",
    "SE3",
    "groups",
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
    "example_file",
    "example_names",
    "extract_pose_graph",
    "generate",
    "initializer_names",
    "make_initializer",
    "poses_with_rotations",
    "file_group",
    "g2o_text",
    "read_g2o",
    "read_g2o_lines",
    "read_pyfg",
    "write_pyfg",
    "pyfg_text",
    "read_plaza",
    "refine",
    "register",
    "rotation_weights",
    "solve_translations",
    "trajectory_errors",
    "write_g2o",
]
