"""The SE(2) synchronization relaxation with an optimality certificate (SE-Sync / CPL-SLAM in 2D).

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

How. The semidefinite relaxation ``min tr(Q X), X >= 0, X_ii = 1`` (X Hermitian) is solved in
Burer-Monteiro form ``X = Y Y^H``, ``Y`` n x r complex with unit rows, by a Riemannian
staircase: at each rank a Riemannian trust region with truncated, preconditioned CG; then the
certificate ``S = Q - Lambda`` with ``Lambda = diag(Re(diag(Q Y Y^H)))``: the rank's critical
point is a global optimum of the relaxation iff ``S >= 0``. This is tested exactly in the
sparse domain: ``S + eta I`` is positive definite iff the sparse Hermitian matrix
``[[L, -B], [-B^H, D - Lambda + eta I]]`` (whose Schur complement is ``S + eta I``) has only
positive pivots in a symmetric, pivot-free LU. If it fails, the staircase escapes the saddle
along the eigenvector of ``lambda_min(S)`` into rank r + 1. The solution is rounded (leading
left singular vector of Y, each entry projected onto the unit circle) and the gauge fixed so
the anchor keeps its angle. Complex rank 1 is the rotation problem itself (SE-Sync's real rank
r = d = 2 without reflections); complex rank r matches SE-Sync's real rank 2r.

Certificate. ``Lambda + lambda_min(S) I`` is feasible for the relaxation's dual, so
``lower_bound = tr(Lambda) + n min(lambda_min, 0)`` bounds the relaxation's optimum (and so
the rotation problem's) from below; ``suboptimality_bound = f(rounded) - lower_bound``. The
tolerance ``eta`` defaults to ``1e-7 x mean(diag Q)`` (``diag Q`` is each pose's summed
weight; the relative 1e-7 sits well above the eigen-solver's round-off at that scale and keeps
``n eta`` below ``1e-7 tr(Q)``). ``certified`` means ``lambda_min >= -eta`` and the rounded
estimate attains the bound: ``suboptimality_bound <= n eta + 1e-6 |f(rounded)|``.

How it ended. Like SE-Sync's ``status``, every certificate says why the staircase stopped
(:class:`Status`): certified; the relaxation solved but not exact (``not_tight``); an
eigenvalue computation that did not converge; a saddle the staircase could not descend from;
the rank, iteration or time limit; or, for :func:`certify`, an estimate that is not the
relaxation's optimum. :meth:`Certificate.describe` says it in one line.

Poses other than the anchor that a hard prior holds are not held by the relaxation; the
translation step that follows it holds them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from enum import Enum

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import (
    ArpackError,
    ArpackNoConvergence,
    LinearOperator,
    SuperLU,
    eigsh,
    splu,
)

from rlpgo_gtsam.chordal import chordal_orientations
from rlpgo_gtsam.errors import GraphError, SolverError
from rlpgo_gtsam.graph import PoseGraph2D, rotation_weights
from rlpgo_gtsam.se2 import wrap

__all__ = ["Certificate", "Status", "synchronize", "certify", "relaxation_cost"]

_RELATIVE_TOLERANCE = 1e-7  # eta / mean(diag Q)
_GAP_TOLERANCE = 1e-6  # relative gap between f(rounded) and tr(Lambda) still called exact
_DENSE_BELOW = 300  # graphs with fewer poses get dense eigenvalue computations
_ARPACK_OPTIONS = {"maxiter": 2000}  # ARPACK's settings besides k, which, v0 and tol
_ESCAPE_HALVINGS = 30  # step halvings an escape from a saddle tries before it gives up


class Status(str, Enum):
    """Why the staircase stopped (SE-Sync's GLOBAL_OPT, EIG_IMPRECISION, SADDLE_POINT,
    RS_ITER_LIMIT, ELAPSED_TIME), as the string it compares equal to and is recorded as."""

    CERTIFIED = "certified"
    """``lambda_min(S) >= -eta`` and the rounded estimate attains the lower bound."""
    NOT_TIGHT = "not_tight"
    """The relaxation is solved at its rank (``lambda_min(S) >= -eta``) but the rounded
    estimate does not attain its bound: the relaxation is not exact on this graph."""
    EIGENVALUE_IMPRECISE = "eigenvalue_imprecise"
    """ARPACK did not converge on the final rank's ``lambda_min(S)`` and ``S`` is not known
    to be positive semidefinite: ``min_eigenvalue`` is the proven floor ``-max(Lambda)`` (as
    ``Q >= 0``), not the eigenvalue, so ``lower_bound`` stays a bound."""
    SADDLE_ESCAPE_FAILED = "saddle_escape_failed"
    """The escape into the final rank found no descent along the eigenvector in
    ``_ESCAPE_HALVINGS`` halvings, and the final rank is not certified either."""
    RANK_LIMIT = "rank_limit"
    """``max_rank`` was reached with ``S`` not positive semidefinite."""
    ITERATION_LIMIT = "iteration_limit"
    """The trust region at the final rank used ``max_iterations`` without meeting its
    gradient tolerance, and ``S`` is not positive semidefinite there."""
    TIME_LIMIT = "time_limit"
    """``time_limit_s`` passed: the best ``Y`` so far was rounded. Stopped inside a trust
    region, nothing was verified: ``min_eigenvalue``, ``lower_bound`` and
    ``suboptimality_bound`` are NaN."""
    NOT_OPTIMAL = "not_optimal"
    """:func:`certify` only: ``S`` has an eigenvalue below ``-eta`` at the estimate given,
    which is not the relaxation's optimum (no optimization was run)."""

    def __str__(self) -> str:
        return self.value


