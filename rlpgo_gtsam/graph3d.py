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
rotation-translation coupling alone makes them indefinite: those as ``gtsam.readG2o``
reads them (GTSAM's Cholesky factor stops at the indefinite pivot), with the relaxation's
weights from the printed matrix (:func:`printed_informations`; docs/pose3.md).
:func:`extract_pose_graph` extracts a planar or a 3D graph, by what it holds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
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
    "printed_informations",
    "MAX_CONDITION_3D",
    "ROUNDING_3D",
    "LIFTED",
    "INDEFINITE",
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
# What the rule did with a matrix: its smallest eigenvalues raised, or, indefinite through
# the rotation-translation coupling alone, kept as printed (GTSAM's model of it is a partial
# Cholesky factor).
LIFTED = "lifted"
INDEFINITE = "indefinite"


@dataclass(frozen=True, eq=False)
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
        printed: the printed matrix (6, 6) of each information that GTSAM's model holds as
            a partial Cholesky factor of an indefinite printed matrix
            (:func:`printed_informations`), keyed by that information's bytes: the
            relaxation weighs such an edge by it (:attr:`weighed`). Keyed by content, so
            that a graph made from this one by ``dataclasses.replace`` with some of its edges
            (the robust path's subgraphs) keeps it.
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
    printed: dict[bytes, np.ndarray] = field(default_factory=dict, repr=False, compare=False)

    @cached_property
    def weighed(self) -> np.ndarray:
        """(m, 6, 6) the information the relaxation's weights come from: each edge's
        ``information``, or its printed matrix where it has one (``printed``)."""
        if not self.printed:
            return self.information
        return np.array([self.printed.get(matrix.tobytes(), matrix)
                         for matrix in self.information]).reshape(-1, 6, 6)

    @cached_property
    def held(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Indices, rotations (k, 3, 3) and translations (k, 3) of the poses the initializers
        keep: the anchor first, then every other hard-prior pose. Made once per graph, read
        only (the certified initializer read it three times: 0.07 ms of tinyGrid3D's run)."""
        mask = self.fixed != self.anchor
        held = (np.concatenate([[self.anchor], self.fixed[mask]]).astype(np.int64),
                np.concatenate([self.anchor_rotation[None], self.fixed_rotations[mask]]),
                np.vstack([self.anchor_translation[None], self.fixed_translations[mask]]))
        for array in held:
            array.setflags(write=False)
        return held

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, *,
                   check_information: bool = True) -> PoseGraph3D:
        """Extract the arrays; the graph must be connected and made of Pose3 factors only.

        Each edge's information must pass :func:`information_problem_6`, or be GTSAM's
        model of a printed matrix that :func:`information_rule_3d` keeps as printed
        (indefinite through the rotation-translation coupling alone): ``gtsam.readG2o``
        turns cubicle's 5021 such matrices into partial Cholesky factors (Eigen's stops at
        the indefinite pivot and GTSAM keeps it) whose information has a condition number
        near 1e16; chi2 is that model's, and the relaxation's weights come from the printed
        matrix it was made from (:func:`printed_informations`, kept in ``printed``), as
        SE-Sync reads the file. What
        :func:`~rlpgo_gtsam.g2o3d.read_g2o3d` makes always passes.
        ``check_information=False`` accepts any information a Gaussian model holds (finite,
        positive semidefinite).

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
                               lambda pose: pose, 6, "3D", False, MAX_CONDITION_3D)
        information = np.array(factors.information).reshape(-1, 6, 6)
        printed = _printed_of(graph, information, check_information)
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
            measured_translations=measured_t, information=information,
            anchor=anchor, fixed=np.array([k for k, _ in hard], dtype=np.int64),
            fixed_rotations=fixed_r, fixed_translations=fixed_t,
            anchor_rotation=np.asarray(anchor_r, float),
            anchor_translation=np.asarray(anchor_t, float), graph=graph,
            printed=printed,
        )
        result.check_connected()
        return result

    def to_values(self, rotations: np.ndarray, translations: np.ndarray) -> gtsam.Values:
        """GTSAM values of the given poses ((n, 3, 3), (n, 3)) under this graph's keys."""
        values = gtsam.Values()
        insert = values.insert  # pose3= passes over insert's other overloads (as in g2o3d)
        for key, r, t in zip(self.keys.tolist(), rotations, translations, strict=True):
            insert(key, pose3=gtsam.Pose3(gtsam.Rot3(r), np.asarray(t, float)))
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
    3x3 rotational block of the information (as SE-Sync's ``read_g2o_file``; of
    :attr:`PoseGraph3D.weighed`: the printed matrix where GTSAM's model is a partial
    factor of it)."""
    return 3.0 / (2.0 * np.trace(np.linalg.inv(pose_graph.weighed[:, :3, :3]),
                                 axis1=1, axis2=2))


def translation_weights(pose_graph: PoseGraph3D) -> np.ndarray:
    """SE-Sync's tau for d = 3: ``3 / tr(Sigma_t)``, ``Sigma_t`` the inverse of the 3x3
    translational block of the information (of :attr:`PoseGraph3D.weighed`)."""
    return 3.0 / np.trace(np.linalg.inv(pose_graph.weighed[:, 3:, 3:]), axis1=1, axis2=2)


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
    use, why each cannot be used (None: it can), and what was done with each (``()``, or
    :data:`INDEFINITE` or :data:`LIFTED`).

    1. A matrix :func:`information_problem_6` accepts is used as it is.
    2. Indefinite beyond rounding, with its rotation block and its translation block each
       usable (rule 1 at size 3): kept as printed (:data:`INDEFINITE`), as
       ``gtsam.readG2o`` keeps it. GTSAM's model of it
       (``noiseModel.Gaussian.Information``) is the upper Cholesky factor ``R`` that
       Eigen's LLT leaves where it stops, at the first non-positive pivot (a translation's:
       the rotation block is definite); chi2 is that model's, whose information ``R^T R``
       weighs the pivot's axis far above the printed value (cubicle: translation z by up
       to 3.9e12 where the file says 10). Where ``R^T R`` is beyond rule 1, the
       extraction reads the printed matrix back from ``R`` (:func:`printed_informations`)
       and the relaxation's weights come from its blocks, as SE-Sync reads every edge;
       where ``R^T R`` is usable, it is taken at its word, weights included. cubicle's
       5021 indefinite matrices are of this kind (4849 and 172).
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
    indefinite = []  # rule 2's candidates, judged in one batch
    for k in [k for k, problem in enumerate(problems) if problem is not None]:
        matrix = matrices[k]
        if not (np.all(np.isfinite(matrix)) and np.allclose(matrix, matrix.T, rtol=1e-9,
                                                             atol=0.0)):
            continue
        if _semidefinite_to_rounding(matrix):
            eigenvalues, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
            floor = eigenvalues[-1] / _LIFT_CONDITION
            lifted = (vectors * np.maximum(eigenvalues, floor)) @ vectors.T
            lifted = 0.5 * (lifted + lifted.T)
            if information_problem_6(lifted) is None:
                matrices[k], problems[k], changes[k] = lifted, None, (LIFTED,)
        else:
            indefinite.append(k)
    if indefinite:
        candidates = np.array(indefinite)
        candidates = candidates[_blocks_usable(matrices[candidates])]
        # GTSAM's model of each must be the partial factor the extraction reads back
        factors = np.array([gtsam.noiseModel.Gaussian.Information(matrices[k]).R()
                            for k in candidates.tolist()]).reshape(-1, 6, 6)
        for k in candidates[printed_informations(factors)[1]].tolist():
            problems[k], changes[k] = None, (INDEFINITE,)
    for k, problem in enumerate(problems):
        if problem == "information matrix is not positive definite":
            eigenvalues = np.linalg.eigvalsh(0.5 * (matrices[k] + matrices[k].T))
            problems[k] += f" (eigenvalues {eigenvalues[0]:.3g} .. {eigenvalues[-1]:.3g})"
    return matrices, problems, changes


def printed_informations(factors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The matrix each upper-triangular factor ``R`` (k, 6, 6) of a GTSAM Gaussian model
    was made from, where it is the partial Cholesky factor of an indefinite matrix that
    :func:`information_rule_3d` keeps as printed; and (k,) whether it is. Where it is not,
    the matrix is ``R^T R``.

    ``noiseModel.Gaussian.Information(M)`` keeps the upper factor of Eigen's LLT of ``M``
    even where the LLT stops at a non-positive pivot ``s``: rows before ``s`` are the
    Cholesky factor's, rows from ``s`` on hold ``M``'s upper triangle unchanged. So ``M``
    is ``R^T R`` but for its block from row and column ``s`` on, which is that printed
    triangle. ``R`` is taken as such a factor at the first ``s`` (3, 4 or 5: the rotation
    block of a matrix the rule keeps is definite) whose pivot ``M_ss - |R_{<s, s}|^2`` is
    not positive and whose ``M`` the rule keeps (indefinite beyond rounding, both blocks
    usable). A definite matrix's factor may also read so: a caller asks only about
    factors whose ``R^T R`` rule 1 refuses.
    """
    factors = np.asarray(factors, dtype=float).reshape(-1, 6, 6)
    products = np.einsum("kri,krj->kij", factors, factors)
    printed, found = products.copy(), np.zeros(len(factors), dtype=bool)
    for stop in (3, 4, 5):
        above = factors[:, :stop, stop]
        candidates = np.flatnonzero(~found & np.all(np.diagonal(factors, axis1=1, axis2=2)
                                                    [:, :stop] > 0, axis=1)
                                    & (factors[:, stop, stop] <= np.sum(above * above, axis=1)))
        if not len(candidates):
            continue
        matrices = products[candidates]
        tail = np.triu(factors[candidates, stop:, stop:])
        matrices[:, stop:, stop:] = tail + np.transpose(np.triu(tail, 1), (0, 2, 1))
        kept = _blocks_usable(matrices) & ~_semidefinite_many(matrices)
        printed[candidates[kept]] = matrices[kept]
        found[candidates[kept]] = True
    return printed, found


_ROTATION, _TRANSLATION = slice(0, 3), slice(3, 6)  # GTSAM's tangent order


def _blocks_usable(matrices: np.ndarray) -> np.ndarray:
    """(k,) whether the rotation block and the translation block of each (k, 6, 6) matrix
    are each usable by rule 1 (at size 3): the relaxation's weights need both."""
    blocks = np.concatenate([matrices[:, _ROTATION, _ROTATION],
                             matrices[:, _TRANSLATION, _TRANSLATION]])
    usable = np.array([p is None for p in information_problems(blocks, MAX_CONDITION_3D)])
    return usable[:len(matrices)] & usable[len(matrices):]


def _semidefinite_many(matrices: np.ndarray) -> np.ndarray:
    """(k,) :func:`_semidefinite_to_rounding` of each (k, 6, 6) symmetric matrix."""
    eigenvalues = np.linalg.eigvalsh(0.5 * (matrices + np.transpose(matrices, (0, 2, 1))))
    low, high = INFORMATION_RANGE
    return (low <= eigenvalues[:, -1]) & (eigenvalues[:, -1] <= high) & \
        (eigenvalues[:, 0] >= -ROUNDING_3D * eigenvalues[:, -1])


def _printed_of(graph: gtsam.NonlinearFactorGraph, information: np.ndarray,
                check: bool) -> dict[bytes, np.ndarray]:
    """The extraction's ``printed``: for each edge's information that rule 1 refuses and
    whose model is GTSAM's partial factor of a printed matrix (:func:`printed_informations`),
    that matrix, keyed by the information's bytes.

    Raises:
        GraphError: with ``check``, an edge whose information rule 1 refuses and whose
            model is no such factor (the first, as the planar extraction names it).
    """
    problems = information_problems(information, MAX_CONDITION_3D)
    refused = [k for k, problem in enumerate(problems) if problem is not None]
    if not refused:
        return {}
    factors = [factor for factor in map(graph.at, range(graph.size()))
               if isinstance(factor, gtsam.BetweenFactorPose3)]
    printed, found = printed_informations(
        np.array([factors[k].noiseModel().R() for k in refused]))
    if check and not found.all():
        first = refused[int(np.flatnonzero(~found)[0])]
        i, j = factors[first].keys()
        raise GraphError(f"between factor {i}-{j}: {problems[first]}")
    return {information[k].tobytes(): matrix
            for k, matrix in zip(np.array(refused)[found].tolist(), printed[found], strict=True)}


def _semidefinite_to_rounding(matrix: np.ndarray) -> bool:
    """Whether a symmetric matrix's eigenvalues lie in ``-ROUNDING_3D x largest ..
    INFORMATION_RANGE[1]``, with the largest at least ``INFORMATION_RANGE[0]``."""
    return bool(_semidefinite_many(matrix[None])[0])


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
