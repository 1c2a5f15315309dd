"""A GTSAM pipeline bootstrapped by RL-PGO: build a graph in code, initialize, optimize.

    python examples/gtsam_pipeline.py

Builds a 300-pose lawn-mower graph with GTSAM factors (the project's generator, noisy
measurements), asks the shipped agent for an initial guess (starting from the chordal
rotations), and runs GTSAM's Levenberg-Marquardt from it and from the raw odometry.
"""

import gtsam
import numpy as np

from rlpgo_gtsam import RLInitializer, chi2, generate

sample = generate(300, sigma_r=0.3, sigma_t=0.05, d=3.0, lc=0.5,
                  rng=np.random.default_rng(7), noisy_measurements=True)
graph, odometry = sample.graph, sample.initial  # a gtsam.NonlinearFactorGraph and Values

initial = RLInitializer(model="preset1", start="chordal").initialize(graph, odometry)

anchored = gtsam.NonlinearFactorGraph(graph)
anchor_noise = gtsam.noiseModel.Isotropic.Sigma(3, 1e-8)
anchored.add(gtsam.PriorFactorPose2(0, odometry.atPose2(0), anchor_noise))
params = gtsam.LevenbergMarquardtParams()
params.setMaxIterations(30)
for label, start in [("odometry", odometry), ("RL-PGO", initial)]:
    result = gtsam.LevenbergMarquardtOptimizer(anchored, start, params).optimize()
    print(f"{label:>9}: initial chi2 {chi2(graph, start):12.4g}"
          f"   after LM30 {chi2(graph, result):10.4g}")
