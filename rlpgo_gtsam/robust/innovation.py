"""How well a map explains a set of closures, given how well it knows their poses.

The verify step judges every closure (and sets of them) at the optimum of the kept edges by
the chi2 of its residual under the map's own uncertainty. With GTSAM's linearization at that
optimum (whitened rows ``A_S``, residuals ``b_S``), ``P`` the map's covariance (inverse
Hessian of the kept edges, held poses fixed, and so are poses no kept edge joins to a held
one: untrusted odometry rejected on both sides of a pose) and ``C_S = A_S P A_S^T``:

- edges left out: ``b_S^T (I + C_S)^-1 b_S``, the innovation: how far their measurements lie
  from what the map predicts, given how well the map knows their poses;
- kept edges: ``b_S^T (I - C_S)^-1 b_S``, the same number for the map without them
  (leave-them-out): closures that alone hold a stretch of the map (high leverage, ``C_S``
  near I) fit well because they bent it, and this undoes that.

Each is the linearized change of the optimum's chi2 when the set is added or removed:
chi-square with ``dof |S|`` dof for true edges. The covariances ``I -+ C_S`` are those of the
residuals themselves under the model, estimated from ``samples`` draws of whitened noise
``z`` on every kept edge (:attr:`~rlpgo_gtsam.robust.problem.Problem.noise`): it moves the
optimum by ``P A^T z`` and leaves a kept edge the residual ``z_e - A_e P A^T z``; a left-out
edge sees ``z_e + A_e P A^T z``. One sparse factorization and one multi-column solve serve
every set; the estimate's relative error, about ``sqrt(2 / samples)``, is the same at any
leverage (estimating ``C_S`` and subtracting it from I would not be: near I the difference is
noise). The statistic is therefore Hotelling's, not chi-square
(:mod:`rlpgo_gtsam.robust.statistics`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import gtsam
import numpy as np

from rlpgo_gtsam.robust.problem import Problem

__all__ = ["Draws", "SetStatistics", "innovation_draws", "set_statistics"]


@dataclass
class Draws:
    """What :func:`set_statistics` needs of a map: the draws' residuals ``residual`` (m, dof,
    samples), the whitened residuals ``b`` (m, dof) and the edges' information factors
    ``upper`` (m, dof, dof), ``upper^T upper = information``."""

    residual: np.ndarray
    b: np.ndarray
    upper: np.ndarray


class SetStatistics(NamedTuple):
    """Per set of edges: ``chi2`` (the statistic), ``spread`` (the geometric mean of its
    residual covariance's eigenvalues: how loosely the map checks it) and ``turn`` (radians:
    the largest rotation by which the map would have to move one of the set's relative poses
    to explain its residual)."""

    chi2: np.ndarray
    spread: np.ndarray
    turn: np.ndarray


def innovation_draws(problem: Problem, values: gtsam.Values, kept: np.ndarray) -> Draws:
    """The draws at ``values`` (the optimum of the ``kept`` edges): one sparse factorization
    of the kept edges' Hessian and one multi-column solve; :func:`set_statistics` reads any
    sets off them."""
    import scipy.sparse as sp  # scipy: loaded when first used
    from scipy.sparse.linalg import splu

    g, samples, block = problem.g, problem.settings.samples, problem.settings.solve_block
    dof = problem.group.dof
    # GTSAM orders the columns by key (sorted, as the pose indices are), dof per pose;
    # the last column is the right-hand side
    rows, cols, entries = problem.edges.linearize(values).sparseJacobian_()
    rows, cols = rows.astype(np.int64) - 1, cols.astype(np.int64) - 1  # 1-based
    size = dof * g.num_poses
    is_b = cols == size
    b_rows = np.zeros(dof * len(kept))
    b_rows[rows[is_b]] = entries[is_b]
    b = b_rows.reshape(-1, dof)
    free = np.ones(size, bool)
    free[(dof * problem.unplaced(kept)[:, None] + np.arange(dof)).ravel()] = False
    a_edges = sp.csr_matrix((entries[~is_b], (rows[~is_b], cols[~is_b])),
                            shape=(dof * len(kept), size))[:, free]
    a_kept = a_edges[np.repeat(kept, dof)]
    # the Hessian is symmetric positive definite: a symmetric ordering without pivoting
    # fills half as much as COLAMD (M3500: 0.38 M against 0.62 M entries), and SuperLU
    # solves the draws fastest in blocks of a few columns
    factor = splu((a_kept.T @ a_kept).tocsc(), permc_spec="MMD_AT_PLUS_A",
                  diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    noise = problem.noise
    pushed = np.asarray(a_kept.T @ noise[kept].reshape(-1, samples))
    shift = np.column_stack([factor.solve(np.asfortranarray(pushed[:, k:k + block]))
                             for k in range(0, samples, block)])
    # the draws' residuals, in place: z_e - A_e P A^T z on kept edges, z_e + A_e P A^T z on
    # the others
    residual = np.asarray(a_edges @ shift).reshape(len(kept), dof, samples)
    residual[kept] *= -1.0
    residual += noise
    return Draws(residual, b, problem.information_factor)


def set_statistics(problem: Problem, draws: Draws,
                   sets: list[np.ndarray] | np.ndarray) -> SetStatistics:
    """Per set of edges (all kept or all left out), its statistic at the map of ``draws``, the
    spread of its residual covariance and its turn (see :class:`SetStatistics`). ``sets``: a
    list of index arrays, or an (n, size) array of n sets of one size."""
    group, samples = problem.group, problem.settings.samples
    dof = group.dof
    residual, b, upper = draws.residual, draws.b, draws.upper
    chi2_sets, spread, turn = np.empty(len(sets)), np.empty(len(sets)), np.empty(len(sets))
    if isinstance(sets, np.ndarray):  # one size, a set per row
        groups = [(np.arange(len(sets)), sets)] if len(sets) else []
    else:
        sizes = np.array([len(which) for which in sets])
        groups = [(index, np.array([sets[n] for n in index.tolist()]))
                  for index in (np.flatnonzero(sizes == size_)
                                for size_ in np.unique(sizes).tolist())]
    for index, members in groups:  # sets of one size at once
        size_ = members.shape[1]
        drawn = residual[members].reshape(len(index), dof * size_, samples)
        eigenvalues, vectors = np.linalg.eigh(drawn @ drawn.transpose(0, 2, 1) / samples)
        whitened = np.einsum("sab,sa->sb", vectors, b[members].reshape(len(index), -1))
        eigenvalues = np.maximum(eigenvalues, problem.settings.leverage_floor)
        # the inverse of a covariance estimated from k draws overstates by k / (k - p - 1)
        unbiased = (samples - dof * size_ - 1) / samples
        chi2_sets[index] = unbiased * np.einsum("sb,sb->s", whitened ** 2, 1.0 / eigenvalues)
        spread[index] = np.exp(np.log(eigenvalues).mean(axis=1))
        # the move of the edges' relative poses that explains the residual: b - S^-1 b
        # (whitened), then in each edge's own coordinates; its largest rotation
        explained = b[members].reshape(len(index), -1) - np.einsum(
            "sab,sb->sa", vectors, whitened / eigenvalues)
        moved_edges = np.linalg.solve(upper[members.ravel()],
                                      explained.reshape(-1, dof, 1))[..., 0]
        turn[index] = np.linalg.norm(moved_edges[:, group.rotation_axes], axis=1).reshape(
            len(index), size_).max(axis=1)
    return SetStatistics(chi2_sets, spread, turn)
