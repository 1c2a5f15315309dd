"""Initial guesses for 3D pose-graph optimization, the planar protocol for Pose3.

Each initializer is an :class:`~rlpgo_gtsam.initializers.Initializer`:
``initialize(graph, values)`` returns :class:`gtsam.Values`, ``run(pose_graph3d, start)``
an :class:`~rlpgo_gtsam.initializers.InitResult` whose ``poses`` is an (n, 3, 4) array of
``[R | t]`` per pose, and ``estimate`` the same as an
:class:`~rlpgo_gtsam.initializers.Estimate`. The anchor and FIXed poses keep their poses.
Rotation initializers get positions from
:func:`~rlpgo_gtsam.translations3d.poses_with_rotations` (GTSAM's cost minimized exactly
for the rotations). They are not in the planar registry: :data:`INITIALIZERS_3D` names them
(the one list of 3D method names; :data:`rlpgo_gtsam.dimension.METHODS_3D` is held equal to
it by a test) and :func:`make_initializer_3d` makes one by name;
:func:`rlpgo_gtsam.dimension.make_initializer_for` makes one for a graph of either dimension.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.chordal3d import chordal_rotations
from rlpgo_gtsam.errors import RlpgoError, SolverError, one_line
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.graph3d import PoseGraph3D, rotation_weights
from rlpgo_gtsam.initializers import (
    Estimate,
    Initializer,
    InitResult,
    build_initializer,
    initializer_names,
)
from rlpgo_gtsam.numerics import numeric_call
from rlpgo_gtsam.translations3d import poses_with_rotations

__all__ = [
    "Initializer3D",
    "RotationInitializer3D",
    "Odometry3D",
    "Chordal3D",
    "Certified3D",
    "InitializePose3",
    "FastSync3D",
    "Shonan3D",
    "INITIALIZERS_3D",
    "pose_matrices",
    "method_names",
    "check_method_3d",
    "make_initializer_3d",
]


def pose_matrices(rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """(n, 3, 4) ``[R | t]`` of each pose."""
    return np.concatenate([rotations, translations[:, :, None]], axis=2)


class Initializer3D(Initializer):
    """The protocol on a :class:`~rlpgo_gtsam.graph3d.PoseGraph3D`; subclasses implement
    :meth:`estimate` returning (n, 3, 4) poses."""

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        return self.run(PoseGraph3D.from_gtsam(graph, values)).values

    @numeric_call
    def run(self, pose_graph: PoseGraph3D, start: InitResult | None = None) -> InitResult:
        began = time.perf_counter()
        estimate = self.estimate(pose_graph, None if start is None else start.poses)
        seconds = time.perf_counter() - began + (0.0 if start is None else start.seconds)
        poses = estimate.poses
        values = pose_graph.to_values(poses[:, :, :3], poses[:, :, 3])
        return InitResult(self.name, values, poses, chi2(pose_graph.graph, values), seconds,
                          estimate.details, estimate.certificate)


class RotationInitializer3D(Initializer3D):
    """Estimates rotations; positions come from the translation step."""

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        start = None if start_poses is None else start_poses[:, :, :3]
        return Estimate(pose_matrices(*poses_with_rotations(
            pose_graph, self.rotations(pose_graph, start))))

    def rotations(self, pose_graph: PoseGraph3D, start: np.ndarray | None) -> np.ndarray:
        """(n, 3, 3) rotations in any gauge (the anchor is re-aligned afterwards)."""
        raise NotImplementedError


class Odometry3D(Initializer3D):
    """The values as given: a file's vertices, or its chained odometry if it had none."""

    name = "odometry"

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        return Estimate(pose_matrices(pose_graph.rotations, pose_graph.translations))


class Chordal3D(RotationInitializer3D):
    """The chordal SO(3) relaxation, projected (:mod:`rlpgo_gtsam.chordal3d`)."""

    name = "chordal"

    def rotations(self, pose_graph: PoseGraph3D, start: np.ndarray | None) -> np.ndarray:
        return chordal_rotations(pose_graph)


