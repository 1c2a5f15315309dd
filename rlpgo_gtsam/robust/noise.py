"""The noise the robust steps judge with: the graph's covariances as stated, scaled, or read
by their printed blocks, and the noise level the odometry chain shows.

Every test of the robust path is a chi-square bound on the noise the covariances state. Where
they understate it, ``covariance_scale`` judges with each covariance times a factor
(:func:`graph_with_scaled_covariances`); a 3D edge whose GTSAM model is the partial Cholesky
factor of an indefinite printed matrix is judged by its printed blocks
(:func:`graph_with_printed_blocks`); the all-edges check reads the odometry's own noise level
(:func:`noise_scale`).
"""

from __future__ import annotations

import gtsam
import numpy as np

from rlpgo_gtsam.graph import PoseGraph, extract_pose_graph
from rlpgo_gtsam.groups import group_of
from rlpgo_gtsam.information import scaled_informations, with_informations
from rlpgo_gtsam.robust.problem import edge_factor_indices
from rlpgo_gtsam.robust.settings import RobustSettings
from rlpgo_gtsam.robust.statistics import chi2_quantile

__all__ = ["graph_with_printed_blocks", "graph_with_scaled_covariances", "noise_scale"]


def graph_with_printed_blocks(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                              g: PoseGraph) -> tuple[gtsam.NonlinearFactorGraph, PoseGraph]:
    """The graph the steps judge and its extraction: ``graph`` itself, except where a 3D
    edge's model is GTSAM's partial Cholesky factor of an indefinite printed matrix
    (``PoseGraph3D.printed``; cubicle: translation z weighed up to 3.9e12 where the file says
    10). Such an edge is judged by its printed rotation and translation blocks, the coupling
    left out, as SE-Sync reads it: under GTSAM's model every residual in z looks like
    evidence (cubicle: 226 of 7219 closures rejected, against 4 judged so). Same factors,
    same order."""
    printed = getattr(g, "printed", None)
    if not printed:
        return graph, g
    edge_factors = edge_factor_indices(graph, g.num_edges, group_of(g).between_factor)
    blocks = {}
    for e, f in enumerate(edge_factors.tolist()):
        matrix = printed.get(g.information[e].tobytes())
        if matrix is not None:  # its rotation and translation blocks, the coupling left out
            block = np.zeros((6, 6))
            block[:3, :3], block[3:, 3:] = matrix[:3, :3], matrix[3:, 3:]
            blocks[int(f)] = block
    judged = with_informations(graph, blocks)
    return judged, extract_pose_graph(judged, values)


def graph_with_scaled_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                                  scale: float) -> tuple[gtsam.NonlinearFactorGraph, PoseGraph]:
    """``graph`` with each between factor's covariance times ``scale`` (its information over
    it; the same factors, measurements and order, priors as they are), and its extraction."""
    judged = scaled_informations(graph, 1.0 / scale)
    return judged, extract_pose_graph(judged, values)


def noise_scale(errors: np.ndarray, information: np.ndarray,
                max_scale: float = RobustSettings.max_noise_scale) -> np.ndarray:
    """(dof,) per tangent component, how much noisier than its information says the
    ``errors`` (k, dof) are, at least 1: ``median(e_c^2 Lambda_cc)`` over the median of
    chi-square with 1 dof (1 for Gaussian errors at their stated noise, below 1 at an
    optimum, where the residuals are smaller than the noise). The median is left alone by a
    minority of bent edges. Above ``max_scale`` in any component the errors are not taken
    for noise (a map that closures squeeze: two contradicting groups put a whole chain 130
    sigma off) and every scale is 1."""
    whitened = errors ** 2 * np.diagonal(information, axis1=1, axis2=2)
    if len(whitened) == 0:
        return np.ones(errors.shape[1])
    scale = np.maximum(np.median(whitened, axis=0) / chi2_quantile(0.5, 1), 1.0)
    return scale if scale.max() <= max_scale else np.ones_like(scale)
