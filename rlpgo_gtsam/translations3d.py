"""The 3D translation step: positions that minimize GTSAM's cost for fixed rotations.

With the rotations fixed, an edge's error ``e = Logmap(measured^-1 X_i^-1 X_j)`` has a fixed
rotation part ``e_R`` and a translation part ``e_t = V(e_R)^-1 R~^T (R_i^T (t_j - t_i) - t~)``
that is linear in the positions (GTSAM's Pose3 Logmap), so
``e^T Lambda e = ||W (e_t + Lambda_tt^-1 Lambda_tR e_R)||^2 + const`` (``W^T W = Lambda_tt``)
is minimized exactly by one sparse linear solve: the full information is kept, rotation-
translation correlations included (as the planar step, :mod:`rlpgo_gtsam.translations`).
Where every edge's translational weight is nearly isotropic (SE-Sync's files but cubicle),
the same minimum is reached by conjugate gradients preconditioned with a scalar Laplacian
(one factorization of n unknowns instead of 3n), to a residual of 1e-13.

:class:`~rlpgo_gtsam.linear.PairwiseSystem` is written for 2-vectors; the same system for
d-vectors (and several right-hand sides at once) is :func:`solve_block_pairwise`.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.graph3d import PoseGraph3D, edge_chi2
from rlpgo_gtsam.linear import WEIGHT_FLOOR
from rlpgo_gtsam.se3 import inverse_left_jacobians, log_so3

__all__ = ["PIVOT_FLOOR", "DenseCholesky", "dense_cholesky", "solve_block_pairwise",
           "solve_translations", "poses_with_rotations", "TranslationStep3D"]

PIVOT_FLOOR = 1e-10  # a pivot below this fraction of its diagonal: the system is indeterminate
# Unknowns (d x free poses) below which the normal equations are solved densely (Cholesky):
# scipy's sparse set-up costs more there. The chordal estimate and the translation step of
# generated 3D graphs took 1.8 ms dense / 3.6 ms sparse at 27 unknowns, 3.6 / 4.9 at 117,
# 5.4 / 5.3 at 147, 7.7 / 5.8 at 177. A dense factor that fails or has a pivot below the
# floor hands over to the sparse LU, whose pivots name the undetermined pose.
_DENSE_BELOW = 150
# The translation step by CG (_solve_isotropic) where every edge's 3x3 weight is within this
# (Frobenius norm, relative to the smallest w_e) of a multiple of I, until the normal
# equations' residual is this fraction of the right-hand side's, in at most this many
# iterations; else (cubicle's informations: condition numbers up to 1e7) the 3n LU.
_ISOTROPIC = 0.1
_CG_TOLERANCE, _CG_ITERATIONS = 1e-13, 30
# Free poses below which _solve_isotropic's incidence and scalar Laplacian are dense arrays
# (the same products; scipy.sparse's set-up took most of a 125-pose step). The translation
# step (CPU ms, dense / sparse): smallGrid3D 4.5 / 5.9, generated graphs of 60 poses 2.3 /
# 4.0, 150: 3.9 / 5.0, 200: 5.2 / 5.6, 300: 9.1 / 6.7; the positions within 4e-15.
_DENSE_LAPLACIAN_BELOW = 200


def solve_block_pairwise(num_poses: int, edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                         b: np.ndarray, held: np.ndarray, held_values: np.ndarray,
                         weights: np.ndarray | None = None) -> np.ndarray:
    """Minimize ``sum_e w_e ||A_i x_i + A_j x_j - b_e||^2`` over d-vectors, some held.

    Args:
        num_poses: number n of unknowns, indexed 0..n-1.
        edges: (m, 2) indices (i, j) of each residual.
        a_i, a_j: (m, d, d) blocks of each residual.
        b: (m, d) right-hand sides, or (m, d, k) for k problems with the same blocks.
        held: (h,) indices held fixed (h >= 1 fixes the gauge).
        held_values: (h, d) or (h, d, k) their values.
        weights: (m,) per-residual weights, or None for 1; residuals weighted at or below
            :data:`~rlpgo_gtsam.linear.WEIGHT_FLOOR` are left out (as the planar system's).

    Returns:
        (n, d) or (n, d, k): the minimizer, held unknowns at their values.

    Raises:
        SolverError: the system is indeterminate (the first undetermined pose is named).
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    a_i, a_j = np.asarray(a_i, float), np.asarray(a_j, float)
    m, d = a_i.shape[0], a_i.shape[1]
    single = np.ndim(b) == 2
    b = np.asarray(b, float).reshape(m, d, -1)
    if weights is not None:
        weights = np.asarray(weights, float).reshape(m)
        kept = weights > WEIGHT_FLOOR
        root = np.sqrt(weights[kept])[:, None, None]
        edges, a_i, a_j, b = edges[kept], root * a_i[kept], root * a_j[kept], root * b[kept]
        m = len(edges)
    k = b.shape[2]
    x = np.zeros((num_poses, d, k))
    held = np.asarray(held, dtype=np.int64).reshape(-1)
    x[held] = np.asarray(held_values, float).reshape(len(held), d, k)
    free = np.ones(num_poses, bool)
    free[held] = False
    unknowns = d * int(free.sum())
    if 0 < unknowns < _DENSE_BELOW:
        solution = _dense_pairwise(edges, a_i, a_j, b, x, free)
        if solution is not None:
            x[free] = solution
            return x[..., 0] if single else x
    if unknowns:  # sparse, or a dense factor that failed: the LU names the pose
        column = np.full(num_poses, -1, np.int64)
        column[free] = np.arange(unknowns // d)
        i, j = edges[:, 0], edges[:, 1]
        rhs = b - a_i @ x[i] - a_j @ x[j]  # held unknowns moved to the right-hand side
        rows, cols, data = [], [], []
        offsets = np.arange(d)
        for index, block in ((i, a_i), (j, a_j)):
            take = column[index] >= 0
            row = (np.flatnonzero(take)[:, None, None] * d + offsets[None, :, None])
            col = column[index[take]][:, None, None] * d + offsets[None, None, :]
            rows.append(np.broadcast_to(row, (int(take.sum()), d, d)).ravel())
            cols.append(np.broadcast_to(col, (int(take.sum()), d, d)).ravel())
            data.append(block[take].ravel())
        x[free] = _least_squares(np.concatenate(rows), np.concatenate(cols),
                                 np.concatenate(data), (m * d, d * int(free.sum())),
                                 rhs.reshape(m * d, k), np.flatnonzero(free), d
                                 ).reshape(-1, d, k)
    return x[..., 0] if single else x


def _dense_pairwise(edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray, b: np.ndarray,
                    x: np.ndarray, free: np.ndarray) -> np.ndarray | None:
    """The free unknowns ((f, d, k)) of :func:`solve_block_pairwise`'s system through dense
    normal equations: each residual's block ``A_e^T A_e`` (``A_e = [a_i a_j]``, 2d x 2d) and
    ``A_e^T b_e`` scattered once over all unknowns, the held ones (``x``, the free ones 0
    there) moved to the right-hand side, LAPACK's Cholesky factor of the free ones
    (tinyGrid3D's translation step: 0.38 -> 0.12 ms CPU, the positions to 1e-15). None
    where the factor fails or a pivot falls below :data:`PIVOT_FLOOR` of its diagonal (the
    sparse LU then names the undetermined pose).

    Raises:
        SolverError: a solution that is not finite.
    """
    m, d, k = b.shape
    size = x.shape[0] * d
    a = np.concatenate([a_i, a_j], axis=2)
    a_t = np.transpose(a, (0, 2, 1))
    places = (d * edges[:, :, None] + np.arange(d)).reshape(m, 2 * d)
    normal = np.bincount((places[:, :, None] * size + places[:, None, :]).ravel(),
                         weights=(a_t @ a).ravel(), minlength=size * size).reshape(size, size)
    rhs = np.bincount((places[:, :, None] * k + np.arange(k)).ravel(), weights=(a_t @ b).ravel(),
                      minlength=size * k).reshape(size, k)
    rows = np.repeat(free, d)
    rhs = (rhs - normal @ x.reshape(size, k))[rows]
    # the transpose of the symmetric (fancy-indexed, C-ordered) block: factored in place
    lower = dense_cholesky(normal[rows][:, rows].T, overwrite=True)
    if lower is None:
        return None
    solution = DenseCholesky(lower).solve(rhs)
    if not np.isfinite(solution).all():
        raise SolverError("linear solve failed: the solution is not finite")
    return solution.reshape(-1, d, k)


def _least_squares(rows: np.ndarray, cols: np.ndarray, data: np.ndarray, shape: tuple[int, int],
                   rhs: np.ndarray, free: np.ndarray, d: int) -> np.ndarray:
    """``argmin ||A x - rhs||`` (``A``: COO entries of ``shape``; ``rhs`` (rows, k)) through
    the normal equations' sparse LU.

    Raises:
        SolverError: a pivot below :data:`PIVOT_FLOOR` of its diagonal (the pose of the
            first, ``free`` mapping unknowns / d to pose indices, is named), or a solution
            that is not finite.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    a = sp.csr_matrix((data, (rows, cols)), shape=shape)
    normal = (a.T @ a).tocsc()
    try:
        lu = splu(normal, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        pivots = np.abs(lu.U.diagonal()[lu.perm_c])
        vanishing = pivots <= PIVOT_FLOOR * np.abs(normal.diagonal())
    except RuntimeError:
        lu, vanishing = None, np.ones(shape[1], bool)
    if lu is None or vanishing.any():
        pose = int(free[np.flatnonzero(vanishing)[0] // d])
        raise SolverError(f"linear solve failed: Indeterminate linear system detected "
                          f"while working near variable {pose}: linear solve left pose "
                          f"index {pose} undetermined")
    solution = lu.solve(np.asarray(a.T @ rhs))
    if not np.all(np.isfinite(solution)):
        raise SolverError("linear solve failed: the solution is not finite")
    return solution


def _solve_isotropic(num_poses: int, edges: np.ndarray, a: np.ndarray, b: np.ndarray,
                     held: np.ndarray, held_values: np.ndarray) -> np.ndarray | None:
    """Minimize ``sum_e ||A_e (x_j - x_i) - b_e||^2`` over 3-vectors, ``held`` fixed, by
    conjugate gradients preconditioned with the scalar Laplacian of ``w_e = tr(M_e) / 3``
    (``M_e = A_e^T A_e``; one sparse LU of n unknowns, three right-hand sides), where every
    ``M_e`` is within :data:`_ISOTROPIC` of ``w_e I``; None where one is not, where the
    Laplacian is singular, where CG did not reach :data:`_CG_TOLERANCE`, or below
    :data:`_DENSE_BELOW` unknowns (the caller then solves the 3n system directly, which
    names an undetermined pose).

    The normal matrix is the Laplacian with the 3x3 weights ``M_e``; with isotropic
    informations ``M_e`` is ``w_e I`` up to the rotation error's Jacobian (``O(|e_R|^2)``),
    so the preconditioner is nearly exact: each iteration cuts the residual by about that.
    """
    # distinct held poses by a set: np.unique (numpy 2.4) imports numpy.ma, 6 ms of a 3D run
    if 3 * (num_poses - len(set(held.tolist()))) < _DENSE_BELOW:
        return None  # the dense Cholesky is faster there
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    weights = np.transpose(a, (0, 2, 1)) @ a
    w = np.trace(weights, axis1=1, axis2=2) / 3.0
    if not np.all(w > WEIGHT_FLOOR):
        return None
    spread = weights - w[:, None, None] * np.eye(3)
    if np.sqrt(np.einsum("eab,eab->e", spread, spread)).max() > _ISOTROPIC * w.min():
        return None
    m = len(edges)
    x = np.zeros((num_poses, 3))
    x[held] = held_values
    free = np.ones(num_poses, bool)
    free[held] = False
    column = np.full(num_poses, -1, np.int64)
    column[free] = np.arange(int(free.sum()))
    i, j = edges[:, 0], edges[:, 1]
    entries = (np.concatenate([-np.ones(m), np.ones(m)]),
               (np.concatenate([np.arange(m), np.arange(m)]), np.concatenate([i, j])))
    if int(free.sum()) < _DENSE_LAPLACIAN_BELOW:  # dense arrays: the same products
        incidence = np.bincount(entries[1][0] * num_poses + entries[1][1], weights=entries[0],
                                minlength=m * num_poses).reshape(m, num_poses)
        held_part = incidence @ x  # the held poses' differences
        incidence = incidence[:, free]
        incidence_t = incidence.T
        laplacian = np.bincount(np.concatenate([i, j, i, j]) * num_poses
                                + np.concatenate([i, j, j, i]),
                                weights=np.concatenate([w, w, -w, -w]),
                                minlength=num_poses * num_poses
                                ).reshape(num_poses, num_poses)[np.ix_(free, free)]
        lower = dense_cholesky(laplacian)
        if lower is None:
            return None
        lu = DenseCholesky(lower)
    else:
        incidence = sp.coo_matrix(entries, shape=(m, num_poses)).tocsc()
        held_part = incidence @ x  # the held poses' differences
        incidence = incidence[:, free].tocsr()
        incidence_t = incidence.T.tocsr()
        laplacian = (incidence_t @ sp.diags(w) @ incidence).tocsc()
        try:
            lu = splu(laplacian, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
        except RuntimeError:
            return None
        if np.any(np.abs(lu.U.diagonal()) <= PIVOT_FLOOR * np.abs(laplacian.diagonal()[
                lu.perm_c])):
            return None

    def normal(v: np.ndarray) -> np.ndarray:
        return incidence_t @ np.einsum("eab,eb->ea", weights, incidence @ v)

    rhs = incidence_t @ np.einsum("eba,eb->ea", a, b - np.einsum("eab,eb->ea", a, held_part))
    scale = np.linalg.norm(rhs)
    solution = lu.solve(rhs)
    residual = rhs - normal(solution)
    z = lu.solve(residual)
    direction, rz = z, float(np.sum(residual * z))
    for _ in range(_CG_ITERATIONS):
        if not np.linalg.norm(residual) > _CG_TOLERANCE * scale:
            break
        product = normal(direction)
        alpha = rz / float(np.sum(direction * product))
        solution = solution + alpha * direction
        residual = residual - alpha * product
        z = lu.solve(residual)
        rz, rz_old = float(np.sum(residual * z)), rz
        direction = z + (rz / rz_old) * direction
    else:
        if np.linalg.norm(residual) > _CG_TOLERANCE * scale:
            return None
    if not np.all(np.isfinite(solution)):
        return None
    x[free] = solution
    return x


def dense_cholesky(matrix: np.ndarray, overwrite: bool = False) -> np.ndarray | None:
    """The lower Cholesky factor of the symmetric ``matrix`` (LAPACK's dpotrf; the upper
    triangle is left as it was), or None where the factorization fails or a pivot falls
    below :data:`PIVOT_FLOOR` of its diagonal: the system is indeterminate (the callers then
    hand over to a solve that names the pose). ``overwrite``: factored in ``matrix``'s own
    memory, which must then be Fortran-ordered (the transpose of a C-ordered symmetric matrix
    is the same matrix in that order)."""
    from scipy.linalg.lapack import dpotrf  # lazily: --help loads no scipy

    diagonal = np.diagonal(matrix).copy()
    lower, info = dpotrf(matrix, lower=1, clean=0, overwrite_a=int(overwrite))
    if info != 0 or not (np.diagonal(lower) ** 2 > PIVOT_FLOOR * diagonal).all():
        return None
    return lower


class DenseCholesky:
    """A dense lower Cholesky factor (LAPACK's, :func:`dense_cholesky`) that solves as a
    SuperLU does."""

    def __init__(self, lower: np.ndarray) -> None:
        self.lower = lower

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg.lapack import dpotrs

        return dpotrs(self.lower, b, lower=1)[0]


class TranslationStep3D:
    """Positions of least GTSAM cost for given rotations, and their chi2; keeps what does
    not depend on the rotations (whitening factors, rotation-translation shifts)."""

    def __init__(self, pose_graph: PoseGraph3D) -> None:
        g = pose_graph
        self.pose_graph = g
        info = g.information
        try:
            lower = np.linalg.cholesky(info[:, 3:, 3:])
        except np.linalg.LinAlgError:
            raise SolverError("an edge's translational information is not positive "
                              "definite") from None
        self.w = np.transpose(lower, (0, 2, 1))  # W^T W = Lambda_tt
        self.shift = np.linalg.solve(info[:, 3:, 3:], info[:, 3:, :3])  # Lambda_tt^-1 Lambda_tR
        self.measured_t = np.transpose(g.measured_rotations, (0, 2, 1))  # R~^T

    def whitened(self, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residuals ``A_e (t_j - t_i) - b_e`` (whitened, 3 dof: ``W (e_t + Lambda_tt^-1
        Lambda_tR e_R)``) at (n, 3, 3) ``rotations``: (m, 3, 3) blocks ``A_e``, (m, 3) ``b_e``."""
        g = self.pose_graph
        i, j = g.edges[:, 0], g.edges[:, 1]
        turned_i = np.transpose(rotations[i], (0, 2, 1))  # R_i^T
        error_r = log_so3(self.measured_t @ turned_i @ rotations[j])
        v_inv = inverse_left_jacobians(error_r)
        a_j = self.w @ v_inv @ self.measured_t @ turned_i
        b = np.einsum("eab,eb->ea", self.w,
                      np.einsum("eab,eb->ea", v_inv @ self.measured_t, g.measured_translations)
                      - np.einsum("eab,eb->ea", self.shift, error_r))
        return a_j, b

    def positions(self, rotations: np.ndarray) -> np.ndarray:
        """(n, 3) positions of least cost for (n, 3, 3) ``rotations`` (held poses keep
        theirs; the rotations are used as given): by :func:`_solve_isotropic` where the
        edges' weights allow, else by :func:`solve_block_pairwise`."""
        g = self.pose_graph
        a_j, b = self.whitened(rotations)
        held, _, held_t = g.held
        positions = _solve_isotropic(g.num_poses, g.edges, a_j, b, held, held_t)
        if positions is None:
            positions = solve_block_pairwise(g.num_poses, g.edges, -a_j, a_j, b, held, held_t)
        return positions

    def solve(self, rotations: np.ndarray) -> tuple[np.ndarray, float]:
        """(n, 3) positions of least cost and the edges' chi2 there."""
        t = self.positions(rotations)
        return t, float(edge_chi2(self.pose_graph, rotations, t).sum())


def solve_translations(pose_graph: PoseGraph3D, rotations: np.ndarray) -> np.ndarray:
    """(n, 3) positions minimizing GTSAM's cost of the edges with ``rotations`` fixed (see
    the module docstring); held poses (the anchor, FIXed poses) keep their positions."""
    return TranslationStep3D(pose_graph).positions(np.asarray(rotations, float))


def poses_with_rotations(pose_graph: PoseGraph3D,
                         rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (n, 3, 3) in the anchor's gauge and positions (n, 3) solved for them.

    ``rotations`` are turned as a whole (``G R_k``) so that the anchor gets its rotation;
    every held pose keeps its rotation and position; the others get positions from
    :func:`solve_translations`.
    """
    g = pose_graph
    held, held_r, _ = g.held
    rotations = np.asarray(rotations, float)
    turned = held_r[0] @ rotations[held[0]].T @ rotations
    turned[held] = held_r
    return turned, solve_translations(g, turned)
