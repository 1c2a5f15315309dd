"""The Riemannian trust region of each rank of the staircase: :func:`trust_region` with
Steihaug-Toint truncated CG (:func:`truncated_cg`), on any
:class:`~rlpgo_gtsam.relaxation.problem.Manifold`.

A rank's trust region also ends where it stalls below the certificate's resolution
(:func:`stall_decrease`); the staircase then verifies ``S`` where it stands.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from rlpgo_gtsam.relaxation.certificate import Status
from rlpgo_gtsam.relaxation.problem import Manifold
from rlpgo_gtsam.relaxation.progress import Progress, Run

__all__ = ["trust_region", "truncated_cg", "stall_decrease", "late", "STALL_WINDOW",
           "STALL_FRACTION"]

# truncated CG stops at ||r|| <= ||g|| min(||g||^theta, kappa), or after max_inner iterations
CG_THETA, CG_KAPPA, CG_MAX_INNER = 1.0, 0.1, 200
# A rank's trust region stalls when its last STALL_WINDOW iterations lowered the cost by less
# than STALL_FRACTION x (rows of Q) x eta: the certificate's own resolution (its gap tolerance
# is rows x eta). The staircase then verifies S there: the bound tr(Lambda) + rows
# min(lambda_min, 0) holds at any Y, so a stalled Y with lambda_min >= -eta is solved to that
# resolution, and one below it is escaped from.
STALL_WINDOW, STALL_FRACTION = 10, 1e-2


def late(deadline: float | None, ahead: float = 0.0) -> bool:
    """Whether ``deadline`` (a ``time.perf_counter()`` time; None: none) has passed, or
    will have once ``ahead`` more seconds are spent."""
    return deadline is not None and time.perf_counter() + ahead > deadline


def stall_decrease(problem: Any, manifold: Manifold, eta: float) -> float:
    """The decrease below which a trust region's last ``STALL_WINDOW`` iterations stall."""
    return STALL_FRACTION * manifold.size(problem.n) * eta


def _inner(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.real(np.vdot(a, b)))


def trust_region(problem: Any, manifold: Manifold, y: np.ndarray, max_iterations: int,
                 grad_tol: float, deadline: float | None = None,
                 progress: Progress | None = None, run: Run | None = None,
                 stall: float = 0.0) -> tuple[np.ndarray, Status | None]:
    """A local minimum of f(Y) = tr(Y^* Q Y) on the manifold: Riemannian trust region with
    truncated CG (Steihaug-Toint), preconditioned by (Q + delta I)^-1 (the problem's
    :meth:`~rlpgo_gtsam.relaxation.problem.Relaxation.preconditioner`, one factor shared by
    the ranks), or, once a CG run took the manifold's ``hessian_preconditioner_after``
    Hessian products or more, by the problem's ``hessian_preconditioner`` at each new Y
    while that is positive definite. The decrease of a trial step and a rejected step's
    radius follow the manifold's ``exact_decrease`` and ``step_radius``.

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
    taken: list[bool] = []  # whether each iteration's step was taken
    rejected = False  # whether the last step was rejected
    path: list[tuple] = []  # the last CG run's path
    pre: Callable[[np.ndarray], np.ndarray]  # the last CG run's preconditioner
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
        if iteration >= STALL_WINDOW and costs[-1 - STALL_WINDOW] - f < stall \
                and any(taken[-STALL_WINDOW:]):
            # stalled below the certificate's resolution; a window of rejected steps alone
            # is the radius still shrinking to the model's reach (a range graph's first
            # radius can be 1e5 times too long), not a stall
            ended = None
            break
        if iteration == max_iterations:
            break
        if deadline is not None and time.perf_counter() > deadline:
            ended = Status.TIME_LIMIT
            break
        if not rejected:  # a rejected step's Y keeps its preconditioner (and CG path)
            held = None  # the Hessian's own preconditioner, where it is taken
            if m.hessian_preconditioner_after is not None and \
                    (hessian or products[0] >= m.hessian_preconditioner_after):
                if late(deadline, factor_s):  # a factorization is not cut once begun
                    ended = Status.TIME_LIMIT
                    break
                factoring = time.perf_counter()
                held = problem.hessian_preconditioner(m, y, lam)
                factor_s = max(factor_s, time.perf_counter() - factoring)
            hessian = held is not None
            if held is None:
                factoring = time.perf_counter()
                pre = _shared_preconditioner(problem, m, y)  # factored once, then cached
                factor_s = max(factor_s, time.perf_counter() - factoring)
            else:
                pre = held

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
        taken.append(not rejected)
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
        if inner > 0 and late(deadline):
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
