"""Numpy arrays of a planar pose graph, extracted once from GTSAM's graph and values.

This is the one module that inspects GTSAM factor types. Everything downstream (rotation
maths, the environment, the initializers) works on a :class:`PoseGraph2D` and hands
results back as :class:`gtsam.Values`.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.g2o import disconnection

__all__ = ["PoseGraph2D", "chi2", "between_factors"]


@dataclass(frozen=True)
class PoseGraph2D:
    """The measurements of a planar pose graph as arrays; poses indexed 0..n-1.

    Attributes:
        keys: (n,) GTSAM keys of the poses, sorted; index ``k`` is pose ``keys[k]``.
        poses: (n, 3) x, y, theta of each pose in the values the graph came with.
        edges: (m, 2) pose indices (i, j) of each between factor, in graph order.
        measured: (m, 3) dx, dy, dtheta of each measurement (pose j in the frame of pose i).
        information: (m, 3, 3) information matrix of each measurement (x, y, theta order).
        anchor: index of the fixed pose: the one with a prior factor, else the first key.
    """

    keys: np.ndarray
    poses: np.ndarray
    edges: np.ndarray
    measured: np.ndarray
    information: np.ndarray
    anchor: int

    @property
    def num_poses(self) -> int:
        return len(self.keys)

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> PoseGraph2D:
        """Extract the arrays; the graph must be connected and made of Pose2 factors only.

        Raises:
            GraphError: a factor other than BetweenFactorPose2 / PriorFactorPose2, a key
                without a Pose2 value, or a graph that is not connected.
        """
        keys = np.array(sorted(values.keys()), dtype=np.uint64)
        index = {int(key): k for k, key in enumerate(keys)}
        try:
            poses = np.array([_pose_array(values.atPose2(int(key))) for key in keys])
        except RuntimeError as error:
            raise GraphError(f"values hold something other than Pose2: {error}") from None
        edges, measured, information, priors = [], [], [], []
        for factor in _factors(graph):
            if isinstance(factor, gtsam.BetweenFactorPose2):
                i, j = factor.keys()
                if i not in index or j not in index:
                    missing = i if i not in index else j
                    raise GraphError(f"a between factor refers to key {missing}, not in values")
                edges.append((index[i], index[j]))
                measured.append(_pose_array(factor.measured()))
                information.append(factor.noiseModel().information())
            elif isinstance(factor, gtsam.PriorFactorPose2):
                priors.append(index[factor.keys()[0]])
            else:
                raise GraphError(
                    f"unsupported factor {type(factor).__name__}: a planar pose graph holds "
                    "BetweenFactorPose2 (and PriorFactorPose2 anchors) only"
                )
        if not edges:
            raise GraphError("the graph has no BetweenFactorPose2 factors")
        result = cls(
            keys=keys,
            poses=poses.reshape(-1, 3),
            edges=np.array(edges, dtype=np.int64),
            measured=np.array(measured),
            information=np.array(information),
            anchor=priors[0] if priors else 0,
        )
        result.check_connected()
        return result

    def check_connected(self) -> None:
        """Raise :class:`GraphError` naming the components if the graph is not connected."""
        keys = [int(key) for key in self.keys]
        problem = disconnection(keys, [(keys[i], keys[j]) for i, j in self.edges.tolist()])
        if problem is not None:
            raise GraphError(problem)

    def to_values(self, poses: np.ndarray) -> gtsam.Values:
        """GTSAM values of the given (n, 3) poses under this graph's keys."""
        values = gtsam.Values()
        for key, (x, y, theta) in zip(self.keys, poses, strict=True):
            values.insert(int(key), gtsam.Pose2(float(x), float(y), float(theta)))
        return values


def _pose_array(pose: gtsam.Pose2) -> np.ndarray:
    return np.array([pose.x(), pose.y(), pose.theta()])


def _factors(graph: gtsam.NonlinearFactorGraph) -> list:
    return [graph.at(i) for i in range(graph.size()) if graph.at(i) is not None]


def between_factors(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The graph's BetweenFactorPose2 factors alone (anchor priors dropped)."""
    result = gtsam.NonlinearFactorGraph()
    for factor in _factors(graph):
        if isinstance(factor, gtsam.BetweenFactorPose2):
            result.add(factor)
    return result


def chi2(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """g2o's chi2: 2 x GTSAM error of the between factors, the anchor fixed (adds nothing)."""
    return 2.0 * between_factors(graph).error(values)
