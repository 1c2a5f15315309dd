"""Numpy arrays of a 3D pose graph, extracted once from GTSAM's graph and values.

The Pose3 sibling of :mod:`rlpgo_gtsam.graph`, with the same meaning kept:

- every ``BetweenFactorPose3`` with a Gaussian noise model becomes an edge with its full 6x6
  information in GTSAM's tangent order (rotation first, then translation);
- a ``PriorFactorPose3`` with a constrained noise model (a g2o ``FIX`` line) holds its pose;
- a ``PriorFactorPose3`` with a Gaussian noise model is a soft prior: it sets the gauge only
  (GTSAM's cost, :func:`~rlpgo_gtsam.graph.chi2`, still evaluates it);
- anything else is a :class:`~rlpgo_gtsam.errors.GraphError` that names it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.graph import PoseArrays, information_problem, sort_factors
from rlpgo_gtsam.se3 import between, logmap

__all__ = [
    "PoseGraph3D",
    "edge_chi2",
    "edge_errors",
    "rotation_weights",
    "translation_weights",
    "information_problem_6",
]


@dataclass(frozen=True)
class PoseGraph3D(PoseArrays):
    """The measurements of a 3D pose graph as arrays; poses indexed 0..n-1.

    Attributes:
        keys: (n,) GTSAM keys of the poses, sorted; index ``k`` is pose ``keys[k]``.
        rotations: (n, 3, 3) rotation of each pose in the values the graph came with.
        translations: (n, 3) position of each pose in those values.
        edges: (m, 2) pose indices (i, j) of each between factor, in graph order.
        measured_rotations: (m, 3, 3) rotation of pose j in the frame of pose i, measured.
        measured_translations: (m, 3) position of pose j in the frame of pose i, measured.
        information: (m, 6, 6) information of each measurement, GTSAM's order (rotation
            first).
        anchor: index of the pose that fixes the gauge: the first hard prior's pose, else the
            first soft prior's, else index 0.
        fixed: (k,) indices of the poses held by hard (constrained) priors.
        fixed_rotations, fixed_translations: (k, 3, 3) and (k, 3), the poses they hold.
        anchor_rotation, anchor_translation: where the initializers put the anchor: its
            prior's value if it has one, else its pose in ``values``.
        graph: the GTSAM graph the arrays came from (costs are evaluated on it).
    """

    keys: np.ndarray
    rotations: np.ndarray
    translations: np.ndarray
    edges: np.ndarray
    measured_rotations: np.ndarray
    measured_translations: np.ndarray
    information: np.ndarray
    anchor: int
    fixed: np.ndarray
    fixed_rotations: np.ndarray
    fixed_translations: np.ndarray
    anchor_rotation: np.ndarray
    anchor_translation: np.ndarray
    graph: gtsam.NonlinearFactorGraph | None = field(default=None, repr=False, compare=False)

    @property
    def held(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Indices, rotations (k, 3, 3) and translations (k, 3) of the poses the initializers
        keep: the anchor first, then every other hard-prior pose."""
        mask = self.fixed != self.anchor
        return (np.concatenate([[self.anchor], self.fixed[mask]]).astype(np.int64),
                np.concatenate([self.anchor_rotation[None], self.fixed_rotations[mask]]),
                np.vstack([self.anchor_translation[None], self.fixed_translations[mask]]))

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, *,
                   check_information: bool = True) -> PoseGraph3D:
        """Extract the arrays; the graph must be connected and made of Pose3 factors only.

        ``check_information=False`` accepts any information a Gaussian model holds (finite,
        positive semidefinite), unusable by :func:`information_problem_6`'s rule or not:
        ``gtsam.readG2o`` turns cubicle's 5020 indefinite informations into matrices with a
        condition number near 1e16, and SE-Sync's published figures are on that graph.

        Raises:
            GraphError: a factor other than BetweenFactorPose3 / PriorFactorPose3, a noise
                model that is not Gaussian, an unusable information matrix, a key without a
                Pose3 value, or a graph that is not connected.
        """
        keys = np.array(sorted(values.keys()), dtype=np.uint64)
        index = {int(key): k for k, key in enumerate(keys)}
        try:
            rotations, translations = _poses(values, keys.tolist())
        except RuntimeError as error:
            raise GraphError(f"values hold something other than Pose3: "
                             f"{' '.join(str(error).split())}") from None
        factors = sort_factors(graph, index, gtsam.BetweenFactorPose3, gtsam.PriorFactorPose3,
                               lambda pose: pose, 6, "3D", check_information)
        hard = factors.hard
        anchor, anchor_prior = factors.anchor
        fixed_r, fixed_t = _pose_arrays([pose for _, pose in hard])
        measured_r, measured_t = _pose_arrays(factors.measured)
        if anchor_prior is None:
            anchor_r, anchor_t = rotations[anchor], translations[anchor]
        else:
            anchor_r, anchor_t = anchor_prior.rotation().matrix(), anchor_prior.translation()
        result = cls(
            keys=keys, rotations=rotations, translations=translations,
            edges=np.array(factors.edges, dtype=np.int64), measured_rotations=measured_r,
            measured_translations=measured_t, information=np.array(factors.information),
            anchor=anchor, fixed=np.array([k for k, _ in hard], dtype=np.int64),
            fixed_rotations=fixed_r, fixed_translations=fixed_t,
            anchor_rotation=np.asarray(anchor_r, float),
            anchor_translation=np.asarray(anchor_t, float), graph=graph,
        )
        result.check_connected()
        return result

    def to_values(self, rotations: np.ndarray, translations: np.ndarray) -> gtsam.Values:
        """GTSAM values of the given poses ((n, 3, 3), (n, 3)) under this graph's keys."""
        values = gtsam.Values()
        for key, r, t in zip(self.keys.tolist(), rotations, translations, strict=True):
            values.insert(key, gtsam.Pose3(gtsam.Rot3(r), np.asarray(t, float)))
        return values

    def poses_of(self, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (n, 3, 3) and translations (n, 3) of ``values`` in this graph's order."""
        return _poses(values, self.keys.tolist())


def edge_chi2(pose_graph: PoseGraph3D, rotations: np.ndarray,
              translations: np.ndarray) -> np.ndarray:
    """(m,) each edge's chi2 at the given poses, as GTSAM's BetweenFactorPose3 charges it:
    ``e^T Lambda e`` with ``e`` from :func:`edge_errors`."""
    error = edge_errors(pose_graph, rotations, translations)
    return np.einsum("ea,eab,eb->e", error, pose_graph.information, error)


def edge_errors(pose_graph: PoseGraph3D, rotations: np.ndarray,
                translations: np.ndarray) -> np.ndarray:
    """(m, 6) each edge's error at the given poses, GTSAM's BetweenFactorPose3's:
    ``e = Logmap(measured^-1 X_i^-1 X_j)`` (rotation first)."""
    g = pose_graph
    i, j = g.edges[:, 0], g.edges[:, 1]
    r_rel, t_rel = between(rotations[i], translations[i], rotations[j], translations[j])
    r_err, t_err = between(g.measured_rotations, g.measured_translations, r_rel, t_rel)
    return logmap(r_err, t_err)


def rotation_weights(pose_graph: PoseGraph3D) -> np.ndarray:
    """SE-Sync's kappa for d = 3: ``3 / (2 tr(Sigma_R))``, ``Sigma_R`` the inverse of the
    3x3 rotational block of the information (as SE-Sync's ``read_g2o_file``)."""
    return 3.0 / (2.0 * np.trace(np.linalg.inv(pose_graph.information[:, :3, :3]),
                                 axis1=1, axis2=2))


def translation_weights(pose_graph: PoseGraph3D) -> np.ndarray:
    """SE-Sync's tau for d = 3: ``3 / tr(Sigma_t)``, ``Sigma_t`` the inverse of the 3x3
    translational block of the information."""
    return 3.0 / np.trace(np.linalg.inv(pose_graph.information[:, 3:, 3:]), axis1=1, axis2=2)


def information_problem_6(information: np.ndarray) -> str | None:
    """Why a 6x6 information matrix cannot be used, or None if it can: the planar rule
    (:func:`rlpgo_gtsam.graph.information_problem`) at size 6."""
    return information_problem(information, 6)


def _pose_arrays(poses: list[gtsam.Pose3]) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([p.rotation().matrix() for p in poses]).reshape(-1, 3, 3),
            np.array([p.translation() for p in poses]).reshape(-1, 3))


def _poses(values: gtsam.Values, keys: list[int]) -> tuple[np.ndarray, np.ndarray]:
    return _pose_arrays([values.atPose3(key) for key in keys])
