"""Landmark measurements: a point's position in a pose's frame, with its information.

GTSAM measures a point from a pose by bearing and range (``BearingRangeFactor2D`` /
``BearingRangeFactor3D``, Gaussian noise in bearing-range coordinates); g2o files measure it as
the point's position in the pose's frame (``EDGE_SE2_XY``, ``EDGE_SE3_TRACKXYZ``), with an
information matrix in those coordinates. The two are the same measurement: a bearing ``b`` and a
range ``r`` are the point ``p = r u(b)`` in the pose's frame, and a covariance moves between the
two coordinates through the Jacobian of that map at the measurement, ``J = [r B, u]`` in 3D
(``B``: the 3x2 tangent basis of the unit vector ``u``, GTSAM's ``Unit3.basis()``, in which a
``Unit3`` error is expressed), ``J = [r u_perp, u]`` in the plane. Reading a g2o line as a
bearing-range factor and writing it back is exact; it is how GTSAM's own ``readG2o`` reads
``EDGE_SE3_TRACKXYZ``.

The relaxation needs the position form: a term ``tau || l - t_i - R_i p ||^2`` with the isotropic
weight ``tau = d / tr(Sigma_p)`` (SE-Sync's rule for translations), which
:func:`relative_point` gives from a factor.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.groups import key_text
from rlpgo_gtsam.information import factor_information

__all__ = ["bearing_range_factor", "relative_point", "point_jacobian", "landmark_key",
           "point_weights", "Points", "Carried", "Split", "split_graph",
           "place_points", "key_text", "outside_kinds", "Ranges", "RANGE_FACTORS"]

# GTSAM's range factors, planar then 3D: pose to pose, pose to point, point to point (a PyFG
# file's EDGE_RANGE lines; a g2o file has no line for them)
RANGE_FACTORS = (gtsam.RangeFactorPose2, gtsam.RangeFactor2D, gtsam.RangeFactor2,
                 gtsam.RangeFactorPose3, gtsam.RangeFactor3D, gtsam.RangeFactor3)


def landmark_key(index: int) -> int:
    """GTSAM's key of landmark ``index`` (``l<index>``), as ``readG2o`` names them."""
    return int(gtsam.symbol("l", int(index)))


def point_jacobian(point: np.ndarray) -> np.ndarray:
    """The Jacobian of ``p(bearing, range)`` at ``point`` (in the pose's frame): (2, 2) with
    columns (angle, range) in the plane, (3, 3) with columns (the ``Unit3`` tangent basis's
    two, range) in 3D.

    Raises:
        GraphError: a point at zero range or not finite (its bearing is undefined).
    """
    point = np.asarray(point, float)
    r = float(np.linalg.norm(point))
    if not (np.isfinite(r) and r > 0.0):
        raise GraphError(f"a landmark measurement at range {r:g}: its bearing is undefined")
    u = point / r
    if len(point) == 2:
        return np.array([[-r * u[1], u[0]], [r * u[0], u[1]]])
    basis = gtsam.Unit3(u).basis()
    return np.column_stack([r * basis, u])


def bearing_range_factor(pose_key: int, point_key: int, point: np.ndarray,
                         information: np.ndarray) -> Any:
    """GTSAM's bearing-range factor (2D or 3D by ``point``'s length) of a point measured at
    ``point`` in the pose's frame with ``information`` (d x d) in those coordinates.

    Raises:
        GraphError: a point at zero range, or an information that is not positive definite.
    """
    point = np.asarray(point, float)
    jacobian = point_jacobian(point)
    information = np.asarray(information, float)
    try:
        np.linalg.cholesky(information)
    except np.linalg.LinAlgError:
        raise GraphError("a landmark measurement's information is not positive "
                         "definite") from None
    # information in bearing-range coordinates: J^T I J (the covariance J^-1 S J^-T inverted)
    noise = gtsam.noiseModel.Gaussian.Information(jacobian.T @ information @ jacobian)
    r = float(np.linalg.norm(point))
    if len(point) == 2:
        return gtsam.BearingRangeFactor2D(pose_key, point_key,
                                          gtsam.Rot2(float(np.arctan2(point[1], point[0]))),
                                          r, noise)
    return gtsam.BearingRangeFactor3D(pose_key, point_key, gtsam.Unit3(point / r), r, noise)


