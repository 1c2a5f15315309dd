"""Cost of one policy step for the ways of running the agent, against one environment step.

    python benchmarks/inference.py [--model preset1] [--steps 3000]

Measures, per edge visited: torch eager (one LSTM step per call), TorchScript (traced),
the fused numpy policy, and the numpy policy batched over 10 rollouts (per rollout); then
one whole RL pass over M3500 (12 cycles, one rollout) against GTSAM LM100 from odometry,
all in this run. Prints a table and writes benchmarks/results/inference.json.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from benchmarks.common import DATASETS, write_result
from rlpgo_gtsam import PoseGraphEnv, RLInitializer, read_g2o, refine
from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.models import resolve_model


def _per_call(function, steps: int) -> float:
    function()  # warm up
    start = time.perf_counter()
    for _ in range(steps):
        function()
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="preset1")
    parser.add_argument("--steps", type=int, default=3000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = resolve_model(args.model)
    actor = model.actor
    graph, values = read_g2o(DATASETS / "M3500.g2o")
    env = PoseGraphEnv(graph=graph, values=values, cycles=100)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (args.steps + 1, 2))
    step_index = iter(range(10**9))
    env_step = _per_call(lambda: env.step(actions[next(step_index) % len(actions)]), args.steps)

    obs = torch.zeros(1, 1, 4)
    last = torch.zeros(1, 1, 2)
    state = {"lstm": None}

    def eager():
        with torch.no_grad():
            _, state["lstm"] = actor.deterministic(obs, last, state["lstm"])

    traced_state = {"h": torch.zeros(1, 1, actor.trunk.hidden), "c": None}
    traced_state["c"] = traced_state["h"].clone()

    class _Step(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.actor = actor

        def forward(self, o, a, h, c):
            action, (h, c) = self.actor.deterministic(o, a, (h, c))
            return action, h, c

    with torch.no_grad():
        traced = torch.jit.trace(_Step(), (obs, last, traced_state["h"], traced_state["c"]))

    def script():
        with torch.no_grad():
            _, traced_state["h"], traced_state["c"] = traced(
                obs, last, traced_state["h"], traced_state["c"]
            )

    policy = NumpyPolicy(actor)
    np_state = {"one": policy.initial_state(1), "ten": policy.initial_state(10)}
    o1, a1 = np.zeros((1, 4)), np.zeros((1, 2))
    o10, a10 = np.zeros((10, 4)), np.zeros((10, 2))

    def numpy_one():
        _, np_state["one"] = policy.step(o1, a1, np_state["one"])

    def numpy_ten():
        _, np_state["ten"] = policy.step(o10, a10, np_state["ten"])

    rows = {
        "environment step": env_step,
        "torch eager": _per_call(eager, args.steps),
        "torchscript (traced)": _per_call(script, args.steps),
        "numpy fused": _per_call(numpy_one, args.steps),
        "numpy fused, 10 rollouts (per rollout)": _per_call(numpy_ten, args.steps) / 10,
    }
    start = time.perf_counter()
    refine(graph, values, "lm", 100)
    lm100 = time.perf_counter() - start
    start = time.perf_counter()
    RLInitializer(model=args.model, cycles=12).initialize(graph, values)
    rl = time.perf_counter() - start
    print(f"hidden {actor.trunk.hidden}; per edge visited, relative to one environment step")
    print(f"{'way':<42}{'x env step':>12}")
    for name, seconds in rows.items():
        print(f"{name:<42}{seconds / env_step:>12.2f}")
    print(f"RL on M3500 (12 cycles, 1 rollout) / GTSAM LM100 from odometry: {rl / lm100:.2f}")
    out = write_result("inference", {
        "model": args.model, "hidden": actor.trunk.hidden,
        "seconds_per_step": rows,
        "relative_to_env_step": {k: v / env_step for k, v in rows.items()},
        "m3500_rl_seconds_over_lm100": rl / lm100,
    })
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