class Certified3D(Initializer3D):
    """SE-Sync's SE(3) relaxation with its certificate (:mod:`rlpgo_gtsam.certified3d`),
    from the chordal estimate (or the start's rotations); the certificate is the result's.

    Args:
        max_rank: highest rank of the Riemannian staircase.
        time_limit_s: the staircase's time limit, or None.
        progress: called with one short line per rank (and inside a long trust region);
            None: silent.
        max_iterations: trust-region iterations per rank.
    """

    name = "certified"

    def __init__(self, max_rank: int = 10, time_limit_s: float | None = None,
                 progress: Callable[[str], None] | None = None,
                 max_iterations: int = 300) -> None:
        self.max_rank = max_rank
        self.time_limit_s = time_limit_s
        self.progress = progress
        self.max_iterations = max_iterations

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        from rlpgo_gtsam.certified3d import synchronize3d

        start = None if start_poses is None else start_poses[:, :, :3]
        rotations, certificate = synchronize3d(pose_graph, start, max_rank=self.max_rank,
                                               time_limit_s=self.time_limit_s,
                                               progress=self.progress,
                                               max_iterations=self.max_iterations)
        return Estimate(pose_matrices(*poses_with_rotations(pose_graph, rotations)),
                        certificate=certificate)


def _between_graph(pose_graph: PoseGraph3D, noise=None) -> gtsam.NonlinearFactorGraph:
    """The between factors only, keyed by pose index, with their own noise models (or
    ``noise(edge)`` for each)."""
    g = pose_graph
    graph = gtsam.NonlinearFactorGraph()
    factors = [g.graph.at(k) for k in range(g.graph.size())]
    between = [f for f in factors if isinstance(f, gtsam.BetweenFactorPose3)]
    for e, ((i, j), factor) in enumerate(zip(g.edges.tolist(), between, strict=True)):
        model = factor.noiseModel() if noise is None else noise(e)
        graph.add(gtsam.BetweenFactorPose3(i, j, factor.measured(), model))
    return graph


def _held_kept(pose_graph: PoseGraph3D, values: gtsam.Values) -> np.ndarray:
    """(n, 3, 4) poses of GTSAM ``values`` keyed by index, moved rigidly so that the anchor
    gets its pose; held poses keep theirs."""
    g = pose_graph
    poses = [values.atPose3(k) for k in range(g.num_poses)]
    held, held_r, held_t = g.held
    shift = gtsam.Pose3(gtsam.Rot3(held_r[0]), held_t[0]).compose(poses[held[0]].inverse())
    moved = [shift.compose(p) for p in poses]
    rotations = np.array([p.rotation().matrix() for p in moved])
    translations = np.array([p.translation() for p in moved])
    rotations[held], translations[held] = held_r, held_t
    return pose_matrices(rotations, translations)


class InitializePose3(Initializer3D):
    """GTSAM's ``InitializePose3.initialize`` (chordal rotations, one Gauss-Newton step on
    the full poses), with a prior on the anchor (it needs one)."""

    name = "initialize_pose3"

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        g = pose_graph
        graph = _between_graph(g)
        held, held_r, held_t = g.held
        graph.add(gtsam.PriorFactorPose3(int(held[0]), gtsam.Pose3(gtsam.Rot3(held_r[0]),
                                                                   held_t[0]),
                                         gtsam.noiseModel.Unit.Create(6)))
        try:
            values = gtsam.InitializePose3.initialize(graph)
        except RuntimeError as error:
            raise SolverError(f"InitializePose3 failed: {one_line(error)}") from None
        return Estimate(_held_kept(g, values))


