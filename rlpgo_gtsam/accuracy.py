"""Trajectory error against a ground truth, as evo (github.com/MichaelGrupp/evo) defines it.

Chi2 says how well a map fits its own measurements; with a ground truth a map is judged by
its trajectory error. :func:`trajectory_errors` gives evo's two numbers for planar (Pose2)
or 3D (Pose3) poses, matched by GTSAM key:

- **APE** (absolute pose error, ``PoseRelation.translation_part``): the distance between
  each estimated and true position after the estimate is aligned onto the ground truth;
  its rmse, mean, median and max over the poses.
- **RPE** (relative pose error, ``delta`` in frames, consecutive pairs): for the pose pairs
  ``(i, i + delta)`` with ``i = 0, delta, 2 delta, ...`` in key order, the error
  ``E_i = (Q_i^-1 Q_{i+delta})^-1 (P_i^-1 P_{i+delta})`` of the estimate's motion ``P``
  against the true motion ``Q``: the rmse of its translation norm (metres) and of its
  rotation angle (degrees). A rigid motion of the whole estimate leaves it unchanged, so
  it needs no alignment.

The alignment is Umeyama's least-squares fit of the positions without scale, as evo's
``align(correct_scale=False)``: in 3D exactly evo's (a rotation, never a mirror image, and a
translation); for planar poses restricted to the plane, a rotation about z and a translation
(SE(2)). For trajectories at z = 0 that is evo's SE(3) alignment whenever the best fit keeps
the estimate's handedness (every estimate near its ground truth); when a mirror image would
fit better, evo's SE(3) fit turns the estimate upside down (a half turn about an axis in the
plane), which no planar motion does, and its APE is then the lower.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.se2 import between, rotation_matrices, wrap
from rlpgo_gtsam.se3 import between as between_3d
from rlpgo_gtsam.se3 import rotation_angles

__all__ = ["TrajectoryErrors", "trajectory_errors", "check_ground_truth", "align_positions"]


@dataclass(frozen=True)
class TrajectoryErrors:
    """evo's APE and RPE of an estimate against its ground truth (see the module docstring).

    Attributes:
        ape_rmse_m: root mean square of the absolute position errors, metres.
        ape_mean_m: their mean, metres.
        ape_median_m: their median, metres.
        ape_max_m: the largest, metres.
        rpe_rmse_m: root mean square of the relative errors' translation norms, metres.
        rpe_rmse_deg: root mean square of the relative errors' rotation angles, degrees.
        rpe_delta: the pose pairs' distance in frames (keys in order).
        aligned: whether the estimate was aligned (Umeyama, SE(2) or SE(3)) before the APE.
        poses: how many poses were compared (every key of the estimate).
        dimension: 2 for planar poses, 3 for 3D ones.
    """

    ape_rmse_m: float
    ape_mean_m: float
    ape_median_m: float
    ape_max_m: float
    rpe_rmse_m: float
    rpe_rmse_deg: float
    rpe_delta: int
    aligned: bool
    poses: int
    dimension: int = 2

    def record(self) -> dict[str, float | int | bool]:
        """The fields as a dict, for JSON."""
        return asdict(self)

    def describe(self) -> str:
        """One line: APE and RPE with their units and how they were taken."""
        how = f"after SE({self.dimension}) alignment" if self.aligned else "unaligned"
        ape = (f"APE {self.ape_rmse_m:.4g} m rmse (mean {self.ape_mean_m:.4g}, max "
               f"{self.ape_max_m:.4g}) {how}")
        rpe = f"RPE {self.rpe_rmse_m:.4g} m, {self.rpe_rmse_deg:.4g} deg rmse"
        return f"{ape}; {rpe} (delta {self.rpe_delta}); {self.poses} poses"


def trajectory_errors(values: gtsam.Values, ground_truth: gtsam.Values, *, align: bool = True,
                      rpe_delta: int = 1) -> TrajectoryErrors:
    """APE and RPE of the Pose2 or Pose3 ``values`` against ``ground_truth``, as evo computes
    them.

    Poses are matched by key: every pose of ``values`` must have a pose of the same type in
    ``ground_truth`` (which may hold more); other values (landmarks) are not compared; the
    RPE pairs follow the keys in ascending order.

    Args:
        values: the estimate (e.g. a refined result), all Pose2 or all Pose3.
        ground_truth: the true poses.
        align: fit the estimate onto the ground truth (rotation + translation, no scale)
            before the APE; without it the frames must already agree.
        rpe_delta: distance in frames of the RPE's pose pairs (evo's ``--delta``).

    Raises:
        GraphError: as :func:`check_ground_truth`; no RPE pair for ``rpe_delta``, or an
            alignment that positions do not determine (all of them in one place).
        ValueError: ``rpe_delta`` below 1.
    """
    if rpe_delta < 1:
        raise ValueError(f"rpe_delta must be at least 1, got {rpe_delta}")
    keys, estimate, truth = _matched(values, ground_truth)
    if len(keys) <= rpe_delta:
        raise GraphError(f"rpe_delta {rpe_delta} leaves no pose pair among {len(keys)} poses")
    dimension = estimate.translations.shape[1]

    positions = estimate.translations
    if align:
        rotation, translation = align_positions(positions, truth.translations)
        positions = positions @ rotation.T + translation
    ape = np.linalg.norm(positions - truth.translations, axis=1)

    rpe_m, rpe_rad = _relative_errors(estimate, truth, rpe_delta)
    return TrajectoryErrors(
        ape_rmse_m=_rmse(ape), ape_mean_m=float(ape.mean()),
        ape_median_m=float(np.median(ape)), ape_max_m=float(ape.max()),
        rpe_rmse_m=_rmse(rpe_m), rpe_rmse_deg=float(np.degrees(_rmse(rpe_rad))),
        rpe_delta=rpe_delta, aligned=align, poses=len(keys), dimension=dimension,
    )


def check_ground_truth(values: gtsam.Values, ground_truth: gtsam.Values) -> None:
    """Raise what :func:`trajectory_errors` would refuse in ``ground_truth`` for the estimate
    ``values`` (before a run whose results it will judge).

    Raises:
        GraphError: a key of ``values`` without a pose in ``ground_truth`` (the first, in
            GTSAM's key format, and how many), a value that is not a finite pose of the
            estimate's type (Pose2 or Pose3), or fewer than two poses.
    """
    _matched(values, ground_truth)


def align_positions(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Umeyama's fit without scale: the rotation ``R`` (d, d) and translation ``t`` (d,)
    minimizing ``sum_k |R estimate_k + t - truth_k|^2`` over (n, d) positions, d = 2 or 3.

    In two dimensions the optimal angle has a closed form: with both point sets centred,
    ``atan2(sum of cross products, sum of dot products)`` of estimate against truth. In three,
    Umeyama's SVD of the centred cross-covariance, its last axis flipped where it would
    otherwise give a mirror image (evo's ``umeyama_alignment``).

    Raises:
        GraphError: every rotation fits equally well (one set's positions all coincide).
    """
    mean_estimate, mean_truth = estimate.mean(axis=0), truth.mean(axis=0)
    a, b = estimate - mean_estimate, truth - mean_truth
    spread = float(np.linalg.norm(a) * np.linalg.norm(b))
    if estimate.shape[1] == 2:
        dot = float(np.sum(a * b))
        cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
        best, rotation = float(np.hypot(dot, cross)), None
    else:
        u, singular, vt = np.linalg.svd(b.T @ a)
        signs = np.ones(3)
        signs[2] = np.sign(np.linalg.det(u) * np.linalg.det(vt)) or 1.0
        best = float(signs @ singular)  # the largest trace of R^T (b^T a) over rotations
        rotation = (u * signs) @ vt
    if not best > 1e-12 * spread:  # also when spread is 0
        raise GraphError("the positions do not determine the alignment (the estimate's or "
                         "the ground truth's all coincide); compare without alignment")
    if rotation is None:
        rotation = rotation_matrices(np.array([np.arctan2(cross, dot)]))[0]
    return rotation, mean_truth - rotation @ mean_estimate


def _relative_errors(estimate: _Poses, truth: _Poses,
                     delta: int) -> tuple[np.ndarray, np.ndarray]:
    """Translation norm and rotation angle (rad) of evo's relative error ``E_i`` for the
    pairs ``(i, i + delta)``, ``i = 0, delta, 2 delta, ...``; two (p,) arrays.

    ``E_i``'s translation is the difference of the two relative translations rotated by the
    true relative rotation, so its norm is the norm of that difference; its angle is the
    difference of the two relative angles (planar), the angle of ``R_Q^T R_P`` (3D).
    """
    first = np.arange(0, len(estimate.translations), delta)
    i, j = first[:-1], first[1:]
    if estimate.angles is not None and truth.angles is not None:
        planar_estimate = np.column_stack([estimate.translations, estimate.angles])
        planar_truth = np.column_stack([truth.translations, truth.angles])
        moved = between(planar_estimate[i], planar_estimate[j])  # P_i^-1 P_j
        true = between(planar_truth[i], planar_truth[j])
        return (np.linalg.norm(moved[:, :2] - true[:, :2], axis=1),
                np.abs(wrap(moved[:, 2] - true[:, 2])))
    r_e, t_e = estimate.rotations, estimate.translations
    r_t, t_t = truth.rotations, truth.translations
    assert r_e is not None and r_t is not None  # 3D poses carry rotations
    moved_r, moved_t = between_3d(r_e[i], t_e[i], r_e[j], t_e[j])
    true_r, true_t = between_3d(r_t[i], t_t[i], r_t[j], t_t[j])
    return (np.linalg.norm(moved_t - true_t, axis=1),
            rotation_angles(np.transpose(true_r, (0, 2, 1)) @ moved_r))


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors ** 2)))


