"""Sparse linear least squares over pairs of planar vectors, solved by GTSAM.

Both linear steps of the initializers have the same shape: one unknown 2-vector per pose
(a position, or a complex number for the chordal rotation relaxation), one whitened 2-row
residual per edge ``A_i x_i + A_j x_j - b``, and the anchor pose held at a known value.
"""

from __future__ import annotations

import gtsam
import numpy as np

from rlpgo_gtsam.errors import SolverError, one_line

__all__ = ["solve_pairwise"]


def solve_pairwise(
    num_poses: int,
    edges: np.ndarray,
    a_i: np.ndarray,
    a_j: np.ndarray,
    b: np.ndarray,
    anchor: int,
    anchor_value: np.ndarray,
) -> np.ndarray:
    """Minimize sum_e ||A_i x_i + A_j x_j - b_e||^2 with x_anchor fixed; returns (n, 2).

    Args:
        num_poses: number n of unknown 2-vectors, indexed 0..n-1.
        edges: (m, 2) indices (i, j).
        a_i, a_j: (m, 2, 2) whitened blocks of each residual.
        b: (m, 2) whitened right-hand sides.
        anchor: index of the vector held fixed; its terms move to the right-hand side.
        anchor_value: (2,) the value it is held at.

    Raises:
        SolverError: GTSAM finds the system indeterminate (a pose no edge constrains).
    """
    graph = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create(2)
    for (i, j), block_i, block_j, rhs in zip(edges, a_i, a_j, b, strict=True):
        if i == anchor:
            graph.add(gtsam.JacobianFactor(int(j), block_j, rhs - block_i @ anchor_value, unit))
        elif j == anchor:
            graph.add(gtsam.JacobianFactor(int(i), block_i, rhs - block_j @ anchor_value, unit))
        else:
            graph.add(gtsam.JacobianFactor(int(i), block_i, int(j), block_j, rhs, unit))
    try:
        solution = graph.optimize()
    except RuntimeError as error:
        raise SolverError(f"linear solve failed: {one_line(error)}") from None
    result = np.empty((num_poses, 2))
    result[anchor] = anchor_value
    for k in range(num_poses):
        if k != anchor:
            if not solution.exists(k):
                raise SolverError(f"linear solve left pose index {k} undetermined")
            result[k] = solution.at(k)
    return result
