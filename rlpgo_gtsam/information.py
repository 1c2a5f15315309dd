"""The information rules of both pose groups, and the one walk that sorts a graph's factors.

An edge's information matrix is used as it is when it is symmetric positive definite with
eigenvalues in :data:`INFORMATION_RANGE` and a condition number at most its group's
``max_condition`` (:data:`MAX_CONDITION` planar, :data:`MAX_CONDITION_3D` 3D). The 3D reader
applies :func:`information_rule_3d`, which also reads matrices that are positive definite
only to rounding, and SE-Sync's files whose rotation-translation coupling alone makes them
indefinite: those as ``gtsam.readG2o`` reads them (GTSAM's Cholesky factor stops at the
indefinite pivot), with the relaxation's weights from the printed matrix
(:func:`printed_informations`; docs/3d.md). :func:`sort_factors` turns a GTSAM graph into
edges, hard and soft priors, for :mod:`rlpgo_gtsam.graph`'s extraction.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.groups import SE2, SE3, key_text

if TYPE_CHECKING:
    from rlpgo_gtsam.groups import Group

__all__ = [
    "INFORMATION_RANGE",
    "MAX_CONDITION",
    "MAX_CONDITION_3D",
    "ROUNDING_3D",
    "LIFTED",
    "INDEFINITE",
    "information_problem",
    "information_problems",
    "information_problem_6",
    "information_problems_6",
    "information_rule_3d",
    "printed_informations",
    "printed_of",
    "Factors",
    "sort_factors",
    "factor_information",
    "with_informations",
    "scaled_informations",
]

# The information matrices every method can use, measured on generated graphs whose edges
# all carry one information: eigenvalues from 1e-20 to 1e20 were certified and refined;
# 1e-30 and 1e200 (overflow in the squares) failed. The condition bounds are the groups'.
INFORMATION_RANGE = (1e-20, 1e20)
MAX_CONDITION = SE2.max_condition
MAX_CONDITION_3D = SE3.max_condition


def information_problem(information: np.ndarray, size: int = 3,
                        max_condition: float = MAX_CONDITION) -> str | None:
    """Why an edge's ``size`` x ``size`` information matrix (3 in 2D, 6 in 3D) cannot be
    used, or None if it can.

    It must be symmetric positive definite with eigenvalues in :data:`INFORMATION_RANGE`
    and a condition number at most ``max_condition`` (the planar rule's
    :data:`MAX_CONDITION`; 3D graphs have their own, :data:`MAX_CONDITION_3D`).
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


# The 3D information rule (docs/3d.md says what the seven 3D files hold).
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


@dataclass(eq=False)
class Factors:
    """A graph's factors sorted by :func:`sort_factors`.

    Attributes:
        edges: (i, j) pose indices of each between factor, in graph order.
        measured: each between factor's measurement, as the caller's ``pose`` reads it.
        information: each between factor's information matrix.
        hard: (index, prior) of each prior with a constrained noise model (a FIX).
        soft: (index, prior) of each prior with a Gaussian noise model.
        soft_information: each soft prior's information matrix, in ``soft``'s order.
    """

    edges: list[tuple[int, int]] = field(default_factory=list)
    measured: list[Any] = field(default_factory=list)
    information: list[np.ndarray] = field(default_factory=list)
    hard: list[tuple[int, Any]] = field(default_factory=list)
    soft: list[tuple[int, Any]] = field(default_factory=list)
    soft_information: list[np.ndarray] = field(default_factory=list)

    @property
    def anchor(self) -> tuple[int, Any]:
        """(index, prior) of the pose that fixes the gauge: the first hard prior's, else the
        first soft prior's, else (0, None)."""
        return (self.hard or self.soft or [(0, None)])[0]


