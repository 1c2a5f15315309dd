"""The one sparse least-squares system over pairs of planar vectors.

Every linear step of the package has the same shape: one unknown 2-vector per pose (a
position, or a complex number for the chordal rotation relaxation), one whitened 2-row
residual per edge ``A_i x_i + A_j x_j - b``, optionally weighted, and the anchor (and any
FIXed pose) held at a known value. :class:`PairwiseSystem` keeps what depends on the graph
alone (which unknowns are free, the sparsity pattern of the normal equations and its fill-
reducing ordering) and solves for any blocks, right-hand sides and weights.

The normal equations are factorized by SuperLU (scipy) in symmetric mode without pivoting
(the matrix is positive definite when the system is determined). An indeterminate system (a
pose the kept edges do not tie to a held pose, or a pivot that vanishes against its
diagonal, e.g. a pose joined by an edge of information 1e-30 only) is a
:class:`~rlpgo_gtsam.errors.SolverError` naming the first undetermined pose index.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.errors import SolverError

__all__ = ["PairwiseSystem", "solve_pairwise", "WEIGHT_FLOOR"]

# Weights at or below this leave an edge out of a weighted solve: even at a tiny weight a
# wrong closure joins two random poses, and such joins ruin the factorization's fill
# (City10K: 0.1 s -> 20 s).
WEIGHT_FLOOR = 1e-12
# A pivot below this fraction of its diagonal entry means the system is indeterminate there.
_PIVOT_FLOOR = 1e-10
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
        if kept is None and weights is None and self._fixed is not None:
            factor, normal = self._fixed
            solution = self._checked(factor.solve(gradient), normal, None)
        else:
            cross = a_i_t @ a_j
            blocks = [a_i_t @ a_i, a_j_t @ a_j, cross, np.transpose(cross, (0, 2, 1))]
            solution = (self._solve_all(blocks, gradient, fixed=weights is None) if kept is None
                        else self._solve_kept(blocks, gradient, kept))
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
            shift = sp.diags(1e-3 * _PIVOT_FLOOR * np.abs(normal.diagonal()) + 1e-300)
            vanishing = _factorize((normal + shift).tocsc(), natural=False)[1]
        loose[np.flatnonzero(self.free)[np.flatnonzero(vanishing) // 2]] = True
        if not loose.any():
            return SolverError("linear solve failed: the factorization is singular")
        k = int(np.flatnonzero(loose)[0])
        return SolverError(f"linear solve failed: Indeterminate linear system detected while "
                           f"working near variable {k}: linear solve left pose index {k} "
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
    return factor, np.abs(pivots) <= _PIVOT_FLOOR * np.abs(normal.diagonal())


def solve_pairwise(num_poses: int, edges: np.ndarray, a_i: np.ndarray, a_j: np.ndarray,
                   b: np.ndarray, held: np.ndarray, held_values: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """One solve of a :class:`PairwiseSystem` (see there); returns (n, 2)."""
    return PairwiseSystem(num_poses, edges, held).solve(a_i, a_j, b, held_values, weights)
