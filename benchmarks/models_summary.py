"""The table of shipped agents for models/README.md, and the figures their tests expect.

    python benchmarks/models_summary.py                    # print the table
    python benchmarks/models_summary.py --write-expected   # rewrite models/expected.json

The table reads models/<name>.zip (training command, seed, episodes, seconds, hidden size)
and models/<name>.eval.json (written by rlpgo-eval). ``--write-expected`` runs every shipped
agent and the edge-balancing rule on the fixed graphs of :data:`EXPECTED_SEEDS` (each
model's own training environment) and records their figures in models/expected.json, which
tests/test_shipped_models.py checks within a tolerance. Rerun it when a change is meant to
alter the agents' behaviour (or a model is retrained), and say why in the commit.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from rlpgo_gtsam.rl.models import models_dir, resolve_model, shipped_models

# Generator seeds of the graphs the expected figures are measured on (training draws its
# graphs from one stream seeded by the run's seed, rlpgo-eval uses 1000 + k: these differ).
EXPECTED_SEEDS = list(range(5000, 5010))
EXPECTED_FILE = "expected.json"


def behaviour(name: str) -> dict:
    """Mean initial OC, mean best OC of the agent and of the edge-balancing rule, and their
    ratios, over one deterministic rollout per graph of :data:`EXPECTED_SEEDS` (the model's
    training environment, its test cycles = training cycles), through the evaluation path."""
    from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
    from rlpgo_gtsam.rl.episode import BalancingPolicy
    from rlpgo_gtsam.rl.evaluation import initial_and_best_oc

    model = resolve_model(name)
    config = model.env_config
    initial, agent = initial_and_best_oc(NumpyPolicy(model.actor), config, EXPECTED_SEEDS)
    _, rule = initial_and_best_oc(BalancingPolicy(config.action_range_rad), config,
                                  EXPECTED_SEEDS)
    initial_mean = float(np.mean(initial))
    return {
        "initial_oc_mean": initial_mean,
        "agent_best_oc_mean": float(np.mean(agent)),
        "balancing_best_oc_mean": float(np.mean(rule)),
        "agent_ratio": float(np.mean(agent)) / initial_mean,
        "balancing_ratio": float(np.mean(rule)) / initial_mean,
    }


def write_expected() -> None:
    path = models_dir() / EXPECTED_FILE
    record = {
        "command": "python benchmarks/models_summary.py --write-expected",
        "seeds": EXPECTED_SEEDS,
        "models": {name: behaviour(name) for name in shipped_models()},
    }
    path.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {path}")


def print_table() -> None:
    folder = models_dir()
    print("| model | command | hidden | episodes | train minutes | initial OC | agent best OC "
          "| random | edge balancing | agent / initial | agent / balancing |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name in shipped_models():
        meta = resolve_model(name).metadata
        for suffix in (".eval.json", ".noisy-eval.json"):
            path = folder / f"{name}{suffix}"
            if not path.exists():
                continue
            e = json.loads(path.read_text())
            label = name + (" (noisy-measurement graphs)" if "noisy" in suffix else "")
            print(f"| {label} | `{meta['command']}` | {meta['hidden']} | {meta['episodes']} | "
                  f"{meta['train_seconds'] / 60:.1f} | {e['initial_oc_mean']:.3f} | "
                  f"{e['agent_best_oc_mean']:.3f} | {e['random_best_oc_mean']:.3f} | "
                  f"{e['greedy_best_oc_mean']:.3f} | "
                  f"{e['agent_best_oc_mean'] / e['initial_oc_mean']:.3f} | "
                  f"{e['agent_best_oc_mean'] / e['greedy_best_oc_mean']:.3f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-expected", action="store_true",
                        help=f"rewrite models/{EXPECTED_FILE} instead of printing the table")
    args = parser.parse_args()
    if args.write_expected:
        write_expected()
    else:
        print_table()


if __name__ == "__main__":
    main()
