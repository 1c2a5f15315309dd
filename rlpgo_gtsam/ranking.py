"""Side-by-side comparison of initializers, each followed by the same GTSAM refinement, on a
planar or a 3D graph."""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError, one_line
from rlpgo_gtsam.graph import check_reach, extract_pose_graph
from rlpgo_gtsam.initializers import InitResult, make_initializer, start_names
from rlpgo_gtsam.numerics import release_free_memory
from rlpgo_gtsam.solvers import RefineResult, refine

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph
    from rlpgo_gtsam.groups import Group

__all__ = ["MethodResult", "compare_methods", "best_of", "tied_best", "run_method",
           "initialize_row", "refine_row", "refine_until", "start_from", "line_progress_options",
           "comparison_methods",
           "FROM_BEST", "TIE_RELATIVE", "ITERATION_PER_CHI2", "FITS_MARGIN",
           "usable_rows", "ties"]

# refine_until's guess of one GN/LM iteration before it has timed one, in units of the start's
# chi2 (a refine of 0 iterations): 25 to 28 times on City10K, M3500 and a 10,000-pose generated
# graph, 23 on 200,000 poses (4 s). Low for dense graphs (about 100 on the 2000-pose
# generated one with loop closures at every step), where an iteration takes 0.2 s.
ITERATION_PER_CHI2 = 25.0
# refine_until runs all its iterations in one call where the time left holds this many times
# their reckoning (ITERATION_PER_CHI2 runs 4 times low on the dense graph above).
FITS_MARGIN = 4.0
_PROGRESS_EVERY_S = 2.0  # refine_until's progress lines, as often as the staircase's


@dataclass(eq=False)
class MethodResult:
    """One method's row of a comparison; ``failure`` says why a method gave no result.

    Attributes:
        dataset, poses, edges: the graph compared.
        method: the method's name.
        init: the initializer's result (guess, chi2, seconds, details), or None if it failed.
        solver, iters: the refinement run (``solver`` None: no refinement).
        refined_chi2, refine_seconds, refined: the refinement's outcome.
        failure: why the method or its refinement failed, or None.
        failed_after_s: the seconds the initializer ran before it failed (None if it did not).
        cut: what a time limit cut short in this row (its refinement), or None.
    """

    dataset: str
    poses: int
    edges: int
    method: str
    init: InitResult | None
    solver: str | None
    iters: int | None = None
    refined_chi2: float | None = None
    refine_seconds: float | None = None
    refined: gtsam.Values | None = None
    failure: str | None = None
    failed_after_s: float | None = None
    cut: str | None = None

    @property
    def init_chi2(self) -> float | None:
        return None if self.init is None else self.init.chi2

    @property
    def init_seconds(self) -> float | None:
        """The initializer's seconds, a failed one's included."""
        return self.failed_after_s if self.init is None else self.init.seconds

    @property
    def seconds(self) -> float:
        """The row's whole wall time: the initializer's and the refinement's."""
        return (self.init_seconds or 0.0) + (self.refine_seconds or 0.0)

    def record(self) -> dict[str, Any]:
        """The JSON record: dataset, poses, edges, method, init_chi2, init_seconds (a failed
        initializer's included), solver, iters, refined_chi2, refine_seconds, failure, the
        method's details where it has any, its certificate's record (status included) where
        it has one, and ``cut`` where a time limit cut the row short."""
        record = {
            "dataset": self.dataset, "poses": self.poses, "edges": self.edges,
            "method": self.method, "init_chi2": self.init_chi2,
            "init_seconds": self.init_seconds, "solver": self.solver, "iters": self.iters,
            "refined_chi2": self.refined_chi2, "refine_seconds": self.refine_seconds,
            "failure": self.failure,
        }
        if self.init is not None and self.init.details:
            record["details"] = self.init.details
        if self.init is not None and self.init.certificate is not None:
            record["certificate"] = self.init.certificate.record()
        if self.cut is not None:
            record["cut"] = self.cut
        return record


