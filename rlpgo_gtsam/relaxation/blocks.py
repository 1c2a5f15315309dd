"""Operations on the spatial relaxation's stacked blocks: ``(3n, r)`` arrays whose rows come
in 3 x r blocks, one per pose (:mod:`~rlpgo_gtsam.relaxation.stiefel`'s ``Y``): their
symmetric parts, their polar factors (by SVD, or by Newton's iteration for square blocks)
and their *fields*, ``(3, r, n)`` arrays on which a blockwise product is one ``einsum``
over the poses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sym", "to_fields", "from_fields", "projected_fields", "polar_svd", "polar_newton"]

# Newton's iteration for the polar factor of a square block converges quadratically from
# any invertible one: it stops once no entry moved by more than _NEWTON_CHANGE (the error,
# squared at each step, is then at round-off), after _NEWTON_ITERATIONS at most. The
# retraction of 5000 rotations moved along random tangent steps (CPU ms): SVD 19, Newton 3.1
# (steps of 0.01, 2 iterations) to 8.5 (3.0, 8 iterations), entries within 1e-14 of the SVD's.
_NEWTON_CHANGE, _NEWTON_ITERATIONS = 1e-9, 50


def sym(a: np.ndarray) -> np.ndarray:
    """The symmetric parts of (k, 3, 3) blocks."""
    return 0.5 * (a + a.transpose(0, 2, 1))


def to_fields(a: np.ndarray) -> np.ndarray:
    """(3, r, n) fields ``F[i, k, p] = a[3p + i, k]`` of (3n, r) stacked blocks."""
    r = a.shape[1]
    return np.ascontiguousarray(a.reshape(-1, 3 * r).T).reshape(3, r, -1)


def from_fields(fields: np.ndarray) -> np.ndarray:
    """The (3n, r) stacked blocks of (3, r, n) fields (:func:`to_fields`' inverse)."""
    r = fields.shape[1]
    return np.ascontiguousarray(fields.reshape(3 * r, -1).T).reshape(-1, r)


def projected_fields(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The tangent projection ``V_i - sym(V_i X_i^T) X_i`` on (3, r, n) fields."""
    a = np.einsum("ikn,jkn->ijn", v, x)
    return v - np.einsum("ijn,jkn->ikn", 0.5 * (a + a.transpose(1, 0, 2)), x)


def polar_svd(x: np.ndarray) -> np.ndarray:
    """The polar factors of the 3 x r blocks of (3n, r) ``x``, from their SVDs."""
    r = x.shape[1]
    u, _, vt = np.linalg.svd(x.reshape(-1, 3, r), full_matrices=False)
    return (u @ vt).reshape(-1, r)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(3, n) the cross products of the columns of (3, n) ``u`` and ``v`` (np.cross's
    set-up took half of a 125-pose retraction)."""
    return np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def polar_newton(x: np.ndarray) -> np.ndarray:
    """The polar factors of the 3 x 3 blocks of (3n, 3) ``x`` by Newton's iteration
    ``X <- (X + X^-T) / 2`` on fields (``X^-T``: the rows' cross products over the
    determinant), until no entry of a block moves by more than :data:`_NEWTON_CHANGE`; a
    block left unconverged or not finite (singular) gets :func:`polar_svd`'s."""
    fields = to_fields(x)
    change = np.full(fields.shape[2], np.inf)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(_NEWTON_ITERATIONS):
            a, b, c = fields
            cofactors = np.stack([_cross(b, c), _cross(c, a), _cross(a, b)])
            new = 0.5 * (fields + cofactors / np.einsum("kn,kn->n", a, cofactors[0]))
            change = np.abs(new - fields).max(axis=(0, 1))
            fields = new
            if not np.any(change > _NEWTON_CHANGE):  # NaN blocks do not hold it up
                break
    polar = from_fields(fields)
    bad = np.flatnonzero(~(change <= _NEWTON_CHANGE))
    if len(bad):
        rows = (3 * bad[:, None] + np.arange(3)).ravel()
        polar[rows] = polar_svd(x[rows])
    return polar
