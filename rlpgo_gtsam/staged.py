"""Certify, else search: the staged default of ``rlpgo-init`` (``--method auto``).

1. ``certified``: the SE(2) synchronization relaxation + GTSAM refinement. If its
   certificate holds, the rounded estimate is the global optimum of the relaxation's cost
   and the run stops there.
2. Otherwise the searches, cheapest first, each refined the same way: ``chordal``;
   ``shonan`` started from the orientations of the best result so far (not from random
   rotations); the agent (``rl``) started from the best result so far.
3. The lowest refined chi2 wins; ties go to the earlier, cheaper stage. No stage starts once
   the time budget is spent.
4. Without a certificate, the winner's per-edge residuals are tested for a heavier tail than
   Gaussian noise gives (:func:`~rlpgo_gtsam.residuals.outlier_suspicion`): wrong loop closures
   are then likely, and the result carries a one-line hint to try the robust path. A
   certified run skips the test.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gtsam

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.initializers import InitResult
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.ranking import MethodResult, best_of, run_method
from rlpgo_gtsam.residuals import outlier_suspicion

__all__ = ["StagedResult", "staged_initialize", "DEFAULT_BUDGET_S", "SEARCHES"]

DEFAULT_BUDGET_S = 120.0
# The searches after a failed certificate, cheapest first: (method, starts from the best?)
SEARCHES = (("chordal", False), ("shonan", True), ("rl", True))


@dataclass
class StagedResult:
    """What :func:`staged_initialize` did.

    Attributes:
        rows: one row per stage that ran, in order (``MethodResult``).
        reasons: per row, why that stage ran.
        best: the row whose refined result is handed over.
        certified: whether the relaxation's certificate held.
        stopped: why no further stage ran.
        seconds: wall time of the whole run.
        hint: without a certificate, a one-line hint when the best refined result fits the
            edges with a heavier tail than Gaussian noise (wrong loop closures are likely);
            None otherwise, and always None when certified or when nothing was refined
            (``iters=0``).
    """

    rows: list[MethodResult] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    best: MethodResult | None = None
    certified: bool = False
    stopped: str = ""
    seconds: float = 0.0
    hint: str | None = None

    @property
    def values(self) -> gtsam.Values:
        """The refined guess of the best stage."""
        if self.best is None or self.best.refined is None:
            raise RlpgoError("no stage produced a result")
        return self.best.refined


@numeric_call
def staged_initialize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    *,
    solver: str = "lm",
    iters: int = 30,
    budget_s: float = DEFAULT_BUDGET_S,
    options: dict[str, dict[str, Any]] | None = None,
    dataset: str = "graph",
    pose_graph: PoseGraph2D | None = None,
    on_stage: Callable[[MethodResult, str], None] | None = None,
) -> StagedResult:
    """Run the stages; see the module docstring.

    Args:
        solver, iters: the refinement after every stage.
        budget_s: no stage starts after this many seconds.
        options: per base method name, options for its factory (``{"rl": {...}}``).
        on_stage: called with each finished row and the reason it ran.
    """
    began = time.perf_counter()
    g = pose_graph if pose_graph is not None else PoseGraph2D.from_gtsam(graph, values)
    run = StagedResult()

    def stage(method: str, label: str, reason: str,
              start: InitResult | None = None) -> MethodResult:
        row = run_method(graph, g, method, solver, iters, dataset, (options or {}).get(method),
                         start)
        row.method = label
        run.rows.append(row)
        run.reasons.append(reason)
        if on_stage is not None:
            on_stage(row, reason)
        return row

    first = stage("certified", "certified", "first: certify")
    certificate = None if first.init is None else first.init.certificate
    run.certified = bool(certificate is not None and certificate.certified and
                         first.failure is None)
    if run.certified:
        run.stopped = "the relaxation is certified exact: its rounded estimate is optimal"
    else:
        why = "relaxation not certified" if certificate is not None else \
            f"certified stage failed ({first.failure})"
        for method, from_best in SEARCHES:
            if time.perf_counter() - began >= budget_s:
                run.stopped = f"time budget of {budget_s:g} s spent"
                break
            start = None
            if from_best:
                best = best_of(run.rows)
                start = InitResult(best.method, best.refined, g.poses_of(best.refined),
                                   best.refined_chi2, 0.0)
                reason = f"{why}; starts from the best so far ({best.method})"
            else:
                reason = f"{why}; the cheapest search"
            stage(method, f"{method}@best" if from_best else method, reason, start)
        else:
            run.stopped = "every search ran"
    run.best = best_of(run.rows)
    if not run.certified and iters > 0 and run.best.refined is not None:
        run.hint = outlier_suspicion(g, run.best.refined)
    run.seconds = time.perf_counter() - began
    return run
