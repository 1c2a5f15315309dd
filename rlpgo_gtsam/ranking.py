"""Side-by-side comparison of initializers, each followed by the same GTSAM refinement."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError, one_line
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.initializers import InitResult, make_initializer
from rlpgo_gtsam.solvers import refine

__all__ = ["MethodResult", "compare_methods", "best_of", "tied_best", "run_method", "TIE_RELATIVE"]


@dataclass
class MethodResult:
    """One method's row of a comparison; ``failure`` says why a method gave no result.

    Attributes:
        dataset, poses, edges: the graph compared.
        method: the method's name.
        init: the initializer's result (guess, chi2, seconds, details), or None if it failed.
        solver, iters: the refinement run (``solver`` None: no refinement).
        refined_chi2, refine_seconds, refined: the refinement's outcome.
        failure: why the method or its refinement failed, or None.
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

    @property
    def init_chi2(self) -> float | None:
        return None if self.init is None else self.init.chi2

    @property
    def init_seconds(self) -> float | None:
        return None if self.init is None else self.init.seconds

    def record(self) -> dict[str, Any]:
        """The JSON record: dataset, poses, edges, method, init_chi2, init_seconds, solver,
        iters, refined_chi2, refine_seconds, failure, the method's details where it has any,
        and its certificate's record (status included) where it has one."""
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
        return record


def run_method(
    graph: gtsam.NonlinearFactorGraph,
    pose_graph: PoseGraph2D,
    method: str,
    solver: str | None = "lm",
    iters: int = 30,
    dataset: str = "graph",
    options: dict[str, Any] | None = None,
    start: InitResult | None = None,
) -> MethodResult:
    """One initializer then ``refine``: a row, with ``failure`` set instead of raising.

    Args:
        method: an initializer name (``rl@chordal`` names a start).
        options: options for the initializer's factory.
        start: the guess to start from, for initializers that take one.
    """
    row = MethodResult(dataset, pose_graph.num_poses, pose_graph.num_edges, method, None, solver)
    try:
        row.init = make_initializer(method, **(options or {})).run(pose_graph, start)
    except RlpgoError as error:
        row.failure = str(error)
        return row
    except (RuntimeError, ArithmeticError, ValueError, np.linalg.LinAlgError) as error:
        # a numerical failure inside GTSAM, scipy or numpy on extreme (finite) input: this
        # method failed, the others may not
        row.failure = f"{type(error).__name__}: {one_line(error)}"
        return row
    if solver is None:
        row.iters, row.refined_chi2, row.refine_seconds = 0, row.init.chi2, 0.0
        row.refined = row.init.values
        return row
    began = time.perf_counter()
    refined = refine(graph, row.init.values, solver=solver, iters=iters, pose_graph=pose_graph)
    row.refine_seconds = time.perf_counter() - began
    row.iters, row.refined_chi2 = refined.iterations, refined.chi2
    row.refined, row.failure = refined.values, refined.failure
    return row


def compare_methods(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    methods: list[str],
    solver: str | None = "lm",
    iters: int = 30,
    dataset: str = "graph",
    options: dict[str, dict[str, Any]] | None = None,
    pose_graph: PoseGraph2D | None = None,
) -> list[MethodResult]:
    """Run each named initializer on one extraction of the graph, then ``refine`` each guess.

    Args:
        methods: initializer names (``rl@chordal`` names a start).
        solver: "lm", "gn", or None for no refinement.
        options: per base method name, options for its factory (``{"rl": {"episodes": 4}}``).
        pose_graph: the graph's extraction, if the caller has it.

    A method that starts from another (``rl@chordal``) reuses that method's guess where it
    ran earlier in the list and is charged its seconds. A method that fails (an
    indeterminate system, a diverging solver) gets a row with ``failure`` set; the others
    still run.
    """
    g = pose_graph if pose_graph is not None else PoseGraph2D.from_gtsam(graph, values)
    rows: dict[str, MethodResult] = {}
    results = []
    for method in methods:
        base, _, start = method.partition("@")
        earlier = rows.get(start) if start else None
        row = run_method(graph, g, method, solver, iters, dataset, (options or {}).get(base),
                         earlier.init if earlier is not None else None)
        rows[method] = row
        results.append(row)
    return results


# Refined costs this close count as the same minimum: the earlier (cheaper) row wins.
TIE_RELATIVE = 1e-6


def best_of(results: list[MethodResult]) -> MethodResult:
    """The row with the lowest refined chi2 among those that did not fail; rows within a
    relative 1e-6 of the lowest are a tie, won by the earliest (the cheaper method)."""
    usable = [r for r in results if r.failure is None and r.refined_chi2 is not None
              and math.isfinite(r.refined_chi2)]
    if not usable:
        raise RlpgoError("every method failed: " + "; ".join(
            f"{r.method}: {r.failure or f'chi2 {r.refined_chi2}'}" for r in results))
    return tied_best(usable)[0]


def tied_best(results: list[MethodResult]) -> list[MethodResult]:
    """The rows tied for the lowest finite refined chi2 (within a relative
    :data:`TIE_RELATIVE`), in their order; empty if no row has one."""
    finite = [r for r in results if r.failure is None and r.refined_chi2 is not None
              and math.isfinite(r.refined_chi2)]
    if not finite:
        return []
    lowest = min(r.refined_chi2 for r in finite)
    return [r for r in finite if r.refined_chi2 <= lowest + TIE_RELATIVE * abs(lowest)]
