"""Matplotlib figures of planar trajectories and training curves, rendered to PNG bytes.

Figures are made with :class:`matplotlib.figure.Figure` directly, not through pyplot: no
backend is chosen and no global figure state is touched, so importing this module changes
nothing for a caller's own plots. The caller writes the bytes (atomically).
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import gtsam
import numpy as np
from matplotlib.figure import Figure

from rlpgo_gtsam.graph import PoseGraph2D, odometry_edges

__all__ = ["Panel", "plot_trajectories", "plot_training_curve"]


def _xy(values: gtsam.Values) -> np.ndarray:
    keys = sorted(values.keys())
    return np.array([[values.atPose2(k).x(), values.atPose2(k).y()] for k in keys])


def _png(figure: Figure, dpi: int) -> bytes:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


@dataclass(frozen=True)
class Panel:
    """One trajectory to draw.

    Attributes:
        label: what it is (``"initial guess"``, ``"certified + LM30"``).
        values: its poses.
        chi2: its g2o chi2 (2 x GTSAM error), shown under the label; None: not shown.
        best: marked as the lowest chi2 (several panels may be: a tie).
    """

    label: str
    values: gtsam.Values
    chi2: float | None = None
    best: bool = False


_COLUMNS = 4
_BEST_COLOUR = "tab:green"


def plot_trajectories(pose_graph: PoseGraph2D, panels: list[Panel], title: str = "") -> bytes:
    """A PNG with a grid of panels (four a row), one per :class:`Panel`: the trajectory in
    metres, the loop closures (edges other than odometry, :func:`~rlpgo_gtsam.graph.
    odometry_edges`) in grey, the chi2 in the panel's title, the best panels framed and
    titled in green. A panel whose poses are not finite (or too far out to draw) says so
    instead of drawing."""
    columns = min(_COLUMNS, len(panels))
    rows = -(-len(panels) // columns)
    figure = Figure(figsize=(3.6 * columns, 3.6 * rows + 0.6))
    axes = figure.subplots(rows, columns, squeeze=False)
    closures = pose_graph.edges[~odometry_edges(pose_graph)]
    handles = {}
    for axis, panel in zip(axes.ravel(), panels, strict=False):
        xy = _xy(panel.values)
        heading = panel.label
        if panel.chi2 is not None:
            heading += f"\nchi2 = {panel.chi2:.6g}"
        if panel.best:
            heading += "  (best)"
        axis.set_title(heading, fontsize=9, color=_BEST_COLOUR if panel.best else "black")
        axis.set_xlabel("x [m]", fontsize=8)
        axis.set_ylabel("y [m]", fontsize=8)
        axis.tick_params(labelsize=7)
        axis.grid(True, linewidth=0.3, alpha=0.5)
        if panel.best:
            for spine in axis.spines.values():
                spine.set_edgecolor(_BEST_COLOUR)
                spine.set_linewidth(2.0)
        if not _drawable(xy):
            axis.text(0.5, 0.5, "poses not finite\n(not drawn)", ha="center", va="center",
                      transform=axis.transAxes, fontsize=9)
            continue
        if len(closures):
            segments = np.stack([xy[closures[:, 0]], xy[closures[:, 1]]], axis=1)
            xs = np.column_stack([segments[:, :, 0], np.full(len(segments), np.nan)]).ravel()
            ys = np.column_stack([segments[:, :, 1], np.full(len(segments), np.nan)]).ravel()
            handles["loop closures"] = axis.plot(xs, ys, color="0.75", linewidth=0.4)[0]
        handles["trajectory (poses in key order)"] = axis.plot(xy[:, 0], xy[:, 1],
                                                               linewidth=0.8)[0]
        axis.set_aspect("equal", adjustable="datalim")
    for axis in axes.ravel()[len(panels):]:
        axis.set_visible(False)
    if handles:
        figure.legend(list(handles.values()), list(handles), loc="lower center",
                      ncol=len(handles), fontsize=8, frameon=False)
    if title:
        figure.suptitle(title)
    figure.tight_layout(rect=(0.0, 0.05 if handles else 0.0, 1.0, 1.0))
    return _png(figure, 110)


def _drawable(xy: np.ndarray) -> bool:
    """Finite, and small enough that matplotlib's limits (span x margins) stay finite."""
    if not len(xy) or not np.all(np.isfinite(xy)):
        return False
    return bool(np.max(np.abs(xy)) < 1e150)


def plot_training_curve(rows: list[dict], title: str = "") -> bytes:
    """Training progress: each episode's reward (and its moving mean), and how far each
    episode brought the orientation cost down, against episodes.

    OC, the orientation cost of the RL-PGO paper, is the square root of the summed chordal
    rotation errors over all edges, ``sqrt(sum ||R_i R~_ij - R_j||_F^2)``; the right panel
    shows the lowest OC an episode reached over its starting OC (lower is better, 1: no
    gain), which the figure says in words under its panels.
    """
    episodes = np.array([int(r["episode"]) for r in rows])
    rewards = np.array([float(r["reward"]) for r in rows])
    ratio = np.array([float(r["best_oc"]) / max(float(r["initial_oc"]), 1e-12) for r in rows])
    window = min(20, len(rows))
    figure = Figure(figsize=(10, 4.2))
    left, right = figure.subplots(1, 2)
    for axis, values, label in ((left, rewards, "episode reward (paper's OC-based reward)"),
                                (right, ratio, "best OC / starting OC (lower is better)")):
        axis.plot(episodes, values, color="0.7", linewidth=0.6, label="each episode")
        axis.plot(episodes[window - 1:], np.convolve(values, np.ones(window) / window, "valid"),
                  linewidth=1.4, label=f"mean of the last {window}")
        axis.set_xlabel("episode")
        axis.set_ylabel(label)
        axis.grid(True, linewidth=0.3, alpha=0.5)
        axis.legend(fontsize=8)
    right.axhline(1.0, color="0.4", linewidth=0.6, linestyle="--")
    figure.text(0.5, 0.01, "OC: orientation cost, the square root of the summed chordal "
                "rotation errors over all edges (the RL-PGO paper's measure).",
                ha="center", fontsize=8)
    if title:
        figure.suptitle(title)
    figure.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
    return _png(figure, 110)
