"""Matplotlib figures of planar trajectories and training curves, rendered to PNG bytes.

Figures are made with :class:`matplotlib.figure.Figure` directly, not through pyplot: no
backend is chosen and no global figure state is touched, so importing this module changes
nothing for a caller's own plots. The caller writes the bytes (atomically).
"""

from __future__ import annotations

import io

import gtsam
import numpy as np
from matplotlib.figure import Figure

from rlpgo_gtsam.graph import PoseGraph2D, odometry_edges

__all__ = ["plot_trajectories", "plot_training_curve"]


def _xy(values: gtsam.Values) -> np.ndarray:
    keys = sorted(values.keys())
    return np.array([[values.atPose2(k).x(), values.atPose2(k).y()] for k in keys])


def _png(figure: Figure, dpi: int) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def plot_trajectories(
    pose_graph: PoseGraph2D,
    panels: list[tuple[str, gtsam.Values]],
    title: str = "",
) -> bytes:
    """A PNG with a panel per (label, values): loop closures in grey, the trajectory on top."""
    figure = Figure(figsize=(4 * len(panels), 4))
    axes = figure.subplots(1, len(panels), squeeze=False)
    closures = pose_graph.edges[~odometry_edges(pose_graph)]
    for axis, (label, values) in zip(axes[0], panels, strict=True):
        xy = _xy(values)
        for i, j in closures:
            axis.plot(xy[[i, j], 0], xy[[i, j], 1], color="0.8", linewidth=0.3)
        axis.plot(xy[:, 0], xy[:, 1], linewidth=0.7)
        axis.set_title(label, fontsize=9)
        axis.set_aspect("equal", adjustable="datalim")
        axis.tick_params(labelsize=7)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return _png(figure, 120)


def plot_training_curve(rows: list[dict], title: str = "") -> bytes:
    """Episode reward (and its 20-episode mean) and best/initial OC against episodes."""
    episodes = np.array([int(r["episode"]) for r in rows])
    rewards = np.array([float(r["reward"]) for r in rows])
    ratio = np.array([float(r["best_oc"]) / max(float(r["initial_oc"]), 1e-12) for r in rows])
    window = min(20, len(rows))
    smooth = np.convolve(rewards, np.ones(window) / window, mode="valid")
    figure = Figure(figsize=(9, 3.5))
    left, right = figure.subplots(1, 2)
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
    return _png(figure, 110)
