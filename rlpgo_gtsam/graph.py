"""Numpy arrays of a planar pose graph, extracted once from GTSAM's graph and values.

This is the one module that inspects GTSAM factor types. Everything downstream (rotation
maths, the rollout, the initializers) works on a :class:`PoseGraph2D` and hands results back
as :class:`gtsam.Values`.

What the arrays keep of GTSAM's meaning:

- every ``BetweenFactorPose2`` with a Gaussian noise model (unit, isotropic, diagonal or full)
  becomes an edge with its full 3x3 information;
- a ``PriorFactorPose2`` with a constrained noise model (a g2o ``FIX`` line) holds its pose:
  every initializer leaves that pose at the prior's value;
- a ``PriorFactorPose2`` with a Gaussian noise model is a soft prior: the initializers use it
  for the gauge only, while :func:`chi2` and :func:`~rlpgo_gtsam.solvers.refine` evaluate it
  as GTSAM does;
- anything else (robust noise models, other factor types, keys without a Pose2 value) is a
  :class:`~rlpgo_gtsam.errors.GraphError` that names it.
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.se2 import between, logmap

__all__ = [
    "PoseGraph2D",
    "chi2",
    "edge_chi2",
    "edge_errors",
    "rotation_weights",
    "odometry_edges",
    "information_problem",
    "information_problems",
    "INFORMATION_RANGE",
    "MAX_CONDITION",
    "disconnection",
    "component_labels",
    "format_ranges",
    "PoseArrays",
    "Factors",
    "sort_factors",
    "factor_information",
    "poses_of_values",
]


class PoseArrays:
    """What the planar and the 3D pose graph's arrays share: ``keys`` (n,) and ``edges``
    (m, 2), their counts, and the connectivity check."""

    keys: np.ndarray
    edges: np.ndarray

    @property
    def num_poses(self) -> int:
        return len(self.keys)

    @property
    def num_edges(self) -> int:
        return len(self.edges)

    def check_connected(self) -> None:
        """Raise :class:`GraphError` naming the components if the graph is not connected.

        The edges already index the poses: their components are labelled directly (City10K:
        0.6 ms, where converting keys and edges to lists for :func:`disconnection` took 15
        ms), and :func:`disconnection` words the message only for a graph in pieces.
        """
        labels = component_labels(self.num_poses, self.edges)
        if np.count_nonzero(labels == np.arange(len(labels))) > 1:
            raise GraphError(disconnection(self.keys, self.keys[self.edges]))


@dataclass(frozen=True, eq=False)
class PoseGraph2D(PoseArrays):
    """The measurements of a planar pose graph as arrays; poses indexed 0..n-1.

    Attributes:
        keys: (n,) GTSAM keys of the poses, sorted; index ``k`` is pose ``keys[k]``.
        poses: (n, 3) x, y, theta of each pose in the values the graph came with.
        edges: (m, 2) pose indices (i, j) of each between factor, in graph order.
        measured: (m, 3) dx, dy, dtheta of each measurement (pose j in the frame of pose i).
        information: (m, 3, 3) information matrix of each measurement (x, y, theta order).
        anchor: index of the pose that fixes the gauge: the first hard prior's pose, else the
            first soft prior's, else index 0.
        fixed: (k,) indices of the poses held by hard (constrained) priors.
        fixed_poses: (k, 3) the poses those priors hold.
        anchor_pose: (3,) where the initializers put the anchor: its prior's value if it has
            one, else its pose in ``values``.
        graph: the GTSAM graph the arrays came from (costs are evaluated on it).
        cache: what the numeric steps derive from these arrays alone and keep for the next
            call on the same graph (the chordal orientations, the translation step's
            system); the arrays are never changed in place, and a graph made from another
            (``dataclasses.replace``) starts with an empty one.
        dimension: 2 (the class's; :class:`~rlpgo_gtsam.graph3d.PoseGraph3D`'s is 3).
    """

    dimension: ClassVar[int] = 2
    keys: np.ndarray
    poses: np.ndarray
    edges: np.ndarray
    measured: np.ndarray
    information: np.ndarray
    anchor: int
    fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    fixed_poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    anchor_pose: np.ndarray | None = None
    graph: gtsam.NonlinearFactorGraph | None = field(default=None, repr=False, compare=False)
    cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def held(self) -> tuple[np.ndarray, np.ndarray]:
        """Indices and poses the initializers keep: the anchor and every hard-prior pose."""
        anchor_pose = self.poses[self.anchor] if self.anchor_pose is None else self.anchor_pose
        mask = self.fixed != self.anchor
        return (np.concatenate([[self.anchor], self.fixed[mask]]).astype(np.int64),
                np.vstack([anchor_pose[None], self.fixed_poses[mask]]))

    @classmethod
    def from_gtsam(cls, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> PoseGraph2D:
        """Extract the arrays; the graph must be connected and made of Pose2 factors only.

        Raises:
            GraphError: a factor other than BetweenFactorPose2 / PriorFactorPose2, a noise
                model that is not Gaussian (robust models), a key without a Pose2 value, or
                a graph that is not connected.
        """
        keys = np.array(sorted(values.keys()), dtype=np.uint64)
        index = {int(key): k for k, key in enumerate(keys)}
        try:
            poses = poses_of_values(values, keys.tolist())
        except RuntimeError as error:
            raise GraphError(f"values hold something other than Pose2: {error}") from None
        factors = sort_factors(graph, index, gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2,
                               _pose_array, 3, "planar")
        hard = factors.hard
        anchor, anchor_pose = factors.anchor
        result = cls(
            keys=keys,
            poses=poses.reshape(-1, 3),
            edges=np.array(factors.edges, dtype=np.int64),
            measured=np.array(factors.measured),
            information=np.array(factors.information),
            anchor=anchor,
            fixed=np.array([k for k, _ in hard], dtype=np.int64),
            fixed_poses=np.array([p for _, p in hard]).reshape(-1, 3),
            anchor_pose=poses[anchor] if anchor_pose is None else np.array(anchor_pose),
            graph=graph,
        )
        result.check_connected()
        return result

    def to_values(self, poses: np.ndarray) -> gtsam.Values:
        """GTSAM values of the given (n, 3) poses under this graph's keys."""
        values = gtsam.Values()
        insert, pose2 = pose2_inserter(values), gtsam.Pose2
        for key, x, y, theta in zip(self.keys.tolist(), *poses.T.tolist(), strict=True):
            insert(key, pose2(x, y, theta))
        return values

    def poses_of(self, values: gtsam.Values) -> np.ndarray:
        """(n, 3) x, y, theta of ``values`` in this graph's pose order."""
        return poses_of_values(values, self.keys.tolist())


