"""The planar relaxation: SE(2) synchronization in CPL-SLAM's complex form (SE-Sync in 2D).

What it solves. Each orientation is a unit complex number ``z_i = exp(i theta_i)``, each
position a complex number ``t_i``, each measurement ``r_e = exp(i theta~_e)``,
``c_e = dx_e + i dy_e``. The relaxation's cost (SE-Sync's, Rosen et al. IJRR 2019, eq. 11, in
the complex form of CPL-SLAM, Fan et al. T-RO 2020) is::

    F(z, t) = sum_e  kappa_e ||R_j - R_i R~_e||_F^2  +  tau_e |t_j - t_i - z_i c_e|^2
            = sum_e  2 kappa_e |z_j - z_i r_e|^2      +  tau_e |t_j - t_i - z_i c_e|^2

with ``kappa_e = information[2, 2]`` (the conditional rotational information, the project's
one rotation weight) and the isotropic ``tau_e = 2 / trace(information[:2, :2]^-1)`` (SE-Sync's
choice for g2o files: the isotropic weight closest to the 2x2 translational information in
information divergence; it keeps the cost quadratic, which an anisotropic 2x2 weight in the
world frame would not). Minimizing over the translations in closed form leaves
``f(z) = min_t F(z, t) = z^H Q z`` with ``Q`` the Schur complement of the anchored
translation Laplacian (never formed: applied through one sparse factorization).

How it differs from GTSAM's cost (g2o chi2 = 2 x GTSAM error):

- the rotation error is chordal, ``||R_j - R_i R~||_F^2 = 8 sin^2(r / 2)``, not geodesic
  ``r^2``, and it carries ``kappa``, not ``kappa / 2``: for small angle errors ``r`` an edge's
  rotation term is ``2 kappa r^2``, twice its chi2 term ``kappa r^2``;
- the translation weight is isotropic: for an isotropic translational information ``tau I``
  the term equals the chi2 term, for an anisotropic one it is the isotropic stand-in above;
- there are no x/y-theta cross terms (``information[:2, 2]`` is ignored).

So the relaxation's cost is about chi2 plus the rotational part of chi2 again near a good
estimate, and its optimum is not a minimum of chi2: refine the rounded estimate with GTSAM.

How (the staircase of :mod:`~rlpgo_gtsam.relaxation.staircase`). The semidefinite relaxation
``min tr(Q X), X >= 0, X_ii = 1`` (X Hermitian) is solved in Burer-Monteiro form ``X = Y Y^H``,
``Y`` n x r complex with unit rows, by a Riemannian staircase: at each rank a Riemannian trust
region with truncated, preconditioned CG; then the certificate ``S = Q - Lambda`` with ``Lambda =
diag(Re(diag(Q Y Y^H)))``: the rank's critical point is a global optimum of the relaxation
iff ``S >= 0``. This is tested exactly in the sparse domain: ``S + eta I`` is positive definite
iff the sparse Hermitian matrix ``[[L, -B], [-B^H, D - Lambda + eta I]]`` (whose Schur
complement is ``S + eta I``) has only positive pivots in a symmetric, pivot-free LU. If it
fails, the staircase escapes the saddle along the eigenvector of ``lambda_min(S)`` into rank
r + 1. A rank whose trust region stalls (its last 10 iterations lowered the cost by less than 1%
of the certificate's resolution ``n eta``) is verified where it stands: the bound below holds
at any ``Y``. The solution is rounded (leading left singular vector of Y, each entry projected
onto the unit circle); if the staircase ended above rank 1 the rounded ``z`` is then polished
by the trust region at rank 1 (a local descent of ``f(z)``, not in SE-Sync: where the
relaxation is not exact the projection can land far uphill), and the gauge fixed so the anchor
keeps its angle. Complex rank 1 is the rotation problem itself (SE-Sync's real rank r = d = 2
without reflections); complex rank r matches SE-Sync's real rank 2r.

Certificate (:mod:`~rlpgo_gtsam.relaxation.certificate`): ``rows`` is ``n`` here. The
tolerance ``eta`` defaults to ``1e-7 x mean(diag Q)`` (``diag Q`` is each pose's summed
weight; the relative 1e-7 sits well above the eigen-solver's round-off at that scale and keeps
``n eta`` below ``1e-7 tr(Q)``).

Poses other than the anchor that a hard prior holds are not held by the relaxation; the
translation step that follows it holds them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import SuperLU, splu

from rlpgo_gtsam.chordal import chordal_rotations
from rlpgo_gtsam.errors import GraphError, SolverError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.groups import SE2
from rlpgo_gtsam.relaxation.problem import (
    ARPACK_OPTIONS,
    ESCAPE_HALVINGS,
    Manifold,
    Relaxation,
    negative_pivots,
)
from rlpgo_gtsam.se2 import wrap

__all__ = ["PlanarProblem", "Circles", "manifold"]

_DENSE_BELOW = 300  # graphs with fewer poses get dense eigenvalue computations
_ARPACK_OPTIONS = ARPACK_OPTIONS  # ARPACK's settings besides k, which, v0 and tol
_ESCAPE_HALVINGS = ESCAPE_HALVINGS  # step halvings an escape from a saddle tries
# (Q + delta I)^-1 preconditions the Hessian, delta = an upper bound on ||Q|| over this number
# minus 1 (SE-Sync's regularized Cholesky preconditioner: condition number at most 1e6). A
# shift of 1e-3 mean(diag Q) leaves the Laplacian's lowest modes unpreconditioned: truncated
# CG then runs 100-200 iterations per step on large easy graphs.
_PRECONDITIONER_CONDITION = 1e6
# A truncated CG run of this many Hessian products or more switches the trust region to the
# Hessian's own preconditioner (at rank 1 the tangent Hessian's factor, above it that of
# S + delta I), refactored at each new Y while positive definite: Q + delta I leaves out
# Lambda, which on long easy graphs outweighs Q's lowest modes (20k poses: 935 Hessian
# products, 75 this way). A factor costs about 15 solves, so short runs keep the shared one.
_HESSIAN_PRECONDITIONER_AFTER = 10
# The tangent Hessian's factor at rank 1 holds A + delta I, delta this times mean(diag Q):
# A is singular along the rotation gauge only, and SE-Sync's condition-1e6 delta would sit
# above the lowest modes of long graphs (20k poses: 117 products instead of 75).
_TANGENT_SHIFT = 1e-10


# --- the problem ---------------------------------------------------------------------------

class PlanarProblem(Relaxation):
    """Q = D - B^H L^-1 B applied as an operator; sparse factorizations of its pieces.

    ``L`` is the tau-weighted translation Laplacian without the anchor's row and column,
    ``B`` (n-1 x n) the translation-rotation coupling, ``D`` the rotations' connection
    Laplacian plus the diagonal ``sum tau |c|^2`` over each pose's outgoing edges.
    """

    pose_graph: PoseGraph2D
    lowest_rank = SE2.lowest_rank
    gradient_tolerance = 1e-9

    def __init__(self, pose_graph: PoseGraph2D) -> None:
        super().__init__(pose_graph)
        g, n, kappa, tau = pose_graph, self.n, self.kappa, self.tau
        if np.any(kappa < 0) or np.any(tau < 0):
            raise GraphError("the relaxation needs non-negative rotational information and a "
                             "positive semidefinite translational information on every edge")
        i, j = g.edges[:, 0], g.edges[:, 1]
        r = np.exp(1j * g.measured[:, 2])
        c = g.measured[:, 0] + 1j * g.measured[:, 1]
        a = 2.0 * kappa
        rows, cols = np.concatenate([i, j, j, i]), np.concatenate([i, j, i, j])
        rot = sp.coo_matrix((np.concatenate([a, a, -a * r, -a * np.conj(r)]), (rows, cols)),
                            shape=(n, n)).tocsr()
        # landmarks and ranges (Relaxation.extra_terms): translation terms like an edge's,
        # without a rotation term; a range's unit row is its direction
        i, j, column, tau, c = self.translation_terms(i, j, tau, c)
        size = self.translation_nodes
        diag = sp.coo_matrix((tau * np.abs(c) ** 2, (column, column)), shape=(n, n)).tocsr()
        self.anchor = g.anchor
        self.rot = rot
        self.d = (rot + diag).tocsr()
        keep = np.delete(np.arange(size), g.anchor)
        rows, cols = np.concatenate([i, j, j, i]), np.concatenate([i, j, i, j])
        lap = sp.coo_matrix((np.concatenate([tau, tau, -tau, -tau]), (rows, cols)),
                            shape=(size, size)).tocsr()
        # residual t_j - t_i - c z_k: coupling -2 Re(t^H B z), B[j, k] += tau c, B[i, k] -= tau c
        coupling = sp.coo_matrix((np.concatenate([tau * c, -tau * c]),
                                  (np.concatenate([j, i]), np.concatenate([column, column]))),
                                 shape=(size, n)).tocsr()
        self.lap = lap[keep][:, keep].tocsc()
        self.b = coupling[keep].tocsr()
        self.bh = self.b.conj().T.tocsr()
        try:
            self.lap_lu = splu(self.lap, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
        except RuntimeError:
            raise SolverError("the measurements do not determine the translations (a pose "
                              "without translational information?)") from None
        # a one-anchor problem's world frame carries its FIX lines' and priors' weights; a
        # range's row carries w r^2, most of which its translations take back (Q's diagonal
        # is far below D's there): the poses' rows set the scale
        self.scale = float(np.mean(np.real(self.d.diagonal())[int(g.world_frame):
                                                              self.num_poses]))
        if not self.scale > 0:
            raise SolverError("every edge has zero information: nothing to synchronize")
        self._layout: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._tangent: tuple | None = None

    def translation_terms(self, i: np.ndarray, j: np.ndarray, tau: np.ndarray,
                          c: np.ndarray) -> tuple[np.ndarray, ...]:
        """The edges' translation terms (i, j, the unit row i, tau, c complex) and the
        landmarks' and ranges' after them (:meth:`Relaxation.extra_terms`)."""
        pose, node, column, weight, measured = self.extra_terms()
        return (np.concatenate([i, pose]), np.concatenate([j, node]),
                np.concatenate([i, column]), np.concatenate([tau, weight]),
                np.concatenate([c, measured[:, 0] + 1j * measured[:, 1]]))

    def _interleaved(self, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions in a block matrix of the translation rows (``width`` rows each) and of
        the rotation rows (n,): each pose's rotation row right after its translation's,
        landmarks' translations alone, in the translation Laplacian's fill-reducing order
        (its factor's column order), then the ranges' directions, the anchor's rotation
        last. SuperLU's own ordering of the whole block found the same fill at about twice
        the time."""
        poses = self.num_poses
        order = np.argsort(self.lap_lu.perm_c)  # translation rows in elimination order
        node = np.delete(np.arange(self.translation_nodes), self.anchor)[order]
        is_pose = node < poses
        span = width + is_pose
        start = np.concatenate([[0], np.cumsum(span)[:-1]])
        pos_t = np.empty(len(node), np.int64)
        pos_t[order] = start
        pos_z = np.empty(self.n, np.int64)
        pos_z[node[is_pose]] = start[is_pose] + width
        end = int(np.sum(span))  # the ranges' directions, then the anchor's rotation
        pos_z[poses:] = end + np.arange(self.n - poses)
        pos_z[self.anchor] = end + self.n - poses
        return pos_t, pos_z

    def apply(self, y: np.ndarray) -> np.ndarray:
        """Q y for y (n, r) complex: one solve of the translation Laplacian's factor with the
        real and imaginary parts of B y as 2r real right-hand sides (no copies besides)."""
        w = np.ascontiguousarray(self.b @ y)  # (n - 1, r) complex, as (n - 1, 2r) real re/im
        x = np.ascontiguousarray(self.lap_lu.solve(w.view(float))).view(complex)
        return self.d @ y - self.bh @ x

    def cost(self, y: np.ndarray) -> float:
        return float(np.real(np.vdot(y, self.apply(y))))

    def norm_bound(self) -> float:
        """``2 max diag D >= ||D|| >= ||Q||`` (D is a weighted Laplacian plus a non-negative
        diagonal, and ``Q = D - B^H L^-1 B <= D``)."""
        return 2.0 * float(np.max(np.real(self.d.diagonal())))

    def _block_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The sparse Hermitian ``[[L, -B], [-B^H, D]]`` (without the shift) as COO arrays in
        an order that eliminates each pose's translation and rotation together, poses in the
        translation Laplacian's own fill-reducing order (its factor's column order, anchor's
        rotation last); and the positions of the rotation rows. SuperLU's own ordering of the
        2n - 1 rows found the same fill at about twice the time."""
        pos_t, pos_z = self._interleaved(1)
        lap, b, d = self.lap.tocoo(), self.b.tocoo(), self.d.tocoo()
        rows = np.concatenate([pos_t[lap.row], pos_t[b.row], pos_z[b.col], pos_z[d.row]])
        cols = np.concatenate([pos_t[lap.col], pos_z[b.col], pos_t[b.row], pos_z[d.col]])
        data = np.concatenate([lap.data.astype(complex), -b.data, -np.conj(b.data), d.data])
        return rows, cols, data, pos_z

    def factor(self, shift: np.ndarray) -> _Shifted:
        """Pivot-free sparse LU of [[L, -B], [-B^H, D + diag(shift)]] in pose order (its
        Schur complement is Q + diag(shift)); RuntimeError on an exactly zero pivot."""
        if self._layout is None:
            self._layout = self._block_layout()
        rows, cols, data, pos_z = self._layout
        size = self.translation_nodes - 1 + self.n
        block = sp.coo_matrix((np.concatenate([data, shift.astype(complex)]),
                               (np.concatenate([rows, pos_z]), np.concatenate([cols, pos_z]))),
                              shape=(size, size)).tocsc()
        lu = splu(block, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
        return _Shifted(lu, pos_z)

    @staticmethod
    def solve_shifted(factor: _Shifted, v: np.ndarray) -> np.ndarray:
        return factor.solve(v)

    def hessian_preconditioner(self, manifold: Manifold, y: np.ndarray, lam: np.ndarray):
        """At rank 1 the exact inverse of the tangent Hessian (:meth:`tangent_factor`), else
        the factor of ``S + delta I`` (:meth:`Relaxation.hessian_preconditioner`); None
        where it is not positive definite."""
        if y.shape[1] > 1:
            return super().hessian_preconditioner(manifold, y, lam)
        factor = self.tangent_factor(y[:, 0], lam, _TANGENT_SHIFT * self.scale)
        return None if factor is None else factor.precondition

    def tangent_factor(self, z: np.ndarray, lam: np.ndarray, delta: float) -> _Tangent | None:
        """The rank-1 Hessian on the tangent space at unit ``z``, in angle coordinates
        (``v = i a z``, ``a`` real): ``2 A`` with ``A = Re(Z^H S Z)``, ``Z = diag(z)``,
        ``S = Q - Lambda``. With ``W = B Z = Wr + i Wi``, ``A`` is the Schur complement of
        the real symmetric ``[[L, 0, -Wr], [0, L, -Wi], [-Wr^T, -Wi^T, Re(Z^H D Z) -
        Lambda]]`` (x, y and angle of each pose together, poses in the translation
        Laplacian's order): that matrix with ``delta`` added to the angles' diagonal, in a
        pivot-free LU; None unless it is positive definite (``A`` is singular along the
        rotation gauge, and indefinite away from a minimum)."""
        if self._tangent is None:
            self._tangent = self._tangent_layout()
        rows, cols, pos_a, lap, b, d = self._tangent
        w = b.data * z[b.col]
        diagonal = np.real(np.conj(z[d.row]) * d.data * z[d.col])
        data = np.concatenate([lap.data, lap.data, -w.real, -w.real, -w.imag, -w.imag,
                               diagonal, delta - lam])
        size = 2 * (self.translation_nodes - 1) + self.n
        block = sp.coo_matrix((data, (rows, cols)), shape=(size, size)).tocsc()
        try:
            lu = splu(block, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                      options={"SymmetricMode": True})
        except RuntimeError:  # an exactly zero pivot
            return None
        return _Tangent(lu, pos_a, z) if negative_pivots(lu) == 0 else None

    def _tangent_layout(self) -> tuple:
        """The index arrays of :meth:`tangent_factor`'s matrix (its data in that order: L
        twice, -Wr twice, -Wi twice, Re(Z^H D Z), the diagonal), the angle rows' positions,
        and L, B and D as COO."""
        pos_x, pos_a = self._interleaved(2)
        pos_y = pos_x + 1
        lap, b, d = self.lap.tocoo(), self.b.tocoo(), self.d.tocoo()
        rows = np.concatenate([pos_x[lap.row], pos_y[lap.row], pos_x[b.row], pos_a[b.col],
                               pos_y[b.row], pos_a[b.col], pos_a[d.row], pos_a])
        cols = np.concatenate([pos_x[lap.col], pos_y[lap.col], pos_a[b.col], pos_x[b.row],
                               pos_a[b.col], pos_y[b.row], pos_a[d.col], pos_a])
        return rows, cols, pos_a, lap, b, d

    # --- the driver's questions (see Relaxation) --------------------------------------------

    def manifold(self) -> Circles:
        return manifold()

    def start(self, rotations: np.ndarray | None) -> np.ndarray:
        if rotations is not None:
            return self.given(rotations)
        return self.given(chordal_rotations(self.pose_graph))

    def given(self, rotations: np.ndarray) -> np.ndarray:
        """``z = exp(i theta)`` (n, 1) of the poses' angles (poses,), then each range's
        direction in the values the graph came with (poses and points)."""
        angles = _angles(rotations, self.num_poses)
        ranges = self.pose_graph.ranges
        if ranges is not None:
            step = self.range_steps()
            angles = np.concatenate([angles, np.arctan2(step[:, 1], step[:, 0])])
        return np.exp(1j * angles)[:, None]

    def rounded(self, y: np.ndarray) -> np.ndarray:
        return _round(y)

    def stacked(self, rotations: np.ndarray) -> np.ndarray:
        return rotations[:, None]

    def unstacked(self, y: np.ndarray) -> np.ndarray:
        return y[:, 0]

    def anchored(self, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The angles of unit complex orientations ``z`` (n,), turned (in place) so that
        the anchor keeps its own angle; and ``z`` (n, 1). With ranges, the poses' angles are
        followed by the ranges' directions."""
        g, z = self.pose_graph, rotations
        z *= np.exp(1j * g.poses[g.anchor, 2]) / z[g.anchor]
        return wrap(np.angle(z)), z[:, None]


