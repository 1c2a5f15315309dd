"""How the certified stage scales, against SE-Sync: easy generated graphs from 5k to 50k poses
(growth), and the hard ones where the relaxation is not exact (every status, chi2 after
GTSAM LM30); this checkout ("after") and, with ``--base``, another ("before"), each case run
in a fresh process, the versions and SE-Sync one after the other per case.

    python benchmarks/relaxation_scale.py [--base /tmp/main-checkout] [--cap 600]
        [--easy 5000,10000,20000,50000] [--hard 1000:0.3:0.5,1000:0.5:0.5,500:3:1,2000:3:1]
        [--sesync BINARY] [--sesync-cap 600] [--cache /tmp/relaxation_scale]
        [--name relaxation_scale] [--append]

Graphs: ``rlpgo-generate --n N --sigma-r S --lc LC --noisy-measurements --seed 1`` (sigma_t
0.05, d 3), cached as g2o files under ``--cache``; easy: sigma_R 0.05, lc 0.3; hard cases are
``N:S:LC``. Per run: CPU seconds (``time.process_time``, one BLAS thread) of the certified
stage as ``rlpgo-init --method certified --refine none`` runs it
(``make_initializer("certified").run``: chordal start, staircase, translations), its status,
final rank, trust-region steps and Hessian products; on hard graphs also chi2 after LM30 from
its estimate. SE-Sync (``benchmarks/sesync``'s driver, default options, one thread; skipped
without a binary): CPU seconds of its whole process (``getrusage``: file reading and the
driver's own eigenvalue check included, so an upper bound), its wall seconds of the
``SESync`` call, status, rank, and chi2 after LM30 from its estimate. A run over ``--cap``
(SE-Sync: ``--sesync-cap``) wall seconds is killed and reported as ``cap``. Prints a
markdown table, writes ``benchmarks/results/<name>.json`` and ``.md``; ``--append`` adds the
rows to those of an earlier run of the same name (to keep each run short).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import RESULTS, ROOT, write_result  # noqa: E402

# The worker runs in a child process whose PYTHONPATH picks the checkout under test.
WORKER = r"""
import json, sys, time
from rlpgo_gtsam import PoseGraph2D, make_initializer, read_g2o, refine
from rlpgo_gtsam.numerics import bounded_threads
import rlpgo_gtsam.staircase as staircase

path, with_lm = sys.argv[1], sys.argv[2] == "1"
graph, values = read_g2o(path)
pose_graph = PoseGraph2D.from_gtsam(graph, values)
counts = {"steps": 0, "hessian_products": 0}
truncated_cg = staircase.truncated_cg

def counted(grad, hess, pre, radius, *args, **kwargs):
    counts["steps"] += 1
    def product(v):
        counts["hessian_products"] += 1
        return hess(v)
    return truncated_cg(grad, product, pre, radius, *args, **kwargs)

staircase.truncated_cg = counted
with bounded_threads():
    cpu, wall = time.process_time(), time.perf_counter()
    result = make_initializer("certified").run(pose_graph)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
certificate = result.certificate
row = {"cpu_s": cpu, "wall_s": wall, "rank": certificate.rank,
       "status": str(certificate.status), "estimate_cost": certificate.estimate_cost, **counts}
if with_lm:
    row["lm30_chi2"] = refine(graph, result.values, "lm", 30).chi2
print("RESULT " + json.dumps(row))
"""

SESYNC_LM = r"""
import json, sys
import numpy as np
from rlpgo_gtsam import PoseGraph2D, read_g2o, refine
graph, values = read_g2o(sys.argv[1])
pose_graph = PoseGraph2D.from_gtsam(graph, values)
poses = np.array(json.loads(sys.stdin.read()))
print("RESULT " + json.dumps({"lm30_chi2": refine(graph, pose_graph.to_values(poses), "lm",
                                                   30).chi2}))
"""


def _graph(cache: Path, n: int, sigma_r: float, lc: float) -> Path:
    """The cached g2o file of one generated graph (generated once, as rlpgo-generate)."""
    path = cache / f"n{n}_s{sigma_r:g}_lc{lc:g}_seed1.g2o"
    if not path.exists():
        import numpy as np

        from rlpgo_gtsam import generate, write_g2o

        sample = generate(n, sigma_r, 0.05, 3.0, lc, np.random.default_rng(1),
                          noisy_measurements=True)
        write_g2o(path, sample.graph, sample.initial)
    return path


def _child_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _result(command: list[str], env: dict, cap: float, cwd: Path,
            stdin: str | None = None) -> dict:
    started = time.perf_counter()
    try:
        done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=cap,
                              cwd=cwd, input=stdin)
    except subprocess.TimeoutExpired:
        return {"status": "cap", "wall_s": time.perf_counter() - started}
    for line in done.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT "):])
    return {"status": "error", "error": (done.stderr.strip().splitlines() or ["?"])[-1]}


def _run(checkout: Path, path: Path, with_lm: bool, cap: float) -> dict:
    """The certified stage in a fresh process on ``checkout``'s code, killed at ``cap``."""
    env = {**os.environ, "PYTHONPATH": f"{checkout}{os.pathsep}{checkout / 'cli'}",
           "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    return _result([sys.executable, "-c", WORKER, str(path), "1" if with_lm else "0"], env,
                   cap, checkout)  # python -c puts the cwd first on sys.path


