"""Initial guesses for planar pose-graph optimization, one protocol, chosen by name.

Every initializer mirrors ``gtsam.lago.initialize``: ``initialize(graph, values)`` takes
GTSAM's graph and values and returns :class:`gtsam.Values`. That call is a thin wrapper: the
graph is extracted once into a :class:`~rlpgo_gtsam.graph.PoseGraph2D`, and :meth:`run`
returns an :class:`InitResult` with the guess, its chi2, the seconds it took and whatever
the method learned (rollout costs, a certificate). Orientation initializers estimate the
orientations only; positions then come from
:func:`~rlpgo_gtsam.translations.poses_with_orientations`. The anchor pose and FIXed poses
keep their poses; every edge's rotation is weighted by
:func:`~rlpgo_gtsam.graph.rotation_weights`.

New initializers plug in with :func:`register`::

    class Mine(OrientationInitializer):
        def orientations(self, pose_graph, start_theta=None):
            return ...  # (n,) angles

    register("mine", Mine)
    make_initializer("mine").initialize(graph, values)
"""

from __future__ import annotations

import importlib
import inspect
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.chordal import chordal_orientations
from rlpgo_gtsam.errors import RlpgoError, SolverError, one_line
from rlpgo_gtsam.graph import PoseGraph2D, chi2, rotation_weights
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.se2 import angle_residuals, chordal_edge_costs
from rlpgo_gtsam.translations import poses_with_orientations

__all__ = [
    "InitResult",
    "Estimate",
    "Initializer",
    "OrientationInitializer",
    "OdometryInitializer",
    "LagoInitializer",
    "ChordalInitializer",
    "ShonanInitializer",
    "CertifiedInitializer",
    "FINISH_PER_START",
    "FastSyncInitializer",
    "CLASSICAL",
    "register",
    "make_initializer",
    "initializer_names",
    "start_names",
    "check_method",
    "build_initializer",
]


@dataclass(eq=False)
class Estimate:
    """What an initializer's :meth:`Initializer.estimate` produces.

    Attributes:
        poses: (n, 3) x, y, theta of the guess, in pose-index order.
        details: JSON-ready facts the method learned (rollout costs, chosen rollout, ...).
        certificate: an optimality certificate, for methods that give one.
    """

    poses: np.ndarray
    details: dict[str, Any] = field(default_factory=dict)
    certificate: Any = None


@dataclass(eq=False)
class InitResult:
    """One initializer's answer for one graph.

    Attributes:
        method: the name it was made by (``make_initializer(method)``).
        values: the guess as GTSAM values.
        poses: (n, 3) the same guess as an array, in pose-index order.
        chi2: g2o chi2 of the guess (2 x GTSAM error of the graph).
        seconds: wall time to produce the guess, its start's included.
        details: JSON-ready facts the method learned.
        certificate: an optimality certificate, for methods that give one.
    """

    method: str
    values: gtsam.Values
    poses: np.ndarray
    chi2: float
    seconds: float
    details: dict[str, Any] = field(default_factory=dict)
    certificate: Any = None


class Initializer:
    """The protocol: subclasses implement :meth:`estimate`.

    Attributes:
        name: the registered name (set by :func:`make_initializer`).
        start: the method whose guess this one starts from, or None.
    """

    name: str = ""
    start: str | None = None

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """The guess for ``graph`` (``values`` gives the anchor pose and any start)."""
        return self.run(PoseGraph2D.from_gtsam(graph, values)).values

    @numeric_call
    def run(self, pose_graph: PoseGraph2D, start: InitResult | None = None) -> InitResult:
        """The guess with its chi2 and seconds; ``start``: the start method's result, if any.

        An initializer with a ``start`` method and no ``start`` result runs that method
        first; either way its seconds are counted in the result.
        """
        began = time.perf_counter()
        if start is None and self.start is not None:
            start = make_initializer(self.start).run(pose_graph)
        estimate = self.estimate(pose_graph, None if start is None else start.poses)
        seconds = time.perf_counter() - began + (0.0 if start is None else start.seconds)
        values = pose_graph.to_values(estimate.poses)
        return InitResult(self.name, values, estimate.poses, chi2(pose_graph.graph, values),
                          seconds, estimate.details, estimate.certificate)

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        """The guess as arrays; ``start_poses``: (n, 3) poses to start from, or None."""
        raise NotImplementedError


