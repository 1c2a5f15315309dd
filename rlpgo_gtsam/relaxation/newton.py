"""Newton's method at the lowest rank (3) of a small spatial relaxation: the point the
staircase's first trust region would stop at, reached in fewer, exact steps where ``Q`` is a
dense matrix (:class:`~rlpgo_gtsam.relaxation.stiefel.SpatialProblem`'s
``verified_shortcut``).
"""

from __future__ import annotations

import functools
import time
from typing import Protocol

import numpy as np

from rlpgo_gtsam.linear import potrf, potrs
from rlpgo_gtsam.relaxation.blocks import sym
from rlpgo_gtsam.se3 import exp_so3

__all__ = ["newton_point", "DenseProblem"]


class DenseProblem(Protocol):
    """What Newton's method reads of a spatial relaxation: ``n`` poses and its dense ``Q``."""

    n: int
    q: np.ndarray

_EYE = np.eye(3)
# Newton's factorizations at most (damped retries included) before the staircase's trust
# region takes over.
_NEWTON_STEPS = 30
# The damping added where a Newton step fails (H + mu I not positive definite, or no
# descent): first this fraction of H's mean diagonal, then 10 times more per failure; a
# successful step divides it by 10, and below _DAMPING x 1e-3 it is dropped (pure Newton).
_DAMPING = 1e-3
# The entries of -[v]_x: rows, columns, which component of v, and its sign.
_SKEW_ROWS, _SKEW_COLS = np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])
_SKEW_FROM, _SKEW_SIGNS = np.array([2, 1, 2, 0, 1, 0]), np.array([1.0, -1.0, -1.0, 1.0, 1.0, -1.0])
_COLUMNS = np.arange(3)[:, None, None]  # c, over (c, pose, entry)
_BLOCK_ROWS, _BLOCK_COLS = np.arange(3)[:, None], np.arange(3)  # a 3x3 block's (a, b)


@functools.lru_cache(maxsize=64)
def _newton_layout(n: int, anchor: int) -> tuple[np.ndarray, ...]:
    """Where :func:`newton_point`'s arrays go, for ``n`` poses with the anchor held: the flat
    places in ``K_0; K_1; K_2`` ((9n, 3n - 3): the anchor has no column) of the entries
    ``K_c[3p + a, 3q + b] = sign x[3p + e, c]`` (``q``: pose p among the free ones; the six
    ``(a, b, e, sign)`` of ``-[v]_x``), those entries' places in ``x``, the places of the
    free poses' diagonal blocks in H, and the free poses. Index patterns of a size alone,
    made once per size (the robust path's subgraphs share theirs; 0.14 ms of tinyGrid3D's
    run), read only."""
    size, columns = 3 * n, 3 * (n - 1)
    free = np.delete(np.arange(n), anchor)
    p, q = 3 * free[:, None], 3 * np.arange(n - 1)[:, None]
    target = _COLUMNS * size * columns + (p + _SKEW_ROWS) * columns + q + _SKEW_COLS
    source = 3 * (p + _SKEW_FROM) + _COLUMNS
    on_diagonal = (columns + 1) * q[:, :, None] + columns * _BLOCK_ROWS + _BLOCK_COLS
    layout = (target.ravel(), source, on_diagonal.ravel(), free)  # source: (3, n - 1, 6)
    for array in layout:
        array.setflags(write=False)
    return layout


def newton_point(problem: DenseProblem, x: np.ndarray, grad_tol: float, anchor: int,
                 deadline: float | None) -> tuple[np.ndarray, bool]:
    """The rank-3 start ``x`` (3n, 3) moved by a damped Newton's method on ``f(X) = tr(X^T Q
    X)`` for a dense problem, until the Riemannian gradient's norm is at most ``grad_tol``
    (the trust region's own stop test, in the same arithmetic: it would end at its first
    iteration there), for at most :data:`_NEWTON_STEPS` factorizations; and whether it got
    there (else the trust region goes on from where it stopped).

    Each block moves as ``X_i <- Exp(w_i) X_i``, the anchor's ``w`` held at 0 (the gauge:
    the Hessian is singular along a common rotation); the step solves ``(H + mu I) w = -g``
    for the others with half the exact gradient and Hessian of ``w -> f(Exp(w) X)`` at 0
    (the same step): ``K_c`` (3n x 3(n-1), a block for each free pose, ``-[X_i[:, c]]_x``)
    maps ``w`` to column c of the blocks ``[w_i]_x X_i``, so ``g = sum_c K_c^T (Q X)_c``
    and ``H = sum_c K_c^T Q K_c + diag(Lambda_i - tr(Lambda_i) I)``, three dense products
    each (:func:`_newton_layout`). A step is taken where it lowers the cost; ``mu``
    (Levenberg-Marquardt's rule, :data:`_DAMPING`) handles a start far from the minimum,
    where ``H`` is indefinite (smallGrid3D's chordal estimate). Near the minimum ``mu =
    0``: quadratic convergence, 3 steps on tinyGrid3D (gradient 54 -> 2e-6 against a
    tolerance of 2e-4), where the trust region took 6 iterations and 10 Hessian
    products."""
    n = problem.n
    size, columns = 3 * n, 3 * (n - 1)
    q = problem.q
    target, source, on_diagonal, free = _newton_layout(n, anchor)
    diagonal = np.arange(columns)
    blocks = np.zeros(3 * size * columns)
    w = np.zeros((n, 3))
    qx = q @ x
    mu, fresh, converged = 0.0, True, False
    for _ in range(_NEWTON_STEPS):
        if fresh:
            xb, qb = x.reshape(n, 3, 3), qx.reshape(n, 3, 3)
            lam = sym(qb @ xb.transpose(0, 2, 1))
            converged = bool(np.linalg.norm(qb - lam @ xb) <= 0.5 * grad_tol)
            if converged or (deadline is not None and time.perf_counter() > deadline):
                break
            blocks[target] = (x.ravel()[source] * _SKEW_SIGNS).ravel()
            k = blocks.reshape(3 * size, columns)  # K_0; K_1; K_2 stacked
            g = k.T @ qx.T.ravel()
            h = k.T @ (q @ blocks.reshape(3, size, columns)).reshape(3 * size, columns)
            lam_free = lam[free]
            traces = np.einsum("kii->k", lam_free)
            h.ravel()[on_diagonal] += (lam_free - traces[:, None, None] * _EYE).ravel()
        damped = h.copy() if mu else h
        if mu:
            damped[diagonal, diagonal] += mu
        lower, info = potrf(damped)  # h is kept for a damped retry
        fresh = False
        if info == 0:
            w[free] = potrs(lower, -g).reshape(-1, 3)
            x_new = (exp_so3(w) @ xb).reshape(-1, 3)
            qx_new = q @ x_new
            fresh = -float(((x_new - x) * (qx_new + qx)).sum()) > 0  # exact decrease
        if fresh:
            x, qx = x_new, qx_new
            if mu:
                mu = 0.0 if mu < 1e-2 * _damping_floor(h) else 0.1 * mu
        else:
            mu = max(10.0 * mu, _damping_floor(h))
    return x, converged


def _damping_floor(h: np.ndarray) -> float:
    """Newton's first damping: :data:`_DAMPING` times the mean diagonal of ``h``."""
    return _DAMPING * float(np.trace(h)) / len(h)