# The human reason per status, after "NOT certified: " (certified has its own words).
_REASONS = {
    Status.NOT_TIGHT: "the relaxation is solved but not exact (the rounded estimate misses "
                      "the lower bound)",
    Status.EIGENVALUE_IMPRECISE: "the minimum-eigenvalue computation did not converge",
    Status.SADDLE_ESCAPE_FAILED: "saddle escape failed",
    Status.RANK_LIMIT: "rank limit reached with a negative eigenvalue",
    Status.ITERATION_LIMIT: "trust-region iteration limit reached",
    Status.TIME_LIMIT: "time limit reached",
    Status.NOT_OPTIMAL: "the estimate is not the relaxation's optimum (negative eigenvalue)",
}


@dataclass(frozen=True)
class Certificate:
    """What the relaxation proves about an orientation estimate (costs in the relaxation's
    own units, see the module docstring: about chi2 plus its rotational part near a good
    estimate), and how the computation ended.

    Attributes:
        status: why the staircase stopped (:class:`Status`); ``certified`` is
            ``status == "certified"``.
        lower_bound: dual lower bound on the relaxation's optimum,
            ``tr(Lambda) + n min(min_eigenvalue, 0)``.
        estimate_cost: relaxation cost ``f(z)`` of the (rounded) estimate, translations
            eliminated.
        suboptimality_bound: ``estimate_cost - lower_bound`` (>= 0): how far, at most, the
            estimate is from the rotation problem's global optimum in this cost.
        min_eigenvalue: ``lambda_min(S)``, ``S = Q - Lambda``, at the final rank; where
            ARPACK did not converge, a proven floor under it (``-tolerance`` when the LU's
            pivots proved ``S + eta I > 0``, else ``-max(Lambda)``); NaN when ``time_limit``
            stopped a trust region before any verification.
        tolerance: eta: the relaxation counts as solved iff ``min_eigenvalue >= -tolerance``.
        rank: the staircase's final (complex) rank; 1 for :func:`certify`.
        seconds: wall time of the call.
    """

    status: Status
    lower_bound: float
    estimate_cost: float
    suboptimality_bound: float
    min_eigenvalue: float
    tolerance: float
    rank: int
    seconds: float

    @property
    def certified(self) -> bool:
        """The relaxation is exact and the rounded estimate is its global optimum
        (``min_eigenvalue >= -tolerance`` and the estimate attains the lower bound)."""
        return self.status == Status.CERTIFIED

    def record(self) -> dict:
        """The fields as a JSON-ready dict: ``status`` (a plain string), ``certified`` and
        the numbers (NaN, where nothing was verified, as None)."""
        record: dict = {"status": Status(self.status).value, "certified": self.certified}
        for item in fields(self)[1:]:
            value = getattr(self, item.name)
            record[item.name] = value if isinstance(value, int) else \
                (float(value) if math.isfinite(value) else None)
        return record

    def describe(self) -> str:
        """One line: the verdict (the reason when not certified), the numbers, the time."""
        if self.certified:
            verdict, rank = "certified optimal", f"rank {self.rank}, "
        else:
            reason = _REASONS[Status(self.status)]
            verdict, rank = f"NOT certified: {reason} at rank {self.rank}", ""
        if math.isnan(self.min_eigenvalue):
            bounds = "not verified"
        else:
            bounds = (f"lower bound {self.lower_bound:.6g}, suboptimality bound "
                      f"{self.suboptimality_bound:.3g}; lambda_min {self.min_eigenvalue:.3g}")
        return (f"{verdict} (relaxation cost {self.estimate_cost:.6g}, {bounds}, tolerance "
                f"{self.tolerance:.3g}, {rank}{self.seconds:.2f} s)")


