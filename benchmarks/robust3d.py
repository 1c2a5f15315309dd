"""The robust path on 3D graphs: SE-Sync's seven files clean, and wrong closures added.

    python benchmarks/robust3d.py [--clean tinyGrid3D,...|none]
        [--cases sphere2500,torus3D,gen] [--modes random,uniform] [--fractions 0.05,0.1]
        [--name robust3d]

Clean rows (each file read by :func:`~rlpgo_gtsam.g2o3d.read_g2o3d`): the rejections of
``robust_initialize`` (0 expected), its chi2 against the clean default's
(``staged_initialize``: the SE(3) relaxation + LM30), both in CPU seconds
(``time.process_time``, the same process).

Wrong-closure rows: ``int(fraction x edges)`` wrong closures (``add_outliers3d`` around the
clean optimum, seed 1; ``gen``: ``generate3d`` with 1000 poses, sigma_R 0.05 rad, sigma_t
0.1 m, d 1 m, lc 0.5, noisy measurements, seed 7, its own wrong closures): precision and
recall of the rejections; the chi2 of the result refined by LM30 on the outlier-free graph
over that graph's optimum (certified + LM to convergence); CPU seconds of the robust call
over the clean default's on the outlier-free graph. Rows go to
``benchmarks/results/<name>.json`` as they finish, the table to ``<name>.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import DATASETS, RESULTS, write_result  # noqa: E402
from rlpgo_gtsam.g2o3d import read_g2o3d  # noqa: E402
from rlpgo_gtsam.robust import robust_initialize  # noqa: E402
from rlpgo_gtsam.solvers import refine, solver_params  # noqa: E402
from rlpgo_gtsam.staged import staged_initialize  # noqa: E402
from rlpgo_gtsam.synthetic import add_outliers3d, generate3d  # noqa: E402

FILES = ["tinyGrid3D", "smallGrid3D", "parking-garage", "sphere2500", "torus3D", "cubicle",
         "sphere_bignoise_vertex3"]
GEN = (1000, 0.05, 0.1, 1.0, 0.5)
SEED = 1


def clean_case(name: str):
    """(graph, values, clean default's chi2 and CPU seconds, optimum values and chi2)."""
    if name == "gen":
        sample = generate3d(*GEN, np.random.default_rng(7), noisy_measurements=True)
        graph, values = sample.graph, sample.initial
    else:
        graph, values = read_g2o3d(DATASETS / "3d" / f"{name}.g2o")
    began = time.process_time()
    default = staged_initialize(graph, values)
    seconds = time.process_time() - began
    params = solver_params("lm", 200)
    params.setRelativeErrorTol(1e-12)
    best = refine(graph, default.values, params)
    return graph, values, default.best.refined_chi2, seconds, best.values, best.chi2


def robust(graph, values):
    began = time.process_time()
    result = robust_initialize(graph, values)
    return result, time.process_time() - began


def clean_row(name: str) -> dict:
    graph, values, default_chi2, default_s, _, _ = clean_case(name)
    result, seconds = robust(graph, values)
    return {"case": name, "rejected": len(result.rejected), "robust_chi2": result.chi2,
            "default_chi2": default_chi2, "relative": result.chi2 / default_chi2 - 1.0,
            "robust_s": seconds, "default_s": default_s, "x_default": seconds / default_s,
            "stopped": result.stopped, "steps": result.steps}


def wrong_row(name: str, case, fraction: float, mode: str) -> dict:
    graph, values, _, default_s, optimum, optimum_chi2 = case
    if name == "gen":
        sample = generate3d(*GEN, np.random.default_rng(7), noisy_measurements=True,
                            outliers=fraction, outlier_mode=mode)
        corrupted, wrong = sample.graph, sample.outlier_edges
    else:
        corrupted, wrong = add_outliers3d(graph, optimum, fraction, np.random.default_rng(SEED),
                                          mode)
    result, seconds = robust(corrupted, values)
    rejected, wrong = set(result.rejected), set(wrong)
    hit = len(rejected & wrong)
    after = refine(graph, result.values, "lm", 30).chi2
    return {"case": name, "mode": mode, "fraction": fraction, "wrong": len(wrong),
            "rejected": len(rejected),
            "precision": hit / len(rejected) if rejected else 1.0,
            "recall": hit / len(wrong) if wrong else 1.0,
            "clean_chi2_after_lm30": after, "optimum_chi2": optimum_chi2,
            "ratio": after / optimum_chi2, "robust_s": seconds, "default_s": default_s,
            "x_default": seconds / default_s, "stopped": result.stopped,
            "steps": result.steps}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--clean", default=",".join(FILES))
    parser.add_argument("--cases", default="sphere2500,torus3D,gen")
    parser.add_argument("--modes", default="random,uniform")
    parser.add_argument("--fractions", default="0.05,0.1")
    parser.add_argument("--name", default="robust3d")
    args = parser.parse_args()

    rows: dict[str, list[dict]] = {"clean": [], "wrong": []}
    for name in [] if args.clean == "none" else args.clean.split(","):
        rows["clean"].append(clean_row(name))
        print(json.dumps({k: v for k, v in rows["clean"][-1].items() if k != "steps"}),
              flush=True)
        write_result(args.name, rows)
    for name in [c for c in args.cases.split(",") if c]:
        case = clean_case(name)
        for mode in args.modes.split(","):
            for fraction in (float(f) for f in args.fractions.split(",")):
                rows["wrong"].append(wrong_row(name, case, fraction, mode))
                print(json.dumps({k: v for k, v in rows["wrong"][-1].items() if k != "steps"}),
                      flush=True)
                write_result(args.name, rows)
    (RESULTS / f"{args.name}.md").write_text(table(rows))
    print(table(rows))


def table(rows: dict[str, list[dict]]) -> str:
    lines = ["| file | rejected | robust chi2 | clean default chi2 | relative | robust CPU s | "
             "default CPU s | x default |", "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['rejected']} | {r['robust_chi2']:.6g} | "
              f"{r['default_chi2']:.6g} | {r['relative']:+.1e} | {r['robust_s']:.2f} | "
              f"{r['default_s']:.2f} | {r['x_default']:.1f} |" for r in rows["clean"]]
    lines += ["", "| case | mode | wrong | rejected | precision | recall | chi2 + LM30 on clean "
              "/ optimum | robust CPU s | default CPU s | x default |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['mode']} | {r['wrong']} ({r['fraction']:.0%}) | "
              f"{r['rejected']} | {r['precision']:.4f} | {r['recall']:.4f} | {r['ratio']:.4f} "
              f"| {r['robust_s']:.2f} | {r['default_s']:.2f} | {r['x_default']:.1f} |"
              for r in rows["wrong"]]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