class OrientationInitializer(Initializer):
    """An initializer that estimates orientations; positions come from the translation step."""

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        start_theta = None if start_poses is None else start_poses[:, 2]
        return Estimate(poses_with_orientations(pose_graph,
                                                self.orientations(pose_graph, start_theta)))

    def orientations(self, pose_graph: PoseGraph2D, start_theta: np.ndarray | None) -> np.ndarray:
        """Orientations (n,), in any gauge (the anchor is re-aligned afterwards)."""
        raise NotImplementedError


class OdometryInitializer(Initializer):
    """The values as given: a file's vertices, or its chained odometry if it had none."""

    name = "odometry"

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        return Estimate(pose_graph.poses.copy())


class LagoInitializer(OrientationInitializer):
    """GTSAM's LAGO orientations, then the translation step with the full information.

    ``gtsam.lago`` rejects full Gaussian noise models ("invalid noise model"), so its
    orientation step runs on a copy of the graph with diagonal models whose rotational
    sigma is ``1 / sqrt(rotation_weights)`` (the package's one convention); the translation
    step then uses each edge's full information.

    Args:
        odometric_path: LAGO's spanning tree follows the odometry edges ``(k, k+1)``
            (pose indices) when True, else a breadth-first tree.
    """

    name = "lago"

    def __init__(self, odometric_path: bool = True) -> None:
        self.odometric_path = odometric_path

    def orientations(self, pose_graph: PoseGraph2D, start_theta: np.ndarray | None) -> np.ndarray:
        g = pose_graph
        sigmas = np.column_stack([
            1.0 / np.sqrt(g.information[:, 0, 0]), 1.0 / np.sqrt(g.information[:, 1, 1]),
            1.0 / np.sqrt(rotation_weights(g)),
        ])
        diagonal = gtsam.NonlinearFactorGraph()
        for factor in _edge_factors(g, sigmas, lambda s: gtsam.noiseModel.Diagonal.Sigmas(
                np.array(s))):
            diagonal.add(factor)
        anchor_pose = gtsam.Pose2(*g.held[1][0])
        diagonal.add(gtsam.PriorFactorPose2(g.anchor, anchor_pose, gtsam.noiseModel.Unit.Create(3)))
        try:
            orientations = gtsam.lago.initializeOrientations(diagonal, self.odometric_path)
            return np.array([orientations.at(k)[0] for k in range(g.num_poses)])
        except (RuntimeError, IndexError) as error:
            raise SolverError(f"LAGO orientation step failed: {one_line(error)}") from None


class ChordalInitializer(OrientationInitializer):
    """Chordal relaxation of the rotations, projected onto SO(2)
    (:func:`~rlpgo_gtsam.chordal.chordal_orientations`), then the translation step."""

    name = "chordal"

    def orientations(self, pose_graph: PoseGraph2D, start_theta: np.ndarray | None) -> np.ndarray:
        return chordal_orientations(pose_graph)


