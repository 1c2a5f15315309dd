"""The spatial relaxation: SE(3) synchronization on products of Stiefel manifolds (SE-Sync
for d = 3).

What it solves. SE-Sync's cost (Rosen et al., IJRR 2019, eq. 11)::

    F(R, t) = sum_e  kappa_e ||R_j - R_i R~_e||_F^2  +  tau_e ||t_j - t_i - R_i t~_e||^2

with SE-Sync's weights for d = 3 (:func:`~rlpgo_gtsam.graph.rotation_weights`,
:func:`~rlpgo_gtsam.graph.translation_weights`: ``kappa = 3 / (2 tr(Sigma_R))``,
``tau = 3 / tr(Sigma_t)``). Minimizing over the translations in closed form (the anchor's
held) leaves ``f(X) = tr(X^T Q X)`` with ``X`` the 3n x r matrix of stacked blocks
``X_i = R_i^T`` (3 x r at rank r) and ``Q = D - B^T L^-1 B`` (SE-Sync's simplified
``L(G^rho) + Q^tau``), applied through one sparse factorization of the anchored translation
Laplacian ``L``, never formed; below ``_DENSE_Q_BELOW`` rows (graphs of fewer than 134 poses)
``Q`` is formed as a dense matrix instead (each edge's terms scattered once as a block,
:meth:`SpatialProblem._set_up_dense`), and its factors are dense (scipy's sparse set-up cost
more than the whole solve there; S's eigenvalues are dense below ``_DENSE_BELOW``); the
chordal start is then solved through the same rotation terms' dense connection Laplacian.
Rows of each block ``X_i`` are orthonormal: ``X_i^T`` is a point of the Stiefel manifold
St(3, r), and SE-Sync's ``Y`` is ``X^T``.

How (the staircase of :mod:`~rlpgo_gtsam.relaxation.staircase`, in real 3x3 blocks). At
each rank a Riemannian trust region with truncated CG preconditioned by ``(Q + delta I)^-1``
(a pivot-free sparse LU of a matrix whose Schur complement is ``Q + delta I``); the
retraction projects each block onto the Stiefel manifold (polar factor), the tangent
projection is ``V_i - sym(V_i X_i^T) X_i``. Certificate: ``S = Q - Lambda(X)``,
``Lambda_i = sym((Q X)_i X_i^T)``; ``S + eta I`` is positive definite iff the sparse matrix
``[[L, -B], [-B^T, D - Lambda + eta I]]`` has only positive pivots (Sylvester's law of
inertia); the eigenvector of ``lambda_min(S)`` (ARPACK, shift-invert) escapes a saddle into
rank r + 1. Rounding (at rank 3 with every block a rotation: ``R_i = X_i^T``, the same
after the anchor's turn): the rank-3 truncated SVD ``X ~ U S V^T`` gives ``R_i = (U_i S)^T``;
if fewer than half of them have a positive determinant they are reflected by
``diag(1, 1, -1)``; each is projected onto SO(3); where the staircase ended above rank 3 they
are polished by the trust region at rank 3 and projected again; the whole is turned so that
the anchor keeps its rotation. The staircase starts at rank 3 (below ``_NEWTON_BELOW``
rows, from the point Newton's method reaches from the chordal estimate,
:mod:`~rlpgo_gtsam.relaxation.newton`, where the trust region would stop at once: S is
verified there first, and where it certifies the staircase is not run, the same check
without its set-up; else the staircase goes on from that point): SE-Sync's default start
(the chordal estimate padded with zeros at rank 5) stays in the same 3-dimensional subspace
until an escape, so starting at 3 gives the same iterates with fewer columns.

Certificate (:mod:`~rlpgo_gtsam.relaxation.certificate`): ``rows`` is ``3n`` here, ``eta =
1e-7 x mean(diag D)`` by default; ``rank`` is the real rank r (SE-Sync's), where the planar
relaxation counts complex columns. The costs are the relaxation's (SE-Sync's), not GTSAM's
chi2: refine the estimate with GTSAM.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from rlpgo_gtsam.chordal import chordal_rotations
from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.graph import PoseGraph3D
from rlpgo_gtsam.groups import SE3
from rlpgo_gtsam.linear import DenseCholesky, potrf, trtrs
from rlpgo_gtsam.relaxation.blocks import (
    from_fields,
    polar_newton,
    polar_svd,
    projected_fields,
    sym,
    to_fields,
)
from rlpgo_gtsam.relaxation.certificate import Check
from rlpgo_gtsam.relaxation.newton import newton_point
from rlpgo_gtsam.relaxation.problem import Manifold, Relaxation
from rlpgo_gtsam.relaxation.progress import Progress, Run
from rlpgo_gtsam.relaxation.verification import verify
from rlpgo_gtsam.se3 import exp_so3, project_to_so3, vee

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["SpatialProblem", "Stiefel", "manifold"]

# Rows of Q (3n) below which Q is a dense matrix: its products, the preconditioner's factor
# and S's eigenvalues are dense. The certified initializer's steady run on generated graphs
# (CPU ms, sparse Q against dense, the translation step sparse): 10 poses 10.7 / 5.7,
# 25: 19.6 / 11.9, 40: 20.5 / 15.9, 50: 24.0 / 20.2, 60: 27.6 / 27.1, 80: 29.0 / 37.5. 150
# keeps every graph of 50 poses or more on the sparse path.
_DENSE_BELOW = 150
# Rows of Q below which Q itself is dense (from _DENSE_BELOW on, S's eigenvalues are still
# found by ARPACK, shift-inverted through a dense Cholesky factor instead of a sparse LU).
_DENSE_Q_BELOW = 400
_REFLECT = np.diag([1.0, 1.0, -1.0])
_EYE, _AXES = np.eye(3), np.arange(3)
# an edge's translation terms: v = (-t~, -1, 1) on the places (X_i, t_i, t_j) of its 8
_STEP = np.array([[-1.0, 1.0]])
# (Q + delta I)^-1 preconditions the Hessian; delta / mean(diag D). 1e-3 takes 1.5x the
# inner iterations on parking-garage; 1e-7 stalls at round-off.
_PRECONDITIONER_SHIFT = 1e-5
# The first trust-region radius, in units of the preconditioned gradient's norm. 10 (the
# planar one) has cubicle's first step rejected six times (cubicle 8.0 s CPU, 0.1: 6.1 s; garage,
# spheres, torus within 10% either way).
_INITIAL_RADIUS = 0.1
# Truncated CG stops once its residual is half the gradient tolerance (the Manifold's
# cg_floor): below it the next gradient passes the stop test anyway. Hessian products with
# the floor against CG to its relative target alone: parking-garage 98 / 164 (its last CG
# run would solve a gradient of 1.8e-3, 1.2x the tolerance, down to 3e-6), cubicle 25 / 30,
# sphere2500 32 / 37; all seven files certified either way (garage's suboptimality bound
# 2.6e-7 / 4.5e-11 against 3n eta = 0.017), chi2 after LM30 within 3e-7 (garage's lower with
# the floor). 0.25: garage 114 products; 0.9: 93.
_CG_FLOOR = 0.5
# Poses from which the blocks' products run field by field: (3n, r) arrays turned into
# (3, r, n) fields, each product one einsum over the poses, instead of n small matrix
# products (numpy's matmul on (n, 3, r) stacks). The tangent projection (CPU ms): 1661 poses
# 0.66 / 0.17, 125: 0.065 / 0.050, 80: 0.048 / 0.040, 40: 0.035 / 0.040, 20: 0.024 / 0.038.
# 50 poses: the sparse problems (3n >= _DENSE_BELOW) take fields, the dense ones stacks.
_FIELDS_FROM = _DENSE_BELOW // 3
# Poses from which the rank-3 retraction is Newton's: steps of 0.3 rad (CPU ms, SVD /
# Newton) 125 poses 0.52 / 0.85, 300: 1.15 / 0.97, 600: 2.30 / 1.13, 1661: 6.3 / 1.5.
_NEWTON_FROM = 250
# Poses from which the trust region's rank-3 trial point X + V (V tangent) is retracted in
# closed form (Stiefel.move; below _NEWTON_FROM). Tangent steps of 0.3 (CPU ms, closed form
# / SVD): 15 poses 0.137 / 0.077, 30: 0.163 / 0.121, 40: 0.142 / 0.153, 125: 0.227 / 0.491,
# 249: 0.309 / 0.940; the same points to 1e-14 for steps from 1e-6 to 5.
_CLOSED_FROM = 40
# Rows of Q below which the trust region starts from Newton's point (S verified there first,
# see SpatialProblem.verified_shortcut). The rank-3 trust region from the chordal estimate
# against Newton's steps and then the trust region (which stops at once), CPU ms:
# tinyGrid3D 2.37 / 1.09; generated graphs (tests' _exact_graph, noise 0.1) of 20 poses
# 2.67 / 0.99, 30: 3.86 / 1.26, 45: 5.38 / 3.36; smallGrid3D (125 poses: damped steps from
# its chordal estimate, a 372-row Hessian each) 14.4 / 27. Newton's dense Hessian costs
# (3n)^3 a step: its products, not the per-call overhead, rule above this size.
_NEWTON_BELOW = _DENSE_BELOW
# With ranges, a truncated CG run of this many Hessian products switches to the Hessian's own
# preconditioner (S + delta I, where positive definite): a range's direction is held by
# multipliers about as large as its terms in Q, which Q + delta I leaves out.
_RANGE_HESSIAN_AFTER = 10


def _stack(rotations: np.ndarray) -> np.ndarray:
    """(3n, 3) the blocks ``X_i = R_i^T`` stacked."""
    return np.transpose(rotations, (0, 2, 1)).reshape(-1, 3)


def _checked_rotations(rotations: np.ndarray, n: int) -> np.ndarray:
    rotations = np.asarray(rotations, dtype=float)
    if rotations.shape != (n, 3, 3):
        raise SolverError(f"rotations must have shape ({n}, 3, 3), got {rotations.shape}")
    if not np.all(np.isfinite(rotations)):
        raise SolverError("rotations must be finite")
    return rotations


# --- the problem ---------------------------------------------------------------------------

def _blocks(rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> tuple:
    """COO entries of 3x3 blocks ``values`` (k, 3, 3) at block rows/cols (k,)."""
    a = np.arange(3)
    r = (3 * rows[:, None, None] + a[None, :, None]) + 0 * a[None, None, :]
    c = (3 * cols[:, None, None] + a[None, None, :]) + 0 * a[None, :, None]
    return values.ravel(), r.ravel(), c.ravel()


def _add_diagonal_blocks(matrix: np.ndarray, n: int, blocks: np.ndarray) -> None:
    """Add ``blocks`` ((n, 3, 3), or what broadcasts to it) to the 3x3 diagonal blocks of the
    dense, C-ordered (3n, 3n) ``matrix``, in place."""
    matrix.reshape(n, 3, n, 3)[np.arange(n), :, np.arange(n), :] += blocks


class SpatialProblem(Relaxation):
    """Q = D - B^T L^-1 B applied as an operator on (3n, r) arrays.

    ``D``: the rotations' connection Laplacian (blocks ``kappa I`` on the diagonal,
    ``-kappa R~`` at (i, j)) plus ``tau t~ t~^T`` at (i, i) of each edge; ``L``: the
    tau-weighted translation Laplacian without the anchor; ``B`` ((n-1) x 3n): the coupling
    of the residual ``t_j - t_i - R_i t~`` (rows without the anchor).
    """

    pose_graph: PoseGraph3D
    lowest_rank = SE3.lowest_rank
    # 1e-7 cost cubicle and torus a last step that changed nothing: on SE-Sync's seven files
    # the status and chi2 after LM30 agree to 11 digits at 1e-6 (at 1e-5, parking-garage's
    # chi2 moved in the 7th)
    gradient_tolerance = 1e-6

    def __init__(self, pose_graph: PoseGraph3D) -> None:
        super().__init__(pose_graph)
        # a range's direction is the first row of a block of its own (CORA's unit vector as
        # a 3x3 block, so every block stays a point of St(3, r)); no term measures its other
        # two rows
        if pose_graph.ranges is not None:
            self.flat = self._flat_rows()
        self.dense = 3 * self.n < max(_DENSE_Q_BELOW, _DENSE_BELOW)
        self._layout: tuple[sp.csc_matrix, np.ndarray, np.ndarray] | None = None
        self._order: np.ndarray | None = None  # the first sparse factor's elimination order
        # a dense problem's connection Laplacian of the rotation terms (D without the tau
        # t~ t~^T blocks): the chordal estimate's matrix (chordal_rotations' connection)
        self.connection: np.ndarray | None = None
        if self.dense:
            self._set_up_dense(pose_graph, self.kappa, self.tau)
        else:
            self._set_up_sparse(pose_graph, self.kappa, self.tau)
        if not self.scale > 0:
            raise SolverError("every edge has zero information: nothing to synchronize")

    def _set_up_dense(self, g: PoseGraph3D, kappa: np.ndarray, tau: np.ndarray) -> None:
        """Q, the connection Laplacian and the scale as dense matrices, each edge's terms
        scattered as one block: ``kappa [[I, -R~], [-R~^T, I]]`` on ``(X_i, X_j)`` into the
        connection Laplacian, ``tau v v^T`` (``v = (-t~, -1, 1)``) on ``(X_i, t_i, t_j)`` into
        the translation terms' matrix over ``(X, t)``, the anchor's translation last; that
        matrix's blocks are the ``tau t~ t~^T`` sums on D's diagonal, ``-B^T`` and ``L``
        (the anchor's row and column left out). ``Q = D - W^T W`` with ``W = C^-1 B``, ``C
        C^T = L`` (LAPACK's Cholesky and triangular solve)."""
        size, nodes = 3 * self.n, self.translation_nodes
        i, j = g.edges[:, 0], g.edges[:, 1]
        m = len(i)
        at = np.concatenate([3 * i[:, None] + _AXES, 3 * j[:, None] + _AXES], axis=1)
        rotation = np.empty((m, 6, 6))
        rotation[:, :3, :3] = rotation[:, 3:, 3:] = _EYE
        rotation[:, :3, 3:] = -g.measured_rotations
        rotation[:, 3:, :3] = -np.transpose(g.measured_rotations, (0, 2, 1))
        rotation *= kappa[:, None, None]
        self.connection = np.bincount((at[:, :, None] * size + at[:, None, :]).ravel(),
                                      weights=rotation.ravel(),
                                      minlength=size * size).reshape(size, size)
        # the edges' translation terms and the landmarks' and ranges' (translation nodes
        # num_poses.., unit rows c)
        pose, node, turn, weight, measured = self.extra_terms()
        turned = np.concatenate([i, turn])
        i, j = np.concatenate([i, pose]), np.concatenate([j, node])
        tau = np.concatenate([tau, weight])
        column = np.arange(nodes) - (np.arange(nodes) > g.anchor)  # t's columns, anchor's last
        column[g.anchor] = nodes - 1
        at = np.concatenate([3 * turned[:, None] + _AXES, size + column[i][:, None],
                             size + column[j][:, None]], axis=1)
        v = np.concatenate([-np.concatenate([g.measured_translations, measured]),
                            _STEP.repeat(len(i), axis=0)], axis=1)
        translation = (tau[:, None, None] * v[:, :, None]) * v[:, None, :]
        terms = np.bincount((at[:, :, None] * (size + nodes) + at[:, None, :]).ravel(),
                            weights=translation.ravel(),
                            minlength=(size + nodes) ** 2).reshape(size + nodes, size + nodes)
        lower, info = potrf(terms[size:-1, size:-1])
        if info != 0:
            raise SolverError("the measurements do not determine the translations")
        w = trtrs(lower, terms[size:-1, :size])
        self.q = w.T @ w
        np.subtract(self.connection, self.q, out=self.q)
        self.q += terms[:size, :size]
        first = 3 * int(g.world_frame)  # a world frame's weights are its FIX lines' and priors'
        end = 3 * self.num_poses  # the poses' rows: a range's own rows hold no rotation term
        self.scale = float(np.sum(np.diagonal(self.connection)[first:end])
                           + np.sum(np.diagonal(terms)[first:end])) / (end - first)

    def _set_up_sparse(self, g: PoseGraph3D, kappa: np.ndarray, tau: np.ndarray) -> None:
        """D, L, B (and its transpose) as sparse matrices, L's LU."""
        import scipy.sparse as sp  # the sparse problems' only (a dense one needs no more
        from scipy.sparse.linalg import splu  # of scipy than scipy.linalg's LAPACK)

        n, nodes = self.n, self.translation_nodes
        i, j = g.edges[:, 0], g.edges[:, 1]
        eye = np.broadcast_to(np.eye(3), (len(i), 3, 3))
        # the edges' translation terms and the landmarks' and ranges' (translation nodes
        # num_poses.., unit rows c)
        pose, node, turn, weight, measured = self.extra_terms()
        t = np.concatenate([g.measured_translations, measured])
        tau_all = np.concatenate([tau, weight])
        anchored = tau_all[:, None, None] * t[:, :, None] * t[:, None, :]  # tau t~ t~^T at (i, i)
        m = len(i)
        parts = [
            _blocks(i, i, kappa[:, None, None] * eye + anchored[:m]),
            _blocks(j, j, kappa[:, None, None] * eye),
            _blocks(i, j, -kappa[:, None, None] * g.measured_rotations),
            _blocks(j, i, -kappa[:, None, None] * np.transpose(g.measured_rotations, (0, 2, 1))),
            _blocks(turn, turn, anchored[m:]),
        ]
        turned = np.concatenate([i, turn])
        i, j, tau = np.concatenate([i, pose]), np.concatenate([j, node]), tau_all
        data, rows, cols = (np.concatenate(p) for p in zip(*parts, strict=True))
        keep = np.delete(np.arange(nodes), g.anchor)
        cols3 = (3 * turned[:, None] + np.arange(3)).ravel()
        matrices = [
            ((data, (rows, cols)), (3 * n, 3 * n)),  # D
            ((np.concatenate([tau, tau, -tau, -tau]),  # the translation Laplacian
              (np.concatenate([i, j, i, j]), np.concatenate([i, j, j, i]))), (nodes, nodes)),
            ((np.concatenate([(tau[:, None] * t).ravel(), -(tau[:, None] * t).ravel()]),
              (np.concatenate([np.repeat(j, 3), np.repeat(i, 3)]),  # the coupling
               np.concatenate([cols3, cols3]))), (nodes, 3 * n)),
        ]
        d, lap, coupling = (sp.coo_matrix(entries, shape=shape).tocsr()
                            for entries, shape in matrices)
        self.d = d
        self.lap = lap[keep][:, keep].tocsc()
        self.b = coupling[keep].tocsr()
        self.bt = self.b.T.tocsr()
        try:
            self.lap_lu = splu(self.lap, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
        except RuntimeError:
            raise SolverError("the measurements do not determine the translations") from None
        self.scale = float(np.mean(self.d.diagonal()[3 * int(g.world_frame):3 * self.num_poses]))

    def decoupled(self, lam: np.ndarray) -> np.ndarray:
        """A range's block of multipliers ``diag(mu, 0, 0)`` with its ``mu``: the rest of
        ``sym((Q X)_c X_c^T)`` is the direction's coupling to the two free rows, zero once
        the gradient is; any symmetric multipliers bound the relaxation from below."""
        if self.flat is None:
            return lam
        lam = lam.copy()
        lam[self.num_poses:, 0, 1:] = lam[self.num_poses:, 1:, 0] = 0.0
        lam[self.num_poses:, 1:, 1:] = 0.0
        return lam

    def conditioned(self, blocks: np.ndarray) -> np.ndarray:
        """A range's free rows weighted as its direction is (``w r^2``), on top of the
        shift: ``Q`` is zero there, and the truncated CG would take long steps along them."""
        ranges = self.pose_graph.ranges
        if ranges is None:
            return blocks
        blocks = np.array(np.broadcast_to(blocks, (self.n, 3, 3)))
        weight = ranges.weights * ranges.measured ** 2
        blocks[self.num_poses:, 1, 1] += weight
        blocks[self.num_poses:, 2, 2] += weight
        return blocks

    def _flat_rows(self) -> np.ndarray:
        """The second and third rows of each range's block (no term measures them)."""
        ranges = self.pose_graph.ranges
        first = 3 * (self.num_poses + np.arange(0 if ranges is None else ranges.count))
        return np.concatenate([first + 1, first + 2])

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Q x for x (3n, r)."""
        if self.dense:
            return self.q @ x
        w = self.lap_lu.solve(np.ascontiguousarray(self.b @ x))
        return self.d @ x - self.bt @ w

    def cost(self, x: np.ndarray) -> float:
        return float(np.sum(x * self.apply(x)))

    def factor(self, blocks: np.ndarray):
        """Pivot-free sparse LU of [[L, -B], [-B^T, D + M]], M block diagonal of (n, 3, 3)
        ``blocks``: its Schur complement is Q + M. A dense problem's: the inverse of Q + M
        (from its Cholesky factor; RuntimeError where Q + M is not positive definite, as the
        LU's on a zero pivot); it only preconditions, as S is then verified densely."""
        if self.dense:
            shifted = self.q.copy()
            _add_diagonal_blocks(shifted, self.n, blocks)
            if 3 * self.n >= _DENSE_BELOW:
                # factored in place: the transpose of the symmetric C-ordered copy is the
                # same matrix in Fortran order (cho_factor copies it again: smallGrid3D's
                # factor 2.85 ms CPU against 1.4)
                lower, info = potrf(shifted.T, overwrite=True)
                if info != 0:
                    raise RuntimeError("not positive definite")
                return DenseCholesky(lower)
            try:
                inverse = np.linalg.inv(np.linalg.cholesky(shifted))
            except np.linalg.LinAlgError:
                raise RuntimeError("not positive definite") from None
            return inverse.T @ inverse
        import scipy.sparse as sp
        from scipy.sparse.linalg import splu

        if self._layout is None:
            self._layout = self._block_layout()
        base, where, in_d = self._layout
        data = base.data.copy()
        data[where] += np.asarray(blocks, float).ravel()
        kept = ~(in_d & (data == 0))  # D + M's zeros left out, as sparse addition leaves them
        if kept.all():
            block = sp.csc_matrix((data, base.indices, base.indptr), shape=base.shape)
        else:
            indptr = np.concatenate([[0], np.cumsum(kept)])[base.indptr]
            block = sp.csc_matrix((data[kept], base.indices[kept], indptr), shape=base.shape)
        if self._order is None:
            lu = splu(block, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
            self._order = np.argsort(lu.perm_c)
            return lu
        order = self._order
        return _Reordered(splu(block[order][:, order].tocsc(), permc_spec="NATURAL",
                               diag_pivot_thresh=0.0, options={"SymmetricMode": True}),
                          order, np.argsort(order))

    def _block_layout(self) -> tuple[sp.csc_matrix, np.ndarray, np.ndarray]:
        """``[[L, -B], [-B^T, D]]`` with the block diagonal of D's rows stored (explicit
        zeros where D has none), the positions in its data of those blocks' entries in
        :func:`_blocks` order (a shift is added there, without building the matrix again),
        and which of its entries lie in the D block."""
        import scipy.sparse as sp

        m, index = self.translation_nodes - 1, np.arange(self.n)
        _, rows, cols = _blocks(index, index, np.zeros((self.n, 3, 3)))
        marks = np.arange(1.0, len(rows) + 1.0)
        stacked = sp.bmat([[self.lap, -self.b], [-self.bt, self.d]], format="coo")
        entries = (np.concatenate([stacked.row, rows + m]),
                   np.concatenate([stacked.col, cols + m]))
        shape = stacked.shape
        base = sp.coo_matrix((np.concatenate([stacked.data, np.zeros(len(rows))]), entries),
                             shape=shape).tocsc()
        marked = sp.coo_matrix((np.concatenate([np.zeros(len(stacked.data)), marks]), entries),
                               shape=shape).tocsc()
        where = np.empty(len(rows), np.int64)
        mask = marked.data > 0
        where[(marked.data[mask] - 1).astype(np.int64)] = np.flatnonzero(mask)
        columns = np.repeat(np.arange(shape[1]), np.diff(base.indptr))
        return base, where, (base.indices >= m) & (columns >= m)

    def solve_shifted(self, lu: Any, v: np.ndarray) -> np.ndarray:
        if self.dense:
            return lu @ v if isinstance(lu, np.ndarray) else lu.solve(v)
        m = self.translation_nodes - 1
        return lu.solve(np.vstack([np.zeros((m, v.shape[1])), v]))[m:]

    # --- the driver's questions (see Relaxation) --------------------------------------------

    def manifold(self) -> Stiefel:
        if self.pose_graph.ranges is None:
            return manifold()
        return replace(manifold(), hessian_preconditioner_after=_RANGE_HESSIAN_AFTER)

    def start(self, rotations: np.ndarray | None) -> np.ndarray:
        """The given ``rotations``' blocks, or the chordal estimate's (a dense problem's
        through its own connection Laplacian)."""
        if rotations is not None:
            return self.given(rotations)
        connection = self.connection
        if connection is not None and self.pose_graph.ranges is not None:
            connection = connection[:3 * self.num_poses, :3 * self.num_poses]
        return self.given(chordal_rotations(self.pose_graph, connection))

    def given(self, rotations: np.ndarray) -> np.ndarray:
        """The blocks of the poses' ``rotations`` (num_poses, 3, 3), then each range's: a
        rotation whose first column is the range's direction in the values the graph came
        with (poses and points)."""
        rotations = _checked_rotations(rotations, self.num_poses)
        if self.pose_graph.ranges is not None:
            rotations = np.concatenate([rotations, _frames(self.range_steps())])
        return _stack(rotations)


    def verified_shortcut(self, manifold: Manifold, x: np.ndarray, eta: float,
                          grad_tol: float, deadline: float | None, progress: Progress
                          ) -> tuple[np.ndarray, Check | None]:
        """Below :data:`_NEWTON_BELOW` rows of a dense problem started at rank 3: the point
        Newton's method reaches (:func:`~rlpgo_gtsam.relaxation.newton.newton_point`), where
        the trust region would stop at once (the gradient test passed in the same
        arithmetic), and its check where it certifies: the staircase's check and progress
        line without its trust region's set-up. Where Newton's method stops short or ``S``
        is not positive semidefinite, the staircase runs from its point."""
        if not (self.dense and 3 * self.n < _NEWTON_BELOW and x.shape[1] == 3) \
                or self.pose_graph.ranges is not None:  # a range's block turns freely about
            return x, None  # its direction: Newton's Hessian is singular there
        x, converged = newton_point(self, x, grad_tol, self.pose_graph.anchor, deadline)
        return x, (_verified_at_once(self, manifold, x, eta, progress) if converged else None)

    def rounded(self, y: np.ndarray) -> np.ndarray:
        return _round(y, self.num_poses)

    def stacked(self, rotations: np.ndarray) -> np.ndarray:
        return _stack(rotations)

    def unstacked(self, y: np.ndarray) -> np.ndarray:
        """The rotations of rank-3 blocks, each projected onto SO(3)."""
        return project_to_so3(np.transpose(y.reshape(-1, 3, 3), (0, 2, 1)))

    def anchored(self, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = self.pose_graph
        rotations = g.anchor_rotation @ rotations[g.anchor].T @ rotations
        return rotations, _stack(rotations)


class _Reordered:
    """A pivot-free LU of the matrix permuted symmetrically by ``order`` (the elimination
    order MMD found for the problem's first factor of the same pattern: the later ones skip
    the ordering, about a fifth of a factorization on torus3D), solving in the matrix's own
    order. A symmetric permutation keeps the inertia its pivots give."""

    def __init__(self, lu: Any, order: np.ndarray, inverse: np.ndarray) -> None:
        self.lu, self.order, self.inverse = lu, order, inverse

    def solve(self, b: np.ndarray) -> np.ndarray:
        return self.lu.solve(b[self.order])[self.inverse]


def _verified_at_once(problem: SpatialProblem, manifold: Manifold, x: np.ndarray, eta: float,
                      progress: Progress) -> Check | None:
    """The staircase's check of a rank-3 ``x`` at which its trust region would stop at once,
    and its progress line, where it certifies; None where it does not."""
    check = verify(problem, manifold, x, eta)
    if not check.certified:
        return None
    if progress.progress is not None:
        qx = problem.apply(x)
        run = Run()
        run.iterations, run.cost = 0, manifold.inner(x, qx)
        run.gradient = float(np.linalg.norm(manifold.gradient(x, qx)))
        progress.rank(3, run, check)
    return check


# --- the product of Stiefel manifolds St(3, r)^n ------------------------------------------

class Stiefel(Manifold):
    """3 x r blocks ``X_i`` with orthonormal rows: the staircase's manifold in 3D; the
    multipliers are the blocks ``Lambda_i = sym((Q X)_i X_i^T)`` (n, 3, 3). From
    :data:`_FIELDS_FROM` poses the blockwise products run on fields
    (:func:`~rlpgo_gtsam.relaxation.blocks.to_fields`)."""

    def size(self, n: int) -> int:
        return 3 * n

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        return float((a * b).sum())

    def project(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """V_i - sym(V_i X_i^T) X_i."""
        r = x.shape[1]
        if x.shape[0] >= 3 * _FIELDS_FROM:
            return from_fields(projected_fields(to_fields(x), to_fields(v)))
        xb, vb = x.reshape(-1, 3, r), v.reshape(-1, 3, r)
        return (vb - sym(vb @ xb.transpose(0, 2, 1)) @ xb).reshape(-1, r)

    def retract(self, x: np.ndarray) -> np.ndarray:
        """Each 3 x r block replaced by its polar factor (orthonormal rows): at rank 3 from
        :data:`_NEWTON_FROM` poses by Newton's iteration
        (:func:`~rlpgo_gtsam.relaxation.blocks.polar_newton`), else by the SVD."""
        if x.shape[1] == 3 and x.shape[0] >= 3 * _NEWTON_FROM:
            return polar_newton(x)
        return polar_svd(x)

    def move(self, x: np.ndarray, step: np.ndarray) -> np.ndarray:
        """At rank 3 from :data:`_CLOSED_FROM` to :data:`_NEWTON_FROM` poses, the polar
        factor of ``X + V`` in closed form: a tangent ``V_i = W_i X_i`` (``W_i = [w_i]_x``)
        makes ``X_i + V_i = (I + W_i) X_i``, whose polar factor is ``Exp(atan|w_i| / |w_i|
        w_i) X_i``; else :meth:`retract` of ``X + V``."""
        if x.shape[1] != 3 or not 3 * _CLOSED_FROM <= x.shape[0] < 3 * _NEWTON_FROM:
            return self.retract(x + step)
        xb = x.reshape(-1, 3, 3)
        turn = step.reshape(-1, 3, 3) @ xb.transpose(0, 2, 1)  # W_i, up to round-off
        w = 0.5 * vee(turn - turn.transpose(0, 2, 1))
        theta = np.linalg.norm(w, axis=1)
        scale = np.arctan(theta) / np.where(theta > 0, theta, 1.0)
        scale[theta == 0] = 1.0
        return (exp_so3(scale[:, None] * w) @ xb).reshape(-1, 3)

    def multipliers(self, x: np.ndarray, qx: np.ndarray) -> np.ndarray:
        r = x.shape[1]
        if x.shape[0] >= 3 * _FIELDS_FROM:
            a = np.einsum("ikn,jkn->nij", to_fields(qx), to_fields(x))
            return sym(a)
        xb, qb = x.reshape(-1, 3, r), qx.reshape(-1, 3, r)
        return sym(qb @ xb.transpose(0, 2, 1))

    def times(self, lam: np.ndarray, v: np.ndarray) -> np.ndarray:
        r = v.shape[1]
        if v.shape[0] >= 3 * _FIELDS_FROM:
            return from_fields(np.einsum("nij,jkn->ikn", lam, to_fields(v)))
        return (lam @ v.reshape(-1, 3, r)).reshape(-1, r)

    def hessian(self, x, lam, v, qv) -> np.ndarray:
        if x.shape[0] >= 3 * _FIELDS_FROM:
            fields = to_fields(qv) - np.einsum("nij,jkn->ikn", lam, to_fields(v))
            return 2.0 * from_fields(projected_fields(to_fields(x), fields))
        return 2.0 * self.project(x, qv - self.times(lam, v))

    def diagonal(self, n: int, value: float) -> np.ndarray:
        return np.broadcast_to(value * np.eye(3), (n, 3, 3))

    def shift(self, lam: np.ndarray, sigma: float) -> np.ndarray:
        return -lam - sigma * np.eye(3)

    def trace(self, lam: np.ndarray) -> float:
        return float(np.trace(lam, axis1=1, axis2=2).sum())

    def largest(self, lam: np.ndarray) -> float:
        return float(np.linalg.eigvalsh(lam)[:, -1].max())

    def start(self, x: np.ndarray) -> np.ndarray:
        """X's first column: ``S X = 0`` at a critical point, so where ``S >= 0`` it is an
        eigenvector of ``lambda_min(S)`` and ARPACK starts on it (21 to 3 shift-invert
        solves on cubicle, and the same answer at every call)."""
        return x[:, 0]

    def superlu(self, factor: Any) -> Any:
        return factor.lu if isinstance(factor, _Reordered) else factor

    def negative_pivots(self, factor: Any) -> int | None:
        """A dense factor (a :class:`~rlpgo_gtsam.linear.DenseCholesky` from
        :data:`_DENSE_BELOW` rows, where its two triangular solves cost less than products
        with the explicit inverse; below, the inverse) is made only where the matrix is
        positive definite."""
        if isinstance(factor, (DenseCholesky, np.ndarray)):
            return 0
        return super().negative_pivots(factor)

    def dense(self, problem: SpatialProblem, lam: np.ndarray) -> np.ndarray:
        """S: a dense problem's Q less the blocks Lambda_i on its diagonal, in one indexed
        subtraction (a loop over the poses took 54 us of tinyGrid3D's, this 15 us)."""
        n = problem.n
        s = problem.q.copy() if problem.dense else problem.apply(np.eye(3 * n))
        _add_diagonal_blocks(s, n, -lam)
        return s


def manifold() -> Stiefel:
    """The spatial staircase's manifold and settings: this module's constants, read at each
    call."""
    return Stiefel(dense_below=_DENSE_BELOW, preconditioner_shift=_PRECONDITIONER_SHIFT,
                   initial_radius=_INITIAL_RADIUS, cg_floor=_CG_FLOOR)


# --- rounding -------------------------------------------------------------------------------

def _round(x: np.ndarray, poses: int | None = None) -> np.ndarray:
    """(n, 3, 3) rotations: rank-3 SVD, reflection rule, projection onto SO(3). At rank 3
    with every block a rotation (the staircase's from an SO(3) start: its retractions keep
    the sign of each determinant) the blocks' transposes are returned as they are: the SVD
    route gives ``V^T X_i^T`` (one orthogonal ``V`` for all), the same rotations once the
    anchor is turned back (to 2e-15 on tinyGrid3D, smallGrid3D and parking-garage; CPU ms,
    the SVD route against the blocks kept: 0.19 / 0.03, 0.77 / 0.07 and 7.8 / 0.6). With
    ranges (blocks after the first ``poses``), their directions are read in the subspace
    of the poses' rows."""
    if x.shape[1] == 3:
        blocks = np.transpose(x.reshape(-1, 3, 3), (0, 2, 1))
        if (np.linalg.det(blocks) > 0).all():
            return blocks.copy()
    poses = len(x) // 3 if poses is None else poses
    if len(x) == 3 * poses:
        u, s, _ = np.linalg.svd(x, full_matrices=False)
        scaled = u[:, :3] * s[:3]  # U_i S
    else:
        # the poses' rows alone: a range's second and third rows are free, and its first
        # (the direction) is read in the poses' subspace: X_i V = U_i S
        scaled = x @ np.linalg.svd(x[:3 * poses], full_matrices=False)[2][:3].T
    blocks = np.transpose(scaled.reshape(-1, 3, 3), (0, 2, 1))  # R_i = (U_i S)^T
    if np.count_nonzero(np.linalg.det(blocks[:poses]) > 0) < 0.5 * poses:
        blocks = _REFLECT @ blocks
    if len(blocks) == poses:
        return project_to_so3(blocks)
    return np.concatenate([project_to_so3(blocks[:poses]), _frames(blocks[poses:, :, 0])])


def _frames(directions: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations whose first columns are ``directions`` (k, 3) normalized (the x
    axis where one is zero)."""
    size = np.linalg.norm(directions, axis=1)
    first = np.where(size[:, None] > 1e-300, directions / np.maximum(size, 1e-300)[:, None],
                     _EYE[0])
    # the axis least aligned with the direction, made orthogonal to it
    other = _EYE[np.argmin(np.abs(first), axis=1)]
    second = other - np.sum(other * first, axis=1)[:, None] * first
    second /= np.linalg.norm(second, axis=1)[:, None]
    return np.stack([first, second, np.cross(first, second)], axis=2)
