"""GTSAM LM30 from SE-Sync's rounded estimate, as a process of its own: the second half of
the baseline that ``benchmarks/process.py`` times (the first is
the ``sesync_rounded`` driver).

    python benchmarks/sesync/lm30.py INPUT.g2o SESYNC.json OUTPUT.g2o

What a GTSAM user would write after SE-Sync: read INPUT.g2o with ``gtsam.readG2o`` (a 3D
file, ``EDGE_SE3:QUAT``, when the record's ``dim`` is 3), take SE-Sync's poses from the
driver's JSON record (moved by one rigid transform onto the file's first vertex: SE-Sync's
gauge is arbitrary), run GTSAM's Levenberg-Marquardt with the settings ``rlpgo-init``
refines with (``rlpgo_gtsam.solvers.solver_params("lm", 30)``: 30 iterations, tolerances
1e-10, damping at most 1e5; when the file has no prior, a prior of sigma 1e-8 on the first
pose, ``Pose2`` or ``Pose3``, as ``refine`` adds), write the graph with the result through
``gtsam.writeG2o`` (GTSAM's writer: 6 significant digits, faster than ours). Prints one JSON
line: ``chi2`` (2 x GTSAM error of the file's graph at the result, computed before writing,
so not rounded by the writer), LM's iterations, and the seconds of each step.
"""

import time

STARTED = time.monotonic()

import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from benchmarks.sesync.runner import reanchor, reanchor3d, record_poses, to_values  # noqa: E402
from rlpgo_gtsam.solvers import _ANCHOR_SIGMA, solver_params  # noqa: E402  (one definition)


def main(input_path: str, record_path: str, output_path: str) -> dict:
    seconds = {"import": time.monotonic() - STARTED}
    began = time.monotonic()
    record = json.loads(Path(record_path).read_text())
    is3d = int(record.get("dim", 2)) == 3
    graph, initial = gtsam.readG2o(input_path, is3d)
    seconds["read"] = time.monotonic() - began
    began = time.monotonic()
    first = min(initial.keys())
    ids = np.asarray(record["ids"], dtype=np.int64)
    if int(ids[0]) != first:
        raise SystemExit(f"SE-Sync's first pose is vertex {int(ids[0])}, the file's is {first}")
    if is3d:
        poses = reanchor3d(record_poses(record), initial.atPose3(first).matrix()[:3])
        prior, size = gtsam.PriorFactorPose3, 6
    else:
        anchor = initial.atPose2(first)
        poses = reanchor(record_poses(record), (anchor.x(), anchor.y(), anchor.theta()))
        prior, size = gtsam.PriorFactorPose2, 3
    start = to_values(ids, poses)
    optimized = graph
    if not any(isinstance(graph.at(i), gtsam.PriorFactorPose2 | gtsam.PriorFactorPose3)
               for i in range(graph.size())):
        optimized = gtsam.NonlinearFactorGraph(graph)
        anchor_pose = start.atPose3(first) if is3d else start.atPose2(first)
        optimized.add(prior(first, anchor_pose,
                            gtsam.noiseModel.Isotropic.Sigma(size, _ANCHOR_SIGMA)))
    optimizer = gtsam.LevenbergMarquardtOptimizer(optimized, start, solver_params("lm", 30))
    result = optimizer.optimize()
    chi2 = 2.0 * graph.error(result)
    seconds["LM"] = time.monotonic() - began
    began = time.monotonic()
    gtsam.writeG2o(graph, result, output_path)
    seconds["write"] = time.monotonic() - began
    return {"chi2": chi2, "iterations": optimizer.iterations(), "seconds": seconds}


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    print(json.dumps(main(*sys.argv[1:])))