def sort_factors(graph: gtsam.NonlinearFactorGraph, index: dict[int, int], group: Group,
                 pose: Callable[[Any], Any], check_information: bool = True) -> Factors:
    """The factors of ``graph`` as edges, hard and soft priors, in graph order (the one walk
    of every pose graph's extraction).

    ``index`` maps a key to its pose index; ``group`` names the factor classes, the
    information's size and condition bound; ``pose`` reads a measurement or a prior;
    ``check_information`` as :func:`factor_information` for the edges (a soft prior's is
    always checked).

    Raises:
        GraphError: a factor of another class, a key without a value, a noise model the
            initializers cannot use (:func:`factor_information`), or no between factor.
    """
    between: Any = group.between_factor
    prior: Any = group.prior_factor
    size, max_condition = group.dof, group.max_condition
    fast = _sort_usable_factors(graph, index, between, prior, pose, size, check_information,
                                max_condition)
    if fast is not None:
        return fast
    factors = Factors()
    names: list[str | tuple[int, int]] = []  # each edge's keys, worded only for an error

    def refuse(message: str) -> GraphError:
        # the edges' information is checked in one batch; an edge before this factor whose
        # information is refused is still the error reported, as in a factor-by-factor walk
        _check_information(factors.information, names, size, check_information,
                           max_condition)
        return GraphError(message)

    for position in range(graph.size()):
        factor: Any = graph.at(position)  # GTSAM's stubs type it as the base class
        if factor is None:
            continue
        if isinstance(factor, between):
            i, j = factor.keys()
            for key in (i, j):
                if key not in index:
                    raise refuse(f"{_between(i, j)}: key {key_text(key)} has no value")
            name = (i, j)
            information = _gaussian_information(factor, name, refuse)
            factors.edges.append((index[i], index[j]))
            factors.measured.append(pose(factor.measured()))
            factors.information.append(information)
            names.append(name)
        elif isinstance(factor, prior):
            key = factor.keys()[0]
            if key not in index:
                raise refuse(f"prior factor on key {key_text(key)}: the key has no value")
            entry = (index[key], pose(factor.prior()))
            if isinstance(factor.noiseModel(), gtsam.noiseModel.Constrained):
                factors.hard.append(entry)
            else:
                _check_information(factors.information, names, size, check_information,
                                   max_condition)
                factors.soft_information.append(
                    factor_information(factor, f"prior factor on key {key_text(key)}", size,
                                       max_condition=max_condition))
                factors.soft.append(entry)
        else:
            raise refuse(
                f"unsupported factor {type(factor).__name__}: a {group.kind} pose graph holds "
                f"{between.__name__} and {prior.__name__} factors only"
            )
    _check_information(factors.information, names, size, check_information, max_condition)
    if not factors.edges:
        raise GraphError(f"the graph has no {between.__name__} factors")
    return factors


def _sort_usable_factors(graph: gtsam.NonlinearFactorGraph, index: dict[int, int],
                         between: Any, prior: Any, pose: Callable[[Any], Any], size: int,
                         check_information: bool, max_condition: float) -> Factors | None:
    """:func:`sort_factors` of a graph it accepts, with each GTSAM accessor mapped over all
    factors at once and each shared noise model asked for its information once (City10K's
    20687 edges: 3 times faster than a factor at a time); None at anything the factor-by-factor
    walk must judge (a factor of another class or a subclass, a key without a value, a
    noise model or information it refuses, no between factor): that walk then raises the
    error it would have raised."""
    factors: list[Any] = list(map(graph.at, range(graph.size())))
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
            sorted_factors.soft_information.append(
                factor_information(factor, f"prior factor on key {key_text(key)}", size,
                                   max_condition=max_condition))
        except GraphError:
            return None
        sorted_factors.soft.append(entry)
    return sorted_factors


def _between(i: int, j: int) -> str:
    return f"between factor {key_text(i)}-{key_text(j)}"


def _worded(name: str | tuple[int, int]) -> str:
    """A factor's name in an error: given, or an edge's keys worded."""
    return name if isinstance(name, str) else _between(*name)


