"""What the relaxation proves about a rotation estimate: :class:`Certificate`, and why the
staircase stopped: :class:`Status` (SE-Sync's GLOBAL_OPT, EIG_IMPRECISION, SADDLE_POINT,
RS_ITER_LIMIT, ELAPSED_TIME); :func:`certificate` makes one from a verification's
:class:`Check`.

The dual bound. At any ``Y``, ``Lambda + lambda_min(S) I`` (``S = Q - Lambda(Y)``) is
feasible for the relaxation's dual, so ``lower_bound = tr(Lambda) + rows x min(lambda_min,
0)`` bounds the relaxation's optimum (and so the rotation problem's) from below, ``rows``
being the rows of ``Q`` (``n`` planar, ``3n`` spatial); ``suboptimality_bound =
f(rounded) - lower_bound``. ``certified`` means ``lambda_min >= -eta`` and the rounded
estimate attains the bound: ``suboptimality_bound <= rows x eta + 1e-6 |f(rounded)|``, and
never more than ``1e-4 max(|f(rounded)|, 1)`` (:data:`GAP_CAP`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from enum import Enum

import numpy as np

__all__ = ["Status", "Certificate", "Check", "certificate", "exact_gap", "only_loose",
           "GAP_TOLERANCE", "GAP_CAP"]

GAP_TOLERANCE = 1e-6  # relative gap between f(rounded) and tr(Lambda) still called exact
# the largest gap ever called exact: this share of f(rounded), or of one unit of cost where f
# is below 1 (exact measurements); a chi2 unit is the cost of one measurement at one sigma
GAP_CAP = 1e-4


class Status(str, Enum):
    """Why the staircase stopped, as the string it compares equal to and is recorded as."""

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
    NOT_APPLICABLE = "not_applicable"
    """The graph holds factors the relaxation does not model (``outside``): whatever the
    relaxation proved of the part it models (``relaxed``), it says nothing of the whole
    graph's optimum."""
    NOT_OPTIMAL = "not_optimal"
    """:func:`~rlpgo_gtsam.relaxation.certify` only: ``S`` has an eigenvalue below ``-eta``
    at the estimate given, which is not the relaxation's optimum (no optimization was
    run)."""

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
    """What the relaxation proves about a rotation estimate (costs in the relaxation's own
    units: about chi2 plus its rotational part near a good estimate, not GTSAM's chi2), and
    how the computation ended.

    Attributes:
        status: why the staircase stopped (:class:`Status`); ``certified`` is
            ``status == "certified"``.
        lower_bound: dual lower bound on the relaxation's optimum,
            ``tr(Lambda) + rows x min(min_eigenvalue, 0)``.
        estimate_cost: relaxation cost ``f`` of the (rounded) estimate, translations
            eliminated.
        suboptimality_bound: ``estimate_cost - lower_bound`` (>= 0): how far, at most, the
            estimate is from the rotation problem's global optimum in this cost.
        min_eigenvalue: ``lambda_min(S)``, ``S = Q - Lambda``, at the final rank; where
            ARPACK did not converge, a proven floor under it (``-tolerance`` when the LU's
            pivots proved ``S + eta I > 0``, else ``-max(Lambda)``); NaN when ``time_limit``
            stopped a trust region before any verification.
        tolerance: eta: the relaxation counts as solved iff ``min_eigenvalue >= -tolerance``.
        rank: the staircase's final rank: complex columns of the planar relaxation (1 is
            the rotation problem itself), real columns of the spatial one (SE-Sync's r, 3
            the rotation problem); the lowest rank for ``certify``.
        seconds: wall time of the call.
        fixed_poses: how many FIXed poses the relaxation held beside its gauge's frame (0: the
            graph's one anchor fixed the gauge; see :mod:`rlpgo_gtsam.anchoring`).
        priors: how many soft priors (on poses and landmarks) it holds as edges from the
            world frame.
        points: how many landmarks it holds (translation-only variables).
        ranges: how many ranges it holds (each with a unit direction of its own).
        outside: the factors of the graph it does not model, by kind (``"RangeFactor2D x
            3"``); where there are any the status is ``not_applicable``.
        relaxed: where ``outside`` is not empty, what the relaxation found on the part it
            models (a :class:`Status` value); empty otherwise.
    """

    status: Status
    lower_bound: float
    estimate_cost: float
    suboptimality_bound: float
    min_eigenvalue: float
    tolerance: float
    rank: int
    seconds: float
    fixed_poses: int = 0
    priors: int = 0
    points: int = 0
    ranges: int = 0
    outside: tuple[str, ...] = ()
    relaxed: str = ""

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
            if isinstance(value, (int, str)):
                record[item.name] = value
            elif isinstance(value, tuple):
                record[item.name] = list(value)
            else:
                record[item.name] = float(value) if math.isfinite(value) else None
        return record

    def describe(self) -> str:
        """One line: the verdict (the reason when not certified), the numbers, the time."""
        if self.certified:
            verdict, rank = "certified optimal", f"rank {self.rank}, "
        elif self.status == Status.NOT_APPLICABLE:
            found = "exact" if self.relaxed == Status.CERTIFIED.value else \
                f"not exact: {_REASONS[Status(self.relaxed)]}"
            verdict = (f"not applicable: {', '.join(self.outside)} outside the relaxation (on "
                       f"the part it models: {found})")
            rank = f"rank {self.rank}, "
        else:
            reason = _REASONS[Status(self.status)]
            verdict, rank = f"NOT certified: {reason} at rank {self.rank}", ""
        if math.isnan(self.min_eigenvalue):
            bounds = "not verified"
        else:
            bounds = (f"lower bound {self.lower_bound:.6g}, suboptimality bound "
                      f"{self.suboptimality_bound:.3g}; lambda_min {self.min_eigenvalue:.3g}")
        inside = [f"{count} {what}" for count, what in
                  ((self.fixed_poses, "FIXed poses"), (self.priors, "priors"),
                   (self.points, "landmarks"), (self.ranges, "ranges")) if count]
        covers = f"with {' and '.join(inside)} inside, " if inside else ""
        return (f"{verdict} (relaxation cost {self.estimate_cost:.6g}, {bounds}, tolerance "
                f"{self.tolerance:.3g}, {rank}{covers}{self.seconds:.2f} s)")


