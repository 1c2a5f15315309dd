"""The RL-PGO paper's three tables, reproduced beside the classical baselines.

    python benchmarks/paper_tables.py [--episodes 10] [--only sigma_t,d,benchmarks,noisy]

Tables (chi2 = 2 x GTSAM error; "RL" is the mean over the rollouts, "RL+X" starts from
the best of them, as in the paper):
  sigma_t  n=300, sigma_R 0.3, d 3, lc 0.5, sigma_t 0.2/0.1/0.05/0.03/0.01 (agent: preset 2);
           on the paper's own graphs (../shared/datasets/paper_sigma_t_sweep) and ours.
  d        n=300, sigma_R 0.1, sigma_t 0.01, lc 0.5, d 1/3/5/8/10 (agent: preset 5).
  benchmarks  the shared g2o files, LM30 / LM100 / RL / RL+LM30, test cycles as the paper.
  noisy    both sweeps again on graphs with noisy measurements.
Each table also has LAGO and chordal rows, alone and + the same solver. Seconds are given
as ratios to the solver's own run from odometry in the same row set. Writes
benchmarks/results/paper_tables[_<only>].{md,json} and one PNG per table.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import DATASETS, RESULTS  # noqa: E402

SIGMA_T = [0.2, 0.1, 0.05, 0.03, 0.01]
SPACING = [1.0, 3.0, 5.0, 8.0, 10.0]
# The paper's test cycles (twice the training cycles) per benchmark file.
BENCHMARK_CYCLES = {"M3500": 12, "M3500A": 10, "M3500B": 10, "M3500C": 10, "City10K": 5,
                    "Intel": 14, "MIT": 10}
GENERATOR_SEED = 2024


@dataclass
class Case:
    label: str
    graph: Any  # gtsam.NonlinearFactorGraph
    values: Any  # gtsam.Values


def _timed(function):
    start = time.perf_counter()
    result = function()
    return result, time.perf_counter() - start


def run_case(case: Case, model: str, episodes: int, cycles: int | None, long_solver: tuple,
             short_solver: tuple, rl_start: str = "odometry") -> dict:
    """All rows of one column: solver from odometry, RL, RL+solver, LAGO, chordal (+solver)."""
    from rlpgo_gtsam import RLInitializer, chi2, extract_pose_graph, make_initializer, refine

    g, v = case.graph, case.values
    name, iters = long_solver
    short_name, short_iters = short_solver
    row = {"case": case.label, "poses": v.size(), "edges": g.size(), "initial": chi2(g, v)}
    long_result, long_seconds = _timed(lambda: refine(g, v, name, iters))
    row[f"{name.upper()}{iters}"] = long_result.chi2
    row["seconds_long_solver"] = long_seconds
    rl = RLInitializer(model=model, cycles=cycles, episodes=episodes, start=rl_start, seed=0)
    result, rl_seconds = _timed(lambda: rl.run(extract_pose_graph(g, v)))
    tag = short_name.upper() + str(short_iters)
    row["RL"] = float(np.mean(result.details["rollout_chi2"]))
    row["RL best"] = result.chi2
    row[f"RL+{tag}"] = refine(g, result.values, short_name, short_iters).chi2
    row["RL seconds / solver seconds"] = rl_seconds / long_seconds
    for method in ("lago", "chordal"):
        initial, seconds = _timed(lambda m=method: make_initializer(m).initialize(g, v))
        row[method.upper() if method == "lago" else "chordal"] = chi2(g, initial)
        row[f"{'LAGO' if method == 'lago' else 'chordal'}+{tag}"] = refine(
            g, initial, short_name, short_iters).chi2
        row[f"{method} seconds / solver seconds"] = seconds / long_seconds
    return row


def _sweep_cases(kind: str, noisy: bool) -> list[Case]:
    from rlpgo_gtsam import generate

    cases = []
    if kind == "sigma_t":
        for sigma_t in SIGMA_T:
            sample = generate(300, 0.3, sigma_t, 3.0, 0.5, np.random.default_rng(GENERATOR_SEED),
                              noisy_measurements=noisy)
            cases.append(Case(f"ours sigma_t={sigma_t}", sample.graph, sample.initial))
    else:
        for d in SPACING:
            sample = generate(300, 0.1, 0.01, d, 0.5, np.random.default_rng(GENERATOR_SEED),
                              noisy_measurements=noisy)
            cases.append(Case(f"ours d={d:g}", sample.graph, sample.initial))
    return cases


def _paper_sigma_t_cases() -> list[Case]:
    from rlpgo_gtsam import read_g2o

    folder = DATASETS / "paper_sigma_t_sweep"
    return [Case(f"paper sigma_t={s}", *read_g2o(folder / f"sigma_t_{s}.g2o")) for s in SIGMA_T]


def _benchmark_cases() -> list[tuple[Case, int]]:
    from rlpgo_gtsam import read_g2o

    return [(Case(name, *read_g2o(harness.shared_file(name))), cycles)
            for name, cycles in BENCHMARK_CYCLES.items()]


def _markdown(title: str, rows: list[dict]) -> str:
    keys = [k for k in rows[0] if k not in ("case",)]
    lines = [f"### {title}", "", "| row | " + " | ".join(r["case"] for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    for key in keys:
        cells = []
        for r in rows:
            value = r[key]
            cells.append(f"{value:.3g}" if isinstance(value, float) else str(value))
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _plot(name: str, title: str, rows: list[dict], keys: list[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 3.5))
    x = np.arange(len(rows))
    for key in keys:
        axis.plot(x, [max(r[key], 1e-12) for r in rows], marker="o", label=key)
    axis.set_yscale("log")
    axis.set_xticks(x, [r["case"] for r in rows], rotation=20, fontsize=7)
    axis.set_ylabel("chi2")
    axis.set_title(title, fontsize=9)
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(RESULTS / f"paper_tables_{name}.png", dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--only", default="sigma_t,d,benchmarks,noisy")
    parser.add_argument("--benchmark-model", default="preset4")
    args = parser.parse_args()
    wanted = set(args.only.split(","))
    tables: dict[str, list[dict]] = {}
    gn100, gn50, gn10, lm30, lm100 = ("gn", 100), ("gn", 50), ("gn", 10), ("lm", 30), ("lm", 100)
    if "sigma_t" in wanted:
        cases = _paper_sigma_t_cases() + _sweep_cases("sigma_t", noisy=False)
        tables["sigma_t"] = [run_case(c, "preset2", args.episodes, None, gn100, gn50)
                             for c in cases]
    if "d" in wanted:
        tables["d"] = [run_case(c, "preset5", args.episodes, None, gn100, gn10)
                       for c in _sweep_cases("d", noisy=False)]
    if "benchmarks" in wanted:
        from rlpgo_gtsam import refine

        rows = []
        for case, cycles in _benchmark_cases():
            row = run_case(case, args.benchmark_model, args.episodes, cycles, lm100, lm30)
            row["LM30"] = refine(case.graph, case.values, "lm", 30).chi2
            rows.append(row)
        tables["benchmarks"] = rows
    if "noisy" in wanted:
        tables["sigma_t_noisy"] = [run_case(c, "preset2", args.episodes, None, gn100, gn50)
                                   for c in _sweep_cases("sigma_t", noisy=True)]
        tables["d_noisy"] = [run_case(c, "preset5", args.episodes, None, gn100, gn10)
                             for c in _sweep_cases("d", noisy=True)]
    titles = {
        "sigma_t": "sigma_t sweep (n=300, sigma_R 0.3, d 3, lc 0.5), agent preset 2",
        "d": "d sweep (n=300, sigma_R 0.1, sigma_t 0.01, lc 0.5), agent preset 5",
        "benchmarks": f"benchmark files, agent {args.benchmark_model}, paper test cycles",
        "sigma_t_noisy": "sigma_t sweep, noisy measurements, agent preset 2",
        "d_noisy": "d sweep, noisy measurements, agent preset 5",
    }
    text = []
    for name, rows in tables.items():
        text.append(_markdown(titles[name], rows))
        solver_keys = [k for k in rows[0] if k.startswith(("GN", "LM", "RL+", "LAGO+",
                                                            "chordal+"))]
        _plot(name, titles[name], rows, ["RL", *solver_keys])
        print(text[-1], flush=True)
    suffix = "" if wanted == {"sigma_t", "d", "benchmarks", "noisy"} else "_" + "_".join(
        sorted(wanted))
    harness.write_result(f"paper_tables{suffix}", harness.command_line(),
                         {"episodes": args.episodes, "tables": tables},
                         "chi2 = 2 x GTSAM error.\n\n" + "\n".join(text))


if __name__ == "__main__":
    main()
