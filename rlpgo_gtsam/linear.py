"""Sparse linear least squares over pairs of planar vectors, solved by GTSAM.

Both linear steps of the initializers have the same shape: one unknown 2-vector per pose
(a position, or a complex number for the chordal rotation relaxation), one whitened 2-row
residual per edge ``A_i x_i + A_j x_j - b``, and the anchor (and any FIXed pose) held at a
known value.
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
    held: np.ndarray,
    held_values: np.ndarray,
) -> np.ndarray:
    """Minimize sum_e ||A_i x_i + A_j x_j - b_e||^2 with some x held; returns (n, 2).

    Args:
        num_poses: number n of unknown 2-vectors, indexed 0..n-1.
        edges: (m, 2) indices (i, j).
        a_i, a_j: (m, 2, 2) whitened blocks of each residual.
        b: (m, 2) whitened right-hand sides.
        held: (k,) indices of the vectors held fixed (k >= 1: the anchor fixes the gauge);
            their terms move to the right-hand side.
        held_values: (k, 2) the values they are held at.

    Raises:
        SolverError: GTSAM finds the system indeterminate (a pose no edge constrains).
    """
    value_of = {int(k): np.asarray(v, dtype=float) for k, v in zip(held, held_values, strict=True)}
    graph = gtsam.GaussianFactorGraph()
    unit = gtsam.noiseModel.Unit.Create(2)
    for (i, j), block_i, block_j, rhs in zip(edges.tolist(), a_i, a_j, b, strict=True):
        if i in value_of and j in value_of:
            continue
        if i in value_of:
            graph.add(gtsam.JacobianFactor(j, block_j, rhs - block_i @ value_of[i], unit))
        elif j in value_of:
            graph.add(gtsam.JacobianFactor(i, block_i, rhs - block_j @ value_of[j], unit))
        else:
            graph.add(gtsam.JacobianFactor(i, block_i, j, block_j, rhs, unit))
    try:
        solution = graph.optimize()
    except RuntimeError as error:
        raise SolverError(f"linear solve failed: {one_line(error)}") from None
    result = np.empty((num_poses, 2))
    for k in range(num_poses):
        if k in value_of:
            result[k] = value_of[k]
        elif not solution.exists(k):
            raise SolverError(f"linear solve left pose index {k} undetermined")
        else:
            result[k] = solution.at(k)
    return result
