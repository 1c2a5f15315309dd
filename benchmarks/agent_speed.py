"""The agent's costs: an environment step, a policy step each way it can run, and one RL cycle
on large graphs, each against GTSAM's LM on the same graph in the same run.

    python benchmarks/agent_speed.py step [--repeats 3]
    python benchmarks/agent_speed.py policy [--model preset1] [--steps 3000]
    python benchmarks/agent_speed.py scale [--sizes 10000,30000,100000] [--model preset1]

``step`` (results ``env_step``): one full cycle of M3500 with random actions, as a ratio to
one GTSAM LM30 on the same graph; each figure the best of ``--repeats`` runs.

``policy`` (results ``inference``): per edge visited, torch eager (one LSTM step a call),
TorchScript (traced), the fused numpy policy, and the numpy policy batched over 10 rollouts
(per rollout), against one environment step; then one whole RL pass over M3500 (12 cycles,
one rollout) against GTSAM LM100 from odometry. Torch on one thread.

``scale`` (results ``agent_scale``): generated lawn-mower graphs (noisy measurements, lc
0.5); each stage (read, LM10, LAGO, one RL cycle, write) in its own process, which reads the
file first; seconds as ratios to LM10, peak memory as the growth of the process's VmHWM over
what the read left.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402

STAGES = ("read", "lm10", "lago", "rl_cycle", "write")


def _peak_mb() -> float:
    """This process's peak resident set, MB: VmHWM, else ``ru_maxrss``."""
    peak = harness.vmhwm_mb()
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 if peak is None else peak


def _cycle_seconds(env, seed: int) -> tuple[float, int]:
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (env.steps_per_episode, 2))
    start = time.perf_counter()
    for action in actions:
        env.step(action)
    return time.perf_counter() - start, len(actions)


def step(args) -> dict:
    """One full cycle of M3500 with random actions against one GTSAM LM30 (best of
    ``--repeats`` each)."""
    from rlpgo_gtsam import PoseGraphEnv, read_g2o, refine

    graph, values = read_g2o(harness.shared_file("M3500"))
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
    return {"graph": "M3500.g2o", "steps": steps, "cycle_seconds": cycle,
            "lm30_seconds": lm30, "lm30_iterations": result.iterations,
            "cycle_over_lm30": ratio, "microseconds_per_step": cycle / steps * 1e6}




def _per_call(function, steps: int) -> float:
    function()  # warm up
    start = time.perf_counter()
    for _ in range(steps):
        function()
    return (time.perf_counter() - start) / steps


def policy(args) -> dict:
    """One policy step, each way of running the agent, against one environment step; one RL
    pass over M3500 against LM100."""
    import torch

    from rlpgo_gtsam import PoseGraphEnv, RLInitializer, read_g2o, refine
    from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
    from rlpgo_gtsam.rl.models import resolve_model

    torch.set_num_threads(1)
    model = resolve_model(args.model)
    actor = model.actor
    graph, values = read_g2o(harness.shared_file("M3500"))
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
    return {"model": args.model, "hidden": actor.trunk.hidden, "seconds_per_step": rows,
            "relative_to_env_step": {k: v / env_step for k, v in rows.items()},
            "m3500_rl_seconds_over_lm100": rl / lm100}


def _stage(stage: str, path: str, model: str) -> dict:
    """Run one stage in this process; returns seconds and peak memory growth."""
    from rlpgo_gtsam import (
        RLInitializer,
        extract_pose_graph,
        make_initializer,
        read_g2o,
        refine,
        write_g2o,
    )
    from rlpgo_gtsam.rl.episode import rollout

    before = _peak_mb()
    start = time.perf_counter()
    graph, values = read_g2o(path)
    seconds = time.perf_counter() - start
    if stage != "read":
        before = _peak_mb()
        start = time.perf_counter()
        if stage == "lm10":
            refine(graph, values, "lm", 10)
        elif stage == "lago":
            make_initializer("lago").initialize(graph, values)
        elif stage == "rl_cycle":
            rl = RLInitializer(model=model, cycles=1)
            pose_graph = extract_pose_graph(graph, values)
            start = time.perf_counter()  # the RL pass alone: the rollout over one cycle
            rollout(rl.policy, pose_graph, pose_graph.poses[:, 2], 1,
                    rl.model.env_config.action_range_rad, rl.last_actions())
        elif stage == "write":
            with tempfile.TemporaryDirectory() as folder:
                write_g2o(Path(folder) / "out.g2o", graph, values)
        seconds = time.perf_counter() - start
    return {"seconds": seconds, "peak_mb": _peak_mb() - before,
            "edges": graph.size(), "poses": values.size()}


