"""Initial guesses for pose-graph optimization, planar or 3D: one protocol, one registry.

Every initializer mirrors ``gtsam.lago.initialize``: ``initialize(graph, values)`` takes
GTSAM's graph and values, planar (``Pose2``) or 3D (``Pose3``), and returns
:class:`gtsam.Values`. That call is a thin wrapper: the graph is extracted once
(:func:`~rlpgo_gtsam.graph.extract_pose_graph`), and :meth:`Initializer.run` returns an
:class:`InitResult` with the guess, its chi2, the seconds it took and whatever the method
learned (rollout costs, a certificate). Rotation initializers estimate the rotations only;
positions then come from :func:`~rlpgo_gtsam.translations.poses_with_rotations`. The anchor
pose and FIXed poses keep their poses.

Each name says which pose groups it takes (:func:`initializer_names` with a group lists
those of that group); a method run on a graph of another group is an
:class:`~rlpgo_gtsam.errors.RlpgoError` that names the group's methods. New initializers plug
in with :func:`register`::

    class Mine(RotationInitializer):
        def rotations(self, pose_graph, start=None):
            return ...  # (n,) angles

    register("mine", Mine)
    make_initializer("mine").initialize(graph, values)
"""

from __future__ import annotations

import functools
import importlib
import inspect
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.anchoring import anchoring
from rlpgo_gtsam.chordal import chordal_cost, chordal_rotations
from rlpgo_gtsam.errors import RlpgoError, SolverError, one_line
from rlpgo_gtsam.graph import (
    PoseGraph,
    PoseGraph2D,
    PoseGraph3D,
    check_reach,
    chi2,
    extract_pose_graph,
    rotation_weights,
)
from rlpgo_gtsam.groups import GROUPS, SE2, SE3, Group
from rlpgo_gtsam.landmarks import outside_kinds
from rlpgo_gtsam.numerics import eliminating_call, numeric_call
from rlpgo_gtsam.translations import poses_and_points, poses_with_rotations