def relative_point(factor: Any) -> tuple[np.ndarray, np.ndarray]:
    """A bearing-range factor's measurement as the point in the pose's frame (d,) and its
    information there (d, d).

    Raises:
        GraphError: a noise model without a Gaussian information (robust or constrained), or a
            measurement at zero range.
    """
    measured = factor.measured()
    r = float(measured.range())
    if isinstance(factor, gtsam.BearingRangeFactor2D):
        theta = measured.bearing().theta()
        point = r * np.array([np.cos(theta), np.sin(theta)])
    else:
        point = r * np.asarray(measured.bearing().point3())
    model = factor.noiseModel()
    if isinstance(model, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
        raise GraphError(f"{type(factor).__name__} on keys {_keys(factor)}: a "
                         f"{type(model).__name__} noise model has no Gaussian information")
    sqrt_information = np.asarray(model.R(), float)
    try:
        jacobian_inverse = np.linalg.inv(point_jacobian(point))
    except GraphError as error:
        raise GraphError(f"{type(factor).__name__} on keys {_keys(factor)}: {error}") from None
    whitened = sqrt_information @ jacobian_inverse
    return point, whitened.T @ whitened


def point_weights(information: np.ndarray) -> np.ndarray:
    """The relaxation's isotropic weight of each point measurement: ``d / tr(Sigma)``
    (SE-Sync's translation weight; 0 where the information is singular)."""
    information = np.asarray(information, float)
    d = information.shape[-1]
    weights = np.zeros(len(information))
    if len(information) == 0:
        return weights
    det = np.linalg.det(information)
    ok = det > 0
    weights[ok] = d / np.trace(np.linalg.inv(information[ok]), axis1=1, axis2=2)
    return weights


def _name(factor: Any) -> str:
    return f"{type(factor).__name__} on {_keys(factor)}"


def _keys(factor: Any) -> str:
    return " ".join(key_text(key) for key in factor.keys())


@dataclass(frozen=True, eq=False)
class Points:
    """A graph's landmarks as arrays (``p`` points, ``k`` measurements, ``q`` priors).

    Attributes:
        keys: (p,) the points' GTSAM keys.
        values: (p, d) their positions in the values the graph came with (a point without a
            value: where its first measurement puts it from its pose's value).
        edges: (k, 2) (pose index, point index) of each measurement.
        measured: (k, d) the point in the pose's frame.
        information: (k, d, d) its information in those coordinates.
        priors: (q,) the point index of each soft prior (``PriorFactorPoint2/3``).
        prior_values: (q, d) the priors' positions.
        prior_information: (q, d, d) their information.
    """

    keys: np.ndarray
    values: np.ndarray
    edges: np.ndarray
    measured: np.ndarray
    information: np.ndarray
    priors: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    prior_values: np.ndarray | None = None
    prior_information: np.ndarray | None = None

    @property
    def count(self) -> int:
        return len(self.keys)

    @property
    def dimension(self) -> int:
        return int(self.values.shape[1])

    def weights(self) -> np.ndarray:
        """(k,) the relaxation's weight of each measurement (:func:`point_weights`)."""
        return point_weights(self.information)


@dataclass(frozen=True, eq=False)
class Ranges:
    """Range measurements between translation nodes: poses ``0..n-1``, then the points
    ``n..n+p-1`` (GTSAM's ``RangeFactor2D`` from a pose to a point, ``RangeFactorPose2``
    between two poses: ``(||t_b - t_a|| - r)^2 / sigma^2``).

    Attributes:
        nodes: (k, 2) the two nodes of each range.
        measured: (k,) the ranges.
        weights: (k,) their precisions ``1 / sigma^2``.
    """

    nodes: np.ndarray
    measured: np.ndarray
    weights: np.ndarray

    @property
    def count(self) -> int:
        return len(self.measured)


@dataclass(frozen=True)
class Carried:
    """A factor outside what the initializers model: LM refines it with the rest."""

    position: int  # in the user's graph
    kind: str  # its class name
    keys: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Split:
    """A whole graph taken apart (:func:`split_graph`): the pose graph's factors and values,
    the landmarks and ranges (by key, not yet indices), the carried factors and their
    variables' values."""

    pose_factors: gtsam.NonlinearFactorGraph
    pose_values: gtsam.Values
    point_keys: list[int]
    point_values: dict[int, np.ndarray]
    measurements: list[tuple[int, int, np.ndarray, np.ndarray]]  # pose key, point key, p, I
    point_priors: list[tuple[int, np.ndarray, np.ndarray]]  # point key, value, information
    carried: tuple[Carried, ...]
    carried_values: gtsam.Values
    ranges: list[tuple[int, int, float, float]]  # key, key, range, weight (1 / variance)


def outside_kinds(carried: tuple[Carried, ...]) -> tuple[str, ...]:
    """Carried factors by kind, in graph order: ``("RangeFactor2D x 3", ...)``."""
    counts = Counter(item.kind for item in carried)
    return tuple(f"{kind} x {count}" for kind, count in counts.items())


def split_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, group: Any) -> Split:
    """Take a whole GTSAM graph apart: the group's between and prior factors (the pose
    graph); bearing-range measurements of points (:func:`relative_point`), in the plane range
    measurements from a pose to a point (``RangeFactor2D``) or between two poses
    (``RangeFactorPose2``), and point priors on those points (the landmarks), each with a
    Gaussian noise model; every other factor, carried.

    Poses are the keys of the pose factors and the measuring ends of the point and range
    measurements; points the measured ends. A carried factor's other keys keep the user's
    values.

    Raises:
        GraphError: a pose factor's key without a pose value, or a carried factor's key
            without a value (naming the factor and the key).
    """
    pose_types = (group.between_factor, group.prior_factor)
    prior_type = gtsam.PriorFactorPoint2 if group.d == 2 else gtsam.PriorFactorPoint3
    factors: list[Any] = [graph.at(position) for position in range(graph.size())]
    pose_keys: set[int] = set()
    for factor in factors:
        if isinstance(factor, pose_types):
            pose_keys.update(int(key) for key in factor.keys())
    in_pose_factors = set(pose_keys)
    modeled = _measurements(factors, group, pose_keys)
    point_keys = sorted({keys[1] for kind, keys in modeled.values() if kind != "pose range"}
                        - pose_keys)
    is_point = set(point_keys)
    pose_factors = gtsam.NonlinearFactorGraph()
    measurements, ranges, point_priors, carried = [], [], [], []
    for position, factor in enumerate(factors):
        if factor is None:
            continue
        keys = [int(key) for key in factor.keys()]
        kind = modeled.get(position, ("", ()))[0]
        if isinstance(factor, pose_types):
            pose_factors.add(factor)
        elif kind == "bearing-range":
            point, information = relative_point(factor)
            measurements.append((keys[0], keys[1], point, information))
        elif kind:
            ranges.append((keys[0], keys[1], float(factor.measured()),
                           float(factor_information(factor, _name(factor), 1, False)[0, 0])))
        elif type(factor) is prior_type and keys[0] in is_point and _gaussian(factor):
            point_priors.append((keys[0], np.asarray(factor.prior(), float),
                                 factor_information(factor, _name(factor), group.d, False)))
        else:
            _check_carried(factor, keys, values, pose_keys | is_point)
            carried.append(Carried(position, type(factor).__name__, tuple(keys)))
    pose_values = gtsam.Values()
    for key in sorted(pose_keys):
        if values.exists(key):
            pose_values.insert(key, _pose_value(values, key, group.pose_type))
        elif key not in in_pose_factors:
            # a pose factor's key without a value: the pose graph's extraction names it
            factor = next(f for f in factors if f is not None and key in f.keys())
            raise GraphError(f"{_name(factor)}: key "
                             f"{key_text(key)} has no value")
    carried_values = gtsam.Values(values)  # every value of the graph's other variables
    for key in pose_keys | is_point:
        if carried_values.exists(key):
            carried_values.erase(key)
    point_values = {key: _point_value(values, key, group.d) for key in point_keys
                    if values.exists(key)}
    return Split(pose_factors, pose_values, point_keys, point_values, measurements,
                 point_priors, tuple(carried), carried_values, ranges)


