"""Which shipped agent measures best across the shared benchmarks (the default model).

    python benchmarks/choose_default.py [--models preset1,...] [--episodes 1]

For every model and benchmark file: the agent from odometry (the paper's setting) with its
default test cycles, then GTSAM LM30. The score of a model is the geometric mean over the
files of (RL+LM30 chi2) / (lowest chi2 any model reached on that file). Prints a table and
writes benchmarks/results/choose_default.json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.common import DATASETS, write_result
from rlpgo_gtsam import RLInitializer, read_g2o, refine
from rlpgo_gtsam.rl.models import shipped_models

FILES = ["M3500", "M3500A", "M3500B", "M3500C", "City10K", "Intel", "MIT", "FR079"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=",".join(shipped_models()))
    parser.add_argument("--episodes", type=int, default=1)
    parser.add_argument("--merge", help="a earlier JSON of this script whose models to include")
    args = parser.parse_args()
    models = args.models.split(",")
    graphs = {name: read_g2o(DATASETS / f"{name}.g2o") for name in FILES}
    costs: dict[str, dict[str, float]] = {}
    for model in models:
        costs[model] = {}
        for name, (graph, values) in graphs.items():
            guess = RLInitializer(model=model, episodes=args.episodes).initialize(graph, values)
            costs[model][name] = refine(graph, guess, "lm", 30).chi2
            print(f"{model:<10}{name:<9}{costs[model][name]:>12.6g}", flush=True)
    if args.merge:
        earlier = json.loads(Path(args.merge).read_text())["rl_plus_lm30"]
        costs |= {m: c for m, c in earlier.items() if m not in costs}
        models = list(costs)
    lowest = {name: min(costs[m][name] for m in models) for name in FILES}
    scores = {m: float(np.exp(np.mean([np.log(costs[m][f] / lowest[f]) for f in FILES])))
              for m in models}
    print(f"{'model':<10}" + "".join(f"{f:>10}" for f in FILES) + f"{'score':>8}")
    for m in sorted(models, key=scores.get):
        print(f"{m:<10}" + "".join(f"{costs[m][f]:>10.4g}" for f in FILES) + f"{scores[m]:>8.3f}")
    best = min(models, key=scores.get)
    print(f"best: {best}")
    write_result("choose_default", {"episodes": args.episodes, "rl_plus_lm30": costs,
                                    "score": scores, "best": best})


if __name__ == "__main__":
    main()