__all__ = [
    "InitResult",
    "Estimate",
    "Initializer",
    "RotationInitializer",
    "OdometryInitializer",
    "LagoInitializer",
    "ChordalInitializer",
    "ShonanInitializer",
    "CertifiedInitializer",
    "FINISH_PER_START",
    "FastSyncInitializer",
    "InitializePose3",
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
        poses: the guess in pose-index order: (n, 3) x, y, theta, or (n, 3, 4) ``[R | t]``.
        details: JSON-ready facts the method learned (rollout costs, chosen rollout, ...).
        certificate: an optimality certificate, for methods that give one.
        points: the landmarks' positions (p, d) where the method solved them with the poses;
            None: placed given the poses (:meth:`~rlpgo_gtsam.graph.PoseGraph2D.to_values`).
    """

    poses: np.ndarray
    details: dict[str, Any] = field(default_factory=dict)
    certificate: Any = None
    points: np.ndarray | None = None


@dataclass(eq=False)
class InitResult:
    """One initializer's answer for one graph.

    Attributes:
        method: the name it was made by (``make_initializer(method)``).
        values: the guess as GTSAM values.
        poses: the same guess as an array ((n, 3) or (n, 3, 4)), in pose-index order.
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
        groups: the pose groups it works on (its registration's, where it was made by
            name).
    """

    name: str = ""
    start: str | None = None
    groups: tuple[Group, ...] = (SE2,)

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """The guess for ``graph`` (``values`` gives the anchor pose and any start)."""
        return self.run(extract_pose_graph(graph, values)).values

    @numeric_call
    def run(self, pose_graph: PoseGraph, start: InitResult | None = None) -> InitResult:
        """The guess with its chi2 and seconds; ``start``: the start method's result, if any.

        An initializer with a ``start`` method and no ``start`` result runs that method
        first; either way its seconds are counted in the result.

        Raises:
            RlpgoError: a graph of a group the method does not take (the group's methods
                are named).
        """
        if pose_graph.group not in self.groups:
            raise RlpgoError(_other_group(self.name or type(self).__name__, self.groups,
                                          pose_graph.group))
        check_reach(pose_graph)
        began = time.perf_counter()
        if start is None and self.start is not None:
            start = make_initializer(self.start).run(pose_graph)
        estimate = self.estimate(pose_graph, None if start is None else start.poses)
        seconds = time.perf_counter() - began + (0.0 if start is None else start.seconds)
        values = pose_graph.to_values(estimate.poses, estimate.points)
        return InitResult(self.name, values, estimate.poses, chi2(pose_graph.factor_graph, values),
                          seconds, estimate.details, estimate.certificate)

    def estimate(self, pose_graph: Any, start_poses: np.ndarray | None) -> Estimate:
        """The guess as arrays; ``start_poses``: poses to start from, or None."""
        raise NotImplementedError


class RotationInitializer(Initializer):
    """An initializer that estimates rotations; positions come from the translation step."""

    def estimate(self, pose_graph: Any, start_poses: np.ndarray | None) -> Estimate:
        start = None if start_poses is None else pose_graph.group.rotations(start_poses)
        return Estimate(poses_with_rotations(pose_graph, self.rotations(pose_graph, start)))

    def rotations(self, pose_graph: Any, start: np.ndarray | None) -> np.ndarray:
        """Rotations (planar angles (n,), 3D matrices (n, 3, 3)) in any gauge (the anchor is
        re-aligned afterwards); ``start``: the start's rotations, or None."""
        raise NotImplementedError


class OdometryInitializer(Initializer):
    """The values as given: a file's vertices, or its chained odometry if it had none."""

    name = "odometry"
    groups = GROUPS

    def estimate(self, pose_graph: PoseGraph, start_poses: np.ndarray | None) -> Estimate:
        return Estimate(pose_graph.poses.copy())


class LagoInitializer(RotationInitializer):
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
    groups = (SE2,)

    def __init__(self, odometric_path: bool = True) -> None:
        self.odometric_path = odometric_path

    def rotations(self, pose_graph: PoseGraph2D, start: np.ndarray | None) -> np.ndarray:
        g = pose_graph
        sigmas = np.column_stack([
            1.0 / np.sqrt(g.information[:, 0, 0]), 1.0 / np.sqrt(g.information[:, 1, 1]),
            1.0 / np.sqrt(rotation_weights(g)),
        ])
        diagonal = gtsam.NonlinearFactorGraph()
        for factor in _edge_factors(g, _shared_models(sigmas, lambda s: (
                gtsam.noiseModel.Diagonal.Sigmas(np.array(s))))):
            diagonal.add(factor)
        anchor_pose = gtsam.Pose2(*g.held[1][0])
        diagonal.add(gtsam.PriorFactorPose2(g.anchor, anchor_pose, gtsam.noiseModel.Unit.Create(3)))
        try:
            orientations = eliminating_call(g.num_poses, lambda: (
                gtsam.lago.initializeOrientations(diagonal, self.odometric_path)), g.num_edges)
            return np.array([orientations.at(k)[0] for k in range(g.num_poses)])
        except (RuntimeError, IndexError) as error:
            raise SolverError(f"LAGO orientation step failed: {one_line(error)}") from None


class ChordalInitializer(RotationInitializer):
    """The chordal relaxation of the rotations, projected
    (:func:`~rlpgo_gtsam.chordal.chordal_rotations`), then the translation step."""

    name = "chordal"
    groups = GROUPS

    def rotations(self, pose_graph: PoseGraph, start: np.ndarray | None) -> np.ndarray:
        return chordal_rotations(pose_graph)


class ShonanInitializer(Initializer):
    """GTSAM's Shonan rotation averaging (``ShonanAveraging2`` / ``ShonanAveraging3``), best
    of its starts.

    Each edge's rotation is weighted by its rotation weight. Started from given rotations
    (a start's poses) it runs once from them; otherwise a planar graph from ``starts``
    seeded random rotations, a 3D graph from the chordal estimate. The result with the
    lowest weighted chordal rotation cost (:func:`~rlpgo_gtsam.chordal.chordal_cost`) wins;
    then the translation step.

    On a graph without cycles (its distinct pose pairs a tree) each pair's rotation is its own
    problem and the chordal estimate is its exact optimum: it is returned without a run
    (``details["tree"]``). Each run is timed:
    ``details["runs"]`` lists, per start, its seconds and its weighted rotation cost or why
    it failed, and a run that failed from every start says how long it
    tried (``Shonan averaging failed from every start (2 runs, 4.1 s): ...``).

    Args:
        starts: number of random starts of a planar graph (when no start is given).
        seed: seed of the random starts.
        max_p: highest rank of the Riemannian staircase.
        progress: called with one line after each run (its seconds and cost, or failure).
    """

    name = "shonan"
    groups = GROUPS

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

    def estimate(self, pose_graph: PoseGraph, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        pairs = np.unique(np.sort(g.edges, axis=1), axis=0)
        if len(pairs) == g.num_poses - 1:
            # a tree of pose pairs (an odometry chain, a landmark graph's poses): each pair's
            # rotation is its own problem, which the chordal estimate solves exactly; GTSAM's
            # Shonan fails its eigenvalue check there (1000 poses: "SparseMinimumEigenValue
            # failed" after 4 s)
            return Estimate(poses_with_rotations(g, chordal_rotations(g)),
                            details={"runs": [], "tree": True})
        began = time.perf_counter()
        averaging, insert, read = _SHONAN[g.group](g, rotation_weights(g))
        starts = self._starts(g, None if start_poses is None else g.group.rotations(start_poses))
        best, best_cost, runs = None, np.inf, []
        for number, rotations in enumerate(starts, 1):
            run_began = time.perf_counter()
            initial = gtsam.Values()
            for k, rotation in enumerate(np.asarray(rotations, dtype=float)):
                insert(initial, k, rotation)
            try:
                result, _ = eliminating_call(g.num_poses, functools.partial(
                    averaging.run, initial, g.group.d, self.max_p), g.num_edges)
            except RuntimeError as error:
                runs.append({"seconds": time.perf_counter() - run_began,
                             "failure": one_line(error)})
            else:
                found = read(result, g.num_poses)
                cost = chordal_cost(g, found)
                runs.append({"seconds": time.perf_counter() - run_began, "rotation_cost": cost})
                if cost < best_cost:
                    best, best_cost = found, cost
            self._report(runs[-1], number, len(starts))
        if best is None:
            raise SolverError(
                f"Shonan averaging failed from every start ({len(runs)} "
                f"run{'s' if len(runs) > 1 else ''}, {time.perf_counter() - began:.2f} s): "
                f"{runs[0]['failure']}")
        return Estimate(poses_with_rotations(g, best), details={"runs": runs})

    def _starts(self, g: PoseGraph, start: np.ndarray | None) -> list[np.ndarray]:
        """The given start, else the planar random starts or the 3D chordal estimate."""
        if start is not None:
            return [start]
        if g.group is SE3:
            return [chordal_rotations(g)]
        rng = np.random.default_rng(self.seed)
        return [rng.uniform(-np.pi, np.pi, g.num_poses) for _ in range(self.starts)]

    def _report(self, run: dict[str, Any], number: int, count: int) -> None:
        if self.progress is not None:
            outcome = (f"failed ({run['failure']})" if "failure" in run else
                       f"rotation cost {run['rotation_cost']:.6g}")
            self.progress(f"run {number} of {count}: {outcome}, {run['seconds']:.2f} s")


def _planar_shonan(g: PoseGraph2D, weights: np.ndarray) -> tuple:
    """ShonanAveraging2 of the edges (each a BetweenFactorPose2 with rotational precision
    its weight; edges joining the same two poses as one, :func:`_merged_rotations`), how a
    start is inserted and how angles are read."""
    merged = _merged_rotations(g.edges, g.measured[:, 2], weights)
    if merged is None:
        factors = _edge_factors(g, _shared_models(weights, lambda w: (
            gtsam.noiseModel.Diagonal.Precisions(np.array([1.0, 1.0, w])))))
    else:
        factors = [gtsam.BetweenFactorPose2(
            i, j, gtsam.Pose2(0.0, 0.0, angle),
            gtsam.noiseModel.Diagonal.Precisions(np.array([1.0, 1.0, weight])))
            for (i, j), angle, weight in zip(*(part.tolist() for part in merged), strict=True)]
    averaging = gtsam.ShonanAveraging2(
        factors, gtsam.ShonanAveragingParameters2(gtsam.LevenbergMarquardtParams()))
    return (averaging, lambda values, k, angle: values.insert(k, gtsam.Rot2(float(angle))),
            lambda result, n: np.array([result.atRot2(k).theta() for k in range(n)]))


def _merged_rotations(edges: np.ndarray, angles: np.ndarray,
                      weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The planar rotation measurements with the edges that join the same two poses made
    one: (edges, angles, weights); None where no two edges do (or their rotations cancel).

    Shonan's cost charges an edge ``w ||R_j - R_i R(theta)||^2``, linear in ``w R(theta)``
    up to a constant, and a sum of weighted planar rotations is a weighted rotation
    (``sum w e^(i theta)``): the one edge has the same minimizers, gradient and certificate.
    GTSAM's ShonanAveraging2 holds about 2 KB for each measurement (10^6 parallel edges
    between two poses took 2.6 GB)."""
    low, high = edges.min(axis=1).astype(np.int64), edges.max(axis=1).astype(np.int64)
    base = int(high.max()) + 1
    pairs, inverse = np.unique(low * base + high, return_inverse=True)
    if len(pairs) == len(edges):
        return None
    signed = np.where(edges[:, 0] <= edges[:, 1], angles, -angles)  # as measured low -> high
    total = (np.bincount(inverse, weights * np.cos(signed), len(pairs))
             + 1j * np.bincount(inverse, weights * np.sin(signed), len(pairs)))
    if np.any(np.abs(total) <= 1e-12 * np.bincount(inverse, weights, len(pairs))):
        return None
    return np.column_stack([pairs // base, pairs % base]), np.angle(total), np.abs(total)


def _spatial_shonan(g: PoseGraph3D, weights: np.ndarray) -> tuple:
    """ShonanAveraging3 of the edges' rotations (isotropic precision kappa), how a start is
    inserted and how rotations are read."""
    measurements = [
        gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(r),
                                    gtsam.noiseModel.Isotropic.Precision(3, float(w)))
        for (i, j), r, w in zip(g.edges.tolist(), g.measured_rotations, weights, strict=True)
    ]
    averaging = gtsam.ShonanAveraging3(
        measurements, gtsam.ShonanAveragingParameters3(gtsam.LevenbergMarquardtParams()))
    return (averaging, lambda values, k, rotation: values.insert(k, gtsam.Rot3(rotation)),
            lambda result, n: np.array([result.atRot3(k).matrix() for k in range(n)]))


_SHONAN: dict[Group, Callable[[Any, np.ndarray], tuple]] = {SE2: _planar_shonan,
                                                            SE3: _spatial_shonan}


class FastSyncInitializer(Initializer):
    """GTSAM's own ``fastSyncPose2`` / ``fastSyncPose3``: a sparse chordal initializer of
    whole poses.

    It takes isotropic noise models only, so it runs on a copy of the graph whose edges get
    an isotropic precision equal to their rotation weight; its poses are then moved rigidly
    so that the anchor gets its pose, and held poses keep theirs.
    """

    name = "fastsync"
    groups = GROUPS

    def estimate(self, pose_graph: PoseGraph, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        dof = g.group.dof
        isotropic = gtsam.NonlinearFactorGraph()
        for factor in _edge_factors(g, _shared_models(rotation_weights(g), lambda w: (
                gtsam.noiseModel.Isotropic.Precision(dof, w)))):
            isotropic.add(factor)
        sync = _FAST_SYNC[g.group]
        try:
            result = sync(isotropic)
        except RuntimeError as error:
            raise SolverError(f"{sync.__name__} failed: {one_line(error)}") from None
        return Estimate(_held_kept(g, result))


_FAST_SYNC: dict[Group, Callable[[gtsam.NonlinearFactorGraph], gtsam.Values]] = {
    SE2: gtsam.fastSyncPose2, SE3: gtsam.fastSyncPose3}


class InitializePose3(Initializer):
    """GTSAM's ``InitializePose3.initialize`` (chordal rotations, one Gauss-Newton step on
    the full poses), with a prior on the anchor (it needs one)."""

    name = "initialize_pose3"
    groups = (SE3,)

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        given = g.factor_graph
        own = [factor.noiseModel() for factor in map(given.at, range(given.size()))
               if isinstance(factor, gtsam.BetweenFactorPose3)]
        graph = gtsam.NonlinearFactorGraph()
        for factor in _edge_factors(g, own):
            graph.add(factor)
        held, held_poses = g.held
        graph.add(gtsam.PriorFactorPose3(int(held[0]), SE3.gtsam_pose(held_poses[0]),
                                         gtsam.noiseModel.Unit.Create(6)))
        try:
            values = eliminating_call(g.num_poses,
                                      lambda: gtsam.InitializePose3.initialize(graph),
                                      g.num_edges)
        except RuntimeError as error:
            raise SolverError(f"InitializePose3 failed: {one_line(error)}") from None
        return Estimate(_held_kept(g, values))


def _shared_models(noise: np.ndarray, model: Callable[[Any], Any]) -> list[Any]:
    """The noise model ``model(row)`` of each row of ``noise`` ((m,) floats or (m, k) rows,
    passed as a float or a tuple), made once per distinct row and shared by the edges that
    have it: a file's edges mostly share theirs (City10K's 20687 edges took 0.3 s with a
    model each, 0.08 s shared)."""
    made: dict[Any, Any] = {}
    models = []
    for row in noise.tolist():
        key = tuple(row) if isinstance(row, list) else row
        if key not in made:
            made[key] = model(key)
        models.append(made[key])
    return models


def _edge_factors(pose_graph: PoseGraph, models: list[Any]) -> list[Any]:
    """One between factor per edge, keyed by pose index, measured as the graph's, with the
    given noise model."""
    group = pose_graph.group
    return [group.between_factor(i, j, group.gtsam_pose(z), model)
            for (i, j), z, model in zip(pose_graph.edges.tolist(), group.measured(pose_graph),
                                        models, strict=True)]


def _held_kept(pose_graph: PoseGraph, values: gtsam.Values) -> np.ndarray:
    """The poses of GTSAM ``values`` keyed by index, moved rigidly so that the anchor gets
    its pose; held poses keep theirs."""
    g, group = pose_graph, pose_graph.group
    poses = [group.pose_at(values, k) for k in range(g.num_poses)]
    held, held_poses = g.held
    shift = group.gtsam_pose(held_poses[0]).compose(poses[held[0]].inverse())
    moved = group.pose_arrays([shift.compose(q) for q in poses])
    moved[held] = held_poses
    return moved


# The certified initializer's steps after its staircase (the translation step, the GTSAM
# values and their chi2), reckoned in seconds of its chordal start (one pairwise solve of the
# same graph, timed in the same run: it slows down with the machine's load as they do). On
# the 200,000-pose generated graph of benchmarks/results/scale_budget.md: chordal 2.49 s;
# translations 2.09 s, values 2.16 s, chi2 0.11 s: 1.75 times.
FINISH_PER_START = 2.0


class CertifiedInitializer(Initializer):
    """The SE(d) synchronization relaxation with an optimality certificate (SE-Sync).

    The relaxation (:mod:`rlpgo_gtsam.relaxation`) is solved from the chordal estimate (or
    the start's rotations); its rounded rotations get positions from the translation step,
    and the result carries the certificate: whether the relaxation was exact (the rounded
    estimate is then the global optimum of the relaxation's cost), its dual lower bound and
    the estimate's suboptimality bound, all in the relaxation's cost, which is not GTSAM's,
    and its ``status``: how the staircase ended. The certificate is the result's
    ``certificate`` (``details`` stays empty).

    Args:
        max_rank: highest rank of the Riemannian staircase.
        time_limit_s: the whole :meth:`run`'s time limit: the staircase rounds what it has
            (status ``time_limit``) once what is left of it only holds the steps after the
            staircase (translations, GTSAM values, chi2), reckoned as
            :data:`FINISH_PER_START` times the chordal start's seconds (none from a given
            start); None: no limit.
        progress: called with one short line per rank and, inside a long trust region, at
            most one every 2 s; None: silent.
        max_iterations: trust-region iterations per rank (status ``iteration_limit`` when a
            rank uses them all).
    """

    name = "certified"
    groups = GROUPS

    def __init__(self, max_rank: int = 10, time_limit_s: float | None = None,
                 progress: Callable[[str], None] | None = None,
                 max_iterations: int = 300) -> None:
        self.max_rank = max_rank
        self.time_limit_s = time_limit_s
        self.progress = progress
        self.max_iterations = max_iterations

    def estimate(self, pose_graph: PoseGraph, start_poses: np.ndarray | None) -> Estimate:
        from rlpgo_gtsam.relaxation import synchronize  # scipy: loaded when first used

        # a graph holding more than its gauge is solved as its one-anchor problem, positions
        # included: its FIX lines hold, its priors pull (rlpgo_gtsam.anchoring)
        anchored = anchoring(pose_graph)
        solved = pose_graph if anchored is None else anchored.graph
        start = None if start_poses is None else pose_graph.group.rotations(start_poses)
        if start is not None and anchored is not None:
            start = anchored.reduced_rotations(start)
        rotations, certificate = synchronize(solved, start, max_rank=self.max_rank,
                                             max_iterations=self.max_iterations,
                                             time_limit_s=self.time_limit_s,
                                             progress=self.progress,
                                             finish_per_start=FINISH_PER_START)
        # with landmarks and ranges, the relaxation's rotations are followed by the ranges'
        # directions: poses and points are positioned together
        poses, points = poses_and_points(solved, rotations)
        if anchored is not None:
            poses = anchored.lifted(poses)
            certificate = anchored.covering(certificate)
        return Estimate(poses, certificate=covering_whole(pose_graph, certificate),
                        points=points)


def covering_whole(pose_graph: PoseGraph, certificate: Any) -> Any:
    """A certificate that says how many landmarks and ranges it held, and, where the graph
    holds factors the relaxation does not model, that it does not apply
    (``not_applicable``, naming them, what the relaxation found on the rest kept in
    ``relaxed``)."""
    from rlpgo_gtsam.relaxation import Status

    points, ranges = pose_graph.points, pose_graph.ranges
    if points is not None:
        certificate = replace(certificate, points=points.count)
    if ranges is not None:
        certificate = replace(certificate, ranges=ranges.count)
    if pose_graph.carried:
        certificate = replace(certificate, status=Status.NOT_APPLICABLE,
                              outside=outside_kinds(pose_graph.carried),
                              relaxed=str(certificate.status))
    return certificate


# The planar comparison's classical rows.
CLASSICAL = ("odometry", "lago", "chordal", "shonan")


@dataclass(frozen=True)
class _Entry:
    """A registered name: its factory (or ``"module:attribute"``, imported on first use),
    the groups it takes, whether it starts from another method, and why it takes no other
    group (None: its groups say it)."""

    factory: Callable[..., Initializer] | str
    groups: tuple[Group, ...]
    takes_start: bool = False
    why: str | None = None


def _entry(factory: Callable[..., Initializer] | str, groups: Sequence[Group] | None = None,
           takes_start: bool = False, why: str | None = None) -> _Entry:
    """An entry whose groups are ``groups``, else the factory's own (its ``groups``
    attribute; planar for an :class:`Initializer` that sets none)."""
    taken = tuple(groups) if groups is not None else tuple(getattr(factory, "groups", (SE2,)))
    return _Entry(factory, taken, takes_start, why)


# The one list of method names, in the order they are listed. Name -> factory, or
# "module:attribute" for one imported on first use (the agent's initializer needs torch:
# importing it here would load torch for every classical run).
_REGISTRY: dict[str, _Entry] = {
    factory.name: _entry(factory)
    for factory in (OdometryInitializer, LagoInitializer, ChordalInitializer, ShonanInitializer,
                    FastSyncInitializer, CertifiedInitializer, InitializePose3)
} | {"rl": _entry("rlpgo_gtsam.rl.initializer:RLInitializer", (SE2,), takes_start=True,
                  why="the agent is planar (it runs on 2D graphs only)")}


def register(name: str, factory: Callable[..., Initializer], takes_start: bool = False,
             groups: Sequence[Group] | None = None) -> None:
    """Make ``factory(**options)`` available as initializer ``name`` (and in the CLIs).

    ``takes_start``: the factory takes ``start=<method name>`` (``name@start`` in lists).
    ``groups``: the pose groups it works on; None: the factory's ``groups`` attribute
    (planar for a subclass of :class:`Initializer` that sets none).
    """
    if not name or "@" in name or "," in name:
        raise RlpgoError(f"an initializer name is a word without '@' or ',', got '{name}'")
    _REGISTRY[name] = _entry(factory, groups, takes_start)


def initializer_names(group: Group | None = None) -> list[str]:
    """Names of the registered initializers, in registration order; given a ``group``,
    those that take its graphs."""
    return [name for name, entry in _REGISTRY.items() if group is None or group in entry.groups]


def start_names(group: Group | None = None) -> list[str]:
    """Names of the initializers another one can start from (those without a start)."""
    return [name for name in initializer_names(group) if not _REGISTRY[name].takes_start]


def check_method(name: str, group: Group | None = None) -> None:
    """Raise :class:`RlpgoError` unless ``name`` (or ``name@start``) names a method, one
    that takes ``group``'s graphs where a group is given."""
    base, at, start = name.partition("@")
    if base not in _REGISTRY:
        raise RlpgoError(f"unknown method '{name}'; choose from "
                         f"{', '.join(initializer_names(group))}")
    entry = _REGISTRY[base]
    if group is not None and group not in entry.groups:
        raise RlpgoError(_other_group(name, entry.groups, group, entry.why))
    if at and not entry.takes_start:
        raise RlpgoError(f"'{name}': method {base} takes no start")
    if at and start not in start_names(group):
        raise RlpgoError(f"'{name}': unknown start '{start}'; choose from "
                         f"{', '.join(start_names(group))}")