def _check_information(informations: list[np.ndarray], names: Sequence[str | tuple[int, int]],
                       size: int,
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
            raise GraphError(f"{_worded(names[first])}: {problems[first]}")
        return
    bad = np.flatnonzero(~_semidefinite(stack))
    if len(bad):
        raise GraphError(f"{_worded(names[bad[0]])}: information matrix is not finite and "
                         "positive semidefinite")


def _semidefinite(stack: np.ndarray) -> np.ndarray:
    """(k,) whether each matrix is finite and positive semidefinite (to round-off)."""
    finite = np.all(np.isfinite(stack), axis=(1, 2))
    result = finite.copy()
    if finite.any():
        smallest = np.linalg.eigvalsh(stack[finite])[:, 0]
        result[finite] = smallest >= -1e-12 * np.abs(stack[finite]).max(axis=(1, 2))
    return result


def _gaussian_information(factor, name: str | tuple[int, int],
                          refuse: Callable[[str], Exception] = GraphError) -> np.ndarray:
    """The information of ``factor``'s noise model, which must be Gaussian and not
    constrained (``refuse(message)`` makes the error)."""
    model = factor.noiseModel()
    if not isinstance(model, gtsam.noiseModel.Gaussian):
        raise refuse(
            f"{_worded(name)} has a {type(model).__name__} noise model; the initializers need "
            "Gaussian models (wrap the graph's robust models after initialization)"
        )
    if isinstance(model, gtsam.noiseModel.Constrained):
        raise refuse(f"{_worded(name)} has a constrained noise model; only priors may be hard")
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


def information_problem_6(information: np.ndarray) -> str | None:
    """Why a 6x6 information matrix cannot be used as it is, or None if it can: the planar
    rule (:func:`information_problem`) at size 6, with a condition number
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
       eigenvalues out of :data:`INFORMATION_RANGE`) is refused.
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
            problems[k] = f"{problem} (eigenvalues {eigenvalues[0]:.3g} .. {eigenvalues[-1]:.3g})"
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


def printed_of(graph: gtsam.NonlinearFactorGraph, information: np.ndarray,
                check: bool) -> dict[bytes, np.ndarray]:
    """The extraction's ``printed``: for each edge's information that rule 1 refuses and
    whose model is GTSAM's partial factor of a printed matrix (:func:`printed_informations`),
    that matrix, keyed by the information's bytes.

    Raises:
        GraphError: with ``check``, an edge whose information rule 1 refuses and whose
            model is no such factor (the first, as :func:`sort_factors` names it).
    """
    problems = information_problems(information, MAX_CONDITION_3D)
    refused = [k for k, problem in enumerate(problems) if problem is not None]
    if not refused:
        return {}
    factors: list[Any] = [factor for factor in map(graph.at, range(graph.size()))
                          if isinstance(factor, gtsam.BetweenFactorPose3)]
    printed, found = printed_informations(
        np.array([factors[k].noiseModel().R() for k in refused]))
    if check and not found.all():
        first = refused[int(np.flatnonzero(~found)[0])]
        i, j = factors[first].keys()
        raise GraphError(f"{_between(i, j)}: {problems[first]}")
    return {information[k].tobytes(): matrix
            for k, matrix in zip(np.array(refused)[found].tolist(), printed[found], strict=True)}


def _semidefinite_to_rounding(matrix: np.ndarray) -> bool:
    """Whether a symmetric matrix's eigenvalues lie in ``-ROUNDING_3D x largest ..
    INFORMATION_RANGE[1]``, with the largest at least ``INFORMATION_RANGE[0]``."""
    return bool(_semidefinite_many(matrix[None])[0])


def with_informations(graph: gtsam.NonlinearFactorGraph,
                      informations: dict[int, np.ndarray]) -> gtsam.NonlinearFactorGraph:
    """``graph`` with the between factor at each index of ``informations`` given that
    information (a Gaussian noise model), its keys and measurement kept; the other factors,
    and the order, as they are."""
    replaced = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        factor: Any = graph.at(k)
        if k in informations:
            factor = type(factor)(factor.keys()[0], factor.keys()[1], factor.measured(),
                                  gtsam.noiseModel.Gaussian.Information(informations[k]))
        replaced.add(factor)
    return replaced


def scaled_informations(graph: gtsam.NonlinearFactorGraph,
                        factor: float) -> gtsam.NonlinearFactorGraph:
    """``graph`` with every between factor's (``BetweenFactorPose2``, ``BetweenFactorPose3``)
    information multiplied by ``factor``: its covariance divided by it, the noise understated
    ``factor`` times (an optimistic front end's covariances) for ``factor > 1``. The same
    factors, measurements and order; other factors as they are."""
    between = (gtsam.BetweenFactorPose2, gtsam.BetweenFactorPose3)
    factors: list[Any] = [graph.at(k) for k in range(graph.size())]
    models: dict[int, Any] = {k: f.noiseModel() for k, f in enumerate(factors)
                              if isinstance(f, between)}
    return with_informations(graph, {k: factor * model.information()
                                     for k, model in models.items()})
