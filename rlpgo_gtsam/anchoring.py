"""Held poses and priors inside the relaxation: the one-anchor pose graph that is the problem.

The relaxation fixes the gauge by one anchor pose. A graph that holds more than its gauge,
FIX lines (hard priors) on several poses, a FIX line and soft priors, or soft priors on
several poses, is another problem: its held poses cannot move, and its priors pull poses
towards values in the world frame. :func:`anchoring` rewrites such a graph exactly as a pose
graph with one anchor, as the SE-Sync family treats anchored poses:

- a new pose, the world frame, is the anchor, held at the identity; the held poses leave
  the graph, rigidly attached to the world frame at their held values ``T_k``;
- an edge from a held pose ``k`` to a free pose ``j`` measuring ``M`` becomes an edge from the
  world frame measuring ``T_k M``, with the same information: GTSAM's between residual
  ``Log(M^-1 T_k^-1 x_j)`` is unchanged;
- an edge from a free ``j`` to a held ``k`` is turned around first: the world frame measures
  ``T_k M^-1``, with information ``Ad(M)^-T Lambda Ad(M)^-1``: the turned residual is
  ``-Ad(M)`` times GTSAM's, so its squared Mahalanobis norm is GTSAM's exactly;
- a soft prior on a free pose measuring ``P`` is an edge from the world frame measuring
  ``P`` (GTSAM's prior residual ``Log(P^-1 x)`` is that edge's);
- edges between held poses, and priors on held poses, are constants: they leave the problem.

GTSAM's cost of the rewritten graph is the original's less those constants, so the
relaxation of the rewritten graph, and its certificate, cover every between factor, every
FIX line and every prior.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, TypeVar

import numpy as np

from rlpgo_gtsam.errors import SolverError
from rlpgo_gtsam.graph import PoseGraph
from rlpgo_gtsam.landmarks import Points, Ranges

__all__ = ["Anchoring", "anchoring"]

_Proof = TypeVar("_Proof", bound=Any)


@dataclass(frozen=True, eq=False)
class Anchoring:
    """A graph's one-anchor problem (:func:`anchoring`).

    Attributes:
        graph: the rewritten pose graph: pose 0 the world frame (its anchor, at the
            identity), then the free poses in the original order.
        free: (f,) the original indices of the rewritten poses 1..f.
        held: (h,) the original indices of the held (FIXed) poses.
        held_poses: (h, ...) their held poses, in the group's form.
        priors: how many soft priors (on poses and on landmarks) entered the problem as
            edges.
    """

    graph: PoseGraph
    free: np.ndarray
    held: np.ndarray
    held_poses: np.ndarray
    priors: int

    def lifted(self, poses: np.ndarray) -> np.ndarray:
        """The original graph's poses from the rewritten graph's (``poses[0]``, the world
        frame, is the identity): the held poses at their held values."""
        full = np.empty((len(self.free) + len(self.held), *poses.shape[1:]))
        full[self.free] = poses[1:]
        full[self.held] = self.held_poses
        return full

    def lifted_rotations(self, rotations: np.ndarray) -> np.ndarray:
        """The original graph's rotations from the rewritten graph's."""
        group = self.graph.group
        full = np.empty((len(self.free) + len(self.held), *rotations.shape[1:]))
        full[self.free] = rotations[1:]
        full[self.held] = group.rotations(self.held_poses)
        return full

    def covering(self, proof: _Proof) -> _Proof:
        """A certificate of the rewritten graph, saying which FIX lines and priors it held."""
        return replace(proof, fixed_poses=len(self.held), priors=self.priors)

    def reduced_rotations(self, rotations: np.ndarray) -> np.ndarray:
        """The rewritten graph's rotations from the original graph's (the world frame's: the
        identity)."""
        group = self.graph.group
        identity = group.rotations(group.identity(1))
        return np.concatenate([identity, np.asarray(rotations)[self.free]])


def anchoring(pose_graph: PoseGraph) -> Anchoring | None:
    """The one-anchor problem of a graph that holds more than its gauge (see the module
    docstring); None where the graph's own anchor is the whole story: at most one FIXed pose
    and no soft prior beside it, or no FIX line and at most one soft prior (which its anchor
    then satisfies exactly). Kept in the graph's cache."""
    g = pose_graph
    if "anchoring" in g.cache:
        return g.cache["anchoring"]
    fixed = np.unique(g.fixed)
    priors = len(g.priors)
    point_priors = 0 if g.points is None else len(g.points.priors)
    plain = point_priors == 0 and ((len(fixed) <= 1 and priors == 0)
                                   or (len(fixed) == 0 and priors <= 1))
    result = None if plain else _rewritten(g, fixed)
    g.cache["anchoring"] = result
    return result


