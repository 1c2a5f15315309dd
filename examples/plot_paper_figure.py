"""Ground truth, initial guess, RL and RL+GN50 side by side, in the style of the paper's figures.

    python examples/plot_paper_figure.py [OUT.png]

A 300-pose graph of the paper's sigma_t sweep (sigma_R 0.3, sigma_t 0.05, d 3, exact
measurements), the shipped preset-2 agent from odometry, then GTSAM Gauss-Newton. The PNG
goes to OUT.png, by default to a new temporary folder.
"""

import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # a script may choose the backend; the library never does
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from rlpgo_gtsam import RLInitializer, chi2, generate, refine  # noqa: E402

if len(sys.argv) > 1:
    out = sys.argv[1]
else:
    out = str(Path(tempfile.mkdtemp(prefix="rlpgo_")) / "paper_figure.png")
sample = generate(300, 0.3, 0.05, 3.0, 0.5, np.random.default_rng(3))
graph = sample.graph
rl = RLInitializer(model="preset2", episodes=4).initialize(graph, sample.initial)
panels = [
    ("ground truth", sample.ground_truth, "green"),
    ("initial guess", sample.initial, "red"),
    ("RL", rl, "black"),
    ("RL+GN50", refine(graph, rl, "gn", 50).values, "magenta"),
]
figure, axes = plt.subplots(1, 4, figsize=(14, 3.8))
for axis, (label, values, color) in zip(axes, panels, strict=True):
    xy = np.array([[values.atPose2(k).x(), values.atPose2(k).y()] for k in range(values.size())])
    axis.plot(xy[:, 0], xy[:, 1], color=color, linewidth=1.0, marker=".", markersize=2)
    axis.set_title(f"{label}\nchi2 {chi2(graph, values):.3g}", fontsize=9)
    axis.set_aspect("equal", adjustable="datalim")
    axis.tick_params(labelsize=7)
figure.tight_layout()
figure.savefig(out, dpi=120)
print(f"wrote {out}")
