"""The Riemannian staircase of the synchronization relaxations, once for the planar one
(:mod:`rlpgo_gtsam.certified`: unit-modulus complex rows) and the 3D one
(:mod:`rlpgo_gtsam.certified3d`: Stiefel blocks); its :class:`Certificate` and
:class:`Status`.

The staircase is generic over two objects:

- a *problem*, the relaxation's ``Q`` as an operator (a :class:`Relaxation`): ``n`` (poses),
  ``scale`` (the mean of ``diag Q``'s weights), ``apply(Y)`` (``Q Y``), ``cost(Y)``
  (``tr(Y^* Q Y)``), ``factor(shift)`` (a pivot-free sparse LU of a matrix whose Schur
  complement is ``Q + shift``), ``solve_shifted(factor, V)`` and, where the manifold asks
  for SE-Sync's preconditioner shift, ``norm_bound()`` (an upper bound on ``||Q||``);
- a :class:`Manifold`: what depends on the blocks (inner product, tangent projection,
  retraction, the multipliers ``Lambda`` and how they act, the dense ``S``, the block
  diagonal a shift is made of) and the settings a module tunes (dense size, preconditioner
  shift, first radius). A module builds it at each call, from its constants of that moment.

What is here: :func:`climb` (the staircase: a trust region at each rank, the verification of
``S = Q - Lambda``, the escape from a saddle into the next rank), :func:`trust_region` with
:func:`truncated_cg` (a rank's trust region also ends where it stalls below the
certificate's resolution: ``STALL_WINDOW``), :func:`verify` (dense below a size; else
Sylvester's inertia from a pivot-free LU, then ARPACK's shift-invert), :func:`escape`,
:func:`polish` (the rounded estimate moved downhill at the lowest rank) and
:func:`certificate` (the dual bound and the status from a :class:`Check`).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from enum import Enum
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from rlpgo_gtsam.errors import SolverError

if TYPE_CHECKING:
    from scipy.sparse.linalg import LinearOperator

__all__ = ["Status", "Certificate", "Check", "Relaxation", "Manifold", "climb", "trust_region",
           "truncated_cg", "verify", "unverified", "escape", "polish", "certificate",
           "check_start", "negative_pivots", "Progress", "Run", "TimeUp"]

RELATIVE_TOLERANCE = 1e-7  # eta / scale (the mean of diag Q's weights)
GAP_TOLERANCE = 1e-6  # relative gap between f(rounded) and tr(Lambda) still called exact
ARPACK_OPTIONS = {"maxiter": 2000}  # ARPACK's settings besides k, which, v0 and tol
# Lanczos vectors where ARPACK starts from the manifold's start (Y's first column, in S's
# null space at a critical point): 7 to 10 shift-invert solves where the default 20 took 21,
# on the shared 2D and 3D files, same eigenvalues to ARPACK's tolerance
STARTED_NCV = 6
ESCAPE_HALVINGS = 30  # step halvings an escape from a saddle tries before it gives up
# truncated CG stops at ||r|| <= ||g|| min(||g||^theta, kappa), or after max_inner iterations
CG_THETA, CG_KAPPA, CG_MAX_INNER = 1.0, 0.1, 200
# A staircase with a deadline that climbs above its first rank keeps this share of the time
# then left for the polish of its rounded estimate (the rounding of a higher rank's Y can land
# far uphill: see polish): on the 2000-pose generated graph of
# benchmarks/results/scale_budget.md cut at rank 2, rounded chi2 1.5e6 unpolished.
POLISH_SHARE = 0.25
PROGRESS_EVERY_S = 2.0  # at most one progress line this often inside a trust region
# A rank's trust region stalls when its last STALL_WINDOW iterations lowered the cost by less
# than STALL_FRACTION x (rows of Q) x eta: the certificate's own resolution (its gap tolerance
# is rows x eta). The staircase then verifies S there: the bound tr(Lambda) + rows
# min(lambda_min, 0) holds at any Y, so a stalled Y with lambda_min >= -eta is solved to that
# resolution, and one below it is escaped from.
STALL_WINDOW, STALL_FRACTION = 10, 1e-2


class TimeUp(Exception):
    """The deadline passed inside a step that has no partial result to hand over (the
    verification of ``S``: its factorization and eigen-solver's solves): the caller rounds
    the ``Y`` it has, unverified."""


def _late(deadline: float | None, ahead: float = 0.0) -> bool:
    """Whether ``deadline`` (a ``time.perf_counter()`` time; None: none) has passed, or
    will have once ``ahead`` more seconds are spent."""
    return deadline is not None and time.perf_counter() + ahead > deadline


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
    ``escape_halvings`` halvings, and the final rank is not certified either."""
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


@dataclass(frozen=True, eq=False)
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


# --- the two objects the staircase is generic over -----------------------------------------

class Relaxation:
    """The part of a relaxation's problem that does not depend on its blocks: the default
    tolerance. A subclass sets ``n`` and ``scale`` and defines ``apply``, ``cost``, ``factor``
    and ``solve_shifted`` (see the module docstring). The preconditioner's factor is kept
    here, made once per problem (its shift does not depend on ``Y``) and shared by the ranks."""

    n: int
    scale: float
    _preconditioner: tuple[float, Any] | None = None

    def norm_bound(self) -> float:
        """An upper bound on ``||Q||`` (for SE-Sync's preconditioner shift)."""
        raise NotImplementedError

    def preconditioner_delta(self, manifold: Manifold) -> float:
        """The preconditioner's shift: ``delta = norm_bound() / (condition - 1)`` with the
        manifold's ``preconditioner_condition`` (SE-Sync's regularized Cholesky
        preconditioner), else ``preconditioner_shift x scale``."""
        m = manifold
        if m.preconditioner_condition is not None:
            return self.norm_bound() / (m.preconditioner_condition - 1.0)
        return m.preconditioner_shift * self.scale

    def preconditioner(self, manifold: Manifold) -> Any:
        """The factor of ``Q + delta I`` (:meth:`preconditioner_delta`); cached per delta."""
        delta = self.preconditioner_delta(manifold)
        if self._preconditioner is None or self._preconditioner[0] != delta:
            self._preconditioner = (delta, self.factor(manifold.diagonal(self.n, delta)))
        return self._preconditioner[1]

    def hessian_preconditioner(self, manifold: Manifold, y: np.ndarray,
                               lam: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """A preconditioner of the Riemannian Hessian at ``y`` (multipliers ``lam``) that
        holds ``Lambda``, as a function of a tangent vector, or None where it is not
        positive definite (away from a minimum; at rank > 1 of a relaxation that is not
        exact). Here the factor of ``S + delta I = Q - Lambda + delta I``: ``(Q + delta
        I)^-1`` leaves out ``Lambda``, which outweighs ``Q``'s lowest modes on long graphs.
        A problem may give a closer one (the planar one at rank 1: the tangent Hessian's
        own factor)."""
        factor = _factor(self, manifold.shift(lam, -self.preconditioner_delta(manifold)))
        if _negative_pivots(manifold, factor) != 0:
            return None
        return lambda v: 0.5 * manifold.project(y, self.solve_shifted(factor, v))

    def tolerance(self, tolerance: float | None) -> float:
        if tolerance is None:
            return RELATIVE_TOLERANCE * self.scale
        if not (np.isfinite(tolerance) and tolerance >= 0):
            raise SolverError(f"tolerance must be a finite number >= 0, got {tolerance}")
        return float(tolerance)


@dataclass(frozen=True, eq=False)
class Manifold:
    """The blocks' operations (methods a subclass defines) and the staircase's settings.

    Attributes:
        dense_below: rows of ``Q`` below which ``S``'s eigenvalues are computed densely.
        preconditioner_shift: delta / scale: ``(Q + delta I)^-1`` preconditions the Hessian
            (where ``preconditioner_condition`` is None).
        preconditioner_condition: if set, delta is the problem's ``norm_bound()`` over this
            number minus 1 (SE-Sync's rule: the preconditioner's condition number at most this).
        initial_radius: the first trust-region radius, in units of the preconditioned
            gradient's norm.
        exact_decrease: a trial step's decrease computed as ``-<Y' - Y, Q (Y' + Y)>`` (exact
            for symmetric Q) rather than as the difference of two costs, which near a minimum
            agree in more digits than their round-off resolves (good steps then rejected).
        step_radius: a rejected step shrinks the radius to a quarter of the smaller of the
            radius and the step's length (SE-Sync's rule); False: a quarter of the radius.
            Both on by default: on tinyGrid3D, smallGrid3D and sphere2500 the 3D staircase
            and its chi2 after 30 LM iterations came out the same either way.
        max_below: where ``S + eta I`` has at most this many non-positive pivots, their
            eigenpairs are computed one by one; more (or 0 here): one shift below them all.
        escape_halvings: step halvings an escape from a saddle tries before it gives up.
        arpack_options: ARPACK's settings besides k, which, v0 and tol.
        hessian_preconditioner_after: a truncated CG run that took at least this many
            Hessian products makes the trust region's next run precondition with the
            problem's :meth:`Relaxation.hessian_preconditioner` at its ``Y`` (refactored at
            each new ``Y`` from then on, as long as it is positive definite; else back to
            ``Q + delta I``); None: always ``Q + delta I``.
        cg_floor: truncated CG also stops once its residual is below this fraction of the
            trust region's gradient tolerance (the next gradient is about that residual:
            solving further only overshoots the stop test); 0: never.
    """

    dense_below: int
    preconditioner_shift: float
    initial_radius: float
    max_below: int = 0
    preconditioner_condition: float | None = None
    exact_decrease: bool = True
    step_radius: bool = True
    escape_halvings: int = ESCAPE_HALVINGS
    arpack_options: dict[str, Any] = field(default_factory=lambda: dict(ARPACK_OPTIONS))
    hessian_preconditioner_after: int | None = None
    cg_floor: float = 0.0
    dtype: ClassVar[type] = float
    """The scalars of ``Y`` (and of the eigenvectors of ``S``)."""

    def size(self, n: int) -> int:
        """Rows of ``Q`` for ``n`` poses."""
        raise NotImplementedError

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        """The real inner product of the ambient space."""
        raise NotImplementedError

    def project(self, y: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``v`` projected onto the tangent space at ``y``."""
        raise NotImplementedError

    def retract(self, y: np.ndarray) -> np.ndarray:
        """``y`` moved back onto the manifold."""
        raise NotImplementedError

    def move(self, y: np.ndarray, step: np.ndarray) -> np.ndarray:
        """The trust region's trial point: ``y`` moved along the tangent vector ``step`` and
        back onto the manifold; :meth:`retract` of ``y + step`` unless a manifold knows a
        cheaper form of the same point."""
        return self.retract(y + step)

    def multipliers(self, y: np.ndarray, qy: np.ndarray) -> np.ndarray:
        """``Lambda(Y)`` from ``Y`` and ``Q Y``."""
        raise NotImplementedError

    def times(self, lam: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``Lambda V``."""
        raise NotImplementedError

    def gradient(self, y: np.ndarray, qy: np.ndarray,
                 lam: np.ndarray | None = None) -> np.ndarray:
        """The Riemannian gradient ``2 (Q Y - Lambda(Y) Y)`` of ``f`` at ``y`` (``qy``: ``Q
        Y``; ``lam``: its multipliers, where known)."""
        lam = self.multipliers(y, qy) if lam is None else lam
        return 2.0 * (qy - self.times(lam, y))

    def hessian(self, y: np.ndarray, lam: np.ndarray, v: np.ndarray,
                qv: np.ndarray) -> np.ndarray:
        """The Riemannian Hessian of ``tr(Y^* Q Y)`` at ``y`` along ``v`` (``qv = Q v``)."""
        raise NotImplementedError

    def diagonal(self, n: int, value: float) -> np.ndarray:
        """The shift ``value I`` as :meth:`factor` takes it."""
        raise NotImplementedError

    def shift(self, lam: np.ndarray, sigma: float) -> np.ndarray:
        """The shift whose factor's Schur complement is ``S - sigma I = Q - Lambda - sigma I``."""
        raise NotImplementedError

    def trace(self, lam: np.ndarray) -> float:
        """``tr(Lambda)``."""
        raise NotImplementedError

    def largest(self, lam: np.ndarray) -> float:
        """The largest eigenvalue of ``Lambda``."""
        raise NotImplementedError

    def dense(self, problem: Any, lam: np.ndarray) -> np.ndarray:
        """``S`` as a dense matrix."""
        raise NotImplementedError

    def start(self, y: np.ndarray) -> np.ndarray | None:
        """ARPACK's start for ``lambda_min(S)`` when ``S + eta I`` is positive definite."""
        return None

    def superlu(self, factor: Any) -> Any:
        """The ``SuperLU`` of a :meth:`factor`'s result (for its pivots)."""
        return factor

    def negative_pivots(self, factor: Any) -> int | None:
        """:func:`negative_pivots` of a :meth:`factor`'s result (not None); by default
        through its :meth:`superlu`."""
        return negative_pivots(self.superlu(factor))


def check_start(started: float, initial_rank: int, max_rank: int, lowest: int,
                time_limit_s: float | None) -> float | None:
    """The deadline of a staircase started at ``started``, after checking its ranks
    (``lowest <= initial_rank <= max_rank``) and time limit.

    Raises:
        SolverError: bad ranks or time limit.
    """
    if not lowest <= initial_rank <= max_rank:
        raise SolverError(f"ranks must satisfy {lowest} <= initial_rank <= max_rank, got "
                          f"initial_rank={initial_rank}, max_rank={max_rank}")
    if time_limit_s is not None and not time_limit_s >= 0:
        raise SolverError(f"time_limit_s must be a number >= 0 or None, got {time_limit_s}")
    return None if time_limit_s is None else started + time_limit_s


# --- the staircase ---------------------------------------------------------------------------

def climb(problem: Any, manifold: Manifold, y: np.ndarray, eta: float, max_rank: int,
          max_iterations: int, grad_tol: float, deadline: float | None,
          progress: Callable[[str], None] | None = None,
          started: float | None = None) -> tuple[np.ndarray, Check, Status]:
    """The staircase from ``y``: a trust region at each rank, then the verification of ``S``;
    a saddle is escaped into the next rank. Returns the last ``Y``, its check, and the
    status told when ``S`` is not known to be positive semidefinite there: where more than
    one reason holds, the first of ``eigenvalue_imprecise``, ``saddle_escape_failed`` (the
    escape into the final rank), ``iteration_limit`` (at the final rank), ``rank_limit``.

    ``deadline`` (a ``time.perf_counter()`` time; None: none) is checked before each
    trust-region iteration, each truncated-CG iteration and each factorization, and before
    each solve of the verification: once it has passed, the last ``Y`` is returned
    unverified with status ``time_limit``. Escaping above its first rank, the staircase
    keeps :data:`POLISH_SHARE` of the time left for the :func:`polish` that follows.

    ``progress`` (None: silent) gets one line per rank and, inside a long trust region or
    verification, one at most every 2 s; its seconds count from ``started`` (default:
    now)."""
    escaped = True  # whether the escape into the current rank descended
    first_rank = y.shape[1]
    stall = _stall(problem, manifold, eta)
    report = Progress(progress, time.perf_counter() if started is None else started)
    while True:
        run = Run()
        y, ended = trust_region(problem, manifold, y, max_iterations, grad_tol, deadline,
                                report, run, stall)
        if ended is Status.TIME_LIMIT:
            check, stop = unverified(problem, y), Status.TIME_LIMIT
            report.rank(y.shape[1], run, check)
            break
        try:
            check = verify(problem, manifold, y, eta,
                           functools.partial(_verifying, deadline, report, y.shape[1]))
        except TimeUp:
            check, stop = unverified(problem, y), Status.TIME_LIMIT
            report.rank(y.shape[1], run, check, "the verification cut by the time limit")
            break
        report.rank(y.shape[1], run, check)
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
        if deadline is not None and y.shape[1] == first_rank:  # the polish's share
            now = time.perf_counter()
            deadline = now + (deadline - now) * (1.0 - POLISH_SHARE)
        y, escaped = escape(problem, manifold, y, check.vector)
    return y, check, stop


def _verifying(deadline: float | None, report: Progress, rank: int, solves: int) -> None:
    """Before each long step of :func:`verify` (``solves``: the eigen-solver's solves so
    far): TimeUp once ``deadline`` has passed; a progress line at most every 2 s."""
    if _late(deadline):
        raise TimeUp
    report.verifying(rank, solves)


def polish(problem: Any, manifold: Manifold, y: np.ndarray, eta: float, max_iterations: int,
           grad_tol: float, deadline: float | None,
           progress: Callable[[str], None] | None = None,
           started: float | None = None) -> np.ndarray:
    """The rounded estimate ``y`` (at the lowest rank: the rotations themselves) moved
    downhill by the trust region at that rank, with the staircase's tolerances and stall
    rule: a local descent of the rotation problem that only lowers the estimate's cost.
    A staircase that ends above the lowest rank rounds a ``Y`` whose projection can be far
    uphill where the relaxation is not exact (a 500-pose graph with 3 rad of rotation noise:
    cost 82255 rounded, 651 polished, against the relaxation's 575). ``progress`` gets one
    line."""
    run = Run()
    report = Progress(None, time.perf_counter() if started is None else started)
    y, _ = trust_region(problem, manifold, y, max_iterations, grad_tol, deadline, report, run,
                        _stall(problem, manifold, eta))
    if progress is not None:
        progress(f"rounded estimate polished: {run.iterations} iterations, cost "
                 f"{run.cost:.9g}, gradient {run.gradient:.3g}, "
                 f"{time.perf_counter() - report.started:.1f} s")
    return y


def _stall(problem: Any, manifold: Manifold, eta: float) -> float:
    """The decrease below which a trust region's last ``STALL_WINDOW`` iterations stall."""
    return STALL_FRACTION * manifold.size(problem.n) * eta


# --- the Riemannian trust region -------------------------------------------------------------

def _inner(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.real(np.vdot(a, b)))


class Progress:
    """Rate-limited progress lines of a staircase (``progress`` None: silent)."""

    def __init__(self, progress: Callable[[str], None] | None, started: float) -> None:
        self.progress = progress
        self.started = started
        self.last = started

    def iteration(self, rank: int, iteration: int, cost: float, gradient: float) -> None:
        self._every(lambda: f"rank {rank}: iteration {iteration}, cost {cost:.9g}, gradient "
                            f"{gradient:.3g}")

    def verifying(self, rank: int, solves: int) -> None:
        self._every(lambda: f"rank {rank}: verifying S, {solves} eigen-solver solves")

    def _every(self, line: Callable[[], str]) -> None:
        """``line()`` and the seconds so far, at most every ``PROGRESS_EVERY_S``."""
        if self.progress is None:
            return
        now = time.perf_counter()
        if now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            self.progress(f"{line()}, {now - self.started:.1f} s")

    def rank(self, rank: int, run: Run, check: Check, note: str = "") -> None:
        if self.progress is not None:
            self.last = now = time.perf_counter()
            self.progress(f"rank {rank}: {run.iterations} iterations, cost {run.cost:.9g}, "
                          f"gradient {run.gradient:.3g}, lambda_min "
                          f"{check.min_eigenvalue:.3g}, {now - self.started:.1f} s"
                          + (f" ({note})" if note else ""))


@dataclass(eq=False)
class Run:
    """What one rank's trust region did (for the progress lines)."""

    iterations: int = 0
    cost: float = math.nan
    gradient: float = math.nan


def trust_region(problem: Any, manifold: Manifold, y: np.ndarray, max_iterations: int,
                 grad_tol: float, deadline: float | None = None,
                 progress: Progress | None = None, run: Run | None = None,
                 stall: float = 0.0) -> tuple[np.ndarray, Status | None]:
    """A local minimum of f(Y) = tr(Y^* Q Y) on the manifold: Riemannian trust region with
    truncated CG (Steihaug-Toint), preconditioned by (Q + delta I)^-1 (the problem's
    :meth:`Relaxation.preconditioner`, one factor shared by the ranks), or, once a CG run
    took the manifold's ``hessian_preconditioner_after`` Hessian products or more, by the
    problem's :meth:`Relaxation.hessian_preconditioner` at each new Y while that is
    positive definite. The decrease of a trial step and a
    rejected step's radius follow the manifold's ``exact_decrease`` and ``step_radius``.

    Returns Y and how it ended: None (gradient tolerance met, no progress left above
    round-off, or stalled: the last ``STALL_WINDOW`` iterations lowered the cost by less
    than ``stall``), ``ITERATION_LIMIT`` (``max_iterations`` used) or ``TIME_LIMIT``
    (``time.perf_counter()`` passed ``deadline`` before an iteration, or a factorization of
    the preconditioner would have ended past it, as long as the last one took); ``run`` (if
    given) gets the iterations, cost and gradient norm. A truncated CG run that the
    deadline stops hands its step so far to the iteration, which takes it if it descends:
    Y is the lowest point reached."""
    m = manifold
    run = Run() if run is None else run
    qy = problem.apply(y)
    f = m.inner(y, qy)
    radius = None
    ended: Status | None = Status.ITERATION_LIMIT
    costs = [f]  # the cost at the start of each iteration
    rejected, path = False, []  # whether the last step was rejected; its CG run's path
    products = [0]  # Hessian products of the last CG run
    hessian = False  # whether the last CG run had the Hessian preconditioner
    factor_s = 0.0  # seconds of the longest preconditioner factorization so far
    for iteration in range(max_iterations + 1):
        lam = m.multipliers(y, qy)
        grad = m.gradient(y, qy, lam)
        grad_norm = float(np.linalg.norm(grad))
        run.iterations, run.cost, run.gradient = iteration, f, grad_norm
        if progress is not None:
            progress.iteration(y.shape[1], iteration, f, grad_norm)
        if grad_norm <= grad_tol:
            ended = None
            break
        if iteration >= STALL_WINDOW and costs[-1 - STALL_WINDOW] - f < stall:
            ended = None  # stalled below the certificate's resolution
            break
        if iteration == max_iterations:
            break
        if deadline is not None and time.perf_counter() > deadline:
            ended = Status.TIME_LIMIT
            break
        if not rejected:  # a rejected step's Y keeps its preconditioner (and CG path)
            pre = None
            if m.hessian_preconditioner_after is not None and \
                    (hessian or products[0] >= m.hessian_preconditioner_after):
                if _late(deadline, factor_s):  # a factorization is not cut once begun
                    ended = Status.TIME_LIMIT
                    break
                factoring = time.perf_counter()
                pre = problem.hessian_preconditioner(m, y, lam)
                factor_s = max(factor_s, time.perf_counter() - factoring)
            hessian = pre is not None
            if pre is None:
                factoring = time.perf_counter()
                pre = _shared_preconditioner(problem, m, y)  # factored once, then cached
                factor_s = max(factor_s, time.perf_counter() - factoring)

        def hess(v: np.ndarray, y=y, lam=lam) -> np.ndarray:
            products[0] += 1
            return m.hessian(y, lam, v, problem.apply(v))

        if radius is None:
            radius = m.initial_radius * np.sqrt(max(m.inner(grad, pre(grad)), 1e-300))
        # a rejected step's Y, gradient and Hessian stand: the smaller radius's step lies on
        # the recorded path of the last run (its iterates do not depend on the radius)
        shortened = _shortened(path, radius) if rejected else None
        if shortened is None:
            path, products[0] = [], 0
            shortened = truncated_cg(grad, hess, pre, radius, path, deadline,
                                     m.cg_floor * grad_tol)
        step, h_step, on_boundary, length = shortened
        model_decrease = -(m.inner(grad, step) + 0.5 * m.inner(step, h_step))
        y_new = m.move(y, step)
        qy_new = problem.apply(y_new)
        if m.exact_decrease:
            actual = -m.inner(y_new - y, qy_new + qy)  # f - f(y_new), free of cancellation
        else:
            actual = f - m.inner(y_new, qy_new)
        rho = actual / model_decrease if model_decrease > 0 else -1.0
        if model_decrease <= 1e-15 * abs(f) and actual <= 1e-15 * abs(f):
            ended = None  # no progress left above round-off
            break
        if rho < 0.25:
            radius = 0.25 * (min(radius, length) if m.step_radius else radius)
        elif rho > 0.75 and on_boundary:
            radius *= 2.0
        rejected = not (rho > 0.1 or (actual > 0 and model_decrease <= 1e-12 * abs(f)))
        if not rejected:
            y, qy, f = y_new, qy_new, m.inner(y_new, qy_new)
        costs.append(f)
    return y, ended


def _shared_preconditioner(problem: Any, manifold: Manifold,
                           y: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """``0.5 P_Y (Q + delta I)^-1``: the problem's factor shared by the ranks."""
    factor = problem.preconditioner(manifold)
    return lambda v: 0.5 * manifold.project(y, problem.solve_shifted(factor, v))


def truncated_cg(grad, hess, pre, radius, path: list | None = None,
                 deadline: float | None = None, floor: float = 0.0):
    """Steihaug-Toint truncated CG for min <g, e> + <e, H e> / 2 in the preconditioner's
    norm ball of ``radius``; returns (step, H step, whether it stopped on the boundary, the
    step's length in the preconditioner's norm). ``path`` (if given) gets the iterations
    that a run with a quarter of the radius or less would stop in (see :func:`_shortened`).
    Once ``time.perf_counter()`` passes ``deadline`` (None: never) it stops after the
    iteration it is in (at least one runs): its step so far lowers the model as each of
    CG's iterates does. It stops at ``||r|| <= ||g|| min(||g||^theta, kappa)``, or at
    ``||r|| <= floor`` where that is larger."""
    step = np.zeros_like(grad)
    h_step = np.zeros_like(grad)
    residual = grad.copy()
    r0 = np.linalg.norm(grad)
    z = pre(residual)
    z_r = _inner(z, residual)
    direction = -z
    e_pe, e_pd, d_pd = 0.0, 0.0, z_r
    target = max(r0 * min(r0 ** CG_THETA, CG_KAPPA), floor)
    for inner in range(CG_MAX_INNER):
        if inner > 0 and _late(deadline):
            break
        h_dir = hess(direction)
        curvature = _inner(direction, h_dir)
        alpha = z_r / curvature if curvature > 0 else np.inf
        e_pe_new = e_pe + 2.0 * alpha * e_pd + alpha * alpha * d_pd
        if path is not None and e_pe < (0.25 * radius) ** 2:
            path.append((step, h_step, direction, h_dir, e_pe, e_pd, d_pd, curvature,
                         e_pe_new))
        if curvature <= 0 or e_pe_new >= radius * radius:
            tau = (-e_pd + np.sqrt(e_pd * e_pd + d_pd * (radius * radius - e_pe))) / d_pd
            return step + tau * direction, h_step + tau * h_dir, True, radius
        step = step + alpha * direction
        h_step = h_step + alpha * h_dir
        e_pe = e_pe_new
        residual = residual + alpha * h_dir
        if np.linalg.norm(residual) <= target:
            break
        z = pre(residual)
        z_r_old, z_r = z_r, _inner(z, residual)
        beta = z_r / z_r_old
        e_pd = beta * (e_pd + alpha * d_pd)
        d_pd = z_r + beta * beta * d_pd
        direction = -z + beta * direction
    return step, h_step, False, float(np.sqrt(max(e_pe, 0.0)))


def _shortened(path: list, radius: float) -> tuple | None:
    """What :func:`truncated_cg` returns for ``radius``, from the ``path`` a run with a
    radius at least 4 times larger recorded (CG's iterates do not depend on the radius until
    one leaves the ball; their preconditioned norm grows): the first recorded iteration
    whose direction has no positive curvature or whose next iterate leaves the ball is where
    the run stops, on the boundary, in the same arithmetic. None if no recorded iteration
    reaches the ball's edge (then CG has to run)."""
    for step, h_step, direction, h_dir, e_pe, e_pd, d_pd, curvature, e_pe_new in path:
        if curvature <= 0 or e_pe_new >= radius * radius:
            tau = (-e_pd + np.sqrt(e_pd * e_pd + d_pd * (radius * radius - e_pe))) / d_pd
            return step + tau * direction, h_step + tau * h_dir, True, radius
    return None


# --- verification, escape, certificate ------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Check:
    certified: bool  # lambda_min(S) >= -eta
    min_eigenvalue: float  # a proven floor under it where imprecise, NaN where not verified
    trace: float  # tr(Lambda) = f(Y)
    vector: np.ndarray | None  # eigenvector of lambda_min(S) where known
    imprecise: bool = False  # ARPACK did not converge on the eigenvalue(s) asked for


def unverified(problem: Any, y: np.ndarray) -> Check:
    """No verification (the time limit passed): lambda_min unknown, so no lower bound."""
    return Check(False, math.nan, problem.cost(y), None)



def verify(problem: Any, manifold: Manifold, y: np.ndarray, eta: float,
           before: Callable[[int], None] | None = None) -> Check:
    """lambda_min(S), S = Q - Lambda(Y), and whether S + eta I >= 0.

    ``before`` (None: nothing) is called before each sparse factorization and each of the
    eigen-solver's solves with the number of solves so far; it may raise :class:`TimeUp`,
    which ends the verification (the caller's deadline)."""
    m = manifold
    if before is not None:  # the eigen-solver's solves call it through the problem
        problem = _Counted(problem, before)
    lam = m.multipliers(y, problem.apply(y))
    trace = m.trace(lam)
    if m.size(problem.n) < m.dense_below:
        s = m.dense(problem, lam)
        values, vectors = np.linalg.eigh(0.5 * (s + s.conj().T))
        return Check(bool(values[0] >= -eta), float(values[0]), trace, vectors[:, 0])
    floor = -max(m.largest(lam), 0.0)  # lambda_min(S) >= -max Lambda as Q >= 0
    # S + eta I > 0  iff  the sparse matrix with Schur complement S + eta I has positive
    # pivots; the same LU then serves shift-invert at -eta
    if before is not None:
        before(0)
    factor = _factor(problem, m.shift(lam, -eta))
    negatives = _negative_pivots(m, factor)
    if negatives == 0:
        start = m.start(y)
        value, vector = _nearest_above(problem, m, factor, -eta, start,
                                       None if start is None else STARTED_NCV)
        if vector is None:  # the pivots proved lambda_min > -eta: that is the floor kept
            return Check(True, -eta, trace, None, imprecise=True)
        return Check(True, value, trace, vector)
    if negatives is not None and negatives <= m.max_below:
        values, vectors, converged = _below(problem, m, factor, -eta, negatives)
        if len(values) == 0:
            return Check(False, floor, trace, None, imprecise=True)
        k = int(np.argmin(values))
        return Check(False, float(values[k]) if converged else floor, trace, vectors[:, k],
                     imprecise=not converged)
    # many negative eigenvalues: shift below them all
    sigma = floor - eta - 1e-3 * problem.scale
    if before is not None:
        before(0)
    value, vector = _nearest_above(problem, m, problem.factor(m.shift(lam, sigma)), sigma, None,
                                   None)
    if vector is None:
        return Check(False, floor, trace, None, imprecise=True)
    return Check(bool(value >= -eta), value, trace, vector)


class _Counted:
    """A problem whose shifted solves first call ``before`` with the solves so far (the rest
    of the problem as it is)."""

    def __init__(self, problem: Any, before: Callable[[int], None]) -> None:
        self._problem, self._before, self._solves = problem, before, 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self._problem, name)

    def solve_shifted(self, factor: Any, v: np.ndarray) -> np.ndarray:
        self._before(self._solves)
        self._solves += 1
        return self._problem.solve_shifted(factor, v)


def _factor(problem: Any, shift: np.ndarray) -> Any:
    """``problem.factor(shift)``, or None where the LU met an exactly zero pivot (a zero
    eigenvalue: not positive definite)."""
    try:
        return problem.factor(shift)
    except RuntimeError:
        return None


def _negative_pivots(manifold: Manifold, factor: Any) -> int | None:
    """Number of eigenvalues of the factored ``Q + shift`` that are <= 0, from its
    pivot-free symmetric sparse LU (Sylvester's law of inertia; L is positive definite), or
    None when there is no LU or it pivoted off the diagonal (the count would not be an
    inertia)."""
    if factor is None:
        return None
    return manifold.negative_pivots(factor)


def negative_pivots(lu: Any) -> int | None:
    """Number of non-positive pivots of a pivot-free symmetric ``SuperLU`` (the inertia of
    the matrix's Schur complements, by Sylvester's law, where the eliminated block is positive
    definite), or None when it pivoted off the diagonal (the count would not be an inertia)."""
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return None
    return int(np.count_nonzero(np.real(lu.U.diagonal()) <= 0))


def _shifted_inverse(problem: Any, manifold: Manifold, factor: Any) -> LinearOperator:
    # scipy.sparse.linalg only here and in _eigsh: a small 3D graph certified by its dense
    # checks loads scipy.linalg alone (a command's run on tinyGrid3D: 0.02 s less)
    from scipy.sparse.linalg import LinearOperator

    size = manifold.size(problem.n)
    return LinearOperator((size, size), dtype=manifold.dtype,
                          matvec=lambda v: problem.solve_shifted(factor, v.reshape(-1, 1))[:, 0])


def _nearest_above(problem, manifold, factor, sigma, start,
                   ncv) -> tuple[float, np.ndarray | None]:
    """The smallest eigenvalue of S when all lie above sigma: the largest of (S - sigma)^-1
    (``factor``: of S - sigma I), from ``start`` (None: :func:`_fixed_start`) with ``ncv``
    Lanczos vectors (None: ARPACK's default); (NaN, None) when ARPACK did not converge."""
    size = manifold.size(problem.n)
    options = {} if ncv is None else {"ncv": min(ncv, size)}
    values, vectors, converged = _eigsh(
        _shifted_inverse(problem, manifold, factor), {**manifold.arpack_options, **options},
        k=1, which="LA", v0=_fixed_start(problem, manifold) if start is None else start,
        tol=1e-10)
    if not converged or len(values) == 0:
        return math.nan, None
    return float(sigma + 1.0 / np.real(values[0])), vectors[:, 0]


def _below(problem, manifold, factor, sigma, count) -> tuple[np.ndarray, np.ndarray, bool]:
    """The ``count`` eigenvalues of S below sigma: the most negative of (S - sigma)^-1; and
    whether ARPACK converged on all of them (if not, those it did converge on)."""
    values, vectors, converged = _eigsh(_shifted_inverse(problem, manifold, factor),
                                        manifold.arpack_options, k=count, which="SA",
                                        v0=_fixed_start(problem, manifold), tol=1e-8)
    return sigma + 1.0 / np.real(values), vectors, converged


def _fixed_start(problem: Any, manifold: Manifold) -> np.ndarray:
    """ARPACK's start where the manifold gives none: a normal sample that depends on the
    size only. ARPACK's own random start carries its seed from call to call, so the same
    graph verified twice in one process got lower bounds apart in the 4th digit."""
    rng = np.random.default_rng(0)
    size = manifold.size(problem.n)
    start = rng.standard_normal(size)
    if np.dtype(manifold.dtype).kind == "c":
        start = start + 1j * rng.standard_normal(size)
    return start


def _eigsh(op: LinearOperator, arpack_options: dict[str, Any],
           **options) -> tuple[np.ndarray, np.ndarray, bool]:
    """ARPACK's eigenpairs of ``op`` and whether all converged: a partial result (maybe
    empty) comes back with False; a failure is a SolverError."""
    from scipy.sparse.linalg import ArpackError, ArpackNoConvergence, eigsh

    try:
        values, vectors = eigsh(op, **arpack_options, **options)
    except ArpackNoConvergence as error:
        return np.asarray(error.eigenvalues), np.asarray(error.eigenvectors), False
    except ArpackError as error:
        raise SolverError(f"the minimum-eigenvalue computation failed: {error}") from None
    return values, vectors, True


def escape(problem: Any, manifold: Manifold, y: np.ndarray,
           vector: np.ndarray) -> tuple[np.ndarray, bool]:
    """Y at rank r + 1, lower than Y, along the eigenvector of lambda_min(S) in the new column
    (a second-order descent direction from the saddle [Y, 0]); and whether it descended (if
    not, after ``escape_halvings`` halvings, the last, shortest trial is returned)."""
    f0 = problem.cost(y)
    v = vector / np.max(np.abs(vector))
    alpha = 1.0
    for _ in range(manifold.escape_halvings):
        y_new = manifold.retract(np.hstack([y, alpha * v[:, None]]))
        if problem.cost(y_new) < f0:
            return y_new, True
        alpha *= 0.5
    return manifold.retract(np.hstack([y, alpha * v[:, None]])), False


def certificate(check: Check, estimate: float, eta: float, size: int, rank: int,
                started: float, stop: Status) -> Certificate:
    """The certificate of the rounded estimate (``size``: rows of ``Q``); ``stop``: the status
    when ``S`` is not known to be positive semidefinite (NaN numbers where nothing was
    verified)."""
    lower = check.trace + size * min(check.min_eigenvalue, 0.0)  # NaN stays NaN
    gap = max(estimate - lower, 0.0)
    if check.certified:
        exact = gap <= size * eta + GAP_TOLERANCE * abs(estimate)
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
