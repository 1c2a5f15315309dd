"""Initial guesses for planar pose-graph optimization, one protocol, chosen by name.

Every initializer mirrors ``gtsam.lago.initialize``: GTSAM graph and values in,
:class:`gtsam.Values` out. The classical ones estimate the orientations first and then
recover the positions with :func:`~rlpgo_gtsam.translations.solve_translations`. The anchor
pose (the prior-marked one, else the first key) keeps the pose it has in ``values``.

New initializers plug in with :func:`register`::

    register("mine", MyInitializer)
    make_initializer("mine").initialize(graph, values)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError, SolverError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.linear import solve_pairwise
from rlpgo_gtsam.rotations import angle_residuals, chordal_edge_costs, wrap
from rlpgo_gtsam.translations import rotation_matrices, solve_translations

__all__ = [
    "Initializer",
    "OdometryInitializer",
    "LagoInitializer",
    "ChordalInitializer",
    "ShonanInitializer",
    "register",
    "make_initializer",
    "initializer_names",
    "poses_with_orientations",
]


class Initializer(Protocol):
    """Anything with ``initialize(graph, values) -> gtsam.Values``."""

    def initialize(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
    ) -> gtsam.Values: ...


def poses_with_orientations(pose_graph: PoseGraph2D, theta: np.ndarray) -> gtsam.Values:
    """Values with the given orientations (re-anchored) and positions from the translation step."""
    theta = wrap(theta - theta[pose_graph.anchor] + pose_graph.poses[pose_graph.anchor, 2])
    positions = solve_translations(pose_graph, theta)
    return pose_graph.to_values(np.column_stack([positions, theta]))


def _rotation_weights(pose_graph: PoseGraph2D) -> np.ndarray:
    return pose_graph.information[:, 2, 2]


class OdometryInitializer:
    """The values as given: a file's vertices, or its chained odometry if it had none."""

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        PoseGraph2D.from_gtsam(graph, values)  # same checks as every other initializer
        return gtsam.Values(values)


class LagoInitializer:
    """GTSAM's LAGO orientations, then the translation step with the full information.

    ``gtsam.lago`` rejects full Gaussian noise models ("invalid noise model"), so its
    orientation step runs on a copy of the graph with diagonal models (the diagonal of each
    edge's covariance); the translation step then uses each edge's full information.

    Args:
        odometric_path: LAGO's spanning tree follows the odometry edges ``(k, k+1)``
            (pose indices) when True, else a breadth-first tree.
    """

    def __init__(self, odometric_path: bool = True) -> None:
        self.odometric_path = odometric_path

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        g = PoseGraph2D.from_gtsam(graph, values)
        diagonal = gtsam.NonlinearFactorGraph()
        for (i, j), z, info in zip(g.edges, g.measured, g.information, strict=True):
            sigmas = np.sqrt(np.diag(np.linalg.inv(info)))
            diagonal.add(
                gtsam.BetweenFactorPose2(
                    int(i), int(j), gtsam.Pose2(*z), gtsam.noiseModel.Diagonal.Sigmas(sigmas)
                )
            )
        anchor_pose = gtsam.Pose2(*g.poses[g.anchor])
        diagonal.add(gtsam.PriorFactorPose2(g.anchor, anchor_pose, gtsam.noiseModel.Unit.Create(3)))
        try:
            orientations = gtsam.lago.initializeOrientations(diagonal, self.odometric_path)
        except RuntimeError as error:
            raise SolverError(f"LAGO orientation step failed: {error}") from None
        theta = np.array([orientations.at(k)[0] for k in range(g.num_poses)])
        return poses_with_orientations(g, theta)


class ChordalInitializer:
    """Chordal relaxation of the rotations, projected onto SO(2), then the translation step.

    Each rotation is a complex number z (a 2-vector); the relaxation minimizes
    ``sum_e w_e |z_j - z_i exp(i theta~_ij)|^2`` with ``w_e`` the edge's rotational
    information and the anchor's z fixed, one sparse linear solve in GTSAM. Each z is then
    projected onto the unit circle.
    """

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        g = PoseGraph2D.from_gtsam(graph, values)
        return poses_with_orientations(g, chordal_orientations(g))


