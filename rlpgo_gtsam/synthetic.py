"""The RL-PGO paper's synthetic pose graphs: a lawn-mower path with vertical loop closures.

Poses run in rows of ten, ``d`` metres apart, rows ``d`` apart, alternating direction; the
motion into the last pose of a row and the one into the first pose of the next each end
with a 90-degree turn. Loop-closure candidates join each pose of a row to the pose right
below it in the previous row (the row's last, turning pose excluded), plus one candidate
between the last two poses, as the paper's code enumerates them; ``int(lc * candidates)``
of them are drawn without replacement. With n = 20, lc = 0.5 this gives 24 edges, with
n = 300 it gives 430, the counts of the paper's graphs.

By default every measurement is exact (the ground truth is the optimum, chi2 = 0) and only
the initial guess is noisy: dead reckoning of the motions, each perturbed by
``Exp([N(0, sigma_t), N(0, sigma_t), N(0, sigma_R)])``, as in the paper's tables. With
``noisy_measurements=True`` every measurement is perturbed that way instead and the initial
guess chains the noisy odometry: graphs whose optimum is not the ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from rlpgo_gtsam.errors import RlpgoError

__all__ = ["SyntheticGraph", "generate", "ROW_LENGTH"]

ROW_LENGTH = 10


@dataclass
class SyntheticGraph:
    """A generated graph: factors, the noisy initial guess and the ground truth, all GTSAM."""

    graph: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    ground_truth: gtsam.Values


def _true_poses(n: int, d: float) -> list[gtsam.Pose2]:
    poses = []
    for k in range(n):
        row, col = divmod(k, ROW_LENGTH)
        x = col if row % 2 == 0 else ROW_LENGTH - 1 - col
        heading = 0.0 if row % 2 == 0 else np.pi
        if col == ROW_LENGTH - 1:  # the turning pose at the end of a row
            heading = np.pi / 2
        poses.append(gtsam.Pose2(x * d, row * d, heading))
    return poses


def _candidates(n: int) -> list[tuple[int, int]]:
    pairs = []
    for k in range(ROW_LENGTH, n):
        col = k % ROW_LENGTH
        if col != ROW_LENGTH - 1:
            pairs.append((k, k - (2 * col + 1)))
    if n >= 2:
        pairs.append((n - 1, n - 2))
    return pairs


def _perturb(pose: gtsam.Pose2, sigma_r: float, sigma_t: float, rng: np.random.Generator):
    noise = rng.normal(0.0, [sigma_t, sigma_t, sigma_r])
    return pose.compose(gtsam.Pose2.Expmap(noise))


def generate(
    n: int,
    sigma_r: float,
    sigma_t: float,
    d: float,
    lc: float,
    rng: np.random.Generator,
    noisy_measurements: bool = False,
) -> SyntheticGraph:
    """Generate one lawn-mower pose graph.

    Args:
        n: number of poses (>= 2).
        sigma_r: rotation noise, radians (> 0).
        sigma_t: translation noise per axis, metres (> 0).
        d: spacing between neighbouring poses and between rows, metres (> 0).
        lc: fraction of the loop-closure candidates to keep, in [0, 1].
        rng: the only source of randomness.
        noisy_measurements: perturb the measurements too (the ground truth is then not the
            optimum); by default measurements are exact and only the initial guess is noisy.
    """
    if n < 2:
        raise RlpgoError(f"a graph needs at least 2 poses, got n={n}")
    if sigma_r <= 0 or sigma_t <= 0 or d <= 0:
        raise RlpgoError("sigma_r, sigma_t and d must be positive")
    if not 0.0 <= lc <= 1.0:
        raise RlpgoError(f"lc must lie in [0, 1], got {lc}")
    truth = _true_poses(n, d)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_t, sigma_t, sigma_r]))
    odometry = [truth[k].between(truth[k + 1]) for k in range(n - 1)]
    candidates = _candidates(n)
    count = int(lc * len(candidates))
    chosen = sorted(rng.choice(len(candidates), size=count, replace=False)) if count else []
    closures = [candidates[c] for c in chosen]

    def measure(between: gtsam.Pose2) -> gtsam.Pose2:
        return _perturb(between, sigma_r, sigma_t, rng) if noisy_measurements else between

    graph = gtsam.NonlinearFactorGraph()
    measured_odometry = []
    for k, between in enumerate(odometry):
        measured = measure(between)
        measured_odometry.append(measured)
        graph.add(gtsam.BetweenFactorPose2(k, k + 1, measured, noise))
    for i, j in closures:
        graph.add(gtsam.BetweenFactorPose2(i, j, measure(truth[i].between(truth[j])), noise))

    initial, ground_truth = gtsam.Values(), gtsam.Values()
    pose = truth[0]
    initial.insert(0, pose)
    for k, measured in enumerate(measured_odometry):
        step = measured if noisy_measurements else _perturb(measured, sigma_r, sigma_t, rng)
        pose = pose.compose(step)
        initial.insert(k + 1, pose)
    for k, true_pose in enumerate(truth):
        ground_truth.insert(k, true_pose)
    return SyntheticGraph(graph, initial, ground_truth)