class FastSync3D(Initializer3D):
    """GTSAM's ``fastSyncPose3`` on a copy whose edges have isotropic precision kappa (it
    takes isotropic models only); moved rigidly onto the anchor."""

    name = "fastsync"

    def estimate(self, pose_graph: PoseGraph3D, start_poses: np.ndarray | None) -> Estimate:
        kappa = rotation_weights(pose_graph)
        graph = _between_graph(pose_graph, lambda e: gtsam.noiseModel.Isotropic.Precision(
            6, float(kappa[e])))
        try:
            values = gtsam.fastSyncPose3(graph)
        except RuntimeError as error:
            raise SolverError(f"fastSyncPose3 failed: {one_line(error)}") from None
        return Estimate(_held_kept(pose_graph, values))


class Shonan3D(RotationInitializer3D):
    """GTSAM's ``ShonanAveraging3`` on the rotations (each weighted by kappa), from the
    chordal estimate or the start's rotations; then the translation step.

    Args:
        max_p: highest rank of Shonan's staircase.
        progress: called with one line when the run ends (its seconds, or its failure).
    """

    name = "shonan"

    def __init__(self, max_p: int = 10, progress: Callable[[str], None] | None = None) -> None:
        self.max_p = max_p
        self.progress = progress

    def rotations(self, pose_graph: PoseGraph3D, start: np.ndarray | None) -> np.ndarray:
        g = pose_graph
        kappa = rotation_weights(g)
        measurements = [
            gtsam.BinaryMeasurementRot3(i, j, gtsam.Rot3(r),
                                        gtsam.noiseModel.Isotropic.Precision(3, float(w)))
            for (i, j), r, w in zip(g.edges.tolist(), g.measured_rotations, kappa, strict=True)
        ]
        shonan = gtsam.ShonanAveraging3(
            measurements, gtsam.ShonanAveragingParameters3(gtsam.LevenbergMarquardtParams()))
        initial = gtsam.Values()
        for k, r in enumerate(chordal_rotations(g) if start is None else start):
            initial.insert(k, gtsam.Rot3(r))
        began = time.perf_counter()
        try:
            result, _ = shonan.run(initial, 3, self.max_p)
        except RuntimeError as error:
            if self.progress is not None:
                self.progress(f"failed after {time.perf_counter() - began:.2f} s")
            raise SolverError(f"ShonanAveraging3 failed: {one_line(error)}") from None
        if self.progress is not None:
            self.progress(f"done in {time.perf_counter() - began:.2f} s")
        return np.array([result.atRot3(k).matrix() for k in range(g.num_poses)])


INITIALIZERS_3D: dict[str, type[Initializer3D]] = {
    cls.name: cls for cls in (Odometry3D, Chordal3D, Certified3D, InitializePose3, FastSync3D,
                              Shonan3D)
}
def method_names(dimension: int) -> list[str]:
    """The method names of graphs of ``dimension`` (2: the planar registry's, 3:
    :data:`INITIALIZERS_3D`'s)."""
    return list(INITIALIZERS_3D) if dimension == 3 else initializer_names()


def check_method_3d(name: str) -> None:
    """Raise :class:`RlpgoError` unless ``name`` is a 3D method; a planar one (the agent
    included) is named as such."""
    if name in INITIALIZERS_3D:
        return
    base = name.partition("@")[0]
    choose = f"the 3D methods are {', '.join(INITIALIZERS_3D)}"
    if base == "rl":
        raise RlpgoError(f"'{name}': the agent is planar (it runs on 2D graphs only); {choose}")
    if base in initializer_names():
        raise RlpgoError(f"'{name}' is a planar method; {choose}")
    raise RlpgoError(f"unknown method '{name}'; {choose}")


def make_initializer_3d(name: str, **options: Any) -> Initializer:
    """A new 3D initializer of a name in :data:`INITIALIZERS_3D`; ``options`` go to its
    factory.

    Raises:
        RlpgoError: an unknown or planar name, or options the method does not take.
    """
    check_method_3d(name)
    return build_initializer(INITIALIZERS_3D[name], name, options)
