"""The default path in a GTSAM pipeline: read a g2o file, initialize, optimize, write.

    python examples/gtsam_pipeline.py [-i INPUT.g2o] [-o OUTPUT.g2o] [-m MAXITER]

The shape of GTSAM's own ``Pose2SLAMExample_g2o.py`` and ``Pose3SLAMExample_g2o.py``, with
``rlpgo_gtsam.staged_initialize`` (the certified relaxation + LM: what ``rlpgo-init`` runs) in
place of the file's guess. A planar or a 3D file; the input defaults, as GTSAM's planar
example's does, to ``noisyToyGraph.txt`` of GTSAM's example data
(``rlpgo_gtsam.example_file``); the output to a file in a new temporary folder.
"""

import argparse
import tempfile
from pathlib import Path

import gtsam

import rlpgo_gtsam

parser = argparse.ArgumentParser(description="read -> initialize -> optimize -> write")
parser.add_argument("-i", "--input", default=None,
                    help="input file, g2o format [default: GTSAM's noisyToyGraph.txt]")
parser.add_argument("-o", "--output", default=None,
                    help="output file, g2o format [default: a file in a new temporary folder]")
parser.add_argument("-m", "--maxiter", type=int, default=100, help="LM iterations")
args = parser.parse_args()
g2o_file = args.input or rlpgo_gtsam.example_file("noisyToyGraph.txt")
output = args.output or str(Path(tempfile.mkdtemp(prefix="rlpgo_")) / "optimized.g2o")

# Read: a gtsam.NonlinearFactorGraph and gtsam.Values (file:line errors on a bad file).
graph, initial = rlpgo_gtsam.read_g2o(g2o_file)
is3D = rlpgo_gtsam.file_group(g2o_file).dimension == 3

# Initialize: the certified relaxation refined by LM (no search after a failed certificate;
# searches=rlpgo_gtsam.staged.SEARCHES adds them).
run = rlpgo_gtsam.staged_initialize(graph, initial)
print(f"initialized by {run.best.method}: certified {run.certified}, {run.seconds:.2f} s")

# Optimize with GTSAM, a prior on the first pose fixing the gauge (as GTSAM's examples do).
first = min(run.values.keys())
priors = gtsam.NonlinearFactorGraph(graph)
if is3D:
    prior_model = gtsam.noiseModel.Diagonal.Variances([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    priors.add(gtsam.PriorFactorPose3(first, run.values.atPose3(first), prior_model))
else:
    prior_model = gtsam.noiseModel.Diagonal.Variances(gtsam.Point3(1e-6, 1e-6, 1e-8))
    priors.add(gtsam.PriorFactorPose2(first, run.values.atPose2(first), prior_model))
params = gtsam.LevenbergMarquardtParams()
params.setMaxIterations(args.maxiter)
result = gtsam.LevenbergMarquardtOptimizer(priors, run.values, params).optimize()

print(f"initial error = {graph.error(initial):.6g}")     # GTSAM error; g2o chi2 is twice it
print(f"initialized error = {graph.error(run.values):.6g}")
print(f"final error = {graph.error(result):.6g}")

# Write.
rlpgo_gtsam.write_g2o(output, graph, result)
print(f"wrote {output}")
