"""Large graphs, in process: seconds and peak memory of read, LAGO, one RL cycle (the agent)
and write, per edge.

    python benchmarks/agent_scale.py [--sizes 10000,30000,100000] [--model preset1]

Each size is a generated lawn-mower graph (noisy measurements, lc 0.5). Each stage runs in
its own process, which reads the file first; its peak memory is the growth of the
process's peak resident set (VmHWM, which exec resets) over what the read left. Seconds
are reported as ratios to GTSAM LM10 on the same graph, measured the same way in this run.
Writes benchmarks/results/agent_scale.json and prints a table. (Named scale.py until the
process-to-process ``benchmarks/scale.py`` took its name; the committed
``results/agent_scale.*`` predate the peak's fix: their peaks read ``ru_maxrss``, which a
child started by a larger parent inherits, so they are too low where the parent was larger.
Their seconds are unaffected.)
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.processes import vmhwm_mb  # noqa: E402

STAGES = ("read", "lm10", "lago", "rl_cycle", "write")


def _peak_mb() -> float:
    """This process's peak resident set, MB: VmHWM, which exec resets (``ru_maxrss`` keeps
    the high-water mark of the process that forked it)."""
    peak = vmhwm_mb()
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 if peak is None else peak


def _stage(stage: str, path: str, model: str) -> dict:
    """Run one stage in this process; returns seconds and peak memory growth."""
    from rlpgo_gtsam import RLInitializer, make_initializer, read_g2o, refine, write_g2o
    from rlpgo_gtsam.graph import PoseGraph2D
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
            pose_graph = PoseGraph2D.from_gtsam(graph, values)
            start = time.perf_counter()  # the RL pass alone: the rollout over one cycle
            rollout(rl.policy, pose_graph, pose_graph.poses[:, 2], 1,
                    rl.model.env_config.action_range_rad, rl.last_actions())
        elif stage == "write":
            with tempfile.TemporaryDirectory() as folder:
                write_g2o(Path(folder) / "out.g2o", graph, values)
        seconds = time.perf_counter() - start
    return {"seconds": seconds, "peak_mb": _peak_mb() - before,
            "edges": graph.size(), "poses": values.size()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,30000,100000")
    parser.add_argument("--model", default="preset1")
    parser.add_argument("--stage", help=argparse.SUPPRESS)
    parser.add_argument("--file", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.stage:
        print(json.dumps(_stage(args.stage, args.file, args.model)))
        return
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
                    [sys.executable, __file__, "--stage", stage, "--file", str(path),
                     "--model", args.model],
                    capture_output=True, text=True, check=True, cwd=ROOT,
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
    header = f"{'poses':>8}{'edges':>8}" + "".join(f"{s + '/LM10':>14}" for s in STAGES) + \
        f"{'RL us/edge':>12}" + "".join(f"{s + ' MB':>12}" for s in STAGES)
    print(header)
    for row in rows:
        print(f"{row['poses']:>8}{row['edges']:>8}"
              + "".join(f"{row[f'{s}_over_lm10']:>14.3f}" for s in STAGES)
              + f"{row['rl_cycle_us_per_edge']:>12.1f}"
              + "".join(f"{row[f'{s}_peak_mb']:>12.1f}" for s in STAGES))
    per_edge = [r["rl_cycle_us_per_edge"] for r in rows]
    summary = {"rl_us_per_edge_max_over_min": max(per_edge) / min(per_edge)}
    print(f"RL pass, seconds per edge, largest / smallest: "
          f"{summary['rl_us_per_edge_max_over_min']:.2f}")
    sys.path.insert(0, str(ROOT))
    from benchmarks.common import write_result

    print(f"wrote {write_result('agent_scale', {'rows': rows, **summary})}")


if __name__ == "__main__":
    main()
