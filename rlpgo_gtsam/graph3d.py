"""Numpy arrays of a 3D pose graph, extracted once from GTSAM's graph and values.

The Pose3 sibling of :mod:`rlpgo_gtsam.graph`, with the same meaning kept:

- every ``BetweenFactorPose3`` with a Gaussian noise model becomes an edge with its full 6x6
  information in GTSAM's tangent order (rotation first, then translation);
- a ``PriorFactorPose3`` with a constrained noise model (a g2o ``FIX`` line) holds its pose;
- a ``PriorFactorPose3`` with a Gaussian noise model is a soft prior: it sets the gauge only
  (GTSAM's cost, :func:`~rlpgo_gtsam.graph.chi2`, still evaluates it);
- anything else is a :class:`~rlpgo_gtsam.errors.GraphError` that names it.

Its information rule is the planar one with a higher condition bound,
:data:`MAX_CONDITION_3D`; the 3D reader applies :func:`information_rule_3d`, which also
reads matrices that are positive definite only to rounding, and SE-Sync's files whose
rotation-translation coupling alone makes them indefinite (docs/pose3.md).
:func:`extract_pose_graph` extracts a planar or a 3D graph, by what it holds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.graph import (
    INFORMATION_RANGE,
    PoseArrays,
    PoseGraph2D,
    information_problem,
    information_problems,
    sort_factors,
)
from rlpgo_gtsam.se3 import between, logmap

__all__ = [
    "PoseGraph3D",
    "AnyPoseGraph",
    "extract_pose_graph",
    "graph_dimension",
    "edge_chi2",
    "edge_errors",
    "rotation_weights",
    "translation_weights",
    "information_problem_6",
    "information_rule_3d",
    "MAX_CONDITION_3D",
    "ROUNDING_3D",
    "LIFTED",
    "UNCOUPLED",
]

# The 3D information rule (docs/pose3.md has the measurements behind it).
# A condition number up to 1e12 is used as given: the planar 1e9 would refuse SE-Sync's
# parking-garage (3 edges above it, the worst 2.67e9: a rotation axis all but unmeasured).
# On smallGrid3D with every edge's information given one weak axis (a rotation or a
# translation) of condition 1e9 .. 1e16, GTSAM LM30 reached the same chi2 at each; 1e12 keeps
# 4 of double's 16 digits for the Cholesky factor GTSAM whitens with.
MAX_CONDITION_3D = 1e12
# Eigenvalues down to -1e-5 x the largest are rounding: printing a matrix's entries with 6
# significant digits (g2o's and SE-Sync's %g) moves its eigenvalues by up to 3e-5 x the
# largest (6 x 5e-6), so an unmeasured axis may print slightly negative.
ROUNDING_3D = 1e-5
# Eigenvalues below the largest / 1e11 are raised to it when a matrix is lifted.
_LIFT_CONDITION = MAX_CONDITION_3D / 10.0
# What the rule changed in a matrix: its smallest eigenvalues raised, or its
# rotation-translation coupling dropped.
LIFTED = "lifted"
UNCOUPLED = "uncoupled"


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
        dimension: 3 (the class's).
    """

    dimension: ClassVar[int] = 3
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

        Each edge's information must pass :func:`information_problem_6` (what
        :func:`~rlpgo_gtsam.g2o3d.read_g2o3d` makes always does). ``check_information=False``
        accepts any information a Gaussian model holds (finite, positive semidefinite):
        ``gtsam.readG2o`` turns cubicle's 5021 indefinite informations into matrices with a
        condition number near 1e16 (Eigen's Cholesky stops at the first negative pivot and
        GTSAM keeps the partial factor), and the benchmark compares with SE-Sync on that
        graph.

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
                               lambda pose: pose, 6, "3D", check_information,
                               MAX_CONDITION_3D)
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
    """Why a 6x6 information matrix cannot be used as it is, or None if it can: the planar
    rule (:func:`rlpgo_gtsam.graph.information_problem`) at size 6, with a condition number
    up to :data:`MAX_CONDITION_3D`."""
    return information_problem(information, 6, MAX_CONDITION_3D)


def information_problems_6(matrices: np.ndarray) -> list[str | None]:
    """:func:`information_problem_6` for a stack of (k, 6, 6) matrices at once."""
    return information_problems(matrices, MAX_CONDITION_3D)


