"""The verification of ``S = Q - Lambda(Y)`` at a staircase's point: ``lambda_min(S)`` and
whether ``S + eta I >= 0`` (:func:`verify`), dense below a size; else Sylvester's inertia
from a pivot-free sparse LU, then ARPACK's shift-invert from the same factor.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.relaxation.certificate import Check
from rlpgo_gtsam.relaxation.problem import Manifold, factor_or_none

if TYPE_CHECKING:
    from scipy.sparse.linalg import LinearOperator

__all__ = ["verify", "unverified", "TimeUp", "STARTED_NCV"]

# Lanczos vectors where ARPACK starts from the manifold's start (Y's first column, in S's
# null space at a critical point): 7 to 10 shift-invert solves where the default 20 took 21,
# on the shared 2D and 3D files, same eigenvalues to ARPACK's tolerance
STARTED_NCV = 6


class TimeUp(Exception):
    """The deadline passed inside a step that has no partial result to hand over (the
    verification of ``S``: its factorization and eigen-solver's solves): the caller rounds
    the ``Y`` it has, unverified."""


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
    # S is zero on the problem's flat rows (if any) and apart from the others
    lam = problem.decoupled(m.multipliers(y, problem.apply(y)))
    flat = problem.flat
    trace = m.trace(lam)  # tr(Lambda) = f(Y)
    if m.size(problem.n) < m.dense_below:
        s = m.dense(problem, lam)
        if flat is not None:
            kept = np.delete(np.arange(len(s)), flat)
            values, found = np.linalg.eigh(_symmetric(s[np.ix_(kept, kept)]))
            vectors = np.zeros((len(s), len(values)), found.dtype)
            vectors[kept] = found
        else:
            values, vectors = np.linalg.eigh(_symmetric(s))
        return Check(bool(values[0] >= -eta), float(values[0]), trace, vectors[:, 0])
    floor = -max(m.largest(lam), 0.0)  # lambda_min(S) >= -max Lambda as Q >= 0
    # S + eta I > 0  iff  the sparse matrix with Schur complement S + eta I has positive
    # pivots; the same LU then serves shift-invert at -eta
    if before is not None:
        before(0)
    factor = factor_or_none(problem, m.shift(lam, -eta))
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


def _symmetric(s: np.ndarray) -> np.ndarray:
    return 0.5 * (s + s.conj().T)


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


def _negative_pivots(manifold: Manifold, factor: Any) -> int | None:
    """Number of eigenvalues of the factored ``Q + shift`` that are <= 0, from its
    pivot-free symmetric sparse LU (Sylvester's law of inertia; L is positive definite), or
    None when there is no LU or it pivoted off the diagonal (the count would not be an
    inertia)."""
    if factor is None:
        return None
    return manifold.negative_pivots(factor)


def _shifted_inverse(problem: Any, manifold: Manifold, factor: Any) -> LinearOperator:
    # scipy.sparse.linalg only here and in _eigsh: a small 3D graph certified by its dense
    # checks loads scipy.linalg alone (a command's run on tinyGrid3D: 0.02 s less)
    from scipy.sparse.linalg import LinearOperator

    size, flat = manifold.size(problem.n), problem.flat

    def matvec(v: np.ndarray) -> np.ndarray:
        v = v.reshape(-1, 1)
        if flat is None:
            return problem.solve_shifted(factor, v)[:, 0]
        # S's zero rows are apart from the rest (decoupled): the inverse keeps them apart
        v = v.copy()
        v[flat] = 0.0
        w = problem.solve_shifted(factor, v)[:, 0]
        w[flat] = 0.0
        return w

    return LinearOperator((size, size), dtype=manifold.dtype, matvec=matvec)


def _nearest_above(problem, manifold, factor, sigma, start,
                   ncv) -> tuple[float, np.ndarray | None]:
    """The smallest eigenvalue of S when all lie above sigma: the largest of (S - sigma)^-1
    (``factor``: of S - sigma I), from ``start`` (None: :func:`_fixed_start`) with ``ncv``
    Lanczos vectors (None: ARPACK's default); (NaN, None) when ARPACK did not converge."""
    size = manifold.size(problem.n)
    options = {} if ncv is None else {"ncv": min(ncv, size)}
    values, vectors, converged = _eigsh(
        _shifted_inverse(problem, manifold, factor), {**manifold.arpack_options, **options},
        k=1, which="LA", v0=_fixed_start(problem, manifold) if start is None else
        _masked_start(problem, start), tol=1e-10)
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
    return _masked_start(problem, start)


def _masked_start(problem: Any, start: np.ndarray) -> np.ndarray:
    """``start`` without the problem's :attr:`~Relaxation.flat` rows."""
    if problem.flat is None:
        return start
    start = start.copy()
    start[problem.flat] = 0.0
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
