"""Trajectory error against a ground truth, as evo (github.com/MichaelGrupp/evo) defines it.

Chi2 says how well a map fits its own measurements; with a ground truth a map is judged by
its trajectory error. :func:`trajectory_errors` gives evo's two numbers for planar poses,
matched by GTSAM key:

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
``align(correct_scale=False)``, restricted to the plane: a rotation about z and a
translation (SE(2)). For trajectories at z = 0 that is evo's SE(3) alignment whenever the
best fit keeps the estimate's handedness (every estimate near its ground truth); when a
mirror image would fit better, evo's SE(3) fit turns the estimate upside down (a half turn
about an axis in the plane), which no planar motion does, and its APE is then the lower.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import gtsam
import numpy as np

from rlpgo_gtsam.errors import GraphError
from rlpgo_gtsam.se2 import between, rotation_matrices, wrap

__all__ = ["TrajectoryErrors", "trajectory_errors", "align_positions"]


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
        aligned: whether the estimate was aligned (SE(2) Umeyama) before the APE.
        poses: how many poses were compared (every key of the estimate).
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

    def record(self) -> dict[str, float | int | bool]:
        """The fields as a dict, for JSON."""
        return asdict(self)

    def describe(self) -> str:
        """One line: APE and RPE with their units and how they were taken."""
        ape = (f"APE {self.ape_rmse_m:.4g} m rmse (mean {self.ape_mean_m:.4g}, max "
               f"{self.ape_max_m:.4g}) " + ("after SE(2) alignment" if self.aligned else
                                            "unaligned"))
        rpe = f"RPE {self.rpe_rmse_m:.4g} m, {self.rpe_rmse_deg:.4g} deg rmse"
        return f"{ape}; {rpe} (delta {self.rpe_delta}); {self.poses} poses"


def trajectory_errors(values: gtsam.Values, ground_truth: gtsam.Values, *, align: bool = True,
                      rpe_delta: int = 1) -> TrajectoryErrors:
    """APE and RPE of the Pose2 ``values`` against ``ground_truth``, as evo computes them.

    Poses are matched by key: every key of ``values`` must have a pose in ``ground_truth``
    (which may hold more); the RPE pairs follow the keys in ascending order.

    Args:
        values: the estimate (e.g. a refined result).
        ground_truth: the true poses.
        align: fit the estimate onto the ground truth (rotation + translation, no scale)
            before the APE; without it the frames must already agree.
        rpe_delta: distance in frames of the RPE's pose pairs (evo's ``--delta``).

    Raises:
        GraphError: a key of ``values`` missing from ``ground_truth``, a value that is not a
            finite Pose2, fewer than two poses, no RPE pair for ``rpe_delta``, or an
            alignment that positions do not determine (all of them in one place).
        ValueError: ``rpe_delta`` below 1.
    """
    if rpe_delta < 1:
        raise ValueError(f"rpe_delta must be at least 1, got {rpe_delta}")
    keys = sorted(values.keys())
    missing = next((key for key in keys if not ground_truth.exists(key)), None)
    if missing is not None:
        raise GraphError(f"key {gtsam.DefaultKeyFormatter(missing)} of the estimate has no "
                         "pose in the ground truth")
    if len(keys) < 2:
        raise GraphError(f"trajectory errors need at least 2 poses, the estimate has "
                         f"{len(keys)}")
    estimate = _pose_rows(values, keys, "estimate")
    truth = _pose_rows(ground_truth, keys, "ground truth")
    if len(keys) <= rpe_delta:
        raise GraphError(f"rpe_delta {rpe_delta} leaves no pose pair among {len(keys)} poses")

    positions = estimate[:, :2]
    if align:
        rotation, translation = align_positions(positions, truth[:, :2])
        positions = positions @ rotation.T + translation
    ape = np.linalg.norm(positions - truth[:, :2], axis=1)

    rpe_m, rpe_rad = _relative_errors(estimate, truth, rpe_delta)
    return TrajectoryErrors(
        ape_rmse_m=_rmse(ape), ape_mean_m=float(ape.mean()),
        ape_median_m=float(np.median(ape)), ape_max_m=float(ape.max()),
        rpe_rmse_m=_rmse(rpe_m), rpe_rmse_deg=float(np.degrees(_rmse(rpe_rad))),
        rpe_delta=rpe_delta, aligned=align, poses=len(keys),
    )


def align_positions(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Umeyama's fit without scale in the plane: the rotation ``R`` (2, 2) and translation
    ``t`` (2,) minimizing ``sum_k |R estimate_k + t - truth_k|^2`` over (n, 2) positions.

    In two dimensions the optimal angle has a closed form: with both point sets centred,
    ``atan2(sum of cross products, sum of dot products)`` of estimate against truth.

    Raises:
        GraphError: every rotation fits equally well (one set's positions all coincide).
    """
    mean_estimate, mean_truth = estimate.mean(axis=0), truth.mean(axis=0)
    a, b = estimate - mean_estimate, truth - mean_truth
    dot = float(np.sum(a * b))
    cross = float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
    spread = float(np.linalg.norm(a) * np.linalg.norm(b))
    if not np.hypot(dot, cross) > 1e-12 * spread:  # also when spread is 0
        raise GraphError("the positions do not determine the alignment (the estimate's or "
                         "the ground truth's all coincide); compare without alignment")
    rotation = rotation_matrices(np.array([np.arctan2(cross, dot)]))[0]
    return rotation, mean_truth - rotation @ mean_estimate


def _relative_errors(estimate: np.ndarray, truth: np.ndarray,
                     delta: int) -> tuple[np.ndarray, np.ndarray]:
    """Translation norm and rotation angle (rad) of evo's relative error ``E_i`` for the
    pairs ``(i, i + delta)``, ``i = 0, delta, 2 delta, ...``; (n, 3) poses in, two (p,) out.

    ``E_i``'s translation is the difference of the two relative translations rotated by the
    true relative rotation, so its norm is the norm of that difference; its angle is the
    difference of the two relative angles.
    """
    first = np.arange(0, len(estimate), delta)
    i, j = first[:-1], first[1:]

    moved, true = between(estimate[i], estimate[j]), between(truth[i], truth[j])  # P_i^-1 P_j
    return (np.linalg.norm(moved[:, :2] - true[:, :2], axis=1),
            np.abs(wrap(moved[:, 2] - true[:, 2])))


def _rmse(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(errors ** 2)))


def _pose_rows(values: gtsam.Values, keys: list[int], name: str) -> np.ndarray:
    """(n, 3) x, y, theta of ``values`` at ``keys``; a non-Pose2 or non-finite value is a
    GraphError naming the key."""
    rows = np.empty((len(keys), 3))
    for k, key in enumerate(keys):
        try:
            pose = values.atPose2(key)
        except RuntimeError:
            raise GraphError(f"key {gtsam.DefaultKeyFormatter(key)} of the {name} is not a "
                             "Pose2") from None
        rows[k] = pose.x(), pose.y(), pose.theta()
        if not np.all(np.isfinite(rows[k])):
            raise GraphError(f"key {gtsam.DefaultKeyFormatter(key)} of the {name} is not "
                             "finite")
    return rows
