"""What the robust path still misses on the generator's graphs, scored at the right map.

    python benchmarks/robust_floor.py [--rows robust_noise_2d_v9] [--n 300] [--fraction 0.1]
        [--name robust_floor_2d]

For every row of a ``benchmarks/robust_noise.py`` result (``--rows``, its name under
``benchmarks/results``) below precision or recall 0.98, the same graph is made again and
``robust_initialize`` run on it; each wrong closure it kept and each true closure it rejected
is then scored at the outlier-free graph's optimum (the clean default and LM 100, as
``robust_noise.py`` scores the map) by the verify step's own statistic, the one its rounds
judge by (its innovation for a closure left out of that map, its leave-out residual for a
true one kept in it, under the map's uncertainty, from the step's 64 seeded draws).

A wrong closure kept that fits that optimum within the bar (chi-square, 0.9999, the group's
dof) is one no test on the stated covariances can reject; a true closure rejected that fits
it with p < 0.05 is one that its own noise put in the tail. A row whose every miss is one of
these is at the floor. Prints one line per row and the totals; writes
``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import RESULTS, write_rows  # noqa: E402
from benchmarks.robust_noise import LC, SIGMA_T  # noqa: E402
from rlpgo_gtsam import refine  # noqa: E402
from rlpgo_gtsam.graph3d import extract_pose_graph  # noqa: E402
from rlpgo_gtsam.robust import pipeline, robust_initialize  # noqa: E402
from rlpgo_gtsam.staged import staged_initialize  # noqa: E402
from rlpgo_gtsam.synthetic import generate, generate3d  # noqa: E402


def statistics_at_optimum(bad, clean, edges_of_interest: list[int]) -> dict[int, float]:
    """Per factor index of ``bad.graph`` in ``edges_of_interest``: the verify step's
    statistic at the outlier-free graph's optimum (its wrong closures left out)."""
    if not edges_of_interest:
        return {}
    g = extract_pose_graph(bad.graph, bad.initial)
    group = pipeline.group_of(g)
    factor_of_edge = pipeline._edge_factor_indices(bad.graph, g.num_edges, group.between_factor)
    edge_of = {int(f): e for e, f in enumerate(factor_of_edge.tolist())}
    optimum = refine(clean.graph, staged_initialize(clean.graph, clean.initial).values, "lm",
                     100).values
    kept = np.ones(g.num_edges, bool)
    kept[[edge_of[f] for f in bad.outlier_edges]] = False
    edges = gtsam.NonlinearFactorGraph()
    for k in factor_of_edge.tolist():
        edges.add(bad.graph.at(k))
    draws = pipeline._innovation_draws(edges, g, optimum, kept, pipeline._draws(g))
    values = pipeline._judged(g, draws, [np.array([edge_of[f]]) for f in edges_of_interest])[0]
    return dict(zip(edges_of_interest, values.tolist(), strict=True))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rows", default="robust_noise_2d_v9")
    parser.add_argument("--n", type=int, default=300)  # as robust_noise.py ran
    parser.add_argument("--fraction", type=float, default=0.1)
    parser.add_argument("--name", default="robust_floor_2d")
    args = parser.parse_args()
    command = " ".join(["python benchmarks/robust_floor.py", *sys.argv[1:]])
    source = json.loads((RESULTS / f"{args.rows}.json").read_text())["rows"]
    rows: list[dict] = []
    lines = ["| dim | sigma_R | d | policy | seed | wrong kept | of them fitting the optimum | "
             "true rejected | of them p < 0.05 there | at the floor |", "|---" * 10 + "|"]
    for row in source:
        if min(row["precision"], row["recall"]) >= 0.98:
            continue
        make = generate if row["dim"] == 2 else generate3d
        shape = (args.n, row["sigma_r"], SIGMA_T, row["d"], LC)
        clean = make(*shape, np.random.default_rng(row["seed"]), noisy_measurements=True)
        bad = make(*shape, np.random.default_rng(row["seed"]), noisy_measurements=True,
                   outliers=args.fraction,
                   outlier_mode=row["mode"])
        result = robust_initialize(bad.graph, bad.initial)
        wrong, rejected = set(bad.outlier_edges), set(result.rejected)
        kept_wrong, lost_true = sorted(wrong - rejected), sorted(rejected - wrong)
        score = statistics_at_optimum(bad, clean, kept_wrong + lost_true)
        dof = pipeline.group_of(extract_pose_graph(bad.graph, bad.initial)).dof
        bar = pipeline.chi2_quantile(pipeline.DEFAULT_INLIER_PROBABILITY, dof)
        tail = pipeline._statistic_at(pipeline.DOUBTFUL_BELOW, dof)
        fitting = sum(score[f] < bar for f in kept_wrong)
        in_tail = sum(score[f] > tail for f in lost_true)
        floor = fitting == len(kept_wrong) and in_tail == len(lost_true)
        out = {key: row[key] for key in ("dim", "sigma_r", "d", "mode", "seed")} | {
            "kept_wrong": len(kept_wrong), "kept_wrong_fitting": int(fitting),
            "rejected_true": len(lost_true), "rejected_true_in_tail": int(in_tail),
            "floor": bool(floor),
            "kept_wrong_statistics": [round(score[f], 1) for f in kept_wrong],
            "rejected_true_statistics": [round(score[f], 1) for f in lost_true]}
        rows.append(out)
        lines.append(f"| {row['dim']} | {row['sigma_r']:g} | {row['d']:g} | {row['mode']} | "
                     f"{row['seed']} | {len(kept_wrong)} | {fitting} | {len(lost_true)} | "
                     f"{in_tail} | {'yes' if floor else 'no'} |")
        print(lines[-1], flush=True)
        write_rows(args.name, command, rows, "\n".join(lines) + "\n")
    totals = {key: sum(r[key] for r in rows) for key in
              ("kept_wrong", "kept_wrong_fitting", "rejected_true", "rejected_true_in_tail",
               "floor")}
    lines.append(f"\nrows below 0.98: {len(rows)}; at the floor: {totals['floor']}; wrong kept "
                 f"{totals['kept_wrong']} ({totals['kept_wrong_fitting']} fit the optimum); "
                 f"true rejected {totals['rejected_true']} ({totals['rejected_true_in_tail']} "
                 "with p < 0.05 there)")
    print(lines[-1])
    write_rows(args.name, command, rows, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