def _rewritten(g: PoseGraph, fixed: np.ndarray) -> Anchoring:
    group = g.group
    if len(fixed):
        held, held_poses = g.held  # the anchor is the first FIXed pose: held is the FIX set
    else:
        held, held_poses = np.zeros(0, np.int64), group.identity(0)
    is_held = np.zeros(g.num_poses, bool)
    is_held[held] = True
    free = np.flatnonzero(~is_held)
    position = np.zeros(g.num_poses, np.int64)  # the rewritten index of each free pose
    position[free] = np.arange(1, len(free) + 1)
    held_at = np.zeros(g.num_poses, np.int64)  # the row of each held pose in held_poses
    held_at[held] = np.arange(len(held))
    i, j = g.edges[:, 0], g.edges[:, 1]
    measured, information = group.measured(g), g.information
    both_free = ~is_held[i] & ~is_held[j]
    from_held = is_held[i] & ~is_held[j]
    to_held = ~is_held[i] & is_held[j]
    turned = measured[to_held]
    adjoint_inverse = np.linalg.inv(group.adjoint(turned))
    edges = [np.column_stack([position[i[both_free]], position[j[both_free]]]),
             np.column_stack([np.zeros(from_held.sum(), np.int64), position[j[from_held]]]),
             np.column_stack([np.zeros(to_held.sum(), np.int64), position[i[to_held]]])]
    measurements = [measured[both_free],
                    group.compose(held_poses[held_at[i[from_held]]], measured[from_held]),
                    group.compose(held_poses[held_at[j[to_held]]], group.inverse(turned))]
    informations = [information[both_free], information[from_held],
                    np.swapaxes(adjoint_inverse, 1, 2) @ information[to_held] @ adjoint_inverse]
    on_free = ~is_held[g.priors]
    if g.prior_poses is not None and g.prior_information is not None:
        edges.append(np.column_stack([np.zeros(on_free.sum(), np.int64),
                                      position[g.priors[on_free]]]))
        measurements.append(g.prior_poses[on_free])
        informations.append(g.prior_information[on_free])
    keys = np.concatenate([[g.keys.max() + np.uint64(1)], g.keys[free]]).astype(np.uint64)
    poses = np.concatenate([group.identity(1), g.poses[free]])
    graph = group.anchored_graph(g, keys, poses, np.concatenate(edges).astype(np.int64),
                                 np.concatenate(measurements), np.concatenate(informations))
    if g.points is not None:
        graph = replace(graph, points=_anchored_points(g, g.points, is_held, position,
                                                       held_at, np.asarray(held_poses)))
    if g.ranges is not None:
        graph = replace(graph, ranges=_anchored_ranges(g, g.ranges, is_held, position))
    priors = int(on_free.sum()) + (0 if g.points is None else len(g.points.priors))
    return Anchoring(graph, free, held, np.asarray(held_poses), priors)


def _anchored_ranges(g: PoseGraph, ranges: Ranges, is_held: np.ndarray,
                     position: np.ndarray) -> Ranges:
    """The ranges of the one-anchor problem, between the rewritten nodes (free poses'
    new indices, the points after them).

    Raises:
        SolverError: a range from a held pose, which would couple its direction with the
            world frame's rotation in one term (outside the relaxation's form).
    """
    n = g.num_poses
    nodes = ranges.nodes
    on_pose = nodes < n
    if np.any(is_held[nodes[on_pose]]):
        raise SolverError("a range measured from a FIXed pose of a graph with several held "
                          "poses or priors is outside the relaxation")
    free = len(position) - int(is_held.sum()) + 1  # the rewritten poses, world frame first
    moved = np.where(on_pose, position[np.minimum(nodes, n - 1)], nodes - n + free)
    return replace(ranges, nodes=moved.astype(np.int64))


def _anchored_points(g: PoseGraph, points: Points, is_held: np.ndarray, position: np.ndarray,
                     held_at: np.ndarray, held_poses: np.ndarray) -> Points:
    """The landmarks of the one-anchor problem: a measurement from a free pose keeps its
    pose's new index; one from a held pose ``k`` is one from the world frame measuring
    ``t_k + R_k z`` with information ``R_k I R_k^T`` (its residual ``R_k^T (l - t_k) - z`` is
    ``R_k^T`` times the world frame's); a point prior is a measurement from the world frame."""
    group = g.group
    i = points.edges[:, 0]
    from_held = is_held[i]
    held = held_poses[held_at[i[from_held]]]
    rotations = group.rotation_matrices(group.rotations(held))
    measured = points.measured.copy()
    measured[from_held] = group.translations(held) + np.einsum("kab,kb->ka", rotations,
                                                               measured[from_held])
    information = points.information.copy()
    information[from_held] = rotations @ information[from_held] @ np.transpose(rotations,
                                                                               (0, 2, 1))
    pose = np.where(from_held, 0, position[i])
    d = points.dimension
    prior_values = np.zeros((0, d)) if points.prior_values is None else points.prior_values
    prior_information = (np.zeros((0, d, d)) if points.prior_information is None
                         else points.prior_information)
    return replace(
        points,
        edges=np.concatenate([np.column_stack([pose, points.edges[:, 1]]),
                              np.column_stack([np.zeros(len(points.priors), np.int64),
                                               points.priors])]).astype(np.int64),
        measured=np.concatenate([measured, prior_values]),
        information=np.concatenate([information, prior_information]),
        priors=np.zeros(0, np.int64), prior_values=None, prior_information=None)