def _gaussian(factor: Any) -> bool:
    return not isinstance(factor.noiseModel(),
                          (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained))


def _measurements(factors: list[Any], group: Any, pose_keys: set[int]
                  ) -> dict[int, tuple[str, tuple[int, ...]]]:
    """The factors the relaxation models besides the pose factors, by position: their kind
    (``"bearing-range"``, ``"point range"``, ``"pose range"``) and keys. Their measuring
    poses join ``pose_keys`` (a pose range's both ends)."""
    point_type, point_range, pose_range = group.measurement_factors
    found: dict[int, tuple[str, tuple[int, ...]]] = {}
    for position, factor in enumerate(factors):
        kind = type(factor)
        if factor is None or kind not in (point_type, point_range, pose_range) \
                or not _gaussian(factor):
            continue
        keys = tuple(int(key) for key in factor.keys())
        if kind is pose_range:
            found[position] = ("pose range", keys)
        elif keys[1] not in pose_keys:
            found[position] = ("bearing-range" if kind is point_type else "point range", keys)
    for name, keys in found.values():
        pose_keys.update(keys if name == "pose range" else keys[:1])
    return found


def _check_carried(factor: Any, keys: list[int], values: gtsam.Values,
                   modeled: set[int]) -> None:
    """A carried factor's keys must have values (a modeled variable's comes from the
    initializer), and GTSAM must be able to evaluate it on the user's values where they are
    all there (a factor on a variable of another type is refused here, not inside LM).

    Raises:
        GraphError: naming the factor, its keys and what is wrong.
    """
    name = _name(factor)
    for key in keys:
        if key not in modeled and not values.exists(key):
            raise GraphError(f"{name}: key {key_text(key)} has no value")
    if all(values.exists(key) for key in keys):
        try:
            factor.error(values)
        except RuntimeError as error:
            reason = " ".join(str(error).split())
            raise GraphError(f"{name}: GTSAM cannot evaluate it on the values given "
                             f"({reason})") from None