def information_rule_3d(matrices: np.ndarray) -> tuple[np.ndarray, list[str | None],
                                                          list[tuple[str, ...]]]:
    """The 3D reader's information rule on a stack of (k, 6, 6) matrices: the matrices to
    use, why each cannot be used (None: it can), and what was changed in each (``()``,
    or :data:`UNCOUPLED` and/or :data:`LIFTED`).

    1. A matrix :func:`information_problem_6` accepts is used as it is.
    2. Indefinite, with its rotation block and its translation block each positive
       definite (to :data:`ROUNDING_3D`): its rotation-translation coupling is dropped
       (:data:`UNCOUPLED`). SE-Sync reads every edge this way (its weights come from
       these two blocks alone); cubicle's 5021 indefinite matrices are of this kind.
    3. Finite and symmetric, largest eigenvalue in range, smallest at least
       ``-ROUNDING_3D`` x the largest, but with a condition number above
       :data:`MAX_CONDITION_3D` or a slightly negative eigenvalue: positive definite to
       rounding. Eigenvalues below the largest / 1e11 are raised to it (:data:`LIFTED`),
       a change of at most 1e-5 of the matrix's norm.
    4. Anything else (not finite, not symmetric, indefinite beyond rounding in a block,
       eigenvalues out of :data:`~rlpgo_gtsam.graph.INFORMATION_RANGE`) is refused.
    """
    matrices = np.array(matrices, dtype=float).reshape(-1, 6, 6)
    problems = information_problems(matrices, MAX_CONDITION_3D)
    changes: list[tuple[str, ...]] = [()] * len(matrices)
    for k in [k for k, problem in enumerate(problems) if problem is not None]:
        matrix, changed = matrices[k].copy(), []
        if not (np.all(np.isfinite(matrix)) and np.allclose(matrix, matrix.T, rtol=1e-9,
                                                             atol=0.0)):
            continue
        if not _semidefinite_to_rounding(matrix) and all(
                _semidefinite_to_rounding(matrix[b, b]) for b in (_ROTATION, _TRANSLATION)):
            matrix[_ROTATION, _TRANSLATION] = 0.0
            matrix[_TRANSLATION, _ROTATION] = 0.0
            changed.append(UNCOUPLED)
        if _semidefinite_to_rounding(matrix) and information_problem_6(matrix) is not None:
            eigenvalues, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
            floor = eigenvalues[-1] / _LIFT_CONDITION
            matrix = (vectors * np.maximum(eigenvalues, floor)) @ vectors.T
            matrix = 0.5 * (matrix + matrix.T)
            changed.append(LIFTED)
        if changed and information_problem_6(matrix) is None:
            matrices[k], problems[k], changes[k] = matrix, None, tuple(changed)
        elif problems[k] == "information matrix is not positive definite":
            eigenvalues = np.linalg.eigvalsh(0.5 * (matrices[k] + matrices[k].T))
            problems[k] += f" (eigenvalues {eigenvalues[0]:.3g} .. {eigenvalues[-1]:.3g})"
    return matrices, problems, changes


_ROTATION, _TRANSLATION = slice(0, 3), slice(3, 6)  # GTSAM's tangent order


def _semidefinite_to_rounding(matrix: np.ndarray) -> bool:
    """Whether a symmetric matrix's eigenvalues lie in ``-ROUNDING_3D x largest ..
    INFORMATION_RANGE[1]``, with the largest at least ``INFORMATION_RANGE[0]``."""
    eigenvalues = np.linalg.eigvalsh(0.5 * (matrix + matrix.T))
    low, high = INFORMATION_RANGE
    return bool(low <= eigenvalues[-1] <= high and
                eigenvalues[0] >= -ROUNDING_3D * eigenvalues[-1])


AnyPoseGraph = PoseGraph2D | PoseGraph3D


def graph_dimension(graph: gtsam.NonlinearFactorGraph) -> int:
    """3 if the first pose factor of ``graph`` is a Pose3 one (between or prior), else 2
    (a graph of neither kind: the planar extraction names what it holds)."""
    for position in range(graph.size()):
        factor = graph.at(position)
        if isinstance(factor, gtsam.BetweenFactorPose3 | gtsam.PriorFactorPose3):
            return 3
        if isinstance(factor, gtsam.BetweenFactorPose2 | gtsam.PriorFactorPose2):
            return 2
    return 2


def extract_pose_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
                       ) -> PoseGraph2D | PoseGraph3D:
    """The one extraction of a planar or a 3D pose graph, by what it holds
    (:func:`graph_dimension`): :class:`~rlpgo_gtsam.graph.PoseGraph2D` or
    :class:`PoseGraph3D`. A graph mixing both is the chosen one's ``GraphError``."""
    if graph_dimension(graph) == 3:
        return PoseGraph3D.from_gtsam(graph, values)
    return PoseGraph2D.from_gtsam(graph, values)


def _pose_arrays(poses: list[gtsam.Pose3]) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([p.rotation().matrix() for p in poses]).reshape(-1, 3, 3),
            np.array([p.translation() for p in poses]).reshape(-1, 3))


def _poses(values: gtsam.Values, keys: list[int]) -> tuple[np.ndarray, np.ndarray]:
    return _pose_arrays([values.atPose3(key) for key in keys])