@dataclass(frozen=True)
class _Poses:
    """Poses at the compared keys: (n, d) positions; planar angles (n,) or 3D rotations
    (n, 3, 3)."""

    translations: np.ndarray
    angles: np.ndarray | None = None
    rotations: np.ndarray | None = None


# the pose types compared, and how many numbers a position has
_POSE_TYPES = {gtsam.Pose2: 2, gtsam.Pose3: 3}


def _matched(values: gtsam.Values,
             ground_truth: gtsam.Values) -> tuple[list[int], _Poses, _Poses]:
    """The estimate's keys in order and both sets of poses at them (see
    :func:`check_ground_truth` for what is refused)."""
    every = sorted(values.keys())
    if not every:
        raise GraphError("trajectory errors need at least 2 poses, the estimate has 0")
    # the poses are compared; landmarks and other variables of a whole graph are not
    pose_type = next((kind for key in every for kind in _POSE_TYPES if _pose(values, key, kind)),
                     None)
    if pose_type is None:
        raise GraphError(f"key {gtsam.DefaultKeyFormatter(every[0])} of the estimate is "
                         "not a Pose2 or a Pose3")
    keys = [key for key in every if _pose(values, key, pose_type) is not None]
    if len(keys) < 2:
        raise GraphError(f"trajectory errors need at least 2 poses, the estimate has "
                         f"{len(keys)}")
    shared = next((key for key in keys if ground_truth.exists(key)), None)
    if shared is not None and _pose(ground_truth, shared, pose_type) is None:
        raise GraphError(f"key {gtsam.DefaultKeyFormatter(shared)} of the ground truth is not "
                         f"a {pose_type.__name__}, as the estimate's poses are")
    missing = [key for key in keys if not ground_truth.exists(key)]
    if missing:
        more = (f" (nor have {len(missing) - 1} more of its {len(keys)})"
                if len(missing) > 1 else "")
        raise GraphError(f"key {gtsam.DefaultKeyFormatter(missing[0])} of the estimate has no "
                         f"pose in the ground truth{more}")
    return (keys, _pose_rows(values, keys, "estimate", pose_type),
            _pose_rows(ground_truth, keys, "ground truth", pose_type))