def chordal_orientations(pose_graph: PoseGraph2D) -> np.ndarray:
    """Orientations (n,) from the chordal relaxation; the anchor keeps its angle."""
    g = pose_graph
    root_w = np.sqrt(_rotation_weights(g))[:, None, None]
    a_i = -root_w * rotation_matrices(g.measured[:, 2])
    a_j = root_w * np.broadcast_to(np.eye(2), a_i.shape)
    anchor_theta = g.poses[g.anchor, 2]
    z = solve_pairwise(
        g.num_poses, g.edges, a_i, a_j, np.zeros((g.num_edges, 2)), g.anchor,
        np.array([np.cos(anchor_theta), np.sin(anchor_theta)]),
    )
    return np.arctan2(z[:, 1], z[:, 0])


class ShonanInitializer:
    """GTSAM's Shonan rotation averaging (SO(2)), best of a few seeded random starts.

    The measurements are built from the graph's factors, each weighted by its rotational
    information (GTSAM's own g2o reader rejects correlated information). The start whose
    result has the lowest weighted rotation cost wins; then the translation step.

    Args:
        starts: number of random starts.
        seed: seed of the random starts.
        max_p: highest rank of the Riemannian staircase.
    """

    def __init__(self, starts: int = 2, seed: int = 0, max_p: int = 10) -> None:
        self.starts = starts
        self.seed = seed
        self.max_p = max_p

    def initialize(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        g = PoseGraph2D.from_gtsam(graph, values)
        factors = [
            gtsam.BetweenFactorPose2(
                int(i), int(j), gtsam.Pose2(*z),
                gtsam.noiseModel.Diagonal.Precisions(np.array([1.0, 1.0, w])),
            )
            for (i, j), z, w in zip(g.edges, g.measured, _rotation_weights(g), strict=True)
        ]
        shonan = gtsam.ShonanAveraging2(
            factors, gtsam.ShonanAveragingParameters2(gtsam.LevenbergMarquardtParams())
        )
        rng = np.random.default_rng(self.seed)
        best_theta, best_cost, failures = None, np.inf, []
        for _ in range(self.starts):
            start = gtsam.Values()
            for k, angle in enumerate(rng.uniform(-np.pi, np.pi, g.num_poses)):
                start.insert(k, gtsam.Rot2(float(angle)))
            try:
                result, _ = shonan.run(start, 2, self.max_p)
            except RuntimeError as error:
                failures.append(str(error).strip())
                continue
            theta = np.array([result.atRot2(k).theta() for k in range(g.num_poses)])
            residuals = angle_residuals(theta, g.edges, g.measured[:, 2])
            cost = float(_rotation_weights(g) @ chordal_edge_costs(residuals))
            if cost < best_cost:
                best_theta, best_cost = theta, cost
        if best_theta is None:
            raise SolverError(f"Shonan averaging failed from every start: {failures[0]}")
        return poses_with_orientations(g, best_theta)


_REGISTRY: dict[str, Callable[..., Initializer]] = {
    "odometry": OdometryInitializer,
    "lago": LagoInitializer,
    "chordal": ChordalInitializer,
    "shonan": ShonanInitializer,
}


def register(name: str, factory: Callable[..., Initializer]) -> None:
    """Make ``factory()`` available as initializer ``name`` (in the CLI's --methods too)."""
    _REGISTRY[name] = factory


def initializer_names() -> list[str]:
    """Names of the registered initializers."""
    return list(_REGISTRY)


def make_initializer(name: str, **options) -> Initializer:
    """A new initializer of a registered name; ``name@start`` passes ``start=...`` too.

    ``options`` go to the factory (``make_initializer("rl@chordal", episodes=10)``).
    """
    base, _, start = name.partition("@")
    if base not in _REGISTRY:
        raise RlpgoError(f"unknown method '{base}'; choose from {', '.join(_REGISTRY)}")
    if start:
        options["start"] = start
    try:
        return _REGISTRY[base](**options)
    except TypeError:
        raise RlpgoError(f"method '{base}' takes no options ({name})") from None