def synchronize(
    pose_graph: PoseGraph2D,
    start_theta: np.ndarray | None = None,
    *,
    max_rank: int = 10,
    tolerance: float | None = None,
    initial_rank: int = 1,
    max_iterations: int = 300,
    gradient_tolerance: float = 1e-9,
    time_limit_s: float | None = None,
) -> tuple[np.ndarray, Certificate]:
    """Orientations (n,) of the rounded estimate (anchor keeps its angle), and its certificate.

    Args:
        pose_graph: the graph; its ``poses[anchor, 2]`` fixes the rotation gauge.
        start_theta: (n,) start of the staircase; by default the chordal estimate (one sparse
            solve of the rotations' connection Laplacian with the anchor held).
        max_rank: the staircase stops at this complex rank (certified or not).
        tolerance: eta; default ``1e-7 x mean(diag Q)`` (see the module docstring).
        initial_rank: the staircase's first complex rank (1: the rotation problem itself).
        max_iterations: trust-region iterations per rank.
        gradient_tolerance: stop a rank when the Riemannian gradient norm falls below this
            times ``sqrt(n) x mean(diag Q)``.
        time_limit_s: checked between trust-region iterations and between ranks: once the
            call has run this long it rounds the current ``Y`` and returns it with status
            ``time_limit``. None: no limit.

    The certificate's ``status`` says how the staircase ended (:class:`Status`). Where the
    final rank is not certified, more than one reason may hold; the first of these is told:
    ``eigenvalue_imprecise``, ``saddle_escape_failed`` (the escape into the final rank),
    ``iteration_limit`` (at the final rank), ``rank_limit``.

    Raises:
        SolverError: bad ranks or tolerance, a ``start_theta`` of the wrong shape, or a
            graph whose translations or rotations the measurements do not determine.
        GraphError: negative or non-finite information.
    """
    started = time.perf_counter()
    if not 1 <= initial_rank <= max_rank:
        raise SolverError(f"ranks must satisfy 1 <= initial_rank <= max_rank, got "
                          f"initial_rank={initial_rank}, max_rank={max_rank}")
    if time_limit_s is not None and not time_limit_s >= 0:
        raise SolverError(f"time_limit_s must be a number >= 0 or None, got {time_limit_s}")
    deadline = None if time_limit_s is None else started + time_limit_s
    problem = _Problem(pose_graph)
    eta = problem.tolerance(tolerance)
    if start_theta is None:
        z = np.exp(1j * chordal_orientations(pose_graph))
    else:
        z = np.exp(1j * _angles(start_theta, problem.n))
    y = np.zeros((problem.n, initial_rank), complex)
    y[:, 0] = z
    grad_tol = gradient_tolerance * np.sqrt(problem.n) * problem.scale
    escaped = True  # whether the escape into the current rank descended
    while True:
        y, ended = _trust_region(problem, y, max_iterations, grad_tol, deadline)
        if ended is Status.TIME_LIMIT:
            check, stop = _unverified(problem, y), Status.TIME_LIMIT
            break
        check = _verify(problem, y, eta)
        if check.imprecise and check.vector is None and not check.certified:
            stop = Status.EIGENVALUE_IMPRECISE  # no direction to escape along
            break
        if check.certified or y.shape[1] >= max_rank:
            stop = (Status.EIGENVALUE_IMPRECISE if check.imprecise else
                    Status.SADDLE_ESCAPE_FAILED if not escaped else ended or Status.RANK_LIMIT)
            break
        if deadline is not None and time.perf_counter() > deadline:
            stop = Status.TIME_LIMIT
            break
        y, escaped = _escape(problem, y, check.vector)
    z = _round(y)
    z *= np.exp(1j * pose_graph.poses[pose_graph.anchor, 2]) / z[pose_graph.anchor]
    theta = wrap(np.angle(z))
    estimate = problem.cost(z[:, None])
    certificate = _certificate(problem, check, estimate, eta, y.shape[1], started, stop)
    return theta, certificate


