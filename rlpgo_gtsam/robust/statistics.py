"""The distributions the robust steps test with, from SciPy's special functions.

Edges and cycles are judged by chi-square quantiles (:func:`chi2_quantile`). The verify step
estimates a residual covariance from ``samples`` draws, so its statistic is Hotelling's T^2:
scaled by ``(k - dof + 1) / (dof (k - dof - 1))`` (``k`` draws) it is F(dof, k - dof + 1)
(:func:`innovation_p_values`, :func:`statistic_at`), whose tail is heavier than chi-square's.
The closures that the statistics reject beyond a bar are chosen by Benjamini and Hochberg's
procedure adapted to the share of true closures (:func:`adaptive_bh_rejections`).

These are ``scipy.stats``' ``chi2.ppf`` and ``f.sf``, called as the ``scipy.special``
functions they wrap: ``scipy.stats`` takes about a second to import, longer than the robust
path takes on a small graph.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from rlpgo_gtsam.robust.settings import RobustSettings

__all__ = ["chi2_quantile", "innovation_p_value", "innovation_p_values", "statistic_at",
           "set_bar", "adaptive_bh_rejections"]

_SAMPLES = RobustSettings.samples


@lru_cache(maxsize=256)
def chi2_quantile(probability: float, dof: int) -> float:
    """The chi-square quantile (``scipy.stats.chi2.ppf``); remembered, as the steps ask for
    the same few bars."""
    from scipy import special

    return float(2.0 * special.gammaincinv(0.5 * dof, probability))


def innovation_p_values(values: np.ndarray, dofs: np.ndarray | int,
                        samples: int = _SAMPLES) -> np.ndarray:
    """P(a true set's statistic >= ``values``) for the verify step's statistics of ``dofs``
    degrees of freedom, from a covariance estimated with ``samples`` draws: Hotelling's T^2
    tail (F after scaling); chi-square's where the draws are too few for it."""
    from scipy import special

    values = np.asarray(values, dtype=float)
    dofs = np.broadcast_to(np.asarray(dofs, dtype=np.int64), values.shape)
    p_values = np.empty(values.shape)
    hotelling = samples - dofs - 1 > 0
    d1 = dofs[hotelling]
    d2 = samples - d1 + 1
    p_values[hotelling] = special.fdtrc(d1, d2, values[hotelling] * d2 / (d1 * (samples - d1 - 1)))
    p_values[~hotelling] = special.chdtrc(dofs[~hotelling], values[~hotelling])
    return p_values


def innovation_p_value(value: float, dof: int, samples: int = _SAMPLES) -> float:
    """:func:`innovation_p_values` of one statistic."""
    return float(innovation_p_values(np.array([value]), dof, samples)[0])


@lru_cache(maxsize=256)
def statistic_at(p_value: float, dof: int, samples: int = _SAMPLES) -> float:
    """The statistic at which :func:`innovation_p_values`' tail falls to ``p_value``
    (``scipy.stats.f.isf``, computed from the incomplete beta's inverse so that small tails
    keep their digits)."""
    from scipy import special

    if samples - dof - 1 <= 0:
        return float(special.chdtri(dof, p_value))
    # I_x(d2 / 2, d1 / 2) is F's tail at x = d2 / (d2 + d1 F), F the scaled statistic
    x = float(special.betaincinv(0.5 * (samples - dof + 1), 0.5 * dof, p_value))
    return (1.0 - x) / x * (samples - dof - 1)


def set_bar(inlier_probability: float, dof: int, hotelling: bool,
            samples: int = _SAMPLES) -> float:
    """The verify step's bar of a set of closures with ``dof`` in all: the chi-square quantile
    at ``inlier_probability``, or, ``hotelling``, where its own tail reaches ``1 -
    inlier_probability``."""
    if hotelling:
        return statistic_at(1.0 - inlier_probability, dof, samples)
    return chi2_quantile(inlier_probability, dof)


def adaptive_bh_rejections(statistics: np.ndarray, sets: list[np.ndarray], kept: np.ndarray,
                           refuted: np.ndarray, dof: int, rate: float,
                           samples: int = _SAMPLES) -> np.ndarray:
    """The kept closures that the false-rejection bar rejects at the false-rejection ``rate``
    ``q`` (0: none), as a mask over the edges: Benjamini and Hochberg's procedure adapted to
    the share of true closures (Storey, Taylor and Siegmund 2004).

    Every set judged (single closures and runs, ``statistics`` per set of ``sets``) has a
    p-value, its statistic's tail for ``dof`` per closure; the closures no longer candidates
    (``refuted``) count as rejections at p = 0. With ``m`` hypotheses in all and ``pi0 =
    min(1, (1 + #{p > 1/2}) / (c / 2))`` the estimated share of true closures over the ``c``
    single closures (the refuted ones included: a run repeats its members), the k smallest
    p-values are rejections, k the largest with ``p_(k) <= q k / (pi0 m)``. Where many
    closures are wrong, one that the inlier bar lets through but the map finds unlikely goes
    with them; where few are, the bar is about q / m. A run's rejection rejects every member.
    """
    refuted_count = int(refuted.sum())
    rejected = np.zeros(len(kept), bool)
    if not len(statistics) or rate <= 0.0:
        return rejected
    values = np.asarray(statistics, dtype=float)
    sizes = np.array([len(which) for which in sets])
    dofs = dof * sizes
    spans = {d: _p_value_span(d, samples) for d in set(dofs.tolist())}
    half = np.array([spans[d][0] for d in dofs.tolist()])
    tiny = np.array([spans[d][1] for d in dofs.tolist()])
    single = sizes == 1
    null_share = min(1.0, (1 + int(np.sum((values <= half) & single)))
                     / (0.5 * (int(single.sum()) + refuted_count)))
    # p-values below 1e-12 are rejections whatever the rest (q k / (pi0 m) is larger), and
    # above 1/2 none is where q / pi0 <= 1/2: those are 0 and 1 without computing them
    p_values = np.ones(len(values))
    p_values[values >= tiny] = 0.0
    computed = (values < tiny) & ((values > half) | (rate / null_share > 0.5))
    p_values[computed] = innovation_p_values(values[computed], dofs[computed], samples)
    ordered = np.sort(p_values)
    ranks = refuted_count + np.arange(1, len(ordered) + 1)
    below = np.flatnonzero(ordered <= rate * ranks / (null_share * (len(values) + refuted_count)))
    if len(below):
        for k in np.flatnonzero(p_values <= ordered[below[-1]]).tolist():
            rejected[sets[k]] = True
    return rejected & kept


@lru_cache(maxsize=256)
def _p_value_span(dof: int, samples: int) -> tuple[float, float]:
    """The statistics at which :func:`innovation_p_values` is 1/2 and 1e-12."""
    return statistic_at(0.5, dof, samples), statistic_at(1e-12, dof, samples)