@dataclass(frozen=True, eq=False)
class _Shifted:
    """A factor of the block matrix whose Schur complement is Q + diag(shift)."""

    lu: SuperLU
    pos_z: np.ndarray  # the rotation rows' positions in the block

    def solve(self, v: np.ndarray) -> np.ndarray:
        """(Q + diag(shift))^-1 v for v (n, r) complex."""
        rhs = np.zeros((self.lu.shape[0], v.shape[1]), complex)
        rhs[self.pos_z] = v
        return self.lu.solve(rhs)[self.pos_z]

    def negative_pivots(self) -> int | None:
        """Number of eigenvalues of Q + diag(shift) that are <= 0 (Sylvester's law of
        inertia; L is positive definite), or None when the LU pivoted off the diagonal."""
        return negative_pivots(self.lu)


@dataclass(frozen=True, eq=False)
class _Tangent:
    """A factor of the rank-1 tangent Hessian at ``z`` (:meth:`PlanarProblem.tangent_factor`)."""

    lu: SuperLU
    pos_a: np.ndarray  # the angle rows' positions in the block
    z: np.ndarray

    def precondition(self, v: np.ndarray) -> np.ndarray:
        """``(2 A)^-1`` of a tangent ``v`` (n, 1), as a tangent vector: ``b = Im(conj(z) v)``
        in angle coordinates, ``a = A^-1 b / 2``, back as ``i a z``."""
        rhs = np.zeros(self.lu.shape[0])
        rhs[self.pos_a] = np.imag(np.conj(self.z) * v[:, 0])
        return (0.5j * self.lu.solve(rhs)[self.pos_a] * self.z)[:, None]


