"""Wrong loop closures: find them, say which they were, and hand over the right start.

:func:`robust_initialize` (:mod:`rlpgo_gtsam.robust.pipeline`) runs the steps: the clean
default on every edge, pairwise consistency (:mod:`~rlpgo_gtsam.robust.consistency`), the
certified start with GNC-TLS on the translation step (:mod:`~rlpgo_gtsam.robust.gnc`),
verification (:mod:`~rlpgo_gtsam.robust.verify`) and GTSAM's GNC-LM, on planar and 3D graphs
alike (:mod:`~rlpgo_gtsam.groups`: SE(2) or SE(3)). :class:`RobustSettings` holds every tuning
constant; :class:`RobustResult` says what was rejected and what each step did.

The pipeline loads on first use: the settings and the noise helpers
(:mod:`~rlpgo_gtsam.robust.noise`) import without it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from rlpgo_gtsam.robust.settings import RobustSettings

if TYPE_CHECKING:
    from rlpgo_gtsam.robust.pipeline import robust_initialize
    from rlpgo_gtsam.robust.results import RobustResult

_WHERE = {"robust_initialize": "rlpgo_gtsam.robust.pipeline",
          "RobustResult": "rlpgo_gtsam.robust.results"}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(_WHERE[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rlpgo_gtsam.robust' has no attribute '{name}'")


__all__ = ["RobustResult", "RobustSettings", "robust_initialize"]