@dataclass(frozen=True, eq=False)
class Check:
    """What a verification of ``S = Q - Lambda(Y)`` found."""

    certified: bool  # lambda_min(S) >= -eta
    min_eigenvalue: float  # a proven floor under it where imprecise, NaN where not verified
    trace: float  # tr(Lambda) = f(Y)
    vector: np.ndarray | None  # eigenvector of lambda_min(S) where known
    imprecise: bool = False  # ARPACK did not converge on the eigenvalue(s) asked for


def exact_gap(estimate: float, eta: float, size: int) -> float:
    """The largest suboptimality bound still called exact for a rounded estimate of cost
    ``estimate`` (``size`` rows of ``Q``): the tolerance follows the weights; where they are
    extreme it can dwarf the cost itself, and a bound that loose proves nothing: the gap is
    capped beside it."""
    return min(size * eta + GAP_TOLERANCE * abs(estimate), GAP_CAP * max(abs(estimate), 1.0))


def only_loose(check: Check, estimate: float, eta: float, size: int) -> bool:
    """Whether a solved relaxation (``S`` within ``eta`` of positive semidefinite) misses
    exactness only through its bound's ``size x lambda_min`` term: the rounded estimate
    attains ``f(Y)`` itself, and an ``S`` nearer positive semidefinite (``Y`` closer to
    first-order stationary) would prove it."""
    return (check.certified and check.min_eigenvalue < 0.0
            and estimate - check.trace <= exact_gap(estimate, eta, size)
            < estimate - check.trace - size * check.min_eigenvalue)


def certificate(check: Check, estimate: float, eta: float, size: int, rank: int,
                started: float, stop: Status) -> Certificate:
    """The certificate of the rounded estimate (``size``: rows of ``Q``); ``stop``: the status
    when ``S`` is not known to be positive semidefinite (NaN numbers where nothing was
    verified)."""
    lower = check.trace + size * min(check.min_eigenvalue, 0.0)  # NaN stays NaN
    gap = max(estimate - lower, 0.0)
    if check.certified:
        status = Status.CERTIFIED if gap <= exact_gap(estimate, eta, size) else \
            Status.NOT_TIGHT
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
