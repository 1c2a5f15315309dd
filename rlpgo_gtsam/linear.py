"""The sparse least-squares systems of the package: one unknown d-vector per pose, one
whitened residual per edge.

Every linear step has the same shape: one unknown vector per pose (a position, or for the
chordal rotation relaxation a complex number or a rotation's rows), one whitened residual
per edge ``A_i x_i + A_j x_j - b``, optionally weighted, and the anchor (and any FIXed pose)
held at a known value. :class:`PairwiseSystem` solves it for 2-vectors and keeps what depends
on the graph alone (which unknowns are free, the sparsity pattern of the normal equations and
its fill-reducing ordering) for the next solve; :func:`solve_block_pairwise` solves it for
d-vectors and several right-hand sides at once, densely below :data:`_DENSE_BELOW` unknowns;
:func:`solve_isotropic` solves the 3D translation step by conjugate gradients where every
edge's translational weight is nearly isotropic (SE-Sync's files but cubicle: one
factorization of n unknowns instead of 3n, to a residual of 1e-13).

The normal equations are factorized by SuperLU (scipy) in symmetric mode without pivoting,
or by LAPACK's Cholesky factor (the matrix is positive definite when the system is
determined). An indeterminate system (a pose the kept edges do not tie to a held pose, or a
pivot that vanishes against its diagonal, e.g. a pose joined by an edge of information 1e-30
only) is a :class:`~rlpgo_gtsam.errors.SolverError` naming the first undetermined pose index.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.errors import SolverError

__all__ = ["PairwiseSystem", "solve_pairwise", "solve_block_pairwise", "solve_isotropic",
           "dense_cholesky", "DenseCholesky", "WEIGHT_FLOOR", "PIVOT_FLOOR", "potrf", "potrs",
           "trtrs", "SMALL_ROWS"]

# Weights at or below this leave an edge out of a weighted solve: even at a tiny weight a
# wrong closure joins two random poses, and such joins ruin the factorization's fill
# (City10K: 0.1 s -> 20 s).
WEIGHT_FLOOR = 1e-12
# A pivot below this fraction of its diagonal entry means the system is indeterminate there.
PIVOT_FLOOR = 1e-10
# Rows below which dense factors and solves go through numpy's LAPACK, not scipy's (potrf).
SMALL_ROWS = 150
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
# (row, col) offsets of a 2x2 block's entries, row-major.
_BLOCK_ROWS = np.array([0, 0, 1, 1])
_BLOCK_COLS = np.array([0, 1, 0, 1])


class PairwiseSystem:
    """Minimize ``sum_e w_e ||A_i x_i + A_j x_j - b_e||^2`` over 2-vectors, some held.

    Args:
        num_poses: number n of unknown 2-vectors, indexed 0..n-1.
        edges: (m, 2) indices (i, j) of each residual.
        held: (k,) indices of the vectors held fixed (k >= 1: the anchor fixes the gauge);
            their terms move to the right-hand side.
        fixed_matrix: the caller's promise that the normal matrix is mathematically the
            same at every solve with every edge kept and no weights (the translation step
            where each edge's translation information is a multiple of the identity: its
            blocks are then ``lambda_e I`` whatever the orientations). The first such
            solve's factorization then serves the later ones, which only form the
            right-hand side; the matrices they would have formed differ from it only by
            rounding (``R R^T`` computed rather than ``I``).

    The pattern of the normal equations (and the ordering SuperLU picks for it) is computed
    on the first solve with every edge kept and reused by the later ones; a solve that
    leaves edges out (weights at or below ``1e-12``) builds its own.
    """

    def __init__(self, num_poses: int, edges: np.ndarray, held: np.ndarray,
                 fixed_matrix: bool = False) -> None:
        self.num_poses = num_poses
        self.fixed_matrix = fixed_matrix
        self._fixed: tuple | None = None  # (factor, normal matrix) once fixed_matrix solved
        self.edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        self.held = np.asarray(held, dtype=np.int64).reshape(-1)
        column = np.full(num_poses, -1, dtype=np.int64)
        free = np.ones(num_poses, bool)
        free[self.held] = False
        column[free] = np.arange(int(free.sum()))
        self.free = free
        self._column = column  # pose index -> block column among the free poses, or -1
        self.unknowns = 2 * int(free.sum())
        i, j = self.edges[:, 0], self.edges[:, 1]
        # the four blocks (i,i), (j,j), (i,j), (j,i) of each edge, kept where both are free
        self._block_keep = [(column[p] >= 0) & (column[q] >= 0) for p, q in
                            ((i, i), (j, j), (i, j), (j, i))]
        # with every edge kept: the entries' rows and columns and the fill-reducing ordering
        # the first solve found (each column's position in it); from the second solve on,
        # the normal equations' CSC structure in that ordering (slots, indices, indptr) and
        # the positions (a one-shot solve never builds it)
        self._ordering: tuple | None = None
        self._pattern: tuple | None = None

    def solve(self, a_i: np.ndarray, a_j: np.ndarray, b: np.ndarray, held_values: np.ndarray,
              weights: np.ndarray | None = None) -> np.ndarray:
        """The minimizer, (n, 2); held vectors at ``held_values``.

        Args:
            a_i, a_j: (m, 2, 2) whitened blocks of each residual.
            b: (m, 2) whitened right-hand sides.
            held_values: (k, 2) the values the held vectors are held at.
            weights: (m,) per-edge weights, or None for 1; edges at or below ``1e-12`` are
                left out.

        Raises:
            SolverError: the system is indeterminate (the first undetermined pose is named).
        """
        x = np.zeros((self.num_poses, 2))
        x[self.held] = np.asarray(held_values, dtype=float).reshape(-1, 2)
        if self.unknowns == 0:
            return x
        i, j = self.edges[:, 0], self.edges[:, 1]
        kept = None
        if weights is not None:
            weights = np.asarray(weights, dtype=float)
            kept = weights > WEIGHT_FLOOR
            if kept.all():
                kept = None
            a_i, a_j, b = (weights[:, None, None] ** 0.5 * a_i, weights[:, None, None] ** 0.5
                           * a_j, weights[:, None] ** 0.5 * b)
        # held vectors move to the right-hand side (free ones are 0 in x here)
        rhs_edge = b - np.einsum("eab,eb->ea", a_i, x[i]) - np.einsum("eab,eb->ea", a_j, x[j])
        a_i_t = np.transpose(a_i, (0, 2, 1))
        a_j_t = np.transpose(a_j, (0, 2, 1))
        gradient = np.zeros(self.unknowns)
        for index, block_t in ((i, a_i_t), (j, a_j_t)):
            take = self._column[index] >= 0
            if kept is not None:
                take &= kept
            part = np.einsum("eab,eb->ea", block_t[take], rhs_edge[take])
            slot = (2 * self._column[index][take][:, None] + [0, 1]).ravel()
            gradient += np.bincount(slot, weights=part.ravel(), minlength=self.unknowns)
        try:
            if kept is None and weights is None and self._fixed is not None:
                factor, normal = self._fixed
                solution = self._checked(factor.solve(gradient), normal, None)
            else:
                cross = a_i_t @ a_j
                blocks = [a_i_t @ a_i, a_j_t @ a_j, cross, np.transpose(cross, (0, 2, 1))]
                solution = (self._solve_all(blocks, gradient, fixed=weights is None)
                            if kept is None else self._solve_kept(blocks, gradient, kept))
        except SolverError as error:
            take = np.ones(len(self.edges), bool) if kept is None else kept
            solution = augmented_least_squares(self.edges[take], a_i[take], a_j[take],
                                               rhs_edge[take], self._column, self.held, error)
        x[self.free] = solution.reshape(-1, 2)
        return x

    # --- the normal equations ---------------------------------------------------------

    def _entries(self, kept: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Row and column of every stored entry, blocks in :meth:`_data` order."""
        i, j = self.edges[:, 0], self.edges[:, 1]
        rows, cols = [], []
        for (p, q), keep in zip(((i, i), (j, j), (i, j), (j, i)), self._block_keep, strict=True):
            if kept is not None:
                keep = keep & kept
            rows.append((2 * self._column[p[keep]][:, None] + _BLOCK_ROWS).ravel())
            cols.append((2 * self._column[q[keep]][:, None] + _BLOCK_COLS).ravel())
        return np.concatenate(rows), np.concatenate(cols)

    def _data(self, blocks: list[np.ndarray], kept: np.ndarray | None) -> np.ndarray:
        parts = []
        for block, keep in zip(blocks, self._block_keep, strict=True):
            if kept is not None:
                keep = keep & kept
            parts.append(block[keep].reshape(-1))
        return np.concatenate(parts)

    def _solve_all(self, blocks: list[np.ndarray], gradient: np.ndarray,
                   fixed: bool = False) -> np.ndarray:
        """Every edge kept: the cached pattern, already permuted into the fill-reducing
        ordering that the first solve found (SuperLU then factorizes in natural order).
        ``fixed`` (no weights): where the matrix is fixed, the first factorization is kept
        for the later solves."""
        import scipy.sparse as sp

        size = self.unknowns
        data = self._data(blocks, None)
        if self._ordering is None:
            rows, cols = self._entries(None)
            slots, indices, indptr = _csc_pattern(rows, cols, size)
            normal = sp.csc_matrix((np.bincount(slots, weights=data, minlength=len(indices)),
                                    indices, indptr), shape=(size, size))
            factor, vanishing = _factorize(normal, natural=False)
            if factor is None or vanishing.any():
                raise self._indeterminate(normal, None, vanishing)
            # column k of the matrix is eliminated at position[k]
            self._ordering = (rows, cols, factor.perm_c)
            if fixed and self.fixed_matrix:
                self._fixed = (factor, normal)
            return self._checked(factor.solve(gradient), normal, None)
        if self._pattern is None:
            rows, cols, position = self._ordering
            self._pattern = (*_csc_pattern(position[rows], position[cols], size), position)
        slots, indices, indptr, position = self._pattern
        permuted = sp.csc_matrix((np.bincount(slots, weights=data, minlength=len(indices)),
                                  indices, indptr), shape=(size, size))
        factor, vanishing = _factorize(permuted, natural=True)
        if factor is not None and not vanishing.any():
            solution = factor.solve(gradient[np.argsort(position)])[position]
            if np.all(np.isfinite(solution)):
                return solution
        normal = permuted[position][:, position].tocsc()
        raise self._indeterminate(normal, None, vanishing[position])

    def _solve_kept(self, blocks: list[np.ndarray], gradient: np.ndarray,
                    kept: np.ndarray) -> np.ndarray:
        """Some edges left out: a pattern (and an ordering) of their own."""
        import scipy.sparse as sp

        size = self.unknowns
        rows, cols = self._entries(kept)
        normal = sp.csc_matrix((self._data(blocks, kept), (rows, cols)), shape=(size, size))
        factor, vanishing = _factorize(normal, natural=False)
        if factor is None or vanishing.any():
            raise self._indeterminate(normal, kept, vanishing)
        return self._checked(factor.solve(gradient), normal, kept)

    def _checked(self, solution: np.ndarray, normal, kept: np.ndarray | None) -> np.ndarray:
        if not np.all(np.isfinite(solution)):
            raise self._indeterminate(normal, kept, np.zeros(len(solution), bool))
        return solution

    def _indeterminate(self, normal, kept: np.ndarray | None,
                       vanishing: np.ndarray) -> SolverError:
        """The error naming the first pose the system leaves undetermined: one the kept
        edges do not tie to a held pose, else the first with a vanishing pivot."""
        import scipy.sparse as sp

        from rlpgo_gtsam.graph import component_labels

        labels = component_labels(self.num_poses, self.edges if kept is None
                                  else self.edges[kept])
        loose = self.free & ~np.isin(labels, labels[self.held])
        if not loose.any() and not vanishing.any():
            # exactly singular although tied: find the pivots on a slightly shifted matrix
            shift = sp.diags(1e-3 * PIVOT_FLOOR * np.abs(normal.diagonal()) + 1e-300)
            vanishing = _factorize((normal + shift).tocsc(), natural=False)[1]
        loose[np.flatnonzero(self.free)[np.flatnonzero(vanishing) // 2]] = True
        if not loose.any():
            return SolverError("linear solve failed: the factorization is singular")
        return _undetermined(int(np.flatnonzero(loose)[0]))


def _undetermined(pose: int) -> SolverError:
    """The error of a system that leaves pose index ``pose`` undetermined (GTSAM's words)."""
    return SolverError(f"linear solve failed: Indeterminate linear system detected while "
                       f"working near variable {pose}: linear solve left pose index {pose} "
                       "undetermined")


def _csc_pattern(rows: np.ndarray, cols: np.ndarray, size: int) -> tuple:
    """The CSC structure of entries at (rows, cols), duplicates summed: each entry's slot in
    the data array, then the row indices and column pointers."""
    key = cols.astype(np.int64) * size + rows
    order = np.argsort(key, kind="stable")  # np.lexsort((rows, cols)), in half the time
    key = key[order]
    first = np.diff(key, prepend=-1) != 0
    unique = key[first]
    slots = np.empty(len(rows), np.int64)
    slots[order] = np.cumsum(first) - 1
    return (slots, (unique % size).astype(np.int32),
            np.searchsorted(unique // size, np.arange(size + 1)).astype(np.int32))


def _factorize(normal, natural: bool) -> tuple:
    """SuperLU of a symmetric positive definite matrix in symmetric mode without pivoting,
    in natural order or in the minimum-degree ordering of A^T + A: (the factor, (size,) bool
    the columns whose pivot vanishes against their diagonal entry). The factor is None when
    SuperLU finds the matrix exactly singular (no column is then marked)."""
    from scipy.sparse.linalg import splu

    try:
        factor = splu(normal, permc_spec="NATURAL" if natural else "MMD_AT_PLUS_A",
                      diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError:
        return None, np.zeros(normal.shape[0], bool)
    pivots = factor.U.diagonal()[factor.perm_c]
    return factor, np.abs(pivots) <= PIVOT_FLOOR * np.abs(normal.diagonal())


def solve_pairwise(num_poses: int, edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                   b: np.ndarray, held: np.ndarray, held_values: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """One solve of a :class:`PairwiseSystem` (see there); returns (n, 2)."""
    return PairwiseSystem(num_poses, edges, held).solve(a_i, a_j, b, held_values, weights)


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
            :data:`WEIGHT_FLOOR` are left out (as the planar system's).

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
        rows, cols, data = _jacobian_entries(edges, a_i, a_j, column)
        try:
            solution = _least_squares(rows, cols, data, (m * d, unknowns),
                                      rhs.reshape(m * d, k), np.flatnonzero(free), d)
        except SolverError as error:
            solution = augmented_least_squares(edges, a_i, a_j, rhs, column, held, error)
        x[free] = solution.reshape(-1, d, k)
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


def augmented_least_squares(edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                            rhs: np.ndarray, column: np.ndarray, held: np.ndarray,
                            error: SolverError) -> np.ndarray:
    """``argmin ||A x - rhs||`` through the augmented system ``[[I, A], [A^T, 0]] [r; x] =
    [rhs; 0]`` (SuperLU with partial pivoting), where the normal equations lost the poses
    that edges of extreme weight tie together: their condition number is ``cond(A)^2``, the
    augmented system's about ``cond(A)`` (MIT with one edge of information 1e12 beside
    weights near 100: the normal equations' pivot falls to 1e-10 of its diagonal, GTSAM's LM
    and this solve both reach the optimum). Only for systems whose every free unknown the
    edges of a weight above :data:`PIVOT_FLOOR` of their median tie to a held one;
    ``error`` (the normal equations') is raised otherwise, or where this solve fails too.

    ``a_i``, ``a_j``: (m, d, d) blocks, ``rhs`` (m, d), or (m, d, k) for k problems, with the
    held unknowns' terms moved there; ``column``: each pose's block column among the free
    ones, -1 for held ones. Returns (free * d,), or (free * d, k).
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import splu

    from rlpgo_gtsam.graph import component_labels

    free = column >= 0
    # the ties that count: an edge whose weight vanishes against the graph's typical one
    # (1e-30 beside 1) ties nothing a solve can resolve, however exact its arithmetic
    weight = np.einsum("eab,eab->e", a_j, a_j) + np.einsum("eab,eab->e", a_i, a_i)
    ties = weight > PIVOT_FLOOR * np.median(weight)
    labels = component_labels(len(column), edges[ties])
    if not np.isin(labels[free], labels[held]).all():
        raise error
    m, d = rhs.shape[0], rhs.shape[1]
    unknowns = d * int(free.sum())
    r, c, v = _jacobian_entries(edges, a_i, a_j, column)
    c = c + m * d  # the unknowns after the residuals
    identity = np.arange(m * d)
    size = m * d + unknowns
    matrix = sp.csc_matrix((np.concatenate([np.ones(m * d), v, v]),
                            (np.concatenate([identity, r, c]), np.concatenate([identity, c, r]))),
                           shape=(size, size))
    right = rhs.reshape(m * d, -1)
    try:
        solution = splu(matrix).solve(np.vstack([right, np.zeros((unknowns, right.shape[1]))]))
    except RuntimeError:
        raise error from None
    if not np.all(np.isfinite(solution)):
        raise error
    return solution[m * d:].reshape(-1) if rhs.ndim == 2 else solution[m * d:]


def _jacobian_entries(edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                      column: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO rows, columns and values of the Jacobian of the residuals ``A_i x_i + A_j x_j``
    over the free unknowns (``column``: each pose's block column, -1 for a held one)."""
    d = a_i.shape[1]
    rows, cols, data = [], [], []
    offsets = np.arange(d)
    for index, block in ((edges[:, 0], a_i), (edges[:, 1], a_j)):
        take = column[index] >= 0
        row = np.flatnonzero(take)[:, None, None] * d + offsets[None, :, None]
        col = column[index[take]][:, None, None] * d + offsets[None, None, :]
        rows.append(np.broadcast_to(row, (int(take.sum()), d, d)).ravel())
        cols.append(np.broadcast_to(col, (int(take.sum()), d, d)).ravel())
        data.append(block[take].ravel())
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(data)


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

    a = sp.csr_matrix((data, (rows, cols)), shape=shape)
    normal = (a.T @ a).tocsc()
    lu, vanishing = _factorize(normal, natural=False)
    if lu is None or vanishing.any():
        raise _undetermined(int(free[(np.flatnonzero(vanishing)[0] if vanishing.any()
                                      else 0) // d]))
    solution = lu.solve(np.asarray(a.T @ rhs))
    if not np.all(np.isfinite(solution)):
        raise SolverError("linear solve failed: the solution is not finite")
    return solution


def solve_isotropic(num_poses: int, edges: np.ndarray, a: np.ndarray, b: np.ndarray,
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


def potrf(matrix: np.ndarray, overwrite: bool = False) -> tuple[np.ndarray, int]:
    """LAPACK's lower Cholesky factor of the symmetric ``matrix`` and its ``info`` (0: done),
    the upper triangle left as it was. Below :data:`SMALL_ROWS` rows through numpy's own
    LAPACK: a small graph's run then loads no scipy (its ``scipy.linalg`` import took 30 ms
    of a 0.19 s ``rlpgo-init`` on tinyGrid3D). ``overwrite``: factored in ``matrix``'s own
    memory where it is Fortran-ordered (the transpose of a C-ordered symmetric matrix is the
    same matrix in that order)."""
    if len(matrix) < SMALL_ROWS:
        try:
            return np.linalg.cholesky(matrix), 0
        except np.linalg.LinAlgError:
            return matrix, 1
    from scipy.linalg.lapack import dpotrf  # lazily: --help loads no scipy

    return dpotrf(matrix, lower=1, clean=0, overwrite_a=int(overwrite))


def potrs(lower: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^-1 b`` from :func:`potrf`'s factor of ``A``."""
    if len(lower) < SMALL_ROWS:
        return trtrs(lower.T, trtrs(lower, b), lower=False)
    from scipy.linalg.lapack import dpotrs

    return dpotrs(lower, b, lower=1)[0]


def trtrs(triangle: np.ndarray, b: np.ndarray, lower: bool = True) -> np.ndarray:
    """``T^-1 b`` for the ``lower`` (or upper) triangle ``T`` of ``triangle``."""
    if len(triangle) < SMALL_ROWS:
        return np.linalg.solve(np.tril(triangle) if lower else np.triu(triangle), b)
    from scipy.linalg.lapack import dtrtrs

    return dtrtrs(triangle, b, lower=int(lower))[0]


def dense_cholesky(matrix: np.ndarray, overwrite: bool = False) -> np.ndarray | None:
    """The lower Cholesky factor of the symmetric ``matrix`` (:func:`potrf`), or None where
    the factorization fails or a pivot falls below :data:`PIVOT_FLOOR` of its diagonal: the
    system is indeterminate (the callers then hand over to a solve that names the pose)."""
    diagonal = np.diagonal(matrix).copy()
    lower, info = potrf(matrix, overwrite)
    if info != 0 or not (np.diagonal(lower) ** 2 > PIVOT_FLOOR * diagonal).all():
        return None
    return lower


class DenseCholesky:
    """A dense lower Cholesky factor (:func:`dense_cholesky`) that solves as a SuperLU
    does."""

    def __init__(self, lower: np.ndarray) -> None:
        self.lower = lower

    def solve(self, b: np.ndarray) -> np.ndarray:
        return potrs(self.lower, b)