def _pose_value(values: gtsam.Values, key: int, pose_type: Any) -> Any:
    try:
        return values.atPose2(key) if pose_type is gtsam.Pose2 else values.atPose3(key)
    except RuntimeError:
        raise GraphError(f"key {key_text(key)} is a pose of the graph but its value is not a "
                         f"{pose_type.__name__}") from None


def _point_value(values: gtsam.Values, key: int, d: int) -> np.ndarray:
    try:
        point = values.atPoint2(key) if d == 2 else values.atPoint3(key)
    except RuntimeError:
        raise GraphError(f"key {key_text(key)} is a landmark measured by bearing and range but "
                         f"its value is not a Point{d}") from None
    return np.asarray(point, float)


def place_points(points: Points, rotations: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """(p, d) the points of least cost given the poses (rotations (n, d, d), positions (n, d)):
    each measurement says ``t_i + R_i z`` with information ``R_i I R_i^T`` in the world frame;
    a point's position is their information-weighted mean, its priors included. A point
    that no measurement or prior fixes keeps its value."""
    d = points.dimension
    i, point = points.edges[:, 0], points.edges[:, 1]
    r = rotations[i]
    world = positions[i] + np.einsum("kab,kb->ka", r, points.measured)
    weight = r @ points.information @ np.transpose(r, (0, 2, 1))
    total = np.zeros((points.count, d, d))
    moment = np.zeros((points.count, d))
    np.add.at(total, point, weight)
    np.add.at(moment, point, np.einsum("kab,kb->ka", weight, world))
    if len(points.priors) and points.prior_information is not None \
            and points.prior_values is not None:
        np.add.at(total, points.priors, points.prior_information)
        np.add.at(moment, points.priors,
                  np.einsum("kab,kb->ka", points.prior_information, points.prior_values))
    placed = points.values.copy()
    fixed = np.linalg.det(total) > 0
    placed[fixed] = np.linalg.solve(total[fixed], moment[fixed][..., None])[..., 0]
    return placed