def pose2_inserter(values: gtsam.Values) -> Callable[[int, gtsam.Pose2], None]:
    """``values.insert`` for a key and a Pose2, the faster way where this GTSAM allows it.

    ``Values.insert`` has some 46 overloads, which pybind11 tries in turn; naming the pose
    argument (``pose2`` in GTSAM's wrapper) passes over the others unconverted: 5.1 us a
    pose instead of 10.1 (5000 inserts, CPU time, GTSAM 4.3).
    """
    insert = values.insert
    return (lambda key, pose: insert(key, pose2=pose)) if _insert_names_pose2() else insert


@functools.cache
def _insert_names_pose2() -> bool:
    try:
        gtsam.Values().insert(0, pose2=gtsam.Pose2())
    except TypeError:  # a wrapper that names it otherwise
        return False
    return True


def rotation_weights(pose_graph: PoseGraph2D) -> np.ndarray:
    """The weight of each edge's rotation error, the one convention of every initializer.

    It is the conditional rotational information ``information[2, 2]``: the precision of
    the angle with the translation error held at zero (what the g2o/GTSAM cost charges for
    an angle error alone). SE-Sync's kappa is the same entry.
    """
    return pose_graph.information[:, 2, 2]


def odometry_edges(pose_graph: PoseGraph2D) -> np.ndarray:
    """(m,) bool: the odometry chain, found from the graph itself: every edge between poses
    adjacent in sorted-key order, completed to span the graph.

    The one definition of "odometry edge":

    1. every edge between poses adjacent in sorted-key order (index ``k`` and ``k + 1``:
       keys k, k + 1, or 0, 10, 20 with gaps), a second edge between the same two poses
       included (the generator's lawn mower closes a loop between the two poses of each
       turn): a robot's odometry;
    2. where those leave the graph in pieces, the other edges in graph (file) order, each
       kept when it joins two pieces not yet connected (Kruskal, union-find): the edge that
       first joins a new pose, as a front end writes them (shuffled ids, a star, a graph
       built in any order).

    On a graph whose keys run 0..n-1 along the robot's path this is the edges (k, k + 1).
    """
    g = pose_graph
    parent = list(range(g.num_poses))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    adjacent = np.abs(g.edges[:, 1] - g.edges[:, 0]) == 1
    order = np.concatenate([np.flatnonzero(adjacent), np.flatnonzero(~adjacent)])
    chain = np.zeros(g.num_edges, bool)
    for e, (i, j) in zip(order.tolist(), g.edges[order].tolist(), strict=True):
        a, b = root(i), root(j)
        if a != b or adjacent[e]:
            parent[a] = b
            chain[e] = True
    return chain


