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

__all__ = ["solve_pairwise", "solve_pairwise_weighted"]

_WEIGHT_FLOOR = 1e-12  # weights at or below this leave an edge out of a weighted solve


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


def solve_pairwise_weighted(num_poses: int, edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                    b: np.ndarray, weights: np.ndarray, held: np.ndarray,
                    held_values: np.ndarray) -> np.ndarray:
    """Minimize sum_e w_e ||A_i x_i + A_j x_j - b_e||^2 with some x held; returns (n, 2).

    :func:`solve_pairwise` with per-edge weights, through one sparse
    factorization of the normal equations (scipy): GNC solves the same pattern many times,
    and building GTSAM factors edge by edge would dominate.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    # edges of weight 0 are left out: even at a tiny weight a wrong closure joins two
    # random poses, and such joins ruin the factorization's fill (City10K: 0.1 s -> 20 s)
    used = weights > _WEIGHT_FLOOR
    w = weights[used][:, None, None]
    edges, a_i, a_j, b = edges[used], a_i[used], a_j[used], b[used]
    i, j = edges[:, 0], edges[:, 1]
    a_i_t = np.transpose(a_i, (0, 2, 1))
    a_j_t = np.transpose(a_j, (0, 2, 1))
    blocks = [(i, i, w * a_i_t @ a_i), (j, j, w * a_j_t @ a_j), (i, j, w * a_i_t @ a_j),
              (j, i, w * a_j_t @ a_i)]
    rows = np.concatenate([(2 * p[:, None] + [0, 0, 1, 1]).ravel() for p, _, _ in blocks])
    cols = np.concatenate([(2 * q[:, None] + [0, 1, 0, 1]).ravel() for _, q, _ in blocks])
    data = np.concatenate([block.reshape(-1) for _, _, block in blocks])
    size = 2 * num_poses
    normal = sp.csr_matrix((data, (rows, cols)), shape=(size, size))
    gradient = np.zeros(size)
    np.add.at(gradient, 2 * i[:, None] + [0, 1], w[..., 0] * np.einsum("eba,eb->ea", a_i, b))
    np.add.at(gradient, 2 * j[:, None] + [0, 1], w[..., 0] * np.einsum("eba,eb->ea", a_j, b))
    x = np.zeros(size)
    held_index = (2 * np.asarray(held)[:, None] + [0, 1]).ravel()
    x[held_index] = np.asarray(held_values, dtype=float).ravel()
    free = np.ones(size, bool)
    free[held_index] = False
    rhs = gradient[free] - normal[free][:, ~free] @ x[~free]
    try:
        # symmetric mode without pivoting: the normal matrix is positive definite
        factor = splu(normal[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A",
                      diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        x[free] = factor.solve(rhs)
    except RuntimeError as error:
        raise SolverError(f"weighted linear solve failed ({one_line(error)}): the edges kept "
                          "leave part of the graph unconstrained") from None
    if not np.all(np.isfinite(x)):
        raise SolverError("weighted linear solve gave non-finite values")
    return x.reshape(num_poses, 2)
