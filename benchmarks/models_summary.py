"""The table of shipped agents for models/README.md, from their metadata and eval JSONs.

    python benchmarks/models_summary.py

Reads models/<name>.zip (training command, seed, episodes, seconds, hidden size) and
models/<name>.eval.json (written by rlpgo-eval), prints a markdown table.
"""

from __future__ import annotations

import json

from rlpgo_gtsam.rl.models import models_dir, resolve_model, shipped_models


def main() -> None:
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


if __name__ == "__main__":
    main()