# The information matrices every method can use, measured on generated graphs whose edges
# all carry one information: eigenvalues from 1e-20 to 1e20 and a condition number up to 1e9
# were certified and refined; 1e-30 and 1e200 (overflow in the squares) failed, and so did a
# condition number of 1e10 (GTSAM's linear solves find the system indeterminate).
INFORMATION_RANGE = (1e-20, 1e20)
MAX_CONDITION = 1e9


def information_problem(information: np.ndarray, size: int = 3,
                        max_condition: float = MAX_CONDITION) -> str | None:
    """Why an edge's ``size`` x ``size`` information matrix (3 in 2D, 6 in 3D) cannot be
    used, or None if it can.

    It must be symmetric positive definite with eigenvalues in :data:`INFORMATION_RANGE`
    and a condition number at most ``max_condition`` (the planar rule's
    :data:`MAX_CONDITION`; 3D graphs have their own, :mod:`rlpgo_gtsam.graph3d`).
    """
    matrix = np.asarray(information, dtype=float)
    if matrix.shape != (size, size):
        return f"information matrix is not a finite {size}x{size} matrix"
    return information_problems(matrix[None], max_condition)[0]


def information_problems(matrices: np.ndarray,
                         max_condition: float = MAX_CONDITION) -> list[str | None]:
    """:func:`information_problem` for a stack of (k, s, s) matrices at once (one batched
    eigenvalue computation: extraction checks every edge)."""
    matrices = np.asarray(matrices, dtype=float)
    size = matrices.shape[-1]
    problems: list[str | None] = [None] * len(matrices)
    finite = np.all(np.isfinite(matrices), axis=(1, 2))
    transposed = np.transpose(matrices, (0, 2, 1))
    with np.errstate(all="ignore"):
        symmetric = np.all(np.abs(matrices - transposed) <= 1e-9 * np.abs(transposed),
                           axis=(1, 2))
        eigenvalues = np.zeros((len(matrices), size))
        usable = finite & symmetric
        eigenvalues[usable] = np.linalg.eigvalsh(matrices[usable])
        low, high = INFORMATION_RANGE
        bad = ~usable | ~(eigenvalues[:, 0] > 0) | (eigenvalues[:, 0] < low) | \
            (eigenvalues[:, -1] > high) | (eigenvalues[:, -1] > max_condition * eigenvalues[:, 0])
    for k in np.flatnonzero(bad).tolist():
        smallest, largest = eigenvalues[k, 0], eigenvalues[k, -1]
        if not finite[k]:
            problems[k] = f"information matrix is not a finite {size}x{size} matrix"
        elif not symmetric[k]:
            problems[k] = "information matrix is not symmetric"
        elif not smallest > 0:
            problems[k] = "information matrix is not positive definite"
        elif smallest < low or largest > high:
            problems[k] = (f"information matrix has eigenvalues {smallest:.3g} .. "
                           f"{largest:.3g}, outside the usable {low:g} .. {high:g}")
        else:
            problems[k] = (f"information matrix is too ill-conditioned (condition number "
                           f"{largest / smallest:.3g} > {max_condition:g}): an axis is all "
                           "but unmeasured")
    return problems


@dataclass(eq=False)
class Factors:
    """A graph's factors sorted by :func:`sort_factors`.

    Attributes:
        edges: (i, j) pose indices of each between factor, in graph order.
        measured: each between factor's measurement, as the caller's ``pose`` reads it.
        information: each between factor's information matrix.
        hard: (index, prior) of each prior with a constrained noise model (a FIX).
        soft: (index, prior) of each prior with a Gaussian noise model.
    """

    edges: list[tuple[int, int]] = field(default_factory=list)
    measured: list[Any] = field(default_factory=list)
    information: list[np.ndarray] = field(default_factory=list)
    hard: list[tuple[int, Any]] = field(default_factory=list)
    soft: list[tuple[int, Any]] = field(default_factory=list)

    @property
    def anchor(self) -> tuple[int, Any]:
        """(index, prior) of the pose that fixes the gauge: the first hard prior's, else the
        first soft prior's, else (0, None)."""
        return (self.hard or self.soft or [(0, None)])[0]


