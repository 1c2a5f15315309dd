"""One full cycle of M3500 with random actions, as a ratio to one GTSAM LM30 on the same graph.

    python benchmarks/env_step.py [--repeats 3]

Prints a table and writes benchmarks/results/env_step.json. Each figure is the best of
``--repeats`` runs; both are measured in this run, on this machine.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.common import DATASETS, write_result
from rlpgo_gtsam import PoseGraphEnv, read_g2o, refine


def _cycle_seconds(env: PoseGraphEnv, seed: int) -> tuple[float, int]:
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (env.steps_per_episode, 2))
    start = time.perf_counter()
    for action in actions:
        env.step(action)
    return time.perf_counter() - start, len(actions)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    path = DATASETS / "M3500.g2o"
    graph, values = read_g2o(path)
    env = PoseGraphEnv(graph=graph, values=values, cycles=1)
    cycle, steps = min(_cycle_seconds(env, seed) for seed in range(args.repeats))
    lm = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        result = refine(graph, values, "lm", 30)
        lm.append(time.perf_counter() - start)
    lm30 = min(lm)
    ratio = cycle / lm30
    print(f"{'graph':<8}{'steps':>7}{'us/step':>10}{'cycle / LM30':>14}")
    print(f"{'M3500':<8}{steps:>7}{cycle / steps * 1e6:>10.1f}{ratio:>14.3f}")
    out = write_result("env_step", {
        "graph": "M3500.g2o", "steps": steps, "cycle_seconds": cycle,
        "lm30_seconds": lm30, "lm30_iterations": result.iterations,
        "cycle_over_lm30": ratio, "microseconds_per_step": cycle / steps * 1e6,
    })
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