class ShonanInitializer(Initializer):
    """GTSAM's Shonan rotation averaging (SO(2)), best of a few starts.

    The measurements are built from the graph's factors, each weighted by its rotation
    weight. Started from given orientations (``start_poses``) it runs once from them;
    otherwise from ``starts`` seeded random rotations. The result with the lowest weighted
    rotation cost wins; then the translation step.

    Each run is timed: ``details["runs"]`` lists, per start, its seconds and its weighted
    rotation cost or why it failed, and a run that failed from every start says how long it
    tried (``Shonan averaging failed from every start (2 runs, 4.1 s): ...``).

    Args:
        starts: number of random starts (when no start orientations are given).
        seed: seed of the random starts.
        max_p: highest rank of the Riemannian staircase.
        progress: called with one line after each run (its seconds and cost, or failure).
    """

    name = "shonan"

    def __init__(self, starts: int = 2, seed: int = 0, max_p: int = 10,
                 progress: Callable[[str], None] | None = None) -> None:
        if not 1 <= starts <= 1000:
            raise SolverError(f"shonan: starts must lie in 1 .. 1000, got {starts}")
        if not 2 <= max_p <= 100:
            raise SolverError(f"shonan: max_p must lie in 2 .. 100, got {max_p}")
        self.starts = starts
        self.seed = seed
        self.max_p = max_p
        self.progress = progress

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        began = time.perf_counter()
        weights = rotation_weights(g)
        factors = _edge_factors(g, weights, lambda w: gtsam.noiseModel.Diagonal.Precisions(
            np.array([1.0, 1.0, w])))
        shonan = gtsam.ShonanAveraging2(
            factors, gtsam.ShonanAveragingParameters2(gtsam.LevenbergMarquardtParams())
        )
        rng = np.random.default_rng(self.seed)
        starts = [start_poses[:, 2]] if start_poses is not None else [
            rng.uniform(-np.pi, np.pi, g.num_poses) for _ in range(self.starts)]
        best_theta, best_cost, runs = None, np.inf, []
        for number, angles in enumerate(starts, 1):
            run_began = time.perf_counter()
            initial = gtsam.Values()
            for k, angle in enumerate(np.asarray(angles, dtype=float).tolist()):
                initial.insert(k, gtsam.Rot2(angle))
            try:
                result, _ = shonan.run(initial, 2, self.max_p)
            except RuntimeError as error:
                runs.append({"seconds": time.perf_counter() - run_began,
                             "failure": one_line(error)})
            else:
                theta = np.array([result.atRot2(k).theta() for k in range(g.num_poses)])
                cost = float(weights @ chordal_edge_costs(angle_residuals(theta, g.edges,
                                                                          g.measured[:, 2])))
                runs.append({"seconds": time.perf_counter() - run_began, "rotation_cost": cost})
                if cost < best_cost:
                    best_theta, best_cost = theta, cost
            if self.progress is not None:
                run = runs[-1]
                outcome = (f"failed ({run['failure']})" if "failure" in run else
                           f"rotation cost {run['rotation_cost']:.6g}")
                self.progress(f"run {number} of {len(starts)}: {outcome}, "
                              f"{run['seconds']:.2f} s")
        if best_theta is None:
            raise SolverError(
                f"Shonan averaging failed from every start ({len(runs)} "
                f"run{'s' if len(runs) > 1 else ''}, {time.perf_counter() - began:.2f} s): "
                f"{runs[0]['failure']}")
        return Estimate(poses_with_orientations(g, best_theta), details={"runs": runs})


# The certified initializer's steps after its staircase (the translation step, the GTSAM
# values and their chi2), reckoned in seconds of its chordal start (one pairwise solve of the
# same graph, timed in the same run: it slows down with the machine's load as they do). On
# the 200,000-pose generated graph of benchmarks/results/scale_budget.md: chordal 2.49 s;
# translations 2.09 s, values 2.16 s, chi2 0.11 s: 1.75 times.
FINISH_PER_START = 2.0


