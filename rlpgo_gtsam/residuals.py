"""The default's test for wrong loop closures: are a refined result's residuals Gaussian?

After a failed certificate, :func:`outlier_suspicion` compares each edge's chi2 with what
Gaussian noise gives; a heavier tail points to wrong loop closures, and the staged default
then hints at the robust path (:mod:`rlpgo_gtsam.robust`). It costs one pass over the edges
and imports nothing of the robust pipeline.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from rlpgo_gtsam.groups import key_text

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph

__all__ = ["outlier_suspicion", "variance_factor"]

# the chance that Gaussian noise lifts an edge's chi2 above its group's suspicion_chi2
_SUSPICION_P = 0.001


def outlier_suspicion(pose_graph: PoseGraph, values: gtsam.Values) -> str | None:
    """A one-line hint when ``values`` (a refined result) fits the edges with a heavier tail
    than Gaussian noise allows; None when the residuals look Gaussian.

    Each edge's chi2 (the group's dof: 3 planar, 6 in 3D) is compared with the group's
    ``suspicion_chi2``, which Gaussian noise exceeds with probability 0.001. The
    hint fires when more edges exceed it than a Gaussian model makes plausible (its expected
    count plus four standard deviations, and at least three edges).
    """
    g = pose_graph
    residuals = g.group.edge_chi2(g, g.poses_of(values))
    bound = g.group.suspicion_chi2
    high = residuals > bound
    count, expected = int(high.sum()), _SUSPICION_P * g.num_edges
    if count < 3 or count <= expected + 4.0 * math.sqrt(expected):
        return None
    worst = np.argsort(-residuals, kind="stable")[:3]
    shown = ", ".join(f"{key_text(g.keys[a])}-{key_text(g.keys[b])}"
                      for a, b in g.edges[worst].tolist())
    return (f"{count} of {g.num_edges} edges fit with chi2 > {bound:g} (Gaussian noise "
            f"gives about {expected:.0f}; worst: edges {shown}): wrong loop closures are likely; "
            "try --robust")


def variance_factor(pose_graph: PoseGraph, chi2_value: float | None,
                    edges: int | None = None) -> float | None:
    """``chi2_value`` over its degrees of freedom, ``dof (edges - poses + held)`` (dof 3
    planar, 6 in 3D; ``edges``: the edges it was taken on, all of the graph's by default;
    held: the anchor and the FIXed poses): about 1 where the covariances state the noise,
    above 1 where they understate it (docs/robust.md); None without a chi2 or without a
    redundant measurement."""
    dof = pose_graph.group.dof
    edges = pose_graph.num_edges if edges is None else edges
    redundancy = dof * (edges - pose_graph.num_poses + len(pose_graph.held[0]))
    return None if chi2_value is None or redundancy <= 0 else chi2_value / redundancy
