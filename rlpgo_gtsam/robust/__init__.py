"""Wrong loop closures: find them, say which they were, and hand over the right start.

:func:`robust_initialize` (:mod:`rlpgo_gtsam.robust.pipeline`) runs the steps: cycle
consistency (:mod:`~rlpgo_gtsam.robust.consistency`), the certified start with GNC-TLS on
the translation step (:mod:`~rlpgo_gtsam.robust.gnc`), verification and GTSAM's GNC-LM, on
planar and 3D graphs alike (:mod:`~rlpgo_gtsam.robust.groups`: SE(2) or SE(3)).
"""

from rlpgo_gtsam.robust.pipeline import (
    DEFAULT_FALSE_REJECTION_RATE,
    DEFAULT_INLIER_PROBABILITY,
    DOUBTFUL_BELOW,
    REJECTED_BELOW,
    RobustResult,
    robust_initialize,
)

__all__ = ["DEFAULT_FALSE_REJECTION_RATE", "DEFAULT_INLIER_PROBABILITY", "DOUBTFUL_BELOW",
           "REJECTED_BELOW", "RobustResult", "robust_initialize"]
