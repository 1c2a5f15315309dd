"""The certified relaxation and the staged default on the shared benchmarks, against GTSAM
LM30 and (optionally) SE-Sync, timed in the same run.

    python benchmarks/certified.py [--sesync /work/sesync-build/build/bin/sesync_rounded]
        [--files M3500.g2o,...] [--generated] [--budget 120]

Per shared file: the ``certified`` initializer's seconds, its certificate (certified, lower
bound, suboptimality bound, lambda_min; in the relaxation's cost) and chi2 after LM30; the
library call behind ``rlpgo-init``'s default (``staged_initialize``): its seconds and the
chi2 it hands over; GTSAM LM30 from the file's vertices as the baseline of every ratio;
with ``--sesync``, SE-Sync's own seconds and its rounded estimate + LM30. ``--generated``
adds 1000-pose graphs of the project's generator with heavy rotation noise (sigma_R 0.4 and
0.5, noisy measurements), compared with chordal + LM30. Prints a markdown table, writes
``benchmarks/results/certified.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import DATASETS, RESULTS, write_result  # noqa: E402
from rlpgo_gtsam import (  # noqa: E402
    PoseGraph2D,
    generate,
    make_initializer,
    read_g2o,
    refine,
    write_g2o,
)
from rlpgo_gtsam.staged import DEFAULT_BUDGET_S, staged_initialize  # noqa: E402

FILES = ["M3500.g2o", "M3500A.g2o", "M3500B.g2o", "M3500C.g2o", "City10K.g2o", "Intel.g2o",
         "MIT.g2o", "FR079.g2o"]
LOWEST_KNOWN = {"M3500.g2o": 137.9, "M3500A.g2o": 912.2, "M3500B.g2o": 2055.4,
                "M3500C.g2o": 2556.4, "City10K.g2o": 512.0, "Intel.g2o": 212.7,
                "MIT.g2o": 41.21, "FR079.g2o": 37.57}
GENERATED = [(0.4, 11), (0.5, 12)]  # (sigma_R, seed): 1000 poses, noisy measurements


def _timed(function):
    gc.collect()
    start = time.perf_counter()
    result = function()
    return result, time.perf_counter() - start


def _case(name: str, graph, values, path: Path, args) -> dict:
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    row: dict = {"file": name, "poses": pose_graph.num_poses, "edges": pose_graph.num_edges}
    lm30, row["lm30_seconds"] = _timed(lambda: refine(graph, values, "lm", 30))
    row["lm30_chi2"] = lm30.chi2
    certified = make_initializer("certified").run(pose_graph)
    certificate = certified.certificate
    row.update(
        certified_seconds=certified.seconds, certified=certificate.certified,
        lower_bound=certificate.lower_bound, estimate_cost=certificate.estimate_cost,
        suboptimality_bound=certificate.suboptimality_bound,
        min_eigenvalue=certificate.min_eigenvalue, tolerance=certificate.tolerance,
        rank=certificate.rank, certified_guess_chi2=certified.chi2,
        certified_lm30_chi2=refine(graph, certified.values, "lm", 30).chi2,
    )
    chordal = make_initializer("chordal").initialize(graph, values)
    row["chordal_lm30_chi2"] = refine(graph, chordal, "lm", 30).chi2
    staged, row["default_seconds"] = _timed(lambda: staged_initialize(
        graph, values, budget_s=args.budget, pose_graph=pose_graph))
    row["default_chi2"] = staged.best.refined_chi2
    row["default_method"] = staged.best.method
    row["default_stages"] = [r.method for r in staged.rows]
    row["default_stopped"] = staged.stopped
    row["default_over_lm30"] = row["default_seconds"] / row["lm30_seconds"]
    if args.sesync:
        from benchmarks.sesync.runner import run_sesync

        run = run_sesync(args.sesync, path)
        estimate = pose_graph.to_values(_by_keys(run, pose_graph))
        sesync_lm30, lm_seconds = _timed(lambda: refine(graph, estimate, "lm", 30))
        row.update(sesync_seconds=run.seconds, sesync_certified=run.certified,
                   sesync_bound=run.suboptimality_bound, sesync_lm30_chi2=sesync_lm30.chi2,
                   sesync_lm30_seconds=lm_seconds)
        row["default_over_sesync_lm30"] = row["default_seconds"] / (run.seconds + lm_seconds)
    return row


def _by_keys(run, pose_graph: PoseGraph2D) -> np.ndarray:
    index = {int(k): i for i, k in enumerate(run.ids)}
    return np.array([run.poses[index[int(key)]] for key in pose_graph.keys])


def _markdown(rows: list[dict], sesync: bool) -> str:
    header = ["file", "poses", "certified", "bound", "lambda_min", "certified s / LM30 s",
              "certified + LM30", "chordal + LM30", "default chi2", "default s / LM30 s",
              "default stages", "lowest known"]
    if sesync:
        header += ["SE-Sync certified", "SE-Sync + LM30", "default s / (SE-Sync + LM30) s"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        cells = [r["file"], r["poses"], "yes" if r["certified"] else "no",
                 f"{r['suboptimality_bound']:.3g}", f"{r['min_eigenvalue']:.2g}",
                 f"{r['certified_seconds'] / r['lm30_seconds']:.2f}",
                 f"{r['certified_lm30_chi2']:.6g}", f"{r['chordal_lm30_chi2']:.6g}",
                 f"{r['default_chi2']:.6g}", f"{r['default_over_lm30']:.2f}",
                 ", ".join(r["default_stages"]), LOWEST_KNOWN.get(r["file"], "-")]
        if sesync:
            cells += ["yes" if r["sesync_certified"] else "no", f"{r['sesync_lm30_chi2']:.6g}",
                      f"{r['default_over_sesync_lm30']:.2f}"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sesync", help="path of the built sesync_rounded driver")
    parser.add_argument("--files", default=",".join(FILES))
    parser.add_argument("--generated", action="store_true")
    parser.add_argument("--budget", type=float, default=DEFAULT_BUDGET_S)
    args = parser.parse_args()
    import rlpgo_gtsam.certified  # noqa: F401  (scipy's import is not the method's time)

    rows = []
    for name in [f for f in args.files.split(",") if f]:
        path = DATASETS / name
        graph, values = read_g2o(path)
        rows.append(_case(name, graph, values, path, args))
        print(rows[-1], flush=True)
    if args.generated:
        with tempfile.TemporaryDirectory() as folder:
            for sigma_r, seed in GENERATED:
                sample = generate(1000, sigma_r, 0.05, 3.0, 0.5, np.random.default_rng(seed),
                                  noisy_measurements=True)
                name = f"generated n=1000 sigma_R={sigma_r} seed={seed}"
                path = Path(folder) / f"generated_{seed}.g2o"
                write_g2o(path, sample.graph, sample.initial)
                rows.append(_case(name, *read_g2o(path), path, args))
                print(rows[-1], flush=True)
    table = _markdown(rows, bool(args.sesync))
    command = "python benchmarks/certified.py " + " ".join(sys.argv[1:])
    text = f"Made by `{command}`; chi2 = 2 x GTSAM error; bounds in the relaxation's cost.\n\n"
    print(table)
    (RESULTS / "certified.md").write_text(text + table + "\n")
    print(f"wrote {write_result('certified', {'command': command, 'rows': rows})}")


if __name__ == "__main__":
    main()