def sort_factors(graph: gtsam.NonlinearFactorGraph, index: dict[int, int], between: type,
                 prior: type, pose: Callable[[Any], Any], size: int, kind: str,
                 check_information: bool = True,
                 max_condition: float = MAX_CONDITION) -> Factors:
    """The factors of ``graph`` as edges, hard and soft priors, in graph order (the one walk
    of both pose graphs' extraction).

    ``index`` maps a key to its pose index; ``between`` and ``prior`` are the factor classes
    (``BetweenFactorPose2``, ``PriorFactorPose2`` or their Pose3 siblings); ``pose`` reads a
    measurement or a prior; ``size`` is the information's (3 or 6); ``check_information``
    as :func:`factor_information` for the edges (a soft prior's is always checked).

    Raises:
        GraphError: a factor of another class, a key without a value, a noise model the
            initializers cannot use (:func:`factor_information`), or no between factor.
    """
    fast = _sort_usable_factors(graph, index, between, prior, pose, size, check_information,
                                max_condition)
    if fast is not None:
        return fast
    factors = Factors()
    names: list[str] = []

    def refuse(message: str) -> GraphError:
        # the edges' information is checked in one batch; an edge before this factor whose
        # information is refused is still the error reported, as in a factor-by-factor walk
        _check_information(factors.information, names, size, check_information,
                           max_condition)
        return GraphError(message)

    for position in range(graph.size()):
        factor = graph.at(position)
        if factor is None:
            continue
        if isinstance(factor, between):
            i, j = factor.keys()
            for key in (i, j):
                if key not in index:
                    raise refuse(f"between factor {i}-{j}: key {key} has no value")
            name = f"between factor {i}-{j}"
            information = _gaussian_information(factor, name, refuse)
            factors.edges.append((index[i], index[j]))
            factors.measured.append(pose(factor.measured()))
            factors.information.append(information)
            names.append(name)
        elif isinstance(factor, prior):
            key = factor.keys()[0]
            if key not in index:
                raise refuse(f"prior factor on key {key}: the key has no value")
            entry = (index[key], pose(factor.prior()))
            if isinstance(factor.noiseModel(), gtsam.noiseModel.Constrained):
                factors.hard.append(entry)
            else:
                _check_information(factors.information, names, size, check_information,
                                   max_condition)
                factor_information(factor, f"prior factor on key {key}", size,
                                   max_condition=max_condition)
                factors.soft.append(entry)
        else:
            raise refuse(
                f"unsupported factor {type(factor).__name__}: a {kind} pose graph holds "
                f"{between.__name__} and {prior.__name__} factors only"
            )
    _check_information(factors.information, names, size, check_information, max_condition)
    if not factors.edges:
        raise GraphError(f"the graph has no {between.__name__} factors")
    return factors


def _sort_usable_factors(graph: gtsam.NonlinearFactorGraph, index: dict[int, int],
                         between: type, prior: type, pose: Callable[[Any], Any], size: int,
                         check_information: bool, max_condition: float) -> Factors | None:
    """:func:`sort_factors` of a graph it accepts, with each GTSAM accessor mapped over all
    factors at once and each shared noise model asked for its information once (City10K's
    20687 edges: 3 times faster than a factor at a time); None at anything the factor-by-factor
    walk must judge (a factor of another class or a subclass, a key without a value, a
    noise model or information it refuses, no between factor): that walk then raises the
    error it would have raised."""
    factors = list(map(graph.at, range(graph.size())))
    kinds = list(map(type, factors))
    if kinds.count(between) + kinds.count(prior) + kinds.count(type(None)) != len(kinds):
        return None
    edges = [factor for factor, kind in zip(factors, kinds, strict=True) if kind is between]
    if not edges:
        return None
    edge_keys = list(itertools.chain.from_iterable(map(between.keys, edges)))
    if len(edge_keys) != 2 * len(edges) or not all(map(index.__contains__, edge_keys)):
        return None
    models = list(map(between.noiseModel, edges))
    distinct = {id(model): model for model in models}  # held: each id stays its model's
    gaussian, constrained = gtsam.noiseModel.Gaussian, gtsam.noiseModel.Constrained
    if not all(isinstance(model, gaussian) and not isinstance(model, constrained)
               for model in distinct.values()):
        return None
    information = {key: model.information() for key, model in distinct.items()}
    stack = np.array([information[id(model)] for model in models]).reshape(-1, size, size)
    if check_information:
        if any(problem is not None for problem in information_problems(stack, max_condition)):
            return None
    elif not _semidefinite(stack).all():
        return None
    sorted_factors = Factors(information=list(stack))
    positions = list(map(index.__getitem__, edge_keys))
    sorted_factors.edges = list(zip(positions[0::2], positions[1::2], strict=True))
    sorted_factors.measured = list(map(pose, map(between.measured, edges)))
    for factor, kind in zip(factors, kinds, strict=True):
        if kind is not prior:
            continue
        key = factor.keys()[0]
        if key not in index:
            return None
        entry = (index[key], pose(factor.prior()))
        if isinstance(factor.noiseModel(), constrained):
            sorted_factors.hard.append(entry)
            continue
        try:
            factor_information(factor, f"prior factor on key {key}", size,
                               max_condition=max_condition)
        except GraphError:
            return None
        sorted_factors.soft.append(entry)
    return sorted_factors


