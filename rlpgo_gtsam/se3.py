"""SE(3) maths on arrays: rotations are (k, 3, 3) matrices, translations (k, 3), quaternions
(k, 4) in g2o's order ``(qx, qy, qz, qw)``, tangent vectors (k, 6) in GTSAM's order (rotation
first, then translation). Every function works on stacks of k elements.

The one home of the spatial group operations (Exp/Log of SO(3), compose, inverse, between,
GTSAM's Pose3 Logmap and adjoint) and of the projection onto SO(3). Nothing here imports GTSAM; the
conventions are GTSAM's (``gtsam.Rot3``, ``gtsam.Pose3`` built with GTSAM_POSE3_EXPMAP, as the
wheels are: a BetweenFactorPose3's error is ``Pose3.Logmap(measured^-1 X_i^-1 X_j)``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "vee",
    "quaternions_to_rotations",
    "rotations_to_quaternions",
    "exp_so3",
    "log_so3",
    "compose",
    "inverse",
    "between",
    "logmap",
    "adjoint",
    "project_to_so3",
    "rotation_angles",
    "pose_matrices",
]

_SMALL = 1e-10  # below this angle GTSAM's Pose3 Logmap returns the translation as is
_SERIES = 1e-4  # below this angle the trigonometric ratios use their Taylor series
# where [w]_x holds w: (2, 1), (0, 2), (1, 0); fancy indexing in place of nine stacked
# columns (skew of 9 vectors: 40 -> 10 us CPU, of 5000: 414 -> 56 us; the same entries)
_VEE_ROWS, _VEE_COLS = np.array([2, 0, 1]), np.array([1, 2, 0])
# rotations_to_quaternions' 4 x 4 products q_c q_d: the diagonal, and the pairs (x, y),
# (x, z), (x, w), (y, z), (y, w), (z, w) set by index in place of nested stacks (CPU, 11
# rotations: 181 -> 155 us, 5000: 1.19 -> 1.06 ms; the same numbers)
_DIAGONAL = np.arange(4)
_EYE = np.eye(3)
_PAIR_ROWS, _PAIR_COLS = np.array([0, 0, 0, 1, 1, 2]), np.array([1, 2, 3, 2, 3, 3])
# the pairs' entries of a flattened rotation: r01 + r10, r02 + r20, r21 - r12, r12 + r21,
# r02 - r20, r10 - r01
_PAIR_FIRST, _PAIR_SECOND = np.array([1, 2, 7, 5, 2, 3]), np.array([3, 6, 5, 7, 6, 1])
_PAIR_SIGNS = np.array([1.0, 1.0, -1.0, 1.0, -1.0, -1.0])
_DIAGONAL_9 = np.array([0, 4, 8])


def skew(w: np.ndarray) -> np.ndarray:
    """(k, 3, 3) skew-symmetric matrices ``[w]_x`` of (k, 3) vectors."""
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    k = np.zeros((len(w), 3, 3))
    k[:, _VEE_ROWS, _VEE_COLS] = w
    k[:, _VEE_COLS, _VEE_ROWS] = -w
    return k


def vee(k: np.ndarray) -> np.ndarray:
    """(k, 3) the vectors ``w`` of (k, 3, 3) matrices' entries ``(2, 1), (0, 2), (1, 0)``:
    :func:`skew`'s inverse on skew-symmetric matrices."""
    return k[:, _VEE_ROWS, _VEE_COLS]


def quaternions_to_rotations(q: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotation matrices of (k, 4) quaternions ``(qx, qy, qz, qw)`` (normalized
    here; the caller rejects zero or non-finite ones)."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1)[:, None]
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotations_to_quaternions(rotations: np.ndarray) -> np.ndarray:
    """(k, 4) unit quaternions ``(qx, qy, qz, qw)`` with ``qw >= 0`` of (k, 3, 3) rotations
    (Shepperd's method: the largest of the four squared components is taken first, so it is
    stable at every angle, pi included). The entries are gathered by index, a few array
    operations in all (11 rotations: 150 -> 70 us CPU; the same numbers)."""
    r = np.asarray(rotations, dtype=float).reshape(-1, 9)
    diagonal = r[:, _DIAGONAL_9]
    trace = diagonal[:, 0] + diagonal[:, 1] + diagonal[:, 2]
    # 4 q_c^2 for c = x, y, z, w
    squares = np.empty((len(r), 4))
    squares[:, :3] = 1 + 2 * diagonal - trace[:, None]
    squares[:, 3] = 1 + trace
    pick = np.argmax(squares, axis=1)
    rows = np.arange(len(r))
    big = np.sqrt(np.maximum(squares[rows, pick], 0.0))  # 2 |q_pick|
    # the off-diagonal sums and differences, 4 q_a q_b for each pair: xy, xz, xw, yz, yw, zw
    pairs = r[:, _PAIR_FIRST] + _PAIR_SIGNS * r[:, _PAIR_SECOND]
    products = np.empty((len(r), 4, 4))  # row c: 4 q_c q_(x, y, z, w)
    products[:, _DIAGONAL, _DIAGONAL] = (big * big)[:, None]
    products[:, _PAIR_ROWS, _PAIR_COLS] = pairs
    products[:, _PAIR_COLS, _PAIR_ROWS] = pairs
    q = products[rows, pick] / (2.0 * np.where(big > 0, big, 1.0))[:, None]
    q /= np.sqrt(np.add.reduce(q * q, axis=1))[:, None]  # np.linalg.norm's arithmetic
    return np.where(q[:, 3:4] < 0, -q, q)


def exp_so3(w: np.ndarray) -> np.ndarray:
    """(k, 3, 3) ``Exp(w)`` of (k, 3) rotation vectors (Rodrigues; series near 0). The series
    are evaluated only where an angle lies in (0, :data:`_SERIES`): a zero angle's ``[w]_x``
    is 0, so any finite ratios give its ``I`` (the same numbers as series everywhere: the
    Newton steps of 9 poses, the anchor's zero, 91 -> 45 us CPU)."""
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    theta = np.sqrt(np.add.reduce(w * w, axis=1))  # np.linalg.norm's own arithmetic
    small = theta < _SERIES
    safe = theta + small  # 1 + theta where small: finite ratios, the series' place there
    a, b = np.sin(safe) / safe, (1 - np.cos(safe)) / (safe * safe)
    if theta[small].any():
        t2 = theta * theta
        a = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, a)
        b = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, b)
    k = skew(w)
    return _EYE + a[:, None, None] * k + b[:, None, None] * (k @ k)


