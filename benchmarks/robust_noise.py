"""The robust path on the generator's graphs as the rotation noise grows: where it holds.

    python benchmarks/robust_noise.py [--dims 2,3] [--sigmas 0.05,0.1,0.2,0.3] [--spacings 1,3]
        [--modes random,local,group,localgroup] [--fraction 0.1] [--seeds 1,2,3]
        [--n 300] [--name robust_noise]

``benchmarks/robust.py`` scores the robust path on one generated graph (1000 poses, sigma_R
0.01 rad); ``rlpgo-generate``'s defaults are far noisier (sigma_R 0.3 rad per measurement,
poses 3 m apart). Per dimension, rotation noise sigma_R, pose spacing d, policy and seed: the
generator's graph (``--n`` poses, sigma_t 0.05 m, lc 0.5, noisy measurements; ``generate``
or ``generate3d``) with ``--fraction`` wrong closures of that policy, and the same graph
without them (the same seed: the wrong closures come after it). ``robust_initialize`` on the
first: precision, recall, the chi2 ratio (its values + LM 100 on the outlier-free graph over
that graph's optimum: the clean default + LM 100) and seconds; on the second: how many closures it
rejected (it should be none).

Prints one line per row; writes ``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import write_rows  # noqa: E402
from benchmarks.robust import scores  # noqa: E402
from rlpgo_gtsam import refine  # noqa: E402
from rlpgo_gtsam.graph3d import extract_pose_graph  # noqa: E402
from rlpgo_gtsam.robust import robust_initialize  # noqa: E402
from rlpgo_gtsam.staged import staged_initialize  # noqa: E402
from rlpgo_gtsam.synthetic import generate, generate3d  # noqa: E402

SIGMA_T, LC = 0.05, 0.5


def optimum_chi2(graph, values) -> float:
    """The chi2 of the clean default (the certified relaxation, SE(2) or SE(3), and LM)
    refined by LM 100 more."""
    g = extract_pose_graph(graph, values)
    start = staged_initialize(graph, values).values
    return refine(graph, start, "lm", 100, pose_graph=g).chi2


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dims", default="2,3")
    parser.add_argument("--sigmas", default="0.05,0.1,0.2,0.3")
    parser.add_argument("--spacings", default="1,3")
    parser.add_argument("--modes", default="random,local,group,localgroup")
    parser.add_argument("--fraction", type=float, default=0.1)
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--n", type=int, default=300)
    parser.add_argument("--name", default="robust_noise")
    args = parser.parse_args()
    command = " ".join(["python benchmarks/robust_noise.py", *sys.argv[1:]])
    rows: list[dict] = []
    lines = ["| dim | sigma_R | d | policy | seed | wrong | rejected | precision | recall | "
             "chi2 ratio | s | clean graph: rejected |", "|---" * 12 + "|"]
    for dim in map(int, args.dims.split(",")):
        make = generate if dim == 2 else generate3d
        for sigma in map(float, args.sigmas.split(",")):
            for d in map(float, args.spacings.split(",")):
                for seed in map(int, args.seeds.split(",")):
                    clean = make(args.n, sigma, SIGMA_T, d, LC, np.random.default_rng(seed),
                                 noisy_measurements=True)
                    best = optimum_chi2(clean.graph, clean.initial)
                    clean_rejected = len(robust_initialize(clean.graph, clean.initial).rejected)
                    for mode in args.modes.split(","):
                        bad = make(args.n, sigma, SIGMA_T, d, LC, np.random.default_rng(seed),
                                   noisy_measurements=True, outliers=args.fraction,
                                   outlier_mode=mode)
                        result = robust_initialize(bad.graph, bad.initial)
                        precision, recall = scores(result.rejected, bad.outlier_edges)
                        ratio = refine(clean.graph, result.values, "lm", 100).chi2 / best
                        row = {"dim": dim, "sigma_r": sigma, "d": d, "mode": mode, "seed": seed,
                               "wrong": len(bad.outlier_edges),
                               "rejected": len(result.rejected), "precision": precision,
                               "recall": recall, "ratio": ratio, "seconds": result.seconds,
                               "clean_rejected": clean_rejected,
                               "doubtful": len(result.doubtful)}
                        rows.append(row)
                        lines.append(f"| {dim} | {sigma:g} | {d:g} | {mode} | {seed} | "
                                     f"{row['wrong']} | {row['rejected']} | {precision:.3f} | "
                                     f"{recall:.3f} | {ratio:.4f} | {result.seconds:.2f} | "
                                     f"{clean_rejected} |")
                        print(lines[-1], flush=True)
                        write_rows(args.name, command, rows, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