def certify(pose_graph: PoseGraph2D, theta: np.ndarray, *,
            tolerance: float | None = None) -> Certificate:
    """The certificate of a given orientation estimate at rank 1 (no optimization).

    ``Lambda`` is computed at ``z = exp(i theta)`` itself: a non-critical estimate (e.g. the
    odometry guess of a loopy graph) gets a clearly negative ``lambda_min(S)``, so it is not
    certified and its suboptimality bound is positive.
    """
    started = time.perf_counter()
    problem = _Problem(pose_graph)
    eta = problem.tolerance(tolerance)
    y = np.exp(1j * _angles(theta, problem.n))[:, None]
    check = _verify(problem, y, eta)
    stop = Status.EIGENVALUE_IMPRECISE if check.imprecise else Status.NOT_OPTIMAL
    return _certificate(problem, check, problem.cost(y), eta, 1, started, stop)


def relaxation_cost(pose_graph: PoseGraph2D, theta: np.ndarray) -> float:
    """``f(z) = min_t F(z, t)`` at ``z = exp(i theta)``: the relaxation's cost with the
    translations eliminated (about chi2 plus chi2's rotational part near a good estimate)."""
    problem = _Problem(pose_graph)
    return problem.cost(np.exp(1j * _angles(theta, problem.n))[:, None])


# --- the problem ---------------------------------------------------------------------------

def _translation_weights(pose_graph: PoseGraph2D) -> np.ndarray:
    """tau = 2 / trace(info_tt^-1) = 2 det(info_tt) / trace(info_tt) (0 if info_tt is 0)."""
    info = pose_graph.information
    trace = info[:, 0, 0] + info[:, 1, 1]
    det = info[:, 0, 0] * info[:, 1, 1] - info[:, 0, 1] * info[:, 1, 0]
    return np.divide(2.0 * det, trace, out=np.zeros_like(trace), where=trace > 0)