def _pose(values: gtsam.Values, key: int, pose_type: type) -> object | None:
    try:
        return getattr(values, f"at{pose_type.__name__}")(key)
    except RuntimeError:
        return None


def _pose_rows(values: gtsam.Values, keys: list[int], name: str, pose_type: type) -> _Poses:
    """The poses of ``values`` at ``keys``; a value of another type or not finite is a
    GraphError naming the key."""
    d = _POSE_TYPES[pose_type]
    translations = np.empty((len(keys), d))
    angles = np.empty(len(keys)) if d == 2 else None
    rotations = np.empty((len(keys), 3, 3)) if d == 3 else None
    for k, key in enumerate(keys):
        pose: Any = _pose(values, key, pose_type)
        if pose is None:
            raise GraphError(f"key {gtsam.DefaultKeyFormatter(key)} of the {name} is not a "
                             f"{pose_type.__name__}, as the estimate's first pose is")
        if angles is not None:
            translations[k] = pose.x(), pose.y()
            angles[k] = pose.theta()
            finite = np.isfinite(angles[k])
        else:
            assert rotations is not None
            translations[k] = pose.translation()
            rotations[k] = pose.rotation().matrix()
            finite = np.all(np.isfinite(rotations[k]))
        if not (finite and np.all(np.isfinite(translations[k]))):
            raise GraphError(f"key {gtsam.DefaultKeyFormatter(key)} of the {name} is not "
                             "finite")
    return _Poses(translations, angles, rotations)