def _other_group(name: str, groups: tuple[Group, ...], group: Group,
                 why: str | None = None) -> str:
    """Why ``name``, which takes ``groups``, cannot run on a graph of ``group``."""
    choose = f"the {group.kind} methods are {', '.join(initializer_names(group))}"
    if why is None:
        return f"'{name}' is a {' and '.join(g.kind for g in groups)} method; {choose}"
    return f"'{name}': {why}; {choose}"


def _factory(name: str) -> Callable[..., Initializer]:
    entry = _REGISTRY[name]
    factory = entry.factory
    if isinstance(factory, str):
        module, _, attribute = factory.partition(":")
        factory = getattr(importlib.import_module(module), attribute)
        _REGISTRY[name] = _Entry(factory, entry.groups, entry.takes_start, entry.why)
    return factory


def make_initializer(name: str, **options: Any) -> Initializer:
    """A new initializer of a registered name; ``name@start`` passes ``start=...`` too.

    ``options`` go to the factory (``make_initializer("rl@chordal", episodes=10)``); the
    initializer takes the graphs of the name's groups (planar, 3D or both).

    Raises:
        RlpgoError: an unknown name, or options the method does not take (named).
    """
    check_method(name)
    base, _, start = name.partition("@")
    if start:
        options["start"] = start
    initializer = build_initializer(_factory(base), name, options)
    initializer.groups = _REGISTRY[base].groups
    return initializer


def build_initializer(factory: Callable[..., Initializer], name: str,
                      options: dict[str, Any]) -> Initializer:
    """``factory(**options)`` named ``name``; options it does not take are an error that
    names them.

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
