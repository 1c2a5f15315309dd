"""Certify, else search: the staged default of ``rlpgo-init`` (``--method auto``).

On a planar graph or a 3D one alike (extracted once:
:func:`~rlpgo_gtsam.graph.extract_pose_graph`); the stages are methods that take the graph's
group.

1. ``certified``: the SE(d) synchronization relaxation + GTSAM refinement. If its
   certificate holds, the rounded estimate is the global optimum of the relaxation's cost
   and the run stops there.
2. Otherwise the default searches no further (:data:`DEFAULT_SEARCHES` is empty): the
   refined certified estimate is the answer, with the residual hint (step 4). The searches
   did not earn their time. Measured on generated 1000-pose graphs the relaxation does not
   certify (``rlpgo-generate --n 1000 --sigma-r S --sigma-t 0.05 --d 3 --lc 0.5
   --noisy-measurements --seed K``), each stage refined by LM30, in the escalation's order
   (each ``@best`` from the best refined result so far, which stayed the certified one);
   the refined chi2 against the certified stage's, and wall seconds on the shared 2-core
   machine (load about 10, so the seconds run high)::

       S, K    certified        chordal          shonan@best        rl@best
       0.3, 1  1316.80  5.1 s   +10.27%  1.9 s   +8.77%    3.8 s   +0.11%  10.6 s
       0.3, 2  1401.74  6.7 s   +5.35%   2.4 s   +3.76%    5.0 s   +0.003%  9.8 s
       0.3, 3  1357.48 56.6 s   +0.11%   4.1 s   +0.14%    4.7 s   +0.02%   8.4 s
       0.5, 1  1315.20 96.3 s   +236%    2.0 s   FAILED   17.2 s   +2.80%   9.8 s
       0.5, 2  1391.47 58.0 s   +214%    2.6 s   FAILED   19.1 s   +0.30%   9.4 s
       0.5, 3  1336.61  158 s   +122%    2.6 s   FAILED   14.2 s   +0.24%  14.4 s

   No search lowered the best refined chi2 on any of the six; Shonan from random starts
   (38-98 s), LAGO and fastSync did not either; nor did any on the 21 arena graphs and
   the hold-outs. The searches stay reachable: ``searches=SEARCHES`` here
   (:data:`SEARCHES_3D` on a 3D graph: the agent is planar), ``--method all`` or a
   method's own name (``--method rl``) on the command line.
3. With ``searches``, each runs refined the same way, cheapest first; the lowest refined
   chi2 wins; ties go to the earlier, cheaper stage.
4. Without a certificate, the winner's per-edge residuals are tested for a heavier tail than
   Gaussian noise gives (:func:`~rlpgo_gtsam.residuals.outlier_suspicion`): wrong loop closures
   are then likely, and the result carries a one-line hint to try the robust path. A
   certified run skips the test.

The time budget bounds the whole run. The certified stage gets the budget less a reserve
(:data:`REFINE_RESERVE` of it) as its time limit, the steps after its staircase included
(:class:`~rlpgo_gtsam.initializers.CertifiedInitializer`); cut there, it hands over its best
estimate so far, not certified. A refinement that the time left may not hold runs in chunks
that end with the budget (:func:`~rlpgo_gtsam.ranking.refine_until`; one that it holds four
times over runs as it would without a budget); no search starts after the budget is spent,
and one that has started runs to its end. ``stopped`` says what was cut.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gtsam

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import check_reach, extract_pose_graph
from rlpgo_gtsam.groups import SE3
from rlpgo_gtsam.initializers import InitResult, check_method, initializer_names
from rlpgo_gtsam.numerics import RELEASE_SIZE, numeric_call, release_free_memory
from rlpgo_gtsam.ranking import MethodResult, best_of, initialize_row, refine_row, start_from
from rlpgo_gtsam.residuals import outlier_suspicion

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph
    from rlpgo_gtsam.relaxation import Certificate

__all__ = ["StagedResult", "staged_initialize", "DEFAULT_BUDGET_S", "DEFAULT_SEARCHES",
           "SEARCHES", "SEARCHES_3D", "REFINE_RESERVE"]

DEFAULT_BUDGET_S = 120.0
# The searches after a failed certificate, cheapest first: (method, starts from the best?)
SEARCHES = (("chordal", False), ("shonan", True), ("rl", True))
# The same on a 3D graph: those that take it (the agent is planar).
SEARCHES_3D = tuple((method, best) for method, best in SEARCHES
                    if method in initializer_names(SE3))
# The default's searches: none (see the module docstring for the measurement).
DEFAULT_SEARCHES: tuple[tuple[str, bool], ...] = ()
# The share of the budget kept for the refinement after the certified stage.
REFINE_RESERVE = 0.2
# The fallback when the certified stage itself fails (not: is not certified).
_FALLBACK = "chordal"


@dataclass(eq=False)
class StagedResult:
    """What :func:`staged_initialize` did.

    Attributes:
        rows: one row per stage that ran, in order (``MethodResult``); the first is the
            certified stage, whose certificate is :attr:`certificate`.
        reasons: per row, why that stage ran.
        best: the row whose refined result is handed over.
        certified: whether the relaxation's certificate held.
        stopped: why no further stage ran, and what the time budget cut, if anything.
        seconds: wall time of the whole run.
        hint: without a certificate, a one-line hint when the best refined result fits the
            edges with a heavier tail than Gaussian noise (wrong loop closures are likely);
            None otherwise, and always None when certified, when nothing was refined
            (``iters=0``), when the time budget cut the best row's refinement (the
            residuals of an unconverged estimate say nothing about the loop closures), and
            on a graph with more than poses (the robust path judges pose graphs only).
    """

    rows: list[MethodResult] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    best: MethodResult | None = None
    certified: bool = False
    stopped: str = ""
    seconds: float = 0.0
    hint: str | None = None

    @property
    def certificate(self) -> Certificate | None:
        """The certified stage's certificate (whether the relaxation was exact, its bounds,
        how the staircase ended); None where that stage failed."""
        row = next((row for row in self.rows if row.method == "certified"), None)
        return None if row is None or row.init is None else row.init.certificate

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
    pose_graph: PoseGraph | None = None,
    on_stage: Callable[[MethodResult, str], None] | None = None,
    searches: Sequence[tuple[str, bool]] = DEFAULT_SEARCHES,
) -> StagedResult:
    """Run the stages on a planar or a 3D graph; see the module docstring.

    Args:
        graph, values: a ``BetweenFactorPose2`` or a ``BetweenFactorPose3`` graph and its
            values.
        solver, iters: the refinement after every stage.
        budget_s: the whole run's time limit (the certified stage's included).
        options: per base method name, options for its factory (``{"rl": {...}}``). The
            certified stage's ``time_limit_s`` is set from the budget (a smaller one given
            here is kept); its ``progress`` is passed on.
        on_stage: called with each finished row and the reason it ran.
        searches: the stages after a failed certificate, as ``(method, starts from the
            best so far?)``, each a method of the graph's dimension; :data:`SEARCHES` is
            every one (:data:`SEARCHES_3D` on a 3D graph), the default none.

    Raises:
        RlpgoError: a search that is not a method of the graph's dimension, or a budget that
            is not a number of seconds >= 0 (before any stage runs); every stage failing.
        GraphError: a graph the package cannot work on.
    """
    if not (isinstance(budget_s, (int, float)) and math.isfinite(budget_s) and budget_s >= 0):
        raise RlpgoError(f"budget_s must be a number of seconds >= 0, got {budget_s!r}")
    began = time.perf_counter()
    deadline = began + budget_s
    g = check_reach(pose_graph if pose_graph is not None else extract_pose_graph(graph, values))
    for method, _ in searches:
        check_method(method, g.group)
    options = options or {}
    run = StagedResult()
    cuts: list[str] = []

    def stage(method: str, label: str, reason: str, method_options: dict[str, Any] | None,
              start: InitResult | None = None) -> MethodResult:
        row = initialize_row(g, method, solver, dataset, method_options, start)
        row.method = label
        if g.num_poses + g.num_edges >= RELEASE_SIZE:
            # what the stage derived and kept (the translation step's system and factor: a
            # 216,000-pose chain's 225 MB) is not held through GTSAM's refinement; a later
            # stage derives it again
            g.cache.clear()
            release_free_memory(g.num_poses + g.num_edges)
        refine_row(row, graph, g, iters, deadline, (method_options or {}).get("progress"))
        if row.cut is not None:
            cuts.append(f"{label}: {row.cut}")
        run.rows.append(row)
        run.reasons.append(reason)
        if on_stage is not None:
            on_stage(row, reason)
        return row

    first = stage("certified", "certified", "first: certify",
                  _certified_options(options.get("certified"), budget_s * (1.0 - REFINE_RESERVE)))
    certificate = run.certificate
    run.certified = bool(certificate is not None and certificate.certified and
                         first.failure is None)
    if run.certified:
        run.stopped = "the relaxation is certified exact: its rounded estimate is optimal"
    elif certificate is not None and str(certificate.status) == "time_limit":
        run.stopped = (f"time budget of {budget_s:g} s spent during the certified stage: its "
                       "best estimate so far, not certified")
    else:
        if certificate is None:
            why = f"certified stage failed ({first.failure})"
        elif certificate.outside:
            why = (f"the certificate does not apply ({', '.join(certificate.outside)} outside "
                   "the relaxation)")
        else:
            why = "relaxation not certified"
        planned = list(searches)
        if certificate is None and all(m != _FALLBACK for m, _ in planned):
            planned.insert(0, (_FALLBACK, False))  # something must give a result
        run.stopped = f"{why}; " + ("every search ran" if planned else
                                    "no search after it (none is in the default)")
        for method, from_best in planned:
            if time.perf_counter() >= deadline:
                run.stopped = f"{why}; time budget of {budget_s:g} s spent"
                break
            start, reason = None, f"{why}; the cheapest search"
            if from_best:
                best = best_of(run.rows)
                start = start_from(best, g)
                reason = f"{why}; starts from the best so far ({best.method})"
            stage(method, f"{method}@best" if from_best else method, reason,
                  options.get(method), start)
    if cuts:
        run.stopped += "; " + "; ".join(cuts)
    run.best = best_of(run.rows)
    # the hint points at --robust, which judges pose graphs only
    if not run.certified and run.best.cut is None and iters > 0 and \
            run.best.refined is not None and not g.whole:
        run.hint = outlier_suspicion(g, run.best.refined)
    run.seconds = time.perf_counter() - began
    return run


def _certified_options(given: dict[str, Any] | None, limit_s: float) -> dict[str, Any]:
    """The certified stage's options: ``time_limit_s`` at most ``limit_s``; any other option
    goes to its factory as given."""
    chosen = dict(given or {})
    limit = chosen.get("time_limit_s")
    chosen["time_limit_s"] = limit_s if limit is None else min(limit, limit_s)
    return chosen
