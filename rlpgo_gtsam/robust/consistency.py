"""Cycle consistency of loop closures: which closures agree with their neighbours.

Two loop closures whose ends lie a few steps apart along the odometry chain close a short
cycle through it; with the cycle's covariance propagated to first order from every
measurement in it, its error tells whether the two closures agree. See
:func:`consistent_closures`.
"""

from __future__ import annotations

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.se2 import adjoint, chain, compose, inverse, logmap
from rlpgo_gtsam.se2 import between as relative_pose

__all__ = ["consistent_closures", "WINDOW", "LOOSE_SUPPORT"]

# Closures whose ends lie this many chain steps apart are compared, ...
WINDOW = 15
# ... a closure needs this many agreeing neighbours in informative tests, ...
_MIN_SUPPORT = 2
# ... or this many in any test for loose support, ...
LOOSE_SUPPORT = 3
# ... a pair agrees below this many times the median score (or the chi-square threshold), ...
_DATA_SCALE = 20.0
# ... and a pair counts only where a wrong closure would agree by chance less often than this.
_CHANCE = 1e-2


def consistent_closures(g: PoseGraph2D, chain_mask: np.ndarray,
                         threshold: float) -> tuple[np.ndarray, np.ndarray, int]:
    """(m,) bool twice, then the number of pairs tested: the closures that agree with at
    least ``_MIN_SUPPORT`` nearby closures in informative tests (the seed), and those that
    agree with at least ``LOOSE_SUPPORT`` in any test (loose support).

    Two closures ``e = (i, j)`` and ``f = (k, l)`` whose ends are at most ``WINDOW``
    chain steps apart (``|i - k|``, ``|j - l|``) close a short cycle through the odometry
    chain: ``Z_e^-1 D(i, k) Z_f D(l, j)`` is the identity up to noise (``D(a, b)`` the
    chained odometry from pose a to pose b). Its error (the cycle's Logmap) is scored, 3
    dof, against the cycle's covariance propagated to first order from every measurement in
    it: each factor's covariance moved into the cycle's end frame by the adjoint of the
    rest of the cycle; a chain segment's covariance comes from prefix sums of the steps'
    covariances in the chain's origin frame, so every pair costs the same whatever its
    length. A score below ``min(threshold, _DATA_SCALE x median score)`` is agreement: the
    nominal covariances of real data often overstate the noise by an order of magnitude, so
    the scores' own median sets the scale there (most pairs join two true closures, which
    come in runs). A test is informative where a wrong closure (translation uniform over a
    square of the chain's extent, any angle) would land inside the agreement ellipsoid with
    probability below ``_CHANCE``: over long cycles with heavy rotation noise the ellipsoid
    grows until anything agrees. Pairs across a break in the chain are not tested.
    """
    n = g.num_poses
    cov = np.linalg.inv(g.information)
    closures = np.flatnonzero(~chain_mask)
    chain_edges = np.flatnonzero(chain_mask)
    consistent = np.zeros(g.num_edges, bool)
    if len(closures) < 2 or len(chain_edges) == 0:
        return consistent, consistent.copy(), 0
    # one odometry step per consecutive pair (the first edge found), chained from pose 0,
    # with its covariance in the step's own (right) frame
    steps = np.zeros((n - 1, 3))
    step_cov = np.zeros((n - 1, 3, 3))
    linked = np.zeros(n - 1, bool)
    lower, first_edge = np.unique(g.edges[chain_edges].min(axis=1), return_index=True)
    used = chain_edges[first_edge]
    steps[lower], step_cov[lower] = _oriented(g.measured[used], cov[used],
                                              g.edges[used, 1] < g.edges[used, 0])
    linked[lower] = True
    segment = np.concatenate([[0], np.cumsum(~linked)])
    chained = chain(steps)
    chain_adjoint = adjoint(chained)
    chain_adjoint_inverse = np.linalg.inv(chain_adjoint)
    # prefix[m]: the covariance of steps 0..m-1 moved into the origin frame, summed
    prefix = np.zeros((n, 3, 3))
    prefix[1:] = np.cumsum(_sandwich(chain_adjoint[1:], step_cov), axis=0)

    def between(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """D(a, b) for index arrays, and its covariance in its right frame."""
        lower, upper = np.minimum(a, b), np.maximum(a, b)
        forward = relative_pose(chained[lower], chained[upper])
        covariance = _sandwich(chain_adjoint_inverse[upper], prefix[upper] - prefix[lower])
        return _oriented(forward, covariance, a > b)

    i, j = g.edges[closures, 0].copy(), g.edges[closures, 1].copy()
    flip = i > j
    measured, closure_cov = _oriented(g.measured[closures], cov[closures], flip)
    i[flip], j[flip] = j[flip], i[flip].copy()
    order = np.argsort(i, kind="stable")
    first = np.searchsorted(i[order], i - WINDOW)
    last = np.searchsorted(i[order], i + WINDOW + 1)
    a_list, b_list = [], []
    for a, (lo, hi) in enumerate(zip(first.tolist(), last.tolist(), strict=True)):
        near = order[lo:hi]
        near = near[(np.abs(j[near] - j[a]) <= WINDOW) & (near != a)]
        a_list.append(np.full(len(near), a))
        b_list.append(near)
    a_idx, b_idx = np.concatenate(a_list), np.concatenate(b_list)
    same = (segment[i[a_idx]] == segment[i[b_idx]]) & (segment[j[a_idx]] == segment[j[b_idx]])
    a_idx, b_idx = a_idx[same], b_idx[same]
    if len(a_idx) == 0:
        return consistent, consistent.copy(), 0

    # the cycle A B C D = Z_e^-1 D(i, k) Z_f D(l, j); a factor's error reaches the cycle's
    # end frame through the adjoint of the inverse of the factors after it
    factors = [_oriented(measured[a_idx], closure_cov[a_idx], np.ones(len(a_idx), bool)),
               between(i[a_idx], i[b_idx]), (measured[b_idx], closure_cov[b_idx]),
               between(j[b_idx], j[a_idx])]
    after = factors[-1][0]
    total = factors[-1][1].copy()
    for pose, covariance in factors[-2::-1]:
        total += _sandwich(adjoint(inverse(after)), covariance)
        after = compose(pose, after)
    error = logmap(after)
    score = np.einsum("ea,ea->e", error, np.linalg.solve(total, error[..., None])[..., 0])
    bar = min(threshold, _DATA_SCALE * float(np.median(score)))
    # the chance that a wrong closure agrees anyway: the agreement ellipsoid's volume over
    # that of the wrong closures' distribution (a square of the chain's extent, 2 pi)
    side = max(float(np.ptp(chained[:, 0])), float(np.ptp(chained[:, 1])), 1e-9)
    volume = 4.0 / 3.0 * np.pi * bar ** 1.5 * np.sqrt(np.maximum(np.linalg.det(total), 0.0))
    chance = volume / (4.0 * side ** 2 * 2.0 * np.pi)
    agree = score < bar
    informative = agree & (chance < _CHANCE)
    loose = consistent.copy()
    consistent[closures] = np.bincount(a_idx[informative], minlength=len(closures)) >= \
        _MIN_SUPPORT
    loose[closures] = np.bincount(a_idx[agree], minlength=len(closures)) >= LOOSE_SUPPORT
    return consistent, loose, int(len(a_idx))

def _sandwich(a: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Row-wise a C a^T."""
    return a @ covariance @ np.transpose(a, (0, 2, 1))

def _oriented(poses: np.ndarray, covariance: np.ndarray,
              reverse: np.ndarray | bool) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) relative poses and their right-frame covariances, inverted where ``reverse``:
    ``(T Exp(d))^-1 = T^-1 Exp(-Ad(T) d)``."""
    reverse = np.broadcast_to(np.asarray(reverse, bool), (len(poses),))
    poses, covariance = poses.copy(), covariance.copy()
    covariance[reverse] = _sandwich(adjoint(poses[reverse]), covariance[reverse])
    poses[reverse] = inverse(poses[reverse])
    return poses, covariance