def initialize_row(
    pose_graph: PoseGraph,
    method: str,
    solver: str | None = "lm",
    dataset: str = "graph",
    options: dict[str, Any] | None = None,
    start: InitResult | None = None,
) -> MethodResult:
    """One initializer's row, not yet refined (see :func:`refine_row`); ``failure`` and
    ``failed_after_s`` set instead of raising."""
    row = MethodResult(dataset, pose_graph.num_poses, pose_graph.num_edges, method, None, solver)
    began = time.perf_counter()
    try:
        row.init = make_initializer(method, **(options or {})).run(pose_graph, start)
    except RlpgoError as error:
        row.failure = str(error)
    except (RuntimeError, ArithmeticError, ValueError, np.linalg.LinAlgError) as error:
        # a numerical failure inside GTSAM, scipy or numpy on extreme (finite) input: this
        # method failed, the others may not
        row.failure = f"{type(error).__name__}: {one_line(error)}"
    if row.init is None:
        row.failed_after_s = time.perf_counter() - began
    release_free_memory(pose_graph.num_poses + pose_graph.num_edges)
    return row


def refine_row(
    row: MethodResult,
    graph: gtsam.NonlinearFactorGraph,
    pose_graph: PoseGraph,
    iters: int = 30,
    deadline: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> MethodResult:
    """Refine ``row``'s guess with its ``solver`` (None: the guess is the result); ``row``
    is filled in and returned. A row whose initializer failed is returned as it is.

    Args:
        deadline: a ``time.perf_counter()`` time the refinement must end by (see
            :func:`refine_until`); None: ``iters`` iterations or convergence, however long.
        progress: with a deadline, one line at most every 2 s inside a long refinement
            (:func:`refine_until`); None: silent.
    """
    if row.init is None:
        return row
    if row.solver is None:
        row.iters, row.refined_chi2, row.refine_seconds = 0, row.init.chi2, 0.0
        row.refined = row.init.values
        return row
    began = time.perf_counter()
    if deadline is None:
        refined = refine(graph, row.init.values, solver=row.solver, iters=iters,
                         pose_graph=pose_graph)
    else:
        refined, row.cut = refine_until(graph, row.init.values, row.solver, iters, deadline,
                                        pose_graph, progress)
    row.refine_seconds = time.perf_counter() - began
    row.iters, row.refined_chi2 = refined.iterations, refined.chi2
    row.refined, row.failure = refined.values, refined.failure
    return row


def refine_until(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    solver: str,
    iters: int,
    deadline: float,
    pose_graph: PoseGraph | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[RefineResult, str | None]:
    """:func:`~rlpgo_gtsam.solvers.refine` in chunks that end by ``deadline``
    (a ``time.perf_counter()`` time), and what the deadline cut (None: nothing).

    GTSAM's solvers take no time limit, so the iterations run in chunks, each a fresh
    ``refine`` from the last one's values: one iteration first, to time one, then as many
    as the time left holds. Before one is timed, an iteration is reckoned as
    :data:`ITERATION_PER_CHI2` times what the start's chi2 took: where the time left holds
    :data:`FITS_MARGIN` times ``iters`` of them, the iterations run in one ``refine`` call
    (its result exactly); else the first starts only if one fits (a 200,000-pose graph's
    first LM iteration takes seconds). It stops at ``iters`` iterations, at convergence (a
    chunk that ended before its cap), at a failure, or when not one more iteration fits.
    The chunks restart LM's damping, so the path may differ slightly from one ``refine``
    call. ``progress`` (None: silent) gets a line at most every 2 s: the iterations done and
    their chi2.
    """
    g = pose_graph if pose_graph is not None else extract_pose_graph(graph, values)
    started = began = time.perf_counter()
    current = refine(graph, values, solver=solver, iters=0, pose_graph=g)
    per_iteration = ITERATION_PER_CHI2 * (time.perf_counter() - began)  # until one is timed
    done, last = 0, [started]

    def report(k: int, value: float) -> None:
        now = time.perf_counter()
        if progress is not None and now - last[0] >= _PROGRESS_EVERY_S:
            last[0] = now
            progress(f"{solver.upper()}: iteration {done + k} of {iters}, chi2 {value:.6g}, "
                     f"{now - started:.1f} s")

    if deadline - time.perf_counter() >= FITS_MARGIN * iters * per_iteration:
        return refine(graph, values, solver=solver, iters=iters, pose_graph=g,
                      on_iteration=report), None
    trace = list(current.chi2_trace)
    while done < iters:
        left = deadline - time.perf_counter()
        chunk = int(left >= per_iteration) if done == 0 else \
            min(iters - done, int(left / per_iteration))
        if left <= 0 or chunk < 1:
            return (RefineResult(current.values, current.chi2, done, trace),
                    f"the time limit stopped {solver.upper()} after {done} of {iters} "
                    "iterations")
        began = time.perf_counter()
        step = refine(graph, current.values, solver=solver, iters=chunk, pose_graph=g,
                      on_iteration=report)
        took = max((time.perf_counter() - began) / max(step.iterations, 1), 1e-9)
        per_iteration = took if done == 0 else max(per_iteration, took)
        done += step.iterations
        trace += step.chi2_trace[1:]
        current = step
        if step.failure is not None or step.iterations < chunk:
            break
    return RefineResult(current.values, current.chi2, done, trace, current.failure), None


def run_method(
    graph: gtsam.NonlinearFactorGraph,
    pose_graph: PoseGraph,
    method: str,
    solver: str | None = "lm",
    iters: int = 30,
    dataset: str = "graph",
    options: dict[str, Any] | None = None,
    start: InitResult | None = None,
    deadline: float | None = None,
) -> MethodResult:
    """One initializer then ``refine``: a row, with ``failure`` set instead of raising.

    Args:
        method: an initializer name (``rl@chordal`` names a start).
        options: options for the initializer's factory.
        start: the guess to start from, for initializers that take one.
        deadline: the refinement ends by this ``time.perf_counter()`` time (see
            :func:`refine_until`); None: no limit.
    """
    row = initialize_row(pose_graph, method, solver, dataset, options, start)
    return refine_row(row, graph, pose_graph, iters, deadline)


def start_from(row: MethodResult, pose_graph: PoseGraph) -> InitResult:
    """``row``'s refined result as a start for another initializer (its seconds not
    charged again: the row already counts them).

    Raises:
        RlpgoError: a row without a refined result.
    """
    if row.refined is None or row.refined_chi2 is None:
        raise RlpgoError(f"{row.method} has no refined result to start from")
    return InitResult(row.method, row.refined, pose_graph.poses_of(row.refined),
                      row.refined_chi2, 0.0)


def comparison_methods(group: Group) -> list[str]:
    """Every method that takes ``group``'s graphs and starts from none, the certified
    relaxation first (ties go to the earlier row): a 3D file's comparison rows."""
    names = start_names(group)
    return ["certified", *(name for name in names if name != "certified")]


# Methods that, in a comparison, start from the lowest refined chi2 of the rows before them
# rather than from their own start: Shonan from random rotations took 52 s on M3500 and
# 154 s on City10K, never won, and often failed.
FROM_BEST = ("shonan",)
# Initializers that can report progress as lines of text (``progress(line)``).
_LINE_PROGRESS = ("certified", "shonan")


def line_progress_options(report: Callable[[str, str], None]) -> dict[str, dict[str, Any]]:
    """Options (for :func:`compare_methods`, ``staged_initialize``) that make each
    initializer able to report progress lines call ``report(method, line)``."""
    return {method: {"progress": functools.partial(report, method)}
            for method in _LINE_PROGRESS}


def compare_methods(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    methods: list[str],
    solver: str | None = "lm",
    iters: int = 30,
    dataset: str = "graph",
    options: dict[str, dict[str, Any]] | None = None,
    pose_graph: PoseGraph | None = None,
    start_from_best: Collection[str] = FROM_BEST,
    on_row: Callable[[MethodResult], None] | None = None,
) -> list[MethodResult]:
    """Run each named initializer on one extraction of the graph, then ``refine`` each guess.

    Args:
        methods: initializer names (``rl@chordal`` names a start), each one that takes the
            graph's group (:func:`~rlpgo_gtsam.initializers.initializer_names`).
        solver: "lm", "gn", or None for no refinement.
        options: per base method name, options for its factory (``{"rl": {"episodes": 4}}``).
        pose_graph: the graph's extraction, if the caller has it.
        start_from_best: methods that, when a row with a result ran before them, start from
            the best of those rows (the lowest refined chi2, :func:`best_of`) instead of
            their own start (by default :data:`FROM_BEST`: Shonan); such a row is named
            ``<method>@best`` and its details say which row it started from.
        on_row: called with each row as soon as it is done (to print it).

    A method that starts from another (``rl@chordal``) reuses that method's guess where it
    ran earlier in the list and is charged its seconds. The rows share what the graph's
    extraction keeps (``pose_graph.cache``: the chordal orientations, the translation step's
    system and, for isotropic translation information, its factorization): a row's seconds
    are what it added after the rows before it. A method that fails (an
    indeterminate system, a diverging solver) gets a row with ``failure`` set; the others
    still run.
    """
    g = check_reach(pose_graph if pose_graph is not None else extract_pose_graph(graph, values))
    rows: dict[str, MethodResult] = {}
    results: list[MethodResult] = []
    for method in methods:
        base, _, start = method.partition("@")
        earlier = rows.get(start) if start else None
        start_result = earlier.init if earlier is not None else None
        best = None
        if method in start_from_best and tied_best(results):
            best = best_of(results)
            start_result = start_from(best, g)
        row = run_method(graph, g, method, solver, iters, dataset, (options or {}).get(base),
                         start_result)
        if best is not None:
            row.method = f"{method}@best"
            if row.init is not None:
                row.init.details = {**row.init.details, "started_from": best.method}
        rows[method] = row
        results.append(row)
        if on_row is not None:
            on_row(row)
    return results


# Refined costs this close count as the same minimum: the earlier (cheaper) row wins.
TIE_RELATIVE = 1e-6


def usable_rows(results: list[MethodResult]) -> list[MethodResult]:
    """The rows that did not fail and have a finite refined chi2, in their order."""
    return [r for r in results if r.failure is None and r.refined_chi2 is not None
            and math.isfinite(r.refined_chi2)]


def ties(chi2: float, lowest: float) -> bool:
    """Whether a refined ``chi2`` is the same minimum as ``lowest`` (within a relative
    :data:`TIE_RELATIVE`)."""
    return chi2 <= lowest + TIE_RELATIVE * abs(lowest)


def best_of(results: list[MethodResult]) -> MethodResult:
    """The row with the lowest refined chi2 among those that did not fail; rows within a
    relative 1e-6 of the lowest are a tie, won by the earliest (the cheaper method)."""
    usable = usable_rows(results)
    if not usable:
        raise RlpgoError("every method failed: " + "; ".join(
            f"{r.method}: {r.failure or f'chi2 {r.refined_chi2}'}" for r in results))
    return tied_best(usable)[0]


def tied_best(results: list[MethodResult]) -> list[MethodResult]:
    """The rows tied for the lowest finite refined chi2 (within a relative
    :data:`TIE_RELATIVE`), in their order; empty if no row has one."""
    finite = [(r, r.refined_chi2) for r in usable_rows(results) if r.refined_chi2 is not None]
    if not finite:
        return []
    lowest = min(chi2 for _, chi2 in finite)
    return [r for r, chi2 in finite if ties(chi2, lowest)]
