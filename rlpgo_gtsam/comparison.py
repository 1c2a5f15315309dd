"""Side-by-side comparison of initializers, each followed by the same GTSAM refinement."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError, one_line
from rlpgo_gtsam.graph import PoseGraph2D, chi2
from rlpgo_gtsam.initializers import make_initializer
from rlpgo_gtsam.solvers import refine

__all__ = ["MethodResult", "compare_methods", "best_of"]

# What an initializer may raise on a graph it cannot handle: our errors, and GTSAM's
# (an indeterminate linear system is a RuntimeError, LAGO's missing key an IndexError).
_FAILURES = (RlpgoError, RuntimeError, IndexError, ValueError, np.linalg.LinAlgError)


@dataclass
class MethodResult:
    """One method's row of a comparison; ``failure`` says why a method gave no result.

    ``record()`` gives the JSON record: dataset, poses, edges, method, init_chi2,
    init_seconds, solver, iters, refined_chi2, refine_seconds.
    """

    dataset: str
    poses: int
    edges: int
    method: str
    init_chi2: float | None
    init_seconds: float | None
    solver: str | None
    iters: int | None
    refined_chi2: float | None
    refine_seconds: float | None
    initial: gtsam.Values | None = None
    refined: gtsam.Values | None = None
    failure: str | None = None

    def record(self) -> dict:
        fields = asdict(self)
        for key in ("initial", "refined", "failure"):
            fields.pop(key)
        return fields


def compare_methods(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    methods: list[str],
    solver: str | None = "lm",
    iters: int = 30,
    dataset: str = "graph",
    rl_options: dict | None = None,
) -> list[MethodResult]:
    """Run each named initializer, then ``refine`` with the given solver and cap.

    Methods ``rl`` and ``rl@<start>`` get ``rl_options`` (model, episodes, cycles, seed)
    and reuse the start's guess where that method ran earlier in the list. With
    ``solver=None`` nothing is refined. A method that fails (an indeterminate system, a
    diverging solver) gets a row with ``failure`` set; the other methods still run.
    """
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    results: list[MethodResult] = []
    guesses: dict[str, gtsam.Values] = {}
    seconds: dict[str, float] = {}
    for method in methods:
        base = dict(dataset=dataset, poses=pose_graph.num_poses, edges=pose_graph.num_edges,
                    method=method, solver=solver)
        start = time.perf_counter()
        try:
            if method.partition("@")[0] == "rl":
                rl = make_initializer(method, **(rl_options or {}))
                start_guess = guesses.get(getattr(rl, "start", ""))
                init_seconds_before = seconds.get(getattr(rl, "start", ""), 0.0)
                initial = rl.initialize(graph, values, start_values=start_guess)
            else:
                init_seconds_before = 0.0
                initial = make_initializer(method).initialize(graph, values)
        except _FAILURES as error:
            results.append(MethodResult(**base, init_chi2=None, init_seconds=None, iters=None,
                                        refined_chi2=None, refine_seconds=None,
                                        failure=one_line(error)))
            continue
        # An RL row that reused its start's guess is charged that start's seconds too.
        init_seconds = time.perf_counter() - start + init_seconds_before
        guesses[method], seconds[method] = initial, init_seconds
        init_chi2 = chi2(graph, initial)
        if solver is None:
            results.append(MethodResult(**base, init_chi2=init_chi2, init_seconds=init_seconds,
                                        iters=0, refined_chi2=init_chi2, refine_seconds=0.0,
                                        initial=initial, refined=initial))
            continue
        start = time.perf_counter()
        refined = refine(graph, initial, solver=solver, iters=iters)
        refine_seconds = time.perf_counter() - start
        results.append(MethodResult(
            **base, init_chi2=init_chi2, init_seconds=init_seconds,
            iters=refined.iterations, refined_chi2=refined.chi2, refine_seconds=refine_seconds,
            initial=initial, refined=refined.values, failure=refined.failure,
        ))
    return results


def best_of(results: list[MethodResult]) -> MethodResult:
    """The row with the lowest refined chi2 among those that did not fail."""
    usable = [r for r in results if r.failure is None and r.refined_chi2 is not None]
    if not usable:
        raise RlpgoError("every method failed: " + "; ".join(
            f"{r.method}: {r.failure}" for r in results))
    return min(usable, key=lambda r: r.refined_chi2)
