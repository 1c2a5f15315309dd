"""Matplotlib figures of planar trajectories."""

from __future__ import annotations

import os

import gtsam
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rlpgo_gtsam.graph import PoseGraph2D  # noqa: E402

__all__ = ["plot_trajectories"]


def _xy(values: gtsam.Values) -> np.ndarray:
    keys = sorted(values.keys())
    return np.array([[values.atPose2(k).x(), values.atPose2(k).y()] for k in keys])


def plot_trajectories(
    path: str | os.PathLike[str],
    graph: gtsam.NonlinearFactorGraph,
    panels: list[tuple[str, gtsam.Values]],
    title: str = "",
) -> None:
    """One PNG with a panel per (label, values): edges in grey, the trajectory on top."""
    pose_graph = PoseGraph2D.from_gtsam(graph, panels[0][1])
    figure, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 4), squeeze=False)
    for axis, (label, values) in zip(axes[0], panels, strict=True):
        xy = _xy(values)
        closures = pose_graph.edges[np.abs(pose_graph.edges[:, 1] - pose_graph.edges[:, 0]) != 1]
        for i, j in closures:
            axis.plot(xy[[i, j], 0], xy[[i, j], 1], color="0.8", linewidth=0.3)
        axis.plot(xy[:, 0], xy[:, 1], linewidth=0.7)
        axis.set_title(label, fontsize=9)
        axis.set_aspect("equal", adjustable="datalim")
        axis.tick_params(labelsize=7)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def plot_training_curve(path: str | os.PathLike[str], rows: list[dict], title: str = "") -> None:
    """Episode reward (and its 20-episode mean) and best/initial OC against episodes."""
    episodes = np.array([int(r["episode"]) for r in rows])
    rewards = np.array([float(r["reward"]) for r in rows])
    ratio = np.array([float(r["best_oc"]) / max(float(r["initial_oc"]), 1e-12) for r in rows])
    window = min(20, len(rows))
    smooth = np.convolve(rewards, np.ones(window) / window, mode="valid")
    figure, (left, right) = plt.subplots(1, 2, figsize=(9, 3.5))
    left.plot(episodes, rewards, color="0.7", linewidth=0.6)
    left.plot(episodes[window - 1:], smooth, linewidth=1.2)
    left.set_xlabel("episode")
    left.set_ylabel("episode reward")
    right.plot(episodes, ratio, color="0.7", linewidth=0.6)
    right.plot(episodes[window - 1:], np.convolve(ratio, np.ones(window) / window, "valid"))
    right.set_xlabel("episode")
    right.set_ylabel("best OC / initial OC")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