def _angles(theta: np.ndarray, n: int) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (n,):
        raise SolverError(f"orientations must have shape ({n},), got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise SolverError("orientations must be finite")
    return theta



# --- the product of unit spheres in C^r, and the staircase on it ----------------------------

class Circles(Manifold):
    """Rows of ``Y`` (n x r complex) of unit length: the staircase's manifold in 2D."""

    dtype = complex

    def size(self, n: int) -> int:
        return n

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        return float(np.real(np.vdot(a, b)))

    def project(self, y: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Row-wise projection of v onto the tangent space at y (rows of y unit vectors)."""
        return v - np.real(np.sum(np.conj(y) * v, axis=1))[:, None] * y

    def retract(self, y: np.ndarray) -> np.ndarray:
        return y / np.linalg.norm(y, axis=1)[:, None]

    def multipliers(self, y: np.ndarray, qy: np.ndarray) -> np.ndarray:
        return np.real(np.sum(np.conj(y) * qy, axis=1))

    def times(self, lam: np.ndarray, v: np.ndarray) -> np.ndarray:
        return lam[:, None] * v

    def hessian(self, y, lam, v, qv) -> np.ndarray:
        return 2.0 * (self.project(y, qv) - lam[:, None] * v)

    def diagonal(self, n: int, value: float) -> np.ndarray:
        return np.full(n, value)

    def shift(self, lam: np.ndarray, sigma: float) -> np.ndarray:
        return -lam - sigma

    def trace(self, lam: np.ndarray) -> float:
        return float(lam.sum())

    def largest(self, lam: np.ndarray) -> float:
        return float(lam.max())

    def dense(self, problem: PlanarProblem, lam: np.ndarray) -> np.ndarray:
        return problem.apply(np.eye(problem.n, dtype=complex)) - np.diag(lam)

    def start(self, y: np.ndarray) -> np.ndarray:
        return y[:, 0]

    def superlu(self, factor: _Shifted) -> SuperLU:
        return factor.lu


def manifold() -> Circles:
    """The planar staircase's manifold and settings: this module's constants, read at each
    call."""
    return Circles(dense_below=_DENSE_BELOW, preconditioner_shift=0.0,
                    preconditioner_condition=_PRECONDITIONER_CONDITION, initial_radius=10.0,
                    max_below=6, escape_halvings=_ESCAPE_HALVINGS,
                    arpack_options=_ARPACK_OPTIONS,
                    hessian_preconditioner_after=_HESSIAN_PRECONDITIONER_AFTER)


# --- rounding -------------------------------------------------------------------------------

def _round(y: np.ndarray) -> np.ndarray:
    """Leading left singular vector of Y, each entry projected onto the unit circle."""
    u = np.linalg.svd(y, full_matrices=False)[0][:, 0] if y.shape[1] > 1 else y[:, 0]
    size = np.abs(u)
    return np.where(size > 1e-300, u / np.maximum(size, 1e-300), 1.0)
