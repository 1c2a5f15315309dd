"""The two objects the staircase is generic over: a :class:`Relaxation` (the problem: ``Q``
as an operator, built from a pose graph, and what the staircase's driver asks of its
dimension) and a :class:`Manifold` (the blocks' operations and the staircase's settings).

The planar relaxation (:mod:`~rlpgo_gtsam.relaxation.circles`: unit-modulus complex rows)
and the spatial one (:mod:`~rlpgo_gtsam.relaxation.stiefel`: 3 x r Stiefel blocks) each
define both.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from rlpgo_gtsam.errors import GraphError, SolverError
from rlpgo_gtsam.graph import rotation_weights, translation_weights

if TYPE_CHECKING:
    from rlpgo_gtsam.graph import PoseGraph
    from rlpgo_gtsam.relaxation.certificate import Check
    from rlpgo_gtsam.relaxation.progress import Progress

__all__ = ["Relaxation", "Manifold", "negative_pivots", "factor_or_none",
           "RELATIVE_TOLERANCE", "ARPACK_OPTIONS", "ESCAPE_HALVINGS"]

RELATIVE_TOLERANCE = 1e-7  # eta / scale (the mean of diag Q's weights)
ARPACK_OPTIONS = {"maxiter": 2000}  # ARPACK's settings besides k, which, v0 and tol
ESCAPE_HALVINGS = 30  # step halvings an escape from a saddle tries before it gives up


class Relaxation:
    """A relaxation's problem, built from a pose graph.

    What the staircase uses: ``n`` (poses), ``scale`` (the mean of ``diag Q``'s weights),
    ``apply(Y)`` (``Q Y``), ``cost(Y)`` (``tr(Y^* Q Y)``), ``factor(shift)`` (a pivot-free
    sparse LU of a matrix whose Schur complement is ``Q + shift``, RuntimeError on an
    exactly zero pivot), ``solve_shifted(factor, V)`` and, where the manifold asks for
    SE-Sync's preconditioner shift, ``norm_bound()`` (an upper bound on ``||Q||``). The
    preconditioner's factor is kept here, made once per problem (its shift does not depend
    on ``Y``) and shared by the ranks.

    What the driver (:func:`~rlpgo_gtsam.relaxation.synchronize`) asks of a dimension: its
    lowest rank (the rotation problem itself) and default gradient tolerance, its
    :meth:`manifold`, the start (:meth:`start`, :meth:`given`), a cheaper way to a verified
    first point where it has one (:meth:`verified_shortcut`), and the way back from ``Y``
    to rotations (:meth:`rounded`, :meth:`stacked`, :meth:`unstacked`, :meth:`anchored`).
    Rotations here are the dimension's own form: unit complex numbers (n,) in the plane,
    matrices (n, 3, 3) in space; the caller's are angles (n,) and matrices.
    """

    lowest_rank: ClassVar[int]
    """The rank of the rotation problem itself (complex columns in the plane, real in
    space)."""
    gradient_tolerance: ClassVar[float]
    """The default stop of a rank's trust region: the Riemannian gradient's norm below this
    times ``sqrt(n) x scale``."""
    n: int
    scale: float
    flat: np.ndarray | None = None
    """Rows of ``Y`` that no term measures (a 3D range's block beyond its direction), or
    None: ``Q`` is zero there, so is ``S`` once :meth:`decoupled` has set their multipliers,
    and the verification looks for ``lambda_min`` on the other rows."""

    def decoupled(self, lam: np.ndarray) -> np.ndarray:
        """The multipliers without :attr:`flat` rows' (``sym((Q Y) Y^*)`` holds them only
        where the gradient is not yet zero); a relaxation without such rows has none."""
        return lam

    def range_steps(self) -> np.ndarray:
        """(k, d) each range's ``t_b - t_a`` in the values the graph came with (poses, then
        points): where its direction starts."""
        g, ranges = self.pose_graph, self.pose_graph.ranges
        if ranges is None:
            return np.zeros((0, g.group.d))
        positions = g.group.translations(g.poses)
        if g.points is not None:
            positions = np.concatenate([positions, g.points.values])
        return positions[ranges.nodes[:, 1]] - positions[ranges.nodes[:, 0]]

    def conditioned(self, blocks: np.ndarray) -> np.ndarray:
        """The preconditioner's shift ``blocks`` (:meth:`Manifold.diagonal`) with weight on
        :attr:`flat` rows, where ``Q`` has none."""
        return blocks
    _preconditioner: tuple[float, Any] | None = None

    def __init__(self, pose_graph: PoseGraph) -> None:
        """Keeps the graph, its pose count and its edges' weights ``kappa`` (rotation) and
        ``tau`` (translation) after checking them.

        Raises:
            GraphError: fewer than 2 poses, or measurements or information not finite.
        """
        g = pose_graph
        if g.num_poses < 2:
            raise GraphError(f"a pose graph for the relaxation needs 2 poses or more, got "
                             f"{g.num_poses}")
        kappa, tau = rotation_weights(g), translation_weights(g)
        if not (np.isfinite(kappa).all() and np.isfinite(tau).all()
                and np.isfinite(g.group.measured(g)).all()):
            raise GraphError("the relaxation needs finite measurements and information")
        self.pose_graph, self.kappa, self.tau = g, kappa, tau
        points, ranges = g.points, g.ranges
        if points is not None:
            if len(points.priors):
                raise GraphError("point priors enter the relaxation as edges from a world "
                                 "frame (rlpgo_gtsam.anchoring), not as given")
            if not (np.isfinite(points.measured).all() and np.isfinite(points.weights()).all()):
                raise GraphError("the relaxation needs finite landmark measurements and "
                                 "information")
        if ranges is not None and not (np.isfinite(ranges.measured).all()
                                       and np.isfinite(ranges.weights).all()):
            raise GraphError("the relaxation needs finite ranges and weights")
        self.num_poses = g.num_poses
        # unit rows: one per pose, then one per range (its direction, a unit vector)
        self.n = g.num_poses + (0 if ranges is None else ranges.count)
        self.translation_nodes = g.num_poses + (0 if points is None else points.count)

    def extra_terms(self) -> tuple[np.ndarray, ...]:
        """The translation terms besides the edges', each ``w || t_b - t_a - U_c m ||^2``
        between translation nodes ``a`` and ``b`` (poses ``0..n-1``, then the points) with
        the unit row ``c``: a landmark measurement (``a`` its pose, ``b`` the point's node,
        ``c = a``, ``m`` the point in the pose's frame, ``w`` its isotropic weight
        (:func:`~rlpgo_gtsam.landmarks.point_weights`)), and in the plane a range (``a``, ``b``
        its nodes, ``c`` its own unit row after the poses', ``m = (r, 0)``, ``w = 1 /
        sigma^2``: CORA's formulation, the direction a unit vector of its own). Returns
        ``(a, b, c, w, m)``: (k,) arrays and (k, d)."""
        g, d = self.pose_graph, self.pose_graph.group.d
        parts = [(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
                  np.zeros(0), np.zeros((0, d)))]
        points, ranges = g.points, g.ranges
        if points is not None:
            parts.append((points.edges[:, 0], self.num_poses + points.edges[:, 1],
                          points.edges[:, 0], points.weights(), points.measured))
        if ranges is not None:
            measured = np.zeros((ranges.count, d))
            measured[:, 0] = ranges.measured
            parts.append((ranges.nodes[:, 0], ranges.nodes[:, 1],
                          self.num_poses + np.arange(ranges.count), ranges.weights, measured))
        return tuple(np.concatenate(column) for column in zip(*parts, strict=True))

    # Q as an operator, the methods of a subclass (see the class docstring)
    apply: Callable[[np.ndarray], np.ndarray]
    cost: Callable[[np.ndarray], float]
    factor: Callable[[np.ndarray], Any]
    solve_shifted: Callable[[Any, np.ndarray], np.ndarray]
    norm_bound: Callable[[], float]

    def preconditioner_delta(self, manifold: Manifold) -> float:
        """The preconditioner's shift: ``delta = norm_bound() / (condition - 1)`` with the
        manifold's ``preconditioner_condition`` (SE-Sync's regularized Cholesky
        preconditioner), else ``preconditioner_shift x scale``."""
        m = manifold
        if m.preconditioner_condition is not None:
            return self.norm_bound() / (m.preconditioner_condition - 1.0)
        return m.preconditioner_shift * self.scale

    def preconditioner(self, manifold: Manifold) -> Any:
        """The factor of ``Q + delta I`` (:meth:`preconditioner_delta`); cached per delta."""
        delta = self.preconditioner_delta(manifold)
        if self._preconditioner is None or self._preconditioner[0] != delta:
            self._preconditioner = (delta, self.factor(
                self.conditioned(manifold.diagonal(self.n, delta))))
        return self._preconditioner[1]

    def hessian_preconditioner(self, manifold: Manifold, y: np.ndarray,
                               lam: np.ndarray) -> Callable[[np.ndarray], np.ndarray] | None:
        """A preconditioner of the Riemannian Hessian at ``y`` (multipliers ``lam``) that
        holds ``Lambda``, as a function of a tangent vector, or None where it is not
        positive definite (away from a minimum; at rank > 1 of a relaxation that is not
        exact). Here the factor of ``S + delta I = Q - Lambda + delta I``: ``(Q + delta
        I)^-1`` leaves out ``Lambda``, which outweighs ``Q``'s lowest modes on long graphs.
        A problem may give a closer one (the planar one at rank 1: the tangent Hessian's
        own factor)."""
        factor = factor_or_none(self, self.conditioned(
            manifold.shift(lam, -self.preconditioner_delta(manifold))))
        if factor is None or manifold.negative_pivots(factor) != 0:
            return None
        return lambda v: 0.5 * manifold.project(y, self.solve_shifted(factor, v))

    def tolerance(self, tolerance: float | None) -> float:
        """eta: ``tolerance``, or by default ``RELATIVE_TOLERANCE x scale``.

        Raises:
            SolverError: a tolerance that is not a finite number >= 0.
        """
        if tolerance is None:
            return RELATIVE_TOLERANCE * self.scale
        if not (np.isfinite(tolerance) and tolerance >= 0):
            raise SolverError(f"tolerance must be a finite number >= 0, got {tolerance}")
        return float(tolerance)

    # --- what the driver asks of a dimension ----------------------------------------------

    def manifold(self) -> Manifold:
        """The staircase's manifold and settings (from its module's constants at the call)."""
        raise NotImplementedError

    def start(self, rotations: np.ndarray | None) -> np.ndarray:
        """``Y`` at the lowest rank: :meth:`given` ``rotations``, or by default the chordal
        estimate."""
        raise NotImplementedError

    def given(self, rotations: np.ndarray) -> np.ndarray:
        """``Y`` at the lowest rank of the caller's ``rotations`` (angles (n,) or matrices
        (n, 3, 3)).

        Raises:
            SolverError: the wrong shape, or values that are not finite.
        """
        raise NotImplementedError

    def verified_shortcut(self, manifold: Manifold, y: np.ndarray, eta: float,
                          grad_tol: float, deadline: float | None, progress: Progress
                          ) -> tuple[np.ndarray, Check | None]:
        """Where the dimension has a cheaper way than the staircase's first trust region to a
        point it would stop at (the spatial one's Newton steps on small graphs): that point
        and its verification where it certifies; else ``(y, None)`` and the staircase runs
        (from the point returned)."""
        return y, None

    def rounded(self, y: np.ndarray) -> np.ndarray:
        """Rotations rounded from ``Y`` at any rank."""
        raise NotImplementedError

    def stacked(self, rotations: np.ndarray) -> np.ndarray:
        """``Y`` at the lowest rank of rotations."""
        raise NotImplementedError

    def unstacked(self, y: np.ndarray) -> np.ndarray:
        """Rotations of ``Y`` at the lowest rank."""
        raise NotImplementedError

    def anchored(self, rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rotations turned so that the anchor keeps its own, in the caller's form, and
        their ``Y``."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Manifold:
    """The blocks' operations (methods a subclass defines) and the staircase's settings.

    Attributes:
        dense_below: rows of ``Q`` below which ``S``'s eigenvalues are computed densely.
        preconditioner_shift: delta / scale: ``(Q + delta I)^-1`` preconditions the Hessian
            (where ``preconditioner_condition`` is None).
        preconditioner_condition: if set, delta is the problem's ``norm_bound()`` over this
            number minus 1 (SE-Sync's rule: the preconditioner's condition number at most this).
        initial_radius: the first trust-region radius, in units of the preconditioned
            gradient's norm.
        exact_decrease: a trial step's decrease computed as ``-<Y' - Y, Q (Y' + Y)>`` (exact
            for symmetric Q) rather than as the difference of two costs, which near a minimum
            agree in more digits than their round-off resolves (good steps then rejected).
        step_radius: a rejected step shrinks the radius to a quarter of the smaller of the
            radius and the step's length (SE-Sync's rule); False: a quarter of the radius.
            Both on by default: on tinyGrid3D, smallGrid3D and sphere2500 the spatial
            staircase and its chi2 after 30 LM iterations came out the same either way.
        max_below: where ``S + eta I`` has at most this many non-positive pivots, their
            eigenpairs are computed one by one; more (or 0 here): one shift below them all.
        escape_halvings: step halvings an escape from a saddle tries before it gives up.
        arpack_options: ARPACK's settings besides k, which, v0 and tol.
        hessian_preconditioner_after: a truncated CG run that took at least this many
            Hessian products makes the trust region's next run precondition with the
            problem's :meth:`Relaxation.hessian_preconditioner` at its ``Y`` (refactored at
            each new ``Y`` from then on, as long as it is positive definite; else back to
            ``Q + delta I``); None: always ``Q + delta I``.
        cg_floor: truncated CG also stops once its residual is below this fraction of the
            trust region's gradient tolerance (the next gradient is about that residual:
            solving further only overshoots the stop test); 0: never.
    """

    dense_below: int
    preconditioner_shift: float
    initial_radius: float
    max_below: int = 0
    preconditioner_condition: float | None = None
    exact_decrease: bool = True
    step_radius: bool = True
    escape_halvings: int = ESCAPE_HALVINGS
    arpack_options: dict[str, Any] = field(default_factory=lambda: dict(ARPACK_OPTIONS))
    hessian_preconditioner_after: int | None = None
    cg_floor: float = 0.0
    dtype: ClassVar[type] = float
    """The scalars of ``Y`` (and of the eigenvectors of ``S``)."""

    def size(self, n: int) -> int:
        """Rows of ``Q`` for ``n`` poses."""
        raise NotImplementedError

    def inner(self, a: np.ndarray, b: np.ndarray) -> float:
        """The real inner product of the ambient space."""
        raise NotImplementedError

    def project(self, y: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``v`` projected onto the tangent space at ``y``."""
        raise NotImplementedError

    def retract(self, y: np.ndarray) -> np.ndarray:
        """``y`` moved back onto the manifold."""
        raise NotImplementedError

    def move(self, y: np.ndarray, step: np.ndarray) -> np.ndarray:
        """The trust region's trial point: ``y`` moved along the tangent vector ``step`` and
        back onto the manifold; :meth:`retract` of ``y + step`` unless a manifold knows a
        cheaper form of the same point."""
        return self.retract(y + step)

    def multipliers(self, y: np.ndarray, qy: np.ndarray) -> np.ndarray:
        """``Lambda(Y)`` from ``Y`` and ``Q Y``."""
        raise NotImplementedError

    def times(self, lam: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``Lambda V``."""
        raise NotImplementedError

    def gradient(self, y: np.ndarray, qy: np.ndarray,
                 lam: np.ndarray | None = None) -> np.ndarray:
        """The Riemannian gradient ``2 (Q Y - Lambda(Y) Y)`` of ``f`` at ``y`` (``qy``: ``Q
        Y``; ``lam``: its multipliers, where known)."""
        lam = self.multipliers(y, qy) if lam is None else lam
        return 2.0 * (qy - self.times(lam, y))

    def hessian(self, y: np.ndarray, lam: np.ndarray, v: np.ndarray,
                qv: np.ndarray) -> np.ndarray:
        """The Riemannian Hessian of ``tr(Y^* Q Y)`` at ``y`` along ``v`` (``qv = Q v``)."""
        raise NotImplementedError

    def diagonal(self, n: int, value: float) -> np.ndarray:
        """The shift ``value I`` as :meth:`Relaxation.factor` takes it."""
        raise NotImplementedError

    def shift(self, lam: np.ndarray, sigma: float) -> np.ndarray:
        """The shift whose factor's Schur complement is ``S - sigma I = Q - Lambda - sigma I``."""
        raise NotImplementedError

    def trace(self, lam: np.ndarray) -> float:
        """``tr(Lambda)``."""
        raise NotImplementedError

    def largest(self, lam: np.ndarray) -> float:
        """The largest eigenvalue of ``Lambda``."""
        raise NotImplementedError

    def dense(self, problem: Any, lam: np.ndarray) -> np.ndarray:
        """``S`` as a dense matrix."""
        raise NotImplementedError

    def start(self, y: np.ndarray) -> np.ndarray | None:
        """ARPACK's start for ``lambda_min(S)`` when ``S + eta I`` is positive definite."""
        return None

    def superlu(self, factor: Any) -> Any:
        """The ``SuperLU`` of a :meth:`Relaxation.factor`'s result (for its pivots)."""
        return factor

    def negative_pivots(self, factor: Any) -> int | None:
        """:func:`negative_pivots` of a :meth:`Relaxation.factor`'s result (not None); by
        default through its :meth:`superlu`."""
        return negative_pivots(self.superlu(factor))


def factor_or_none(problem: Any, shift: np.ndarray) -> Any:
    """``problem.factor(shift)``, or None where the LU met an exactly zero pivot (a zero
    eigenvalue: not positive definite)."""
    try:
        return problem.factor(shift)
    except RuntimeError:
        return None


def negative_pivots(lu: Any) -> int | None:
    """Number of non-positive pivots of a pivot-free symmetric ``SuperLU`` (the inertia of
    the matrix's Schur complements, by Sylvester's law, where the eliminated block is positive
    definite), or None when it pivoted off the diagonal (the count would not be an inertia)."""
    if not np.array_equal(lu.perm_r, lu.perm_c):
        return None
    return int(np.count_nonzero(np.real(lu.U.diagonal()) <= 0))