def log_so3(rotations: np.ndarray) -> np.ndarray:
    """(k, 3) ``Log(R)`` of (k, 3, 3) rotations, angles in [0, pi] (through the quaternion:
    ``theta = 2 atan2(|v|, w)``, stable near 0 and near pi)."""
    q = rotations_to_quaternions(rotations)
    v, w = q[:, :3], q[:, 3]
    norm_v = np.sqrt(np.add.reduce(v * v, axis=1))  # np.linalg.norm's arithmetic
    theta = 2.0 * np.arctan2(norm_v, w)
    # theta / |v|, or its series 2 / w (1 - |v|^2 / (3 w^2)) where |v| is tiny
    small = norm_v < 1e-8
    if small.any():
        scale = np.where(small, 2.0 / np.where(w > 0, w, 1.0) * (1 - norm_v ** 2 / 3.0),
                         theta / np.where(small, 1.0, norm_v))
    else:
        scale = theta / norm_v
    return scale[:, None] * v


def rotation_angles(rotations: np.ndarray) -> np.ndarray:
    """(k,) angles in [0, pi] of (k, 3, 3) rotations: ``|Log(R)|``."""
    return np.linalg.norm(log_so3(rotations), axis=1)


def pose_matrices(rotations: np.ndarray, translations: np.ndarray) -> np.ndarray:
    """(n, 3, 4) ``[R | t]`` of each pose: the packed form of a 3D graph's poses."""
    return np.concatenate([rotations, translations[:, :, None]], axis=2)


def compose(r_a: np.ndarray, t_a: np.ndarray, r_b: np.ndarray,
            t_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a * b`` of poses given as rotations (k, 3, 3) and translations (k, 3)."""
    return r_a @ r_b, t_a + np.einsum("kab,kb->ka", r_a, t_b)


def inverse(r: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a^-1``: ``(R^T, -R^T t)``."""
    r_t = np.transpose(r, (0, 2, 1))
    return r_t, -np.einsum("kab,kb->ka", r_t, t)


def between(r_a: np.ndarray, t_a: np.ndarray, r_b: np.ndarray,
            t_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a^-1 * b``: ``(R_a^T R_b, R_a^T (t_b - t_a))``."""
    r_t = np.transpose(r_a, (0, 2, 1))
    return r_t @ r_b, np.einsum("kab,kb->ka", r_t, t_b - t_a)


def inverse_left_jacobians(w: np.ndarray) -> np.ndarray:
    """(k, 3, 3) the matrices ``V(w)^-1`` with which GTSAM's Pose3 Logmap turns a translation
    into its tangent part: ``I - W / 2 + c W^2``, ``W = [w]_x``,
    ``c = (1 - (theta / 2) / tan(theta / 2)) / theta^2`` (series near 0)."""
    w = np.asarray(w, dtype=float).reshape(-1, 3)
    theta = np.sqrt(np.add.reduce(w * w, axis=1))  # np.linalg.norm's arithmetic
    small = theta < _SERIES
    safe = theta + small  # 1 + theta where small: a finite ratio, the series' place there
    half = 0.5 * safe
    c = (1.0 - half / np.tan(half)) / (safe * safe)
    if small.any():
        c = np.where(small, 1.0 / 12.0 + theta * theta / 720.0, c)
    k = skew(w)
    result = _EYE - 0.5 * k + c[:, None, None] * (k @ k)
    result[theta < _SMALL] = _EYE  # GTSAM returns the translation as is there
    return result


def logmap(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(k, 6) GTSAM's ``Pose3.Logmap`` of poses (rotation first): ``(w, V(w)^-1 t)`` with
    ``w = Log(R)``."""
    w = log_so3(r)
    return np.hstack([w, np.einsum("kab,kb->ka", inverse_left_jacobians(w), t)])


def adjoint(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(k, 6, 6) GTSAM's Pose3 adjoint maps (rotation first): ``[[R, 0], [[t]_x R, R]]``,
    so that ``X Exp(d) X^-1 = Exp(Ad(X) d)``."""
    result = np.zeros((len(r), 6, 6))
    result[:, :3, :3] = result[:, 3:, 3:] = r
    result[:, 3:, :3] = skew(t) @ r
    return result


def project_to_so3(matrices: np.ndarray) -> np.ndarray:
    """(k, 3, 3) the nearest rotations (Frobenius norm) to (k, 3, 3) matrices: ``U D V^T``
    from the SVD, with ``D = diag(1, 1, det(U V^T))`` fixing the sign."""
    u, _, vt = np.linalg.svd(np.asarray(matrices, dtype=float).reshape(-1, 3, 3))
    rotations = u @ vt
    sign = np.sign(np.linalg.det(rotations))
    if (sign > 0).all():
        return rotations  # no sign to fix: the product below, unchanged
    u[:, :, 2] *= np.where(sign == 0, 1.0, sign)[:, None]
    return u @ vt