class CertifiedInitializer(Initializer):
    """The SE(2) synchronization relaxation with an optimality certificate (SE-Sync in 2D).

    The relaxation (:mod:`rlpgo_gtsam.certified`) is solved from the chordal estimate; its
    rounded orientations get positions from the translation step, and the result carries
    the :class:`~rlpgo_gtsam.certified.Certificate`: whether the relaxation was exact (the
    rounded estimate is then the global optimum of the relaxation's cost), its dual lower
    bound and the estimate's suboptimality bound, all in the relaxation's cost, which is
    not GTSAM's (see :mod:`rlpgo_gtsam.certified`), and its ``status``: how the staircase
    ended. The certificate is the result's ``certificate`` (``details`` stays empty).

    Args:
        max_rank: highest rank of the Riemannian staircase.
        time_limit_s: the whole :meth:`run`'s time limit: the staircase rounds what it has
            (status ``time_limit``) once what is left of it only holds the steps after the
            staircase (translations, GTSAM values, chi2), reckoned as
            :data:`FINISH_PER_START` times the chordal start's seconds (none from a given
            start); None: no limit.
        progress: called with one short line per rank and, inside a long trust region, at
            most one every 2 s (see :func:`~rlpgo_gtsam.certified.synchronize`); None: silent.
        max_iterations: trust-region iterations per rank (status ``iteration_limit`` when a
            rank uses them all).
    """

    name = "certified"

    def __init__(self, max_rank: int = 10, time_limit_s: float | None = None,
                 progress: Callable[[str], None] | None = None,
                 max_iterations: int = 300) -> None:
        self.max_rank = max_rank
        self.time_limit_s = time_limit_s
        self.progress = progress
        self.max_iterations = max_iterations

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        from rlpgo_gtsam.certified import synchronize  # scipy: loaded when first used

        began = time.perf_counter()
        start_theta = chordal_orientations(pose_graph) if start_poses is None else \
            start_poses[:, 2]
        limit = self.time_limit_s
        if limit is not None:
            spent = time.perf_counter() - began
            limit = max(limit - spent * (1.0 + FINISH_PER_START), 0.0)
        theta, certificate = synchronize(pose_graph, start_theta, max_rank=self.max_rank,
                                         max_iterations=self.max_iterations,
                                         time_limit_s=limit, progress=self.progress)
        return Estimate(poses_with_orientations(pose_graph, theta), certificate=certificate)


class FastSyncInitializer(Initializer):
    """GTSAM's own ``gtsam.fastSyncPose2``: a sparse chordal initializer of whole poses.

    It takes isotropic noise models only, so it runs on a copy of the graph whose edges get
    an isotropic precision equal to their rotation weight; its poses are then moved rigidly
    so that the anchor gets its pose, and held poses keep theirs.
    """

    name = "fastsync"

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        isotropic = gtsam.NonlinearFactorGraph()
        for factor in _edge_factors(g, rotation_weights(g),
                                    lambda w: gtsam.noiseModel.Isotropic.Precision(3, w)):
            isotropic.add(factor)
        try:
            result = gtsam.fastSyncPose2(isotropic)
        except RuntimeError as error:
            raise SolverError(f"fastSyncPose2 failed: {one_line(error)}") from None
        poses = [result.atPose2(k) for k in range(g.num_poses)]
        held, held_poses = g.held
        shift = gtsam.Pose2(*held_poses[0]).compose(poses[held[0]].inverse())
        moved = np.array([[p.x(), p.y(), p.theta()] for p in (shift.compose(q) for q in poses)])
        moved[held] = held_poses
        return Estimate(moved)


def _edge_factors(pose_graph: PoseGraph2D, noise: np.ndarray,
                  model: Callable[[Any], gtsam.noiseModel.Base]) -> list[gtsam.BetweenFactorPose2]:
    """One ``BetweenFactorPose2`` per edge, measured as the graph's, with the noise model
    ``model(row)`` of its row of ``noise`` ((m,) floats or (m, k) rows, passed as a float
    or a tuple). A model is made once per distinct row and shared by the edges that have
    it: a file's edges mostly share theirs (City10K's 20687 edges took 0.3 s with a model
    each, 0.08 s shared)."""
    made: dict[Any, gtsam.noiseModel.Base] = {}
    factors = []
    for (i, j), z, row in zip(pose_graph.edges.tolist(), pose_graph.measured.tolist(),
                              noise.tolist(), strict=True):
        key = tuple(row) if isinstance(row, list) else row
        if key not in made:
            made[key] = model(key)
        factors.append(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*z), made[key]))
    return factors


