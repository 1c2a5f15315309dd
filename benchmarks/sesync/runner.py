"""Run the SE-Sync driver (``sesync_rounded``: ``benchmarks/sesync/sesync_rounded.cpp`` built
with SE-Sync) on a planar or 3D g2o file and read its result back.

SE-Sync (Rosen, Carlone, Bandeira, Leonard, IJRR 2019) is the project's certified anchor:
when it certifies, its rounded estimate is the global optimum of *its* cost (isotropic
translational weights, chordal rotation distance), not of g2o's chi2; LM from it is what the
benchmarks compare against. The binary is optional: nothing in the package needs it.

    from benchmarks.sesync.runner import run_sesync
    run = run_sesync("/work/sesync-build/build/bin/sesync_rounded", "M3500A.g2o")
    run.certified, run.suboptimality_bound, run.poses   # poses: (n, 3) x y theta
    values = to_values(run.ids, run.poses)              # gtsam.Values of Pose2 / Pose3

The poses come in the order of the file's sorted vertex ids (``run.ids``), moved by one
rigid transform so that the first of them equals the file's first vertex (its
``VERTEX_SE2`` / ``VERTEX_SE3:QUAT`` line; the origin if the file has none): SE-Sync returns
its estimate in an arbitrary gauge. ``run.raw_poses`` is the estimate as SE-Sync returned it.
A 3D file's poses (``run.dim == 3``) are (n, 3, 4) matrices ``[R | t]``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["SesyncRun", "run_sesync", "default_binary", "reanchor", "reanchor3d",
           "record_poses", "to_values", "BINARY_ENV", "THREAD_VARIABLES"]

BINARY_ENV = "RLPGO_SESYNC_BINARY"
"""Environment variable naming the ``sesync_rounded`` binary (see :func:`default_binary`)."""


@dataclass
class SesyncRun:
    """One SE-Sync run on one g2o file.

    Attributes:
        seconds: wall time of the whole ``SESync::SESync(measurements, options)`` call as the
            driver timed it (problem construction included, file reading and the driver's
            own eigenvalue check excluded).
        certified: the rounded estimate is a certified global optimum of SE-Sync's cost:
            SE-Sync's verification passed and its suboptimality bound is 0 (up to
            1e-6 x max(1, |lower_bound|)). False on M3500C: there the relaxation is solved
            (``verification_passed``) but not tight (bound 679).
        min_eigenvalue: smallest eigenvalue of that certificate matrix, computed by the
            driver after the timed call (about 0 when certified, negative when not).
        objective: SE-Sync's cost of its rounded estimate, F(xhat).
        lower_bound: tr(Lambda), the dual value: a lower bound on the optimum of SE-Sync's
            cost when the certificate is PSD.
        suboptimality_bound: objective - lower_bound (SE-Sync's bound; about 0 when certified).
        rank: final level of the Riemannian staircase.
        poses: re-anchored estimate (see the module docstring): (n, 3) x, y, theta in 2D,
            (n, 3, 4) ``[R | t]`` in 3D.
        ids: the file's vertex ids, sorted; row k of ``poses`` is vertex ``ids[k]``.
        verification_passed: SE-Sync's test passed (status ``GlobalOpt``): the certificate
            matrix at the final rank is PSD up to SE-Sync's tolerance eta = 1e-3, i.e. the
            staircase solved the semidefinite relaxation.
        status: SE-Sync's termination status (GlobalOpt, SaddlePoint, EigImprecision,
            MaxRank, ElapsedTime).
        sdp_value: F(Y'Y), the relaxation's value at SE-Sync's solution.
        sesync_seconds: SE-Sync's own total_computation_time (problem construction excluded).
        raw_poses: the rounded estimate in SE-Sync's own gauge, shaped like ``poses``.
        record: the driver's whole JSON record, poses and ids left out.
        dim: 2 or 3.
    """

    seconds: float
    certified: bool
    min_eigenvalue: float
    objective: float
    lower_bound: float
    suboptimality_bound: float
    rank: int
    poses: np.ndarray
    ids: np.ndarray
    verification_passed: bool
    status: str
    sdp_value: float
    sesync_seconds: float
    raw_poses: np.ndarray
    record: dict
    dim: int


def default_binary() -> Path | None:
    """The binary named by ``$RLPGO_SESYNC_BINARY`` if that file exists, else None."""
    name = os.environ.get(BINARY_ENV)
    if name and Path(name).is_file():
        return Path(name)
    return None


THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
"""The BLAS / OpenMP thread variables that ``threads`` sets for a run."""


def run_sesync(binary: str | os.PathLike[str], g2o_path: str | os.PathLike[str],
               timeout: float | None = None, threads: int | None = 1) -> SesyncRun:
    """Run ``binary`` (the ``sesync_rounded`` driver) on ``g2o_path`` in a temporary
    directory and parse its record.

    Args:
        timeout: seconds before the run is abandoned (None: no limit).
        threads: BLAS / OpenMP threads of the run (OPENBLAS_NUM_THREADS, OMP_NUM_THREADS,
            MKL_NUM_THREADS); None keeps the caller's environment. SE-Sync itself runs one
            OpenMP thread; left to itself OpenBLAS starts one thread per core inside
            CHOLMOD's factorizations, which on a loaded 2-core machine made the timed call
            up to 10x slower (City10K: 16 s instead of 1.5 s).

    Raises:
        RuntimeError: one line: the binary or the file is missing, the driver failed (its
            own message), timed out, or wrote a record that does not fit the file.
    """
    binary = Path(binary).expanduser()
    g2o_path = Path(g2o_path).expanduser()
    if not binary.is_file():
        raise RuntimeError(f"SE-Sync binary not found: {binary}")
    if not os.access(binary, os.X_OK):
        raise RuntimeError(f"SE-Sync binary is not executable: {binary}")
    if not g2o_path.is_file():
        raise RuntimeError(f"g2o file not found: {g2o_path}")
    first_vertex = _first_vertex(g2o_path)
    with tempfile.TemporaryDirectory(prefix="sesync_") as tmp:
        out = Path(tmp) / "result.json"
        env = dict(os.environ)
        if threads is not None:
            env.update({name: str(int(threads)) for name in THREAD_VARIABLES})
        try:
            proc = subprocess.run([str(binary.resolve()), str(g2o_path.resolve()), str(out)],
                                  cwd=tmp, env=env, capture_output=True, text=True,
                                  timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            raise RuntimeError(f"SE-Sync timed out after {timeout} s on {g2o_path}") from None
        except OSError as error:
            raise RuntimeError(f"cannot run SE-Sync binary {binary}: {_one_line(error)}") from None
        if proc.returncode != 0:
            message = _last_line(proc.stderr) or _last_line(proc.stdout) or "no message"
            raise RuntimeError(
                f"SE-Sync failed on {g2o_path} (exit status {proc.returncode}): {message}")
        try:
            record = json.loads(out.read_text())
        except (OSError, ValueError) as error:
            raise RuntimeError(
                f"SE-Sync wrote no readable record for {g2o_path}: {_one_line(error)}") from None
    return _parse_record(record, g2o_path, first_vertex)


def _parse_record(record: dict, g2o_path: Path,
                  first_vertex: tuple[int, np.ndarray] | None) -> SesyncRun:
    try:
        raw = record_poses(record)
        ids = np.asarray(record["ids"], dtype=np.int64)
        n = int(record["num_poses"])

        def number(key: str) -> float:
            value = record[key]
            return math.nan if value is None else float(value)

        run = SesyncRun(
            seconds=number("seconds"),
            certified=bool(record["certified"]),
            min_eigenvalue=number("min_eigenvalue"),
            objective=number("objective"),
            lower_bound=number("lower_bound"),
            suboptimality_bound=number("suboptimality_bound"),
            rank=int(record["rank"]),
            poses=raw,  # replaced below
            ids=ids,
            verification_passed=bool(record["verification_passed"]),
            status=str(record["status"]),
            sdp_value=number("sdp_value"),
            sesync_seconds=number("sesync_reported_seconds"),
            raw_poses=raw,
            record={k: v for k, v in record.items() if k not in ("poses", "ids")},
            dim=int(record.get("dim", 2)),
        )
    except (KeyError, TypeError, ValueError) as error:
        raise RuntimeError(
            f"SE-Sync record for {g2o_path} is malformed: {_one_line(error)}") from None
    if len(raw) != n or len(ids) != n or n == 0:
        raise RuntimeError(f"SE-Sync record for {g2o_path} holds {len(raw)} poses and "
                           f"{len(ids)} ids for {n} poses")
    if not np.all(np.isfinite(raw)):
        raise RuntimeError(f"SE-Sync returned non-finite poses for {g2o_path}")
    if first_vertex is not None and first_vertex[0] != int(ids[0]):
        raise RuntimeError(f"SE-Sync's first pose is vertex {int(ids[0])}, the file's first "
                           f"vertex is {first_vertex[0]} ({g2o_path})")
    if first_vertex is not None and first_vertex[1].shape != raw.shape[1:]:
        raise RuntimeError(f"SE-Sync's record is {run.dim}D, the file's first vertex is not "
                           f"({g2o_path})")
    if run.dim == 3:
        anchor3d = np.eye(3, 4) if first_vertex is None else first_vertex[1]
        run.poses = reanchor3d(raw, anchor3d)
    else:
        anchor = (0.0, 0.0, 0.0) if first_vertex is None else tuple(first_vertex[1])
        run.poses = reanchor(raw, anchor)
    return run


def record_poses(record: dict) -> np.ndarray:
    """The poses of a driver record as written, in SE-Sync's gauge: (n, 3) x, y, theta when
    its ``dim`` is 2 (or absent), (n, 3, 4) ``[R | t]`` when it is 3 (the record's rows are
    ``x y z r11 r12 r13 r21 ... r33``)."""
    dim = int(record.get("dim", 2))
    if dim == 2:
        return np.asarray(record["poses"], dtype=float).reshape(-1, 3)
    if dim != 3:
        raise ValueError(f"dim {dim} is neither 2 nor 3")
    rows = np.asarray(record["poses"], dtype=float).reshape(-1, 12)
    return np.concatenate([rows[:, 3:].reshape(-1, 3, 3), rows[:, :3, None]], axis=2)


def reanchor(poses: np.ndarray, anchor: tuple[float, float, float]) -> np.ndarray:
    """Apply the one rigid transform T that maps ``poses[0]`` onto ``anchor`` to every pose:
    T = anchor * poses[0]^-1, pose_k -> T * pose_k (angles wrapped to (-pi, pi])."""
    poses = np.asarray(poses, dtype=float)
    x0, y0, th0 = poses[0]
    ax, ay, ath = anchor
    dth = ath - th0
    c, s = math.cos(dth), math.sin(dth)
    dx = poses[:, 0] - x0
    dy = poses[:, 1] - y0
    out = np.empty_like(poses)
    out[:, 0] = ax + c * dx - s * dy
    out[:, 1] = ay + s * dx + c * dy
    out[:, 2] = np.arctan2(np.sin(poses[:, 2] + dth), np.cos(poses[:, 2] + dth))
    out[0] = (ax, ay, math.atan2(math.sin(ath), math.cos(ath)))
    return out


def reanchor3d(poses: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """:func:`reanchor` in 3D: ``poses`` (n, 3, 4) and ``anchor`` (3, 4) matrices ``[R | t]``;
    T = anchor * poses[0]^-1, pose_k -> T * pose_k (``rlpgo_gtsam.se3``'s compose and
    inverse), so that pose 0 becomes the anchor."""
    from rlpgo_gtsam.se3 import compose, inverse

    poses = np.asarray(poses, dtype=float).reshape(-1, 3, 4)
    anchor = np.asarray(anchor, dtype=float).reshape(1, 3, 4)
    r, t = poses[:, :, :3], poses[:, :, 3]
    r_shift, t_shift = compose(anchor[:, :, :3], anchor[:, :, 3], *inverse(r[:1], t[:1]))
    r, t = compose(np.broadcast_to(r_shift, r.shape), np.broadcast_to(t_shift, t.shape), r, t)
    out = np.concatenate([r, t[:, :, None]], axis=2)
    out[0] = anchor[0]
    return out


def to_values(ids: np.ndarray, poses: np.ndarray):
    """``gtsam.Values`` keyed by ``ids`` holding ``poses`` (rows of :class:`SesyncRun`'s
    ``poses``): ``Pose2(x, y, theta)`` for (n, 3), ``Pose3(Rot3(R), t)`` for (n, 3, 4)."""
    import gtsam

    poses = np.asarray(poses, dtype=float)
    values = gtsam.Values()
    if poses.ndim == 3:
        for key, pose in zip(np.asarray(ids).tolist(), poses, strict=True):
            values.insert(int(key), gtsam.Pose3(gtsam.Rot3(pose[:, :3]), pose[:, 3]))
    else:
        for key, (x, y, theta) in zip(np.asarray(ids).tolist(), poses.tolist(), strict=True):
            values.insert(int(key), gtsam.Pose2(x, y, theta))
    return values


def _first_vertex(path: Path) -> tuple[int, np.ndarray] | None:
    """The vertex with the smallest id and its pose, or None if the file has none: a
    ``VERTEX_SE2`` as (3,) x, y, theta; a ``VERTEX_SE3:QUAT`` (x y z qx qy qz qw) as the
    (3, 4) matrix ``[R | t]``."""
    best: tuple[int, tuple[float, ...]] | None = None
    widths = {"VERTEX_SE2": 3, "VERTEX_SE3:QUAT": 7}  # numbers after the id
    try:
        with path.open("r", encoding="utf-8", errors="replace") as handle:
            for line in handle:
                tokens = line.split()
                width = widths.get(tokens[0], 0) if tokens else 0
                if width and len(tokens) >= 2 + width:
                    try:
                        key = int(tokens[1])
                        pose = tuple(float(v) for v in tokens[2:2 + width])
                    except ValueError:
                        continue  # the driver reports malformed lines itself
                    if best is None or key < best[0]:
                        best = (key, pose)
    except OSError as error:
        raise RuntimeError(f"cannot read {path}: {_one_line(error)}") from None
    if best is None:
        return None
    numbers = np.array(best[1])
    if len(numbers) == 3:
        return best[0], numbers
    from rlpgo_gtsam.se3 import quaternions_to_rotations

    rotation = quaternions_to_rotations(numbers[3:])[0]
    return best[0], np.concatenate([rotation, numbers[:3, None]], axis=1)


def _last_line(text: str | None) -> str:
    lines = [line.strip() for line in (text or "").splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _one_line(error: BaseException) -> str:
    return " ".join(str(error).split()) or type(error).__name__
