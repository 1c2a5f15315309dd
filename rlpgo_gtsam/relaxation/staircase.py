"""The Riemannian staircase, written once for both relaxations, and its entry points.

:func:`synchronize` solves the relaxation of a pose graph's rotations (planar:
:mod:`~rlpgo_gtsam.relaxation.circles`, spatial: :mod:`~rlpgo_gtsam.relaxation.stiefel`,
chosen by ``pose_graph.dimension``) by :func:`climb`: a trust region at each rank
(:mod:`~rlpgo_gtsam.relaxation.trust_region`), the verification of ``S = Q - Lambda``
(:mod:`~rlpgo_gtsam.relaxation.verification`), the :func:`escape` from a saddle into the
next rank; it rounds the last ``Y``, polishes the rounded estimate at the lowest rank where
the staircase climbed (:func:`polish`) and returns it with its
:class:`~rlpgo_gtsam.relaxation.certificate.Certificate`. :func:`certify` verifies a given
estimate, :func:`relaxation_cost` prices one, :func:`descend` moves the chordal estimate
downhill at the lowest rank without a proof.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from rlpgo_gtsam.anchoring import anchoring
from rlpgo_gtsam.errors import GraphError, SolverError
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.relaxation.certificate import (
    GAP_CAP,
    Certificate,
    Check,
    Status,
    certificate,
    only_loose,
)
from rlpgo_gtsam.relaxation.problem import Manifold, Relaxation
from rlpgo_gtsam.relaxation.progress import Progress, Run
from rlpgo_gtsam.relaxation.trust_region import late, stall_decrease, trust_region
from rlpgo_gtsam.relaxation.verification import TimeUp, unverified, verify

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph

__all__ = ["synchronize", "certify", "relaxation_cost", "descend", "relaxation_type", "climb",
           "polish", "escape", "check_start", "POLISH_SHARE"]

# A staircase with a deadline that climbs above its first rank keeps this share of the time
# then left for the polish of its rounded estimate (the rounding of a higher rank's Y can land
# far uphill: see polish): a 2000-pose generated graph whose deadline cut it at rank 2 had a
# rounded chi2 of 1.5e6 unpolished.
POLISH_SHARE = 0.25
# Where a solved relaxation's bound misses the rounded estimate only by rows x lambda_min, the
# trust region goes on at this share of the gradient tolerance (see synchronize).
SHARPEN = 1e-3


@numeric_call
def synchronize(pose_graph: PoseGraph, start: np.ndarray | None = None, *,
                max_rank: int = 10, tolerance: float | None = None,
                initial_rank: int | None = None, max_iterations: int = 300,
                gradient_tolerance: float | None = None, time_limit_s: float | None = None,
                progress: Callable[[str], None] | None = None,
                finish_per_start: float = 0.0) -> tuple[np.ndarray, Certificate]:
    """The rotations of the rounded estimate (the anchor keeps its own) in the group's form
    (planar: angles (n,); spatial: matrices (n, 3, 3)), and their certificate.

    A graph that holds more than its gauge (several FIXed poses, or priors beside a FIX line
    or each other) is solved as its one-anchor problem
    (:func:`~rlpgo_gtsam.anchoring.anchoring`): its held poses keep their rotations and the
    certificate covers its FIX lines and priors (``Certificate.fixed_poses``, ``priors``).

    Args:
        pose_graph: a planar or spatial pose graph (by its ``dimension``); its anchor's
            rotation fixes the gauge.
        start: rotations to start the staircase from, in the form returned; by default the
            chordal estimate.
        max_rank: the staircase stops at this rank (certified or not).
        tolerance: eta; default ``1e-7 x mean(diag Q)``.
        initial_rank: the staircase's first rank, from the lowest (the rotation problem
            itself: complex rank 1 in the plane, real rank 3 in space) to ``max_rank``;
            None: the lowest.
        max_iterations: trust-region iterations per rank.
        gradient_tolerance: stop a rank when the Riemannian gradient norm falls below this
            times ``sqrt(n) x mean(diag Q)``; None: the dimension's (planar 1e-9, spatial
            1e-6, see each problem's ``gradient_tolerance``).
        time_limit_s: checked before each trust-region and truncated-CG iteration, each
            factorization and each solve of the verification (:func:`climb`): once the call
            has run this long it rounds the lowest ``Y`` reached and returns it with status
            ``time_limit``. None: no limit.
        progress: called with one short line per rank (rank, trust-region iterations, cost,
            gradient norm, lambda_min, seconds so far), one after the rounded estimate's
            polish (where the staircase climbed) and, inside a long trust region or
            verification, one line at most every 2 s. None: silent.
        finish_per_start: the seconds the caller's steps after this call take, in seconds
            of the chordal start (timed here: it slows down with the machine's load as they
            do): the staircase rounds what it has once what is left of ``time_limit_s``
            only holds them. 0 (and from a given ``start``): the whole limit is the call's.

    The certificate's ``status`` says how the staircase ended
    (:class:`~rlpgo_gtsam.relaxation.certificate.Status`). Where the final rank is not
    certified, more than one reason may hold; the first of these is told:
    ``eigenvalue_imprecise``, ``saddle_escape_failed`` (the escape into the final rank),
    ``iteration_limit`` (at the final rank), ``rank_limit``.

    Raises:
        SolverError: bad ranks, tolerance or time limit, a ``start`` of the wrong shape, or
            a graph whose translations or rotations the measurements do not determine.
        GraphError: negative or non-finite information.
    """
    anchored = anchoring(pose_graph)
    if anchored is not None:
        reduced_start = None if start is None else anchored.reduced_rotations(start)
        rotations, proof = synchronize(
            anchored.graph, reduced_start, max_rank=max_rank, tolerance=tolerance,
            initial_rank=initial_rank, max_iterations=max_iterations,
            gradient_tolerance=gradient_tolerance, time_limit_s=time_limit_s,
            progress=progress, finish_per_start=finish_per_start)
        return anchored.lifted_rotations(rotations), anchored.covering(proof)
    kind = relaxation_type(pose_graph)  # its first call imports the module: not the solve's time
    started = time.perf_counter()
    lowest = kind.lowest_rank
    initial_rank = lowest if initial_rank is None else initial_rank
    deadline = check_start(started, initial_rank, max_rank, lowest, time_limit_s)
    problem = kind(pose_graph)
    eta = problem.tolerance(tolerance)
    starting = time.perf_counter()
    first = problem.start(start)
    if deadline is not None and start is None:
        deadline -= finish_per_start * (time.perf_counter() - starting)
    manifold = problem.manifold()
    y: np.ndarray = np.zeros((manifold.size(problem.n), initial_rank), manifold.dtype)
    y[:, :lowest] = first
    grad_tol = _gradient_tolerance(problem, gradient_tolerance)
    y, check = problem.verified_shortcut(manifold, y, eta, grad_tol, deadline,
                                         Progress(progress, started))
    stop = Status.RANK_LIMIT  # told only where S is not positive semidefinite
    if check is None:
        y, check, stop = climb(problem, manifold, y, eta, max_rank, max_iterations, grad_tol,
                               deadline, progress, started)
    size = manifold.size(problem.n)
    rotations, estimate = _rounded(problem, manifold, y, eta, max_iterations, grad_tol,
                                   deadline, progress, started)
    if only_loose(check, estimate, eta, size) and not late(deadline):
        # the rounded estimate attains f(Y) but lambda_min's share of the bound hides it:
        # the staircase goes on from Y to a tighter gradient (an exactly measured range
        # graph: lambda_min -2.6e-6 at 1e-9, -5e-13 at 1e-11 against a cost of 3e-11), and
        # escapes where a negative eigenvalue that eta let pass is still large enough to
        # hide the gap (with heavy weights eta can pass a saddle)
        sharp_eta = min(eta, GAP_CAP * max(abs(estimate), 1.0) / size)
        sharper = climb(problem, manifold, y, sharp_eta, max_rank, max_iterations,
                        grad_tol * SHARPEN, deadline, progress, started)
        if sharper[1].certified:
            y, check, stop = sharper
            rotations, estimate = _rounded(problem, manifold, y, eta, max_iterations, grad_tol,
                                           deadline, progress, started)
    return rotations, certificate(check, estimate, eta, size, y.shape[1], started, stop)


def _rounded(problem: Relaxation, manifold: Manifold, y: np.ndarray, eta: float,
             max_iterations: int, grad_tol: float, deadline: float | None,
             progress: Callable[[str], None] | None, started: float
             ) -> tuple[np.ndarray, float]:
    """The rotations rounded from ``y`` (polished where ``y`` is above the lowest rank), the
    anchor's turned back, and the relaxation's cost of them."""
    rotations = problem.rounded(y)
    if y.shape[1] > problem.lowest_rank:
        rotations = problem.unstacked(polish(problem, manifold, problem.stacked(rotations), eta,
                                             max_iterations, grad_tol, deadline, progress,
                                             started))
    rotations, rounded = problem.anchored(rotations)
    return rotations, problem.cost(rounded)


@numeric_call
def certify(pose_graph: PoseGraph, rotations: np.ndarray, *,
            tolerance: float | None = None) -> Certificate:
    """The certificate of given rotations (angles (n,) planar, matrices (n, 3, 3) spatial)
    at the lowest rank, no optimization.

    ``Lambda`` is computed at the estimate itself: a non-critical one (e.g. the odometry
    guess of a loopy graph) gets a clearly negative ``lambda_min(S)`` (status
    ``not_optimal``), so it is not certified and its suboptimality bound is positive.
    """
    anchored = anchoring(pose_graph)
    if anchored is not None:
        return anchored.covering(certify(anchored.graph, anchored.reduced_rotations(rotations),
                                         tolerance=tolerance))
    started = time.perf_counter()
    problem = relaxation_type(pose_graph)(pose_graph)
    eta = problem.tolerance(tolerance)
    y = problem.given(rotations)
    manifold = problem.manifold()
    check = verify(problem, manifold, y, eta)
    stop = Status.EIGENVALUE_IMPRECISE if check.imprecise else Status.NOT_OPTIMAL
    return certificate(check, problem.cost(y), eta, manifold.size(problem.n),
                       problem.lowest_rank, started, stop)


def relaxation_cost(pose_graph: PoseGraph, rotations: np.ndarray) -> float:
    """The relaxation's cost with the translations eliminated, ``min_t F(R, t)``, at given
    rotations (angles (n,) planar, matrices (n, 3, 3) spatial): about chi2 plus chi2's
    rotational part near a good estimate; of the one-anchor problem where the graph holds
    more than its gauge (its constant terms, edges between held poses, left out)."""
    anchored = anchoring(pose_graph)
    if anchored is not None:
        return relaxation_cost(anchored.graph, anchored.reduced_rotations(rotations))
    problem = relaxation_type(pose_graph)(pose_graph)
    return problem.cost(problem.given(rotations))


@numeric_call
def descend(pose_graph: PoseGraph, *, max_iterations: int,
            gradient_tolerance: float | None = None) -> np.ndarray:
    """Rotations (in :func:`synchronize`'s form) of the rotation problem (the relaxation at
    its lowest rank) descended from the chordal estimate by at most ``max_iterations``
    trust-region iterations, with the staircase's tolerances: :func:`synchronize`'s first
    rank without its verification (no certificate, no escape), for a caller that wants
    good rotations and no proof (the robust path's start: on City10K with 10% local wrong
    closures the verification of that one rank took 6 s of sparse factorizations, against
    1 s for the descent). The anchor keeps its rotation."""
    problem = relaxation_type(pose_graph)(pose_graph)
    eta = problem.tolerance(None)
    grad_tol = _gradient_tolerance(problem, gradient_tolerance)
    y = polish(problem, problem.manifold(), problem.start(None), eta, max_iterations, grad_tol,
               None)
    return problem.anchored(problem.unstacked(y))[0]


def relaxation_type(pose_graph: PoseGraph) -> type[Relaxation]:
    """The relaxation of a pose graph's dimension (its module imported on first use: a
    planar run loads no spatial code, a small spatial one no sparse SciPy).

    Raises:
        GraphError: a dimension other than 2 or 3.
    """
    dimension = getattr(pose_graph, "dimension", None)
    if dimension == 2:
        from rlpgo_gtsam.relaxation.circles import PlanarProblem

        return PlanarProblem
    if dimension == 3:
        from rlpgo_gtsam.relaxation.stiefel import SpatialProblem

        return SpatialProblem
    raise GraphError(f"the relaxation takes planar or spatial pose graphs, got dimension "
                     f"{dimension!r}")


def _gradient_tolerance(problem: Relaxation, relative: float | None) -> float:
    """A rank's gradient tolerance: ``relative`` (None: the problem's) times ``sqrt(n) x
    scale``."""
    relative = problem.gradient_tolerance if relative is None else relative
    return relative * math.sqrt(problem.n) * problem.scale


# --- the staircase ---------------------------------------------------------------------------

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
    stall = stall_decrease(problem, manifold, eta)
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
        # verify leaves out the eigenvector only where it is imprecise: stopped above
        assert check.vector is not None
        y, escaped = escape(problem, manifold, y, check.vector)
    return y, check, stop


def _verifying(deadline: float | None, report: Progress, rank: int, solves: int) -> None:
    """Before each long step of :func:`verify` (``solves``: the eigen-solver's solves so
    far): TimeUp once ``deadline`` has passed; a progress line at most every 2 s."""
    if late(deadline):
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
                        stall_decrease(problem, manifold, eta))
    if progress is not None:
        progress(f"rounded estimate polished: {run.iterations} iterations, cost "
                 f"{run.cost:.9g}, gradient {run.gradient:.3g}, "
                 f"{time.perf_counter() - report.started:.1f} s")
    return y


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


