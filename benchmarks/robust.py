"""Wrong loop closures: the robust initializer against the clean default and GTSAM GNC-LM.

    python benchmarks/robust.py [--cases gen0.1,gen0.2,Intel,M3500,City10K]
        [--fractions 0.05,0.1,0.2,0.3] [--mode random|plausible] [--repeat 3]
        [--anchor-timeout 60] [--anchor-fractions 0.05,0.1] [--name robust]

Per case (a shared benchmark file, or a 1000-pose graph of the project's generator with
noisy measurements, sigma_R 0.1 or 0.2, sigma_t 0.05 m, d 1 m, lc 0.5) and per fraction of
wrong closures (``int(fraction x edges)`` of them, :func:`add_outliers` /
``generate(outliers=...)``, seed 1; random by default, ``--mode plausible`` for far-apart
poses measured like a true closure):

- ``robust_initialize`` on the corrupted graph: precision and recall of its rejections,
  the chi2 of its values on the outlier-free graph against that graph's lowest known chi2
  (the shared files' README; for generated graphs LM from the ground truth on the clean
  graph), the RMS position error against the outlier-free solution (LM from chordal on the
  clean graph) and its seconds;
- the clean default (``staged_initialize`` on the outlier-free graph) as the time
  reference: "x clean" is robust seconds / clean-default seconds, each the median of
  ``--repeat`` runs in the same process;
- GTSAM's ``GncLMOptimizer`` (TLS, odometry edges known inliers) from the odometry guess as
  the anchor, in a subprocess with a time limit; where the project's REFERENCE measured it
  not finishing in 10 minutes (M3500 at 20%, Intel at 10%) or a lower fraction already ran
  out of time it is not run again.

Rows are checkpointed to ``benchmarks/results/<name>.json`` as they finish; the markdown
table goes to ``benchmarks/results/<name>.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import DATASETS, RESULTS, write_result  # noqa: E402
from rlpgo_gtsam import (  # noqa: E402
    PoseGraph2D,
    chi2,
    generate,
    make_initializer,
    read_g2o,
    refine,
    write_g2o,
)
from rlpgo_gtsam.graph import odometry_edges  # noqa: E402
from rlpgo_gtsam.robust import robust_initialize  # noqa: E402
from rlpgo_gtsam.staged import staged_initialize  # noqa: E402
from rlpgo_gtsam.synthetic import add_outliers  # noqa: E402

LOWEST_KNOWN = {"M3500": 137.9, "Intel": 212.7, "City10K": 512.0}  # datasets/README.md
# (case, first fraction) where REFERENCE.md measured GNC-LM from odometry not finishing
# within 10 minutes (random wrong closures).
ANCHOR_DID_NOT_FINISH = {"M3500": 0.2, "Intel": 0.1}
SEED = 1


def clean_case(name: str):
    """(graph, values, lowest known chi2, outlier-free solution) of a case."""
    if name.startswith("gen"):
        sample = generate(1000, float(name[3:]), 0.05, 1.0, 0.5, np.random.default_rng(7),
                          noisy_measurements=True)
        graph, values = sample.graph, sample.initial
        lowest = refine(graph, sample.ground_truth, "lm", 1000).chi2
    else:
        graph, values = read_g2o(DATASETS / f"{name}.g2o")
        lowest = LOWEST_KNOWN[name]
    g = PoseGraph2D.from_gtsam(graph, values)
    solution = refine(graph, make_initializer("chordal").run(g).values, "lm", 1000,
                      pose_graph=g).values
    return graph, values, lowest, solution


def corrupted(name: str, graph, values, solution, fraction: float, mode: str = "random"):
    """(graph with wrong closures, their factor indices)."""
    if name.startswith("gen"):
        sample = generate(1000, float(name[3:]), 0.05, 1.0, 0.5, np.random.default_rng(7),
                          noisy_measurements=True, outliers=fraction, outlier_mode=mode)
        return sample.graph, sample.outlier_edges
    return add_outliers(graph, solution, fraction, np.random.default_rng(SEED), mode)


def timed(repeat: int, call, *args, **kwargs):
    """The last result of ``call(*args, **kwargs)`` run ``repeat`` times, and the median of
    its seconds."""
    seconds, result = [], None
    for _ in range(repeat):
        began = time.perf_counter()
        result = call(*args, **kwargs)
        seconds.append(time.perf_counter() - began)
    return result, float(np.median(seconds))


def rms(g: PoseGraph2D, values, reference) -> float:
    difference = g.poses_of(values)[:, :2] - g.poses_of(reference)[:, :2]
    return float(np.sqrt(np.mean(np.sum(difference ** 2, axis=1))))


def scores(rejected: set[int], outliers: set[int]) -> tuple[float, float]:
    hits = len(rejected & outliers)
    return (hits / len(rejected) if rejected else 1.0, hits / len(outliers) if outliers else 1.0)


def run_anchor(graph, values, timeout_s: float) -> dict | None:
    """GTSAM GNC-LM from ``values`` in a subprocess; None if it ran out of time."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "graph.g2o"
        out = Path(folder) / "result.json"
        write_g2o(path, graph, values)
        began = time.perf_counter()
        try:
            subprocess.run([sys.executable, __file__, "--anchor-child", str(path), str(out)],
                           check=True, timeout=timeout_s, capture_output=True)
        except subprocess.TimeoutExpired:
            return None
        seconds = time.perf_counter() - began
        result = json.loads(out.read_text())
        result["wall_seconds"] = seconds
        return result