CLASSICAL = ("odometry", "lago", "chordal", "shonan")

# The one list of method names. Name -> factory, or "module:attribute" for one imported on
# first use (the agent's initializer needs torch: importing it here would load torch for
# every classical run).
_REGISTRY: dict[str, Callable[..., Initializer] | str] = {
    "odometry": OdometryInitializer,
    "lago": LagoInitializer,
    "chordal": ChordalInitializer,
    "shonan": ShonanInitializer,
    "fastsync": FastSyncInitializer,
    "certified": CertifiedInitializer,
    "rl": "rlpgo_gtsam.rl.initializer:RLInitializer",
}
# Methods that start from another method's guess (``name@start``); the others can be starts.
_TAKES_START = {"rl"}


def register(name: str, factory: Callable[..., Initializer], takes_start: bool = False) -> None:
    """Make ``factory(**options)`` available as initializer ``name`` (and in the CLIs).

    ``takes_start``: the factory takes ``start=<method name>`` (``name@start`` in lists).
    """
    if not name or "@" in name or "," in name:
        raise RlpgoError(f"an initializer name is a word without '@' or ',', got '{name}'")
    _REGISTRY[name] = factory
    _TAKES_START.discard(name)
    if takes_start:
        _TAKES_START.add(name)


def initializer_names() -> list[str]:
    """Names of the registered initializers, in registration order."""
    return list(_REGISTRY)


def start_names() -> list[str]:
    """Names of the initializers another one can start from (those without a start)."""
    return [name for name in _REGISTRY if name not in _TAKES_START]


def check_method(name: str) -> None:
    """Raise :class:`RlpgoError` unless ``name`` (or ``name@start``) names a method."""
    base, at, start = name.partition("@")
    if base not in _REGISTRY:
        raise RlpgoError(f"unknown method '{name}'; choose from {', '.join(_REGISTRY)}")
    if at and base not in _TAKES_START:
        raise RlpgoError(f"'{name}': method {base} takes no start")
    if at and start not in start_names():
        raise RlpgoError(f"'{name}': unknown start '{start}'; choose from "
                         f"{', '.join(start_names())}")


def _factory(name: str) -> Callable[..., Initializer]:
    factory = _REGISTRY[name]
    if isinstance(factory, str):
        module, _, attribute = factory.partition(":")
        factory = _REGISTRY[name] = getattr(importlib.import_module(module), attribute)
    return factory


def make_initializer(name: str, **options: Any) -> Initializer:
    """A new initializer of a registered name; ``name@start`` passes ``start=...`` too.

    ``options`` go to the factory (``make_initializer("rl@chordal", episodes=10)``).

    Raises:
        RlpgoError: an unknown name, or options the method does not take (named).
    """
    check_method(name)
    base, _, start = name.partition("@")
    if start:
        options["start"] = start
    return build_initializer(_factory(base), name, options)


def build_initializer(factory: Callable[..., Initializer], name: str,
                      options: dict[str, Any]) -> Initializer:
    """``factory(**options)`` named ``name``; options it does not take are an error that
    names them (every registry's factories are made here).

    Raises:
        RlpgoError: options the factory does not take.
    """
    base = name.partition("@")[0]
    accepted = inspect.signature(factory).parameters
    unknown = sorted(set(options) - set(accepted))
    if unknown and not any(p.kind is p.VAR_KEYWORD for p in accepted.values()):
        takes = ", ".join(accepted) or "no options"
        raise RlpgoError(f"method '{base}' does not take {', '.join(unknown)} (it takes: {takes})")
    initializer = factory(**options)
    initializer.name = name
    return initializer