def scale(args) -> dict:
    """Read, LM10, LAGO, one RL cycle and write on growing graphs, each in its own process."""
    from rlpgo_gtsam import generate, write_g2o

    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for size in (int(s) for s in args.sizes.split(",")):
            path = Path(folder) / f"scale_{size}.g2o"
            sample = generate(size, 0.05, 0.05, 3.0, 0.5, np.random.default_rng(size),
                              noisy_measurements=True)
            write_g2o(path, sample.graph, sample.initial)
            row = {"poses": size}
            for stage in STAGES:
                out = subprocess.run(
                    [sys.executable, __file__, "stage", stage, str(path), args.model],
                    capture_output=True, text=True, check=True, cwd=harness.ROOT,
                )
                result = json.loads(out.stdout.strip().splitlines()[-1])
                row["edges"] = result["edges"]
                row[f"{stage}_seconds"] = result["seconds"]
                row[f"{stage}_peak_mb"] = result["peak_mb"]
            for stage in STAGES:
                row[f"{stage}_over_lm10"] = row[f"{stage}_seconds"] / row["lm10_seconds"]
            row["rl_cycle_us_per_edge"] = row["rl_cycle_seconds"] / row["edges"] * 1e6
            rows.append(row)
            print(json.dumps(row), flush=True)
    per_edge = [r["rl_cycle_us_per_edge"] for r in rows]
    return {"rows": rows, "rl_us_per_edge_max_over_min": max(per_edge) / min(per_edge)}


def scale_table(data: dict) -> str:
    """Seconds over LM10, the RL cycle's microseconds per edge and the peaks, per size."""
    lines = ["| poses | edges | " + " | ".join(f"{s} / LM10" for s in STAGES) + " | RL us/edge | "
             + " | ".join(f"{s} MB" for s in STAGES) + " |", "|---" * (3 + 2 * len(STAGES)) + "|"]
    for row in data["rows"]:
        lines.append(f"| {row['poses']} | {row['edges']} | "
                     + " | ".join(f"{row[f'{s}_over_lm10']:.3f}" for s in STAGES)
                     + f" | {row['rl_cycle_us_per_edge']:.1f} | "
                     + " | ".join(f"{row[f'{s}_peak_mb']:.1f}" for s in STAGES) + " |")
    lines.append(f"\nRL pass, seconds per edge, largest / smallest: "
                 f"{data['rl_us_per_edge_max_over_min']:.2f}")
    return "\n".join(lines) + "\n"


def main() -> None:
    if len(sys.argv) == 5 and sys.argv[1] == "stage":  # one stage of scale, in this process
        print(json.dumps(_stage(*sys.argv[2:])))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    st = sub.add_parser("step", help="an environment cycle against LM30")
    st.add_argument("--repeats", type=int, default=3)
    po = sub.add_parser("policy", help="a policy step each way, against an environment step")
    po.add_argument("--model", default="preset1")
    po.add_argument("--steps", type=int, default=3000)
    sc = sub.add_parser("scale", help="one RL cycle on large graphs, per edge")
    sc.add_argument("--sizes", default="10000,30000,100000")
    sc.add_argument("--model", default="preset1")
    for each, name in ((st, "env_step"), (po, "inference"), (sc, "agent_scale")):
        each.add_argument("--name", default=name, help="results file name")
    args = parser.parse_args()
    run = {"step": step, "policy": policy, "scale": scale}[args.command]
    data = run(args)
    table = scale_table(data) if args.command == "scale" else None
    if table:
        print(table)
    print(f"wrote {harness.write_result(args.name, harness.command_line(), data, table)}")


if __name__ == "__main__":
    main()