def _check_information(informations: list[np.ndarray], names: list[str], size: int,
                       check: bool, max_condition: float = MAX_CONDITION) -> None:
    """Raise the error of the first of the edges' information matrices that
    :func:`factor_information` would refuse (all checked at once)."""
    if not informations:
        return
    stack = np.array(informations).reshape(-1, size, size)
    if check:
        problems = information_problems(stack, max_condition)
        first = next((k for k, problem in enumerate(problems) if problem is not None), None)
        if first is not None:
            raise GraphError(f"{names[first]}: {problems[first]}")
        return
    bad = np.flatnonzero(~_semidefinite(stack))
    if len(bad):
        raise GraphError(f"{names[bad[0]]}: information matrix is not finite and positive "
                         "semidefinite")


def _semidefinite(stack: np.ndarray) -> np.ndarray:
    """(k,) whether each matrix is finite and positive semidefinite (to round-off)."""
    finite = np.all(np.isfinite(stack), axis=(1, 2))
    result = finite.copy()
    if finite.any():
        smallest = np.linalg.eigvalsh(stack[finite])[:, 0]
        result[finite] = smallest >= -1e-12 * np.abs(stack[finite]).max(axis=(1, 2))
    return result


def _gaussian_information(factor, name: str, refuse: Callable[[str], Exception] = GraphError
                          ) -> np.ndarray:
    """The information of ``factor``'s noise model, which must be Gaussian and not
    constrained (``refuse(message)`` makes the error)."""
    model = factor.noiseModel()
    if not isinstance(model, gtsam.noiseModel.Gaussian):
        raise refuse(
            f"{name} has a {type(model).__name__} noise model; the initializers need Gaussian "
            "models (wrap the graph's robust models after initialization)"
        )
    if isinstance(model, gtsam.noiseModel.Constrained):
        raise refuse(f"{name} has a constrained noise model; only priors may be hard")
    return model.information()


def factor_information(factor, name: str, size: int = 3, check: bool = True,
                       max_condition: float = MAX_CONDITION) -> np.ndarray:
    """The information of ``factor``'s Gaussian, not constrained, noise model (``name`` in
    the errors): usable by :func:`information_problem` at ``size`` and ``max_condition``,
    or with ``check=False`` only finite and positive semidefinite.

    Raises:
        GraphError: a model that is not Gaussian (robust models), a constrained one, or
            information the rule refuses.
    """
    information = _gaussian_information(factor, name)
    _check_information([information], [name], size, check, max_condition)
    return information


def poses_of_values(values: gtsam.Values, keys: list[int]) -> np.ndarray:
    """(n, 3) x, y, theta of ``values`` at ``keys``, in that order: where ``keys`` are all
    of ``values``' keys in ascending order and every value a Pose2, GTSAM's own
    ``extractPose2`` in one call (the same numbers, 7 times faster than a call per pose)."""
    if len(keys) == values.size() and keys == sorted(keys):
        every = gtsam.utilities.extractPose2(values)
        if every.shape == (len(keys), 3):
            return np.ascontiguousarray(every)
    return np.array([_pose_array(values.atPose2(key)) for key in keys]).reshape(-1, 3)


def _pose_array(pose: gtsam.Pose2) -> tuple[float, float, float]:
    """x, y, theta of ``pose`` (a tuple: the callers make one array of many)."""
    return pose.x(), pose.y(), pose.theta()