class _Problem:
    """Q = D - B^H L^-1 B applied as an operator; sparse factorizations of its pieces.

    ``L`` is the tau-weighted translation Laplacian without the anchor's row and column,
    ``B`` (n-1 x n) the translation-rotation coupling, ``D`` the rotations' connection
    Laplacian plus the diagonal ``sum tau |c|^2`` over each pose's outgoing edges.
    """

    def __init__(self, pose_graph: PoseGraph2D) -> None:
        g = pose_graph
        n = g.num_poses
        if n < 2:
            raise GraphError(f"a pose graph for the relaxation needs 2 poses or more, got {n}")
        kappa = np.asarray(rotation_weights(g), float)
        tau = _translation_weights(g)
        if not (np.all(np.isfinite(kappa)) and np.all(np.isfinite(tau))
                and np.all(np.isfinite(g.measured))):
            raise GraphError("the relaxation needs finite measurements and information")
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
        diag = sp.coo_matrix((tau * np.abs(c) ** 2, (i, i)), shape=(n, n)).tocsr()
        self.n = n
        self.anchor = g.anchor
        self.rot = rot
        self.d = (rot + diag).tocsr()
        keep = np.delete(np.arange(n), g.anchor)
        lap = sp.coo_matrix((np.concatenate([tau, tau, -tau, -tau]), (rows, cols)),
                            shape=(n, n)).tocsr()
        # residual t_j - t_i - c z_i: coupling -2 Re(t^H B z), B[j, i] += tau c, B[i, i] -= tau c
        coupling = sp.coo_matrix((np.concatenate([tau * c, -tau * c]),
                                  (np.concatenate([j, i]), np.concatenate([i, i]))),
                                 shape=(n, n)).tocsr()
        self.lap = lap[keep][:, keep].tocsc()
        self.b = coupling[keep].tocsr()
        self.bh = self.b.conj().T.tocsr()
        try:
            self.lap_lu = splu(self.lap, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
        except RuntimeError:
            raise SolverError("the measurements do not determine the translations (a pose "
                              "without translational information?)") from None
        self.scale = float(np.mean(np.real(self.d.diagonal())))
        if not self.scale > 0:
            raise SolverError("every edge has zero information: nothing to synchronize")

    def tolerance(self, tolerance: float | None) -> float:
        if tolerance is None:
            return _RELATIVE_TOLERANCE * self.scale
        if not (np.isfinite(tolerance) and tolerance >= 0):
            raise SolverError(f"tolerance must be a finite number >= 0, got {tolerance}")
        return float(tolerance)

    def apply(self, y: np.ndarray) -> np.ndarray:
        """Q y for y (n, r) complex."""
        w = self.b @ y
        r = w.shape[1]
        x = self.lap_lu.solve(np.ascontiguousarray(np.hstack([w.real, w.imag])))
        return self.d @ y - self.bh @ (x[:, :r] + 1j * x[:, r:])

    def cost(self, y: np.ndarray) -> float:
        return float(np.real(np.vdot(y, self.apply(y))))

    def factor(self, shift: np.ndarray) -> tuple[SuperLU, int]:
        """Pivot-free sparse LU of [[L, -B], [-B^H, D + diag(shift)]]: its Schur complement
        is Q + diag(shift), solved by :meth:`solve_shifted`; returns (the LU, n - 1: the
        rows of the translation block before the rotation block)."""
        m = self.n - 1
        block = sp.bmat([[self.lap, -self.b], [-self.bh, self.d + sp.diags(shift)]],
                        format="csc")
        return splu(block, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                    options={"SymmetricMode": True}), m

    @staticmethod
    def solve_shifted(factor: tuple[SuperLU, int], v: np.ndarray) -> np.ndarray:
        lu, m = factor
        rhs = np.vstack([np.zeros((m, v.shape[1]), complex), v])
        return lu.solve(rhs)[m:]


def _angles(theta: np.ndarray, n: int) -> np.ndarray:
    theta = np.asarray(theta, dtype=float)
    if theta.shape != (n,):
        raise SolverError(f"orientations must have shape ({n},), got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise SolverError("orientations must be finite")
    return theta


# --- the Riemannian trust region on the product of unit spheres in C^r ---------------------

_PRECONDITIONER_SHIFT = 1e-3  # (Q + delta I)^-1 preconditions the Hessian; delta / mean(diag Q)


def _project(y: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Row-wise projection of v onto the tangent space at y (rows of y unit vectors)."""
    return v - np.real(np.sum(np.conj(y) * v, axis=1))[:, None] * y


def _retract(y: np.ndarray) -> np.ndarray:
    return y / np.linalg.norm(y, axis=1)[:, None]


def _inner(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.real(np.vdot(a, b)))


def _trust_region(problem: _Problem, y: np.ndarray, max_iterations: int, grad_tol: float,
                  deadline: float | None = None) -> tuple[np.ndarray, Status | None]:
    """A local minimum of f(Y) = tr(Y^H Q Y) over unit-row Y: Riemannian trust region with
    truncated CG (Steihaug-Toint), preconditioned by (Q + delta I)^-1.

    Returns Y and how it ended: None (gradient tolerance met, or no progress left above
    round-off), ``ITERATION_LIMIT`` (``max_iterations`` used) or ``TIME_LIMIT``
    (``time.perf_counter()`` passed ``deadline`` before an iteration)."""
    precon = None
    qy = problem.apply(y)
    f = _inner(y, qy)
    radius = None
    for _ in range(max_iterations):
        lam = np.real(np.sum(np.conj(y) * qy, axis=1))
        grad = 2.0 * (qy - lam[:, None] * y)
        if np.linalg.norm(grad) <= grad_tol:
            return y, None
        if deadline is not None and time.perf_counter() > deadline:
            return y, Status.TIME_LIMIT
        if precon is None:
            precon = problem.factor(np.full(problem.n, _PRECONDITIONER_SHIFT * problem.scale))

        def hess(v: np.ndarray, y=y, lam=lam) -> np.ndarray:
            return 2.0 * (_project(y, problem.apply(v)) - lam[:, None] * v)

        def pre(v: np.ndarray, y=y, precon=precon) -> np.ndarray:
            return 0.5 * _project(y, _Problem.solve_shifted(precon, v))

        if radius is None:
            radius = 10.0 * np.sqrt(max(_inner(grad, pre(grad)), 1e-300))
        step, h_step, on_boundary = _truncated_cg(grad, hess, pre, radius)
        model_decrease = -(_inner(grad, step) + 0.5 * _inner(step, h_step))
        y_new = _retract(y + step)
        qy_new = problem.apply(y_new)
        f_new = _inner(y_new, qy_new)
        actual = f - f_new
        rho = actual / model_decrease if model_decrease > 0 else -1.0
        if model_decrease <= 1e-15 * abs(f) and actual <= 1e-15 * abs(f):
            return y, None  # no progress left above round-off
        if rho < 0.25:
            radius *= 0.25
        elif rho > 0.75 and on_boundary:
            radius *= 2.0
        if rho > 0.1 or (actual > 0 and model_decrease <= 1e-12 * abs(f)):
            y, qy, f = y_new, qy_new, f_new
    return y, Status.ITERATION_LIMIT


def _truncated_cg(grad, hess, pre, radius, theta=1.0, kappa=0.1, max_inner=200):
    """Steihaug-Toint truncated CG for min <g, e> + <e, H e> / 2 in the preconditioner's
    norm ball of ``radius``; returns (step, H step, whether it stopped on the boundary)."""
    step = np.zeros_like(grad)
    h_step = np.zeros_like(grad)
    residual = grad.copy()
    r0 = np.linalg.norm(grad)
    z = pre(residual)
    z_r = _inner(z, residual)
    direction = -z
    e_pe, e_pd, d_pd = 0.0, 0.0, z_r
    for _ in range(max_inner):
        h_dir = hess(direction)
        curvature = _inner(direction, h_dir)
        alpha = z_r / curvature if curvature > 0 else np.inf
        e_pe_new = e_pe + 2.0 * alpha * e_pd + alpha * alpha * d_pd
        if curvature <= 0 or e_pe_new >= radius * radius:
            tau = (-e_pd + np.sqrt(e_pd * e_pd + d_pd * (radius * radius - e_pe))) / d_pd
            return step + tau * direction, h_step + tau * h_dir, True
        step = step + alpha * direction
        h_step = h_step + alpha * h_dir
        e_pe = e_pe_new
        residual = residual + alpha * h_dir
        if np.linalg.norm(residual) <= r0 * min(r0 ** theta, kappa):
            break
        z = pre(residual)
        z_r_old, z_r = z_r, _inner(z, residual)
        beta = z_r / z_r_old
        e_pd = beta * (e_pd + alpha * d_pd)
        d_pd = z_r + beta * beta * d_pd
        direction = -z + beta * direction
    return step, h_step, False


# --- verification, escape, rounding --------------------------------------------------------

@dataclass(frozen=True)
class _Check:
    certified: bool  # lambda_min(S) >= -eta
    min_eigenvalue: float  # a proven floor under it where imprecise, NaN where not verified
    trace: float  # tr(Lambda) = f(Y)
    vector: np.ndarray | None  # eigenvector of lambda_min(S) where known
    imprecise: bool = False  # ARPACK did not converge on the eigenvalue(s) asked for


def _unverified(problem: _Problem, y: np.ndarray) -> _Check:
    """No verification (the time limit passed): lambda_min unknown, so no lower bound."""
    return _Check(False, math.nan, problem.cost(y), None)


def _verify(problem: _Problem, y: np.ndarray, eta: float) -> _Check:
    """lambda_min(S), S = Q - Lambda(Y), and whether S + eta I >= 0."""
    n = problem.n
    lam = np.real(np.sum(np.conj(y) * problem.apply(y), axis=1))
    trace = float(lam.sum())
    if n < _DENSE_BELOW:
        s = problem.apply(np.eye(n, dtype=complex)) - np.diag(lam)
        values, vectors = np.linalg.eigh(0.5 * (s + s.conj().T))
        return _Check(bool(values[0] >= -eta), float(values[0]), trace, vectors[:, 0])
    floor = -max(float(lam.max()), 0.0)  # lambda_min(S) >= -max Lambda as Q >= 0
    # S + eta I > 0  iff  the sparse matrix with Schur complement S + eta I has positive pivots
    negatives = _negative_pivots(problem, -lam + eta)
    if negatives == 0:
        value, vector = _nearest_above(problem, lam, -eta, y[:, 0])
        if vector is None:  # the pivots proved lambda_min > -eta: that is the floor kept
            return _Check(True, -eta, trace, None, imprecise=True)
        return _Check(True, value, trace, vector)
    if negatives is not None and negatives <= 6:
        values, vectors, converged = _below(problem, lam, -eta, negatives)
        if len(values) == 0:
            return _Check(False, floor, trace, None, imprecise=True)
        k = int(np.argmin(values))
        return _Check(False, float(values[k]) if converged else floor, trace, vectors[:, k],
                      imprecise=not converged)
    # many negative eigenvalues: shift below them all
    value, vector = _nearest_above(problem, lam, floor - eta - 1e-3 * problem.scale, None)
    if vector is None:
        return _Check(False, floor, trace, None, imprecise=True)
    return _Check(bool(value >= -eta), value, trace, vector)


def _negative_pivots(problem: _Problem, shift: np.ndarray) -> int | None:
    """Number of eigenvalues of Q + diag(shift) that are <= 0, from a pivot-free symmetric
    sparse LU (Sylvester's law of inertia; L is positive definite), or None when the LU
    pivoted off the diagonal (the count would not be an inertia)."""
    try:
        lu, _ = problem.factor(shift)
    except RuntimeError:  # an exactly zero pivot: a zero eigenvalue, so not positive definite
        return None
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return None
    return int(np.count_nonzero(np.real(lu.U.diagonal()) <= 0))


def _shifted_inverse(problem: _Problem, lam: np.ndarray, sigma: float) -> LinearOperator:
    factor = problem.factor(-lam - sigma)
    n = problem.n
    return LinearOperator((n, n), dtype=complex,
                          matvec=lambda v: _Problem.solve_shifted(factor, v.reshape(n, 1))[:, 0])


def _nearest_above(problem, lam, sigma, start) -> tuple[float, np.ndarray | None]:
    """The smallest eigenvalue of S when all lie above sigma: the largest of (S - sigma)^-1;
    (NaN, None) when ARPACK did not converge."""
    values, vectors, converged = _eigsh(_shifted_inverse(problem, lam, sigma), k=1,
                                        which="LA", v0=start, tol=1e-10)
    if not converged:
        return math.nan, None
    return float(sigma + 1.0 / np.real(values[0])), vectors[:, 0]


def _below(problem, lam, sigma, count) -> tuple[np.ndarray, np.ndarray, bool]:
    """The ``count`` eigenvalues of S below sigma: the most negative of (S - sigma)^-1; and
    whether ARPACK converged on all of them (if not, those it did converge on)."""
    values, vectors, converged = _eigsh(_shifted_inverse(problem, lam, sigma), k=count,
                                        which="SA", tol=1e-8)
    return sigma + 1.0 / np.real(values), vectors, converged


def _eigsh(op: LinearOperator, **options) -> tuple[np.ndarray, np.ndarray, bool]:
    """ARPACK's eigenpairs of ``op`` and whether all converged: a partial result (maybe
    empty) comes back with False; a failure is a SolverError."""
    try:
        values, vectors = eigsh(op, **_ARPACK_OPTIONS, **options)
    except ArpackNoConvergence as error:
        return np.asarray(error.eigenvalues), np.asarray(error.eigenvectors), False
    except ArpackError as error:
        raise SolverError(f"the minimum-eigenvalue computation failed: {error}") from None
    return values, vectors, True


def _escape(problem: _Problem, y: np.ndarray, vector: np.ndarray) -> tuple[np.ndarray, bool]:
    """Y at rank r + 1, lower than Y, along the eigenvector of lambda_min(S) in the new column
    (a second-order descent direction from the saddle [Y, 0]); and whether it descended (if
    not, after ``_ESCAPE_HALVINGS`` halvings, the last, shortest trial is returned)."""
    f0 = problem.cost(y)
    v = vector / np.max(np.abs(vector))
    alpha = 1.0
    for _ in range(_ESCAPE_HALVINGS):
        y_new = _retract(np.hstack([y, alpha * v[:, None]]))
        if problem.cost(y_new) < f0:
            return y_new, True
        alpha *= 0.5
    return _retract(np.hstack([y, alpha * v[:, None]])), False


def _round(y: np.ndarray) -> np.ndarray:
    """Leading left singular vector of Y, each entry projected onto the unit circle."""
    u = np.linalg.svd(y, full_matrices=False)[0][:, 0] if y.shape[1] > 1 else y[:, 0]
    size = np.abs(u)
    return np.where(size > 1e-300, u / np.maximum(size, 1e-300), 1.0)


def _certificate(problem: _Problem, check: _Check, estimate: float, eta: float, rank: int,
                 started: float, stop: Status) -> Certificate:
    """The certificate of the rounded estimate; ``stop``: the status when ``S`` is not
    known to be positive semidefinite (NaN numbers where nothing was verified)."""
    n = problem.n
    lower = check.trace + n * min(check.min_eigenvalue, 0.0)  # NaN stays NaN
    gap = max(estimate - lower, 0.0)
    if check.certified:
        exact = gap <= n * eta + _GAP_TOLERANCE * abs(estimate)
        status = Status.CERTIFIED if exact else Status.NOT_TIGHT
    else:
        status = stop
    return Certificate(
        status=status,
        lower_bound=float(lower),
        estimate_cost=float(estimate),
        suboptimality_bound=float(gap),
        min_eigenvalue=float(check.min_eigenvalue),
        tolerance=float(eta),
        rank=int(rank),
        seconds=time.perf_counter() - started,
    )