def anchor_child(path: str, out: str) -> None:
    """Run GNC-LM (TLS, odometry known inliers, anchor prior) and write poses + weights."""
    import gtsam

    from rlpgo_gtsam.solvers import solver_params

    graph, values = read_g2o(path)
    g = PoseGraph2D.from_gtsam(graph, values)
    edge_factors = [k for k in range(graph.size())
                    if isinstance(graph.at(k), gtsam.BetweenFactorPose2)]
    inliers = [edge_factors[e] for e in np.flatnonzero(odometry_edges(g)).tolist()]
    key = int(g.keys[g.anchor])
    optimized = gtsam.NonlinearFactorGraph(graph)
    optimized.add(gtsam.PriorFactorPose2(key, values.atPose2(key),
                                         gtsam.noiseModel.Isotropic.Sigma(3, 1e-8)))
    params = gtsam.GncLMParams(solver_params("lm", 100))
    params.setLossType(gtsam.GncLossType.TLS)
    params.setKnownInliers(inliers + [optimized.size() - 1])
    began = time.perf_counter()
    optimizer = gtsam.GncLMOptimizer(optimized, values, params)
    result = optimizer.optimize()
    seconds = time.perf_counter() - began
    weights = np.asarray(optimizer.getWeights()).ravel()
    rejected = [k for k in edge_factors if weights[k] < 0.5]
    Path(out).write_text(json.dumps({"seconds": seconds, "rejected": rejected,
                                     "poses": g.poses_of(result).tolist()}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", default="gen0.1,gen0.2,Intel,M3500,City10K")
    parser.add_argument("--fractions", default="0.05,0.1,0.2,0.3")
    parser.add_argument("--mode", default="random", choices=["random", "plausible"])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--name", default="robust")
    parser.add_argument("--anchor-fractions", default="0.05,0.1")
    parser.add_argument("--anchor-timeout", type=float, default=60.0)
    parser.add_argument("--anchor-child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.anchor_child:
        anchor_child(*args.anchor_child)
        return
    fractions = [float(f) for f in args.fractions.split(",")]
    anchor_fractions = {float(f) for f in args.anchor_fractions.split(",") if f}
    command = "python benchmarks/robust.py " + " ".join(sys.argv[1:])
    rows: list[dict] = []
    # warm-up: first calls pay for imports (scipy.stats, scipy.sparse) that later ones do not
    warm = generate(100, 0.1, 0.05, 1.0, 0.5, np.random.default_rng(0), noisy_measurements=True,
                    outliers=0.1)
    robust_initialize(warm.graph, warm.initial)
    staged_initialize(warm.graph, warm.initial)
    header = ("| case | poses | wrong closures | rejected | precision | recall | chi2 on clean "
              "| lowest known | gap | RMS m | robust s | clean default s | x clean "
              "| GNC-LM from odometry |")
    print(header + "\n|" + "---|" * 14, flush=True)
    for name in args.cases.split(","):
        graph, values, lowest, solution = clean_case(name)
        g = PoseGraph2D.from_gtsam(graph, values)
        default, default_seconds = timed(args.repeat, staged_initialize, graph, values,
                                         pose_graph=g)
        anchor_out_of_time = False
        for fraction in fractions:
            bad, outliers = corrupted(name, graph, values, solution, fraction, args.mode)
            result, robust_seconds = timed(args.repeat, robust_initialize, bad, values)
            precision, recall = scores(set(result.rejected), set(outliers))
            clean_chi2 = chi2(graph, result.values)
            row = {
                "case": name, "mode": args.mode, "poses": g.num_poses, "edges": g.num_edges,
                "fraction": fraction,
                "wrong_closures": len(outliers), "rejected": len(result.rejected),
                "precision": precision, "recall": recall, "chi2_on_clean": clean_chi2,
                "lowest_known": lowest, "gap": clean_chi2 / lowest - 1.0,
                "rms_m": rms(g, result.values, solution), "robust_seconds": robust_seconds,
                "clean_default_seconds": default_seconds,
                "clean_default_chi2": default.best.refined_chi2,
                "x_clean": robust_seconds / default_seconds, "steps": result.steps,
            }
            first_dnf = ANCHOR_DID_NOT_FINISH.get(name)
            if first_dnf is not None and fraction >= first_dnf and args.mode == "random":
                row["anchor"] = "did not finish within 600 s (REFERENCE.md)"
            elif anchor_out_of_time:
                row["anchor"] = (f"not run: did not finish within {args.anchor_timeout:g} s "
                                 "at a lower fraction")
            elif fraction not in anchor_fractions:
                row["anchor"] = "not run"
            else:
                anchor = run_anchor(bad, values, args.anchor_timeout)
                if anchor is None:
                    anchor_out_of_time = True
                    row["anchor"] = f"did not finish within {args.anchor_timeout:g} s"
                else:
                    a_precision, a_recall = scores(set(anchor["rejected"]), set(outliers))
                    poses = np.array(anchor["poses"])
                    a_values = g.to_values(poses)
                    row["anchor"] = {
                        "seconds": anchor["seconds"], "precision": a_precision,
                        "recall": a_recall, "chi2_on_clean": chi2(graph, a_values),
                        "rms_m": rms(g, a_values, solution)}
            rows.append(row)
            write_result(args.name, {"command": command, "rows": rows})
            print(markdown_row(row), flush=True)
    table = "\n".join([header, "|" + "---|" * 14] + [markdown_row(r) for r in rows])
    (RESULTS / f"{args.name}.md").write_text(
        f"Made by `{command}`; chi2 = 2 x GTSAM error, scored on the outlier-free graph; "
        f"{args.mode} wrong closures, seed 1; seconds are medians of {args.repeat} runs.\n\n"
        + table + "\n")


def markdown_row(row: dict) -> str:
    anchor = row["anchor"]
    if isinstance(anchor, dict):
        anchor = (f"{anchor['seconds']:.1f} s, P {anchor['precision']:.3f} R "
                  f"{anchor['recall']:.3f}, chi2 {anchor['chi2_on_clean']:.6g}, "
                  f"RMS {anchor['rms_m']:.3g} m")
    return (f"| {row['case']} | {row['poses']} | {row['wrong_closures']} "
            f"({row['fraction']:.0%}) | {row['rejected']} | {row['precision']:.4f} "
            f"| {row['recall']:.4f} | {row['chi2_on_clean']:.6g} | {row['lowest_known']:.6g} "
            f"| {row['gap']:+.3%} | {row['rms_m']:.3g} | {row['robust_seconds']:.2f} "
            f"| {row['clean_default_seconds']:.2f} | {row['x_clean']:.2f} | {anchor} |")


if __name__ == "__main__":
    main()