def _sesync(binary: str, path: Path, with_lm: bool, cap: float) -> dict:
    """SE-Sync's driver on ``path``: its process's CPU seconds, its result, LM30 from it."""
    from benchmarks.sesync.runner import run_sesync

    before = _child_cpu()
    try:
        run = run_sesync(binary, path, timeout=cap)
    except RuntimeError as error:
        text = str(error)
        return {"status": "cap" if "timed out" in text.lower() else "error", "error": text,
                "cpu_s": _child_cpu() - before, "wall_s": cap}
    row = {"cpu_s": _child_cpu() - before, "wall_s": run.seconds, "status": run.status,
           "rank": run.rank, "certified": run.certified}
    if with_lm:
        env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{ROOT / 'cli'}"}
        row.update(_result([sys.executable, "-c", SESYNC_LM, str(path)], env, cap, ROOT,
                           json.dumps(run.poses.tolist())))
    return row


def _cell(row: dict | None, with_lm: bool) -> str:
    if row is None:
        return "-"
    if row["status"] == "cap":
        cpu = f", {row['cpu_s']:.0f} s CPU" if "cpu_s" in row else ""
        return f"cap ({row.get('wall_s', 0):.0f} s wall{cpu})"
    if row["status"] == "error":
        return "error"
    text = f"{row['cpu_s']:.2f} s, {row['status']} r{row['rank']}"
    if "steps" in row:
        text += f", {row['steps']} steps, {row['hessian_products']} Hv"
    if with_lm and row.get("lm30_chi2") is not None:
        text += f", LM30 {row['lm30_chi2']:.8g}"
    return text


def _growth(rows: list[dict], name: str) -> None:
    """The exponent of CPU seconds against poses between consecutive easy sizes (runs that
    ended, capped ones left out)."""
    easy = [r for r in rows if r["kind"] == "easy" and (r.get(name) or {}).get("cpu_s")
            and r[name]["status"] not in ("cap", "error")]
    for a, b in zip(easy, easy[1:], strict=False):
        b[name]["growth"] = math.log(b[name]["cpu_s"] / a[name]["cpu_s"]) / \
            math.log(b["poses"] / a["poses"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", type=Path, help="checkout of the 'before' code")
    parser.add_argument("--after", type=Path, default=ROOT,
                        help="checkout of the 'after' code (default: this one)")
    parser.add_argument("--cap", type=float, default=600.0, help="wall seconds per run")
    parser.add_argument("--easy", default="5000,10000,20000,50000")
    parser.add_argument("--hard", default="1000:0.3:0.5,1000:0.5:0.5,500:3:1,2000:3:1",
                        help="N:SIGMA_R:LC per hard graph")
    parser.add_argument("--sesync", help="SE-Sync driver (default: $RLPGO_SESYNC_BINARY or "
                        "none); 'none' skips it")
    parser.add_argument("--sesync-cap", type=float, help="wall seconds per SE-Sync run "
                        "(default: --cap)")
    parser.add_argument("--cache", type=Path, default=Path("/tmp/relaxation_scale"))
    parser.add_argument("--name", default="relaxation_scale")
    parser.add_argument("--append", action="store_true",
                        help="add the rows to benchmarks/results/<name>.json's")
    args = parser.parse_args()
    from benchmarks.sesync.runner import default_binary

    binary = None if args.sesync == "none" else (args.sesync or default_binary())
    args.cache.mkdir(parents=True, exist_ok=True)
    cases = []
    for spec in filter(None, args.hard.split(",")):
        n, sigma_r, lc = spec.split(":")
        cases.append(("hard", int(n), float(sigma_r), float(lc)))
    cases += [("easy", int(n), 0.05, 0.3) for n in filter(None, args.easy.split(","))]
    versions = [("after", args.after)] + ([("before", args.base)] if args.base else [])
    columns = [name for name, _ in versions] + (["sesync"] if binary else [])
    header = ("| graph | " + " | ".join(f"{name}: CPU s, status, rank, steps, Hv, LM30 chi2"
                                         for name in columns) + " |\n|---|"
              + "---|" * len(columns))
    print(header, flush=True)
    rows: list[dict] = []
    commands = ["python benchmarks/relaxation_scale.py " + " ".join(sys.argv[1:])]
    if args.append and (RESULTS / f"{args.name}.json").exists():
        earlier = json.loads((RESULTS / f"{args.name}.json").read_text())
        rows, commands = earlier["rows"], earlier["commands"] + commands
    for kind, n, sigma_r, lc in cases:
        path = _graph(args.cache, n, sigma_r, lc)
        row: dict = {"graph": f"{kind} n={n} sigma_R={sigma_r:g} lc={lc:g}", "kind": kind,
                     "poses": n, "sigma_r": sigma_r, "lc": lc}
        with_lm = kind == "hard"
        for name, checkout in versions:  # one after the other, in one run
            row[name] = _run(checkout, path, with_lm, args.cap)
        if binary:
            row["sesync"] = _sesync(binary, path, with_lm, args.sesync_cap or args.cap)
        rows.append(row)
        print(f"| {row['graph']} | " + " | ".join(_cell(row[c], with_lm) for c in columns)
              + " |", flush=True)
        write_result(args.name, {"commands": commands, "rows": rows})
    rows.sort(key=lambda row: (row["kind"], row["poses"], row["sigma_r"]))
    for name in columns:
        for row in rows:
            (row.get(name) or {}).pop("growth", None)
        _growth(rows, name)
    lines = [header]
    for row in rows:
        cells = []
        for name in columns:
            cell = _cell(row.get(name), row["kind"] == "hard")
            if "growth" in row.get(name, {}):
                cell += f" (growth n^{row[name]['growth']:.2f})"
            cells.append(cell)
        lines.append(f"| {row['graph']} | " + " | ".join(cells) + " |")
    table = "\n".join(lines) + "\n"
    print(table)
    write_result(args.name, {"commands": commands, "rows": rows})
    (RESULTS / f"{args.name}.md").write_text(table)


if __name__ == "__main__":
    main()