def chi2(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
    """g2o's chi2: 2 x GTSAM error of the whole graph (every prior included).

    A hard (FIX) prior adds nothing while its pose is held; g2o fixes its first pose, so on a
    graph read from a g2o file this is g2o's own chi2.

    Raises:
        GraphError: a factor's key has no value.
    """
    try:
        return 2.0 * graph.error(values)
    except RuntimeError as error:
        raise GraphError(f"cannot evaluate the graph: {' '.join(str(error).split())}") from None


def edge_chi2(pose_graph: PoseGraph2D, poses: np.ndarray) -> np.ndarray:
    """(m,) each edge's chi2 at ``poses`` (n, 3), as GTSAM's BetweenFactorPose2 charges it:
    ``e^T Lambda e`` with ``e`` from :func:`edge_errors`."""
    error = edge_errors(pose_graph, poses)
    return np.einsum("ea,eab,eb->e", error, pose_graph.information, error)


def edge_errors(pose_graph: PoseGraph2D, poses: np.ndarray) -> np.ndarray:
    """(m, 3) each edge's error at ``poses`` (n, 3), GTSAM's BetweenFactorPose2's:
    ``e = Logmap(measured^-1 (X_i^-1 X_j))``."""
    g = pose_graph
    relative = between(poses[g.edges[:, 0]], poses[g.edges[:, 1]])
    return logmap(between(g.measured, relative))


def disconnection(keys: Iterable[int] | np.ndarray,
                  pairs: Iterable[tuple[int, int]] | np.ndarray) -> str | None:
    """None if ``pairs`` join all ``keys`` into one component, else a message naming them.

    Keys are GTSAM keys (below 2**64); arrays (keys, (m, 2) pairs) are taken as they are.
    """
    keys = np.sort(np.fromiter(keys, np.uint64) if not isinstance(keys, np.ndarray)
                   else keys.astype(np.uint64))
    keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))] if len(keys) else keys
    pairs = np.asarray(pairs if isinstance(pairs, np.ndarray) else list(pairs),
                       dtype=np.uint64).reshape(-1, 2)
    index = np.searchsorted(keys, pairs)
    if len(pairs) and (not len(keys)
                       or not (keys[np.minimum(index, len(keys) - 1)] == pairs).all()):
        raise KeyError("a pair names a key that is not in keys")
    labels = component_labels(len(keys), index)
    count = int(np.count_nonzero(labels == np.arange(len(keys))))
    if count <= 1:
        return None
    parts: dict[int, list[int]] = {}
    for key, label in zip(keys.tolist(), labels.tolist(), strict=True):
        parts.setdefault(label, []).append(key)
    ordered = sorted(parts.values(), key=lambda part: part[0])
    shown = " and ".join(f"keys {format_ranges(part)}" for part in ordered[:3])
    more = f" and {len(ordered) - 3} more" if len(ordered) > 3 else ""
    return (f"graph has {count} connected components ({shown}{more}); an initializer "
            "needs one")


def component_labels(count: int, pairs: np.ndarray) -> np.ndarray:
    """(count,) the connected component of each of ``count`` nodes that the (m, 2) index
    ``pairs`` join, as the smallest node index in it (a node is its component's label
    exactly when it is the smallest there).

    numpy only (SciPy's ``connected_components`` cost its 5 ms import to every read): each
    round hooks every component's label onto the smallest label an edge joins it to, then
    points every node straight at its label; on a pose graph's files (odometry in key
    order) one or two rounds.
    """
    labels = np.arange(count)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    first, second = pairs[:, 0], pairs[:, 1]
    while True:
        one, other = labels[first], labels[second]
        apart = one != other
        if not apart.any():
            return labels
        # labels only ever move down: no cycle, and a label is always its own label
        np.minimum.at(labels, np.maximum(one, other)[apart], np.minimum(one, other)[apart])
        while True:
            jumped = labels[labels]
            if np.array_equal(jumped, labels):
                break
            labels = jumped


def format_ranges(keys: list[int], limit: int = 4) -> str:
    """``[0, 1, 2, 5, 7, 8]`` -> ``'0-2, 5, 7-8'`` (at most ``limit`` runs, then '...')."""
    runs: list[list[int]] = []
    for key in keys:
        if runs and key == runs[-1][1] + 1:
            runs[-1][1] = key
        else:
            runs.append([key, key])
    text = [f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:limit]]
    return ", ".join(text) + (", ..." if len(runs) > limit else "")
