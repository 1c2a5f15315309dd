"""Graduated non-convexity with truncated least squares (robust/gnc.py) on problems whose
answer is known by hand."""

from __future__ import annotations

import numpy as np
import pytest

from rlpgo_gtsam.robust.gnc import gnc_tls, tls_weights


def test_tls_weights_follow_yang_et_al():
    """w = 1 inside mu/(mu+1) c^2, 0 outside (mu+1)/mu c^2, sqrt(c^2 mu (mu+1) / r^2) - mu
    between (Yang et al. 2020, eq. 14)."""
    threshold, mu = 4.0, 2.0
    inner, outer = mu / (mu + 1) * threshold, (mu + 1) / mu * threshold
    r2 = np.array([0.0, inner * 0.999, inner * 1.001, 4.0, outer * 0.999, outer * 1.001, 1e9])
    w = tls_weights(r2, threshold, mu)
    assert w[0] == w[1] == 1.0 and w[5] == w[6] == 0.0
    middle = r2[2:5]
    np.testing.assert_allclose(w[2:5], np.sqrt(threshold * mu * (mu + 1) / middle) - mu,
                               rtol=1e-12)
    assert np.all(np.diff(w) <= 0)  # larger residuals never weigh more
    assert w[3] == pytest.approx(np.sqrt(6.0) - 2.0)


def test_tls_weights_approach_the_truncated_square_as_mu_grows():
    r2 = np.array([0.5, 0.99, 1.01, 3.0])
    np.testing.assert_array_equal(tls_weights(r2, 1.0, 1e6), [1.0, 1.0, 0.0, 0.0])


def _line_problem(outliers: list[int]):
    """Fit one offset x to 12 measurements z_k = 3 (+ 40 at the outliers); weighted mean."""
    z = np.full(12, 3.0)
    z[outliers] += 40.0

    def solve(weights: np.ndarray) -> np.ndarray:
        return np.array([np.sum(weights * z) / np.sum(weights)])

    def residuals(x: np.ndarray) -> np.ndarray:
        return (z - x[0]) ** 2

    return solve, residuals


@pytest.mark.parametrize("outliers", [[], [4], [0, 5, 9]])
def test_gnc_tls_rejects_exactly_the_gross_errors(outliers):
    solve, residuals = _line_problem(outliers)
    known = np.zeros(12, bool)
    x, weights, solves = gnc_tls(solve, residuals, known, np.zeros(12, bool), threshold=1.0,
                                 iterations=100)
    assert x[0] == pytest.approx(3.0, abs=1e-9)
    np.testing.assert_array_equal(np.flatnonzero(weights < 0.5), outliers)
    assert solves == 1 if not outliers else solves > 1


def test_known_inliers_keep_their_weight_and_excluded_edges_stay_out():
    solve, residuals = _line_problem([4])
    known = np.zeros(12, bool)
    known[4] = True  # told the gross error is an inlier: it stays in, and pulls the fit
    excluded = np.zeros(12, bool)
    excluded[7] = True
    x, weights, _ = gnc_tls(solve, residuals, known, excluded, threshold=1.0, iterations=100)
    assert weights[4] == 1.0 and weights[7] == 0.0
    assert x[0] > 3.0
