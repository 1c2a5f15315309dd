"""Large graphs, process to process: ``rlpgo-init FILE -o OUT`` on generated graphs of 10k,
100k and 200k poses (seconds per phase, peak memory, growth with size) against SE-Sync +
GTSAM LM30 in the same run; and ``--budget`` kept: wall seconds against 1.2 x the budget on
the largest graph and on a hard 2000-pose graph, with what the command said it cut.

    python benchmarks/scale.py [--sizes 10000,100000,200000] [--repeats 1] [--sesync BIN]
        [--budget 30] [--hard-n 2000] [--cache DIR] [--timeout 600]
        [--no-budget | --budget-only] [--name scale]

Graphs (made once into ``--cache``, a folder outside the repository, and reused): the easy
ones are ``rlpgo-generate --n N --sigma-r 0.05 --sigma-t 0.05 --d 3 --lc 0.3
--noisy-measurements --seed 1`` (the graphs of ``benchmarks/g2o_speed.py``); the hard one is
``rlpgo-generate --n 2000 --sigma-r 3.0 --lc 1.0 --noisy-measurements --seed 1``.

Per size: ``rlpgo-init FILE -o OUT`` as a user runs it (median wall seconds of ``--repeats``
runs, start to exit, and the process's peak resident set from ``wait4``;
``benchmarks/processes.py``), then one instrumented run of it (``processes.probe``): seconds
of each step (start-up, import, read, extraction, certified stage, LM, write, exit) and the
peak resident set (VmHWM) after each; with the SE-Sync driver (``--sesync`` or
``$RLPGO_SESYNC_BINARY``), SE-Sync + LM30 as two processes, as ``benchmarks/process.py``
runs them. Growth: for each pair of consecutive sizes, the exponent k in seconds ~ edges^k
(1 is linear). Budget rows: ``rlpgo-init FILE -o OUT --budget B`` once each; "within" is
wall seconds <= 1.2 B, the process's start-up and exit included. ``--budget-only`` runs
only these (the largest of ``--sizes`` is the easy graph), no size rows.

Prints the tables, writes ``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import processes  # noqa: E402
from benchmarks.common import RESULTS, write_result  # noqa: E402
from benchmarks.process import (  # noqa: E402
    add_common_options,
    cell,
    check_binaries,
    chi2_of,
    graph_size,
    median,
    run_baseline,
    run_ours,
)

EASY = {"sigma_r": 0.05, "sigma_t": 0.05, "d": 3.0, "lc": 0.3, "seed": 1}
HARD = {"sigma_r": 3.0, "lc": 1.0, "seed": 1}
GROWTH = ("total", "read", "certified", "LM", "write", "SE-Sync", "LM30", "peak MB")


def _size_row(n: int, path: Path, folder: Path, args) -> dict:
    import gtsam

    poses, edges = graph_size(path, 2)
    out = folder / "ours.g2o"
    runs = [run_ours(path, out, args.timeout) for _ in range(args.repeats)]
    graph, _ = gtsam.readG2o(str(path), False)
    last = runs[-1]
    row = {"n": n, "poses": poses, "edges": edges, "file_mb": path.stat().st_size / 2**20,
           "ours_seconds": median([r["seconds"] for r in runs if r["failure"] is None]),
           "ours_seconds_all": [r["seconds"] for r in runs],
           "ours_peak_mb": median([r["peak_mb"] for r in runs]),
           "ours_failure": last["failure"], "ours_certified": last["certified"],
           "ours_stopped": last["stopped"], "ours_last_line": last["last"],
           "ours_chi2": chi2_of(graph, out, 2) if last["failure"] is None else None}
    phases = processes.probe([str(path), "-o", str(folder / "probe.g2o"), "--overwrite"],
                             args.timeout)
    phases.pop("stdout")
    row["phases"] = phases
    if args.sesync:
        base = run_baseline(path, folder, args.sesync, args.sesync_threads, args.timeout, False)
        row.update(base)
        if base.get("lm30_failure", "no run") is None:
            row["baseline_seconds"] = base["sesync_seconds"] + base["lm30_seconds"]
            if row["ours_seconds"] is not None:
                row["ratio"] = row["ours_seconds"] / row["baseline_seconds"]
    return row


def _figures(row: dict) -> dict[str, float | None]:
    """The figures whose growth is reported, for one size."""
    seconds = row["phases"]["seconds"]
    return {"total": row["ours_seconds"], "read": seconds["read"],
            "certified": seconds["certified"], "LM": seconds["LM"], "write": seconds["write"],
            "SE-Sync": row.get("sesync_seconds"), "LM30": row.get("lm30_seconds"),
            "peak MB": row["ours_peak_mb"]}


def _growth(rows: list[dict]) -> list[dict]:
    """Exponent k of figure ~ edges^k between consecutive sizes."""
    found = []
    for a, b in zip(rows, rows[1:], strict=False):
        fa, fb = _figures(a), _figures(b)
        scale = math.log(b["edges"] / a["edges"])
        exponents = {key: (math.log(fb[key] / fa[key]) / scale
                           if fa[key] and fb[key] and fa[key] > 0 and fb[key] > 0 else None)
                     for key in GROWTH}
        found.append({"from": a["n"], "to": b["n"], **exponents})
    return found


def _budget_row(name: str, path: Path, folder: Path, args) -> dict:
    poses, edges = graph_size(path, 2)
    run = run_ours(path, folder / "budget.g2o", args.timeout, ("--budget", f"{args.budget:g}"))
    limit = 1.2 * args.budget
    return {"graph": name, "poses": poses, "edges": edges, "budget": args.budget,
            "limit": limit, "seconds": run["seconds"], "failure": run["failure"],
            "within": run["seconds"] is not None and run["seconds"] <= limit,
            "certified": run["certified"], "stopped": run["stopped"], "last_line": run["last"]}


def _tables(rows: list[dict], growth: list[dict], budgets: list[dict]) -> str:
    steps = ("start-up", "import", "read", "extraction", "certified", "LM", "write", "exit")
    head = ["poses", "edges", "file MB", "ours s", *(f"{s} s" for s in steps),
            "peak MB (after read / default / write)", "SE-Sync s", "LM30 s",
            "ours / (SE-Sync + LM30)", "peak MB (SE-Sync / LM30)", "chi2 (ours / SE-Sync + LM30)",
            "certified (ours / SE-Sync)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] if rows else []
    for r in rows:
        seconds, peaks = r["phases"]["seconds"], r["phases"]["peaks_mb"]
        ours = cell(r["ours_seconds"]) if r["ours_failure"] is None else \
            f"fails: {r['ours_failure'][:60]}"
        peak = f"{cell(r['ours_peak_mb'], '.0f')} (" + " / ".join(
            cell(peaks.get(s), ".0f") for s in ("read", "default", "write")) + ")"
        sesync = cell(r.get("sesync_seconds")) if not r.get("sesync_failure") else \
            f"fails: {r['sesync_failure'][:60]}"
        lines.append("| " + " | ".join([
            str(r["poses"]), str(r["edges"]), cell(r["file_mb"], ".1f"), ours,
            *(cell(seconds[s]) for s in steps), peak, sesync, cell(r.get("lm30_seconds")),
            cell(r.get("ratio")),
            f"{cell(r.get('sesync_peak_mb'), '.0f')} / {cell(r.get('lm30_peak_mb'), '.0f')}",
            f"{cell(r['ours_chi2'], '.6g')} / {cell(r.get('lm30_chi2'), '.6g')}",
            f"{cell(r['ours_certified'])} / {cell(r.get('sesync_certified'))}"]) + " |")
    text = "\n".join(lines) + "\n" if rows else ""
    if growth:
        text += "\nGrowth: k in figure ~ edges^k between consecutive sizes (1: linear)\n\n"
        text += "| sizes | " + " | ".join(GROWTH) + " |\n|" + "---|" * (len(GROWTH) + 1) + "\n"
        for g in growth:
            text += f"| {g['from']} -> {g['to']} | " + " | ".join(
                cell(g[key]) for key in GROWTH) + " |\n"
    if budgets:
        text += "\n`rlpgo-init FILE -o OUT --budget B`, once each\n\n"
        text += ("| graph | poses | edges | budget s | wall s | 1.2 x budget | within | "
                 "certified | stopped | last line |\n|" + "---|" * 10 + "\n")
        for b in budgets:
            wall = cell(b["seconds"]) if b["failure"] is None else f"fails: {b['failure']}"
            text += "| " + " | ".join([
                b["graph"], str(b["poses"]), str(b["edges"]), f"{b['budget']:g}", wall,
                f"{b['limit']:g}", cell(b["within"]), cell(b["certified"]),
                b["stopped"] or "-", (b["last_line"] or "-").replace("|", "/")]) + " |\n"
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_common_options(parser, "scale")
    parser.add_argument("--sizes", default="10000,100000,200000")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--budget", type=float, default=30.0)
    parser.add_argument("--hard-n", type=int, default=2000)
    parser.add_argument("--no-budget", action="store_true")
    parser.add_argument("--budget-only", action="store_true",
                        help="only the budget rows (the easy graph: the largest of --sizes)")
    args = parser.parse_args()
    if args.no_budget and args.budget_only:
        parser.error("--no-budget and --budget-only leave nothing to run")
    check_binaries(parser, args, ("sesync",))
    print(f"SE-Sync driver: {args.sesync or 'none (left out)'}", flush=True)
    sizes = [int(s) for s in args.sizes.split(",")]
    rows, budgets = [], []
    with tempfile.TemporaryDirectory(prefix="rlpgo_scale_") as name:
        folder = Path(name)
        for n in [] if args.budget_only else sizes:
            path = processes.generated_graph(args.cache, n, **EASY)
            rows.append(_size_row(n, path, folder, args))
            print(json.dumps(rows[-1]), flush=True)
        if not args.no_budget:
            largest = processes.generated_graph(args.cache, max(sizes), **EASY)
            hard = processes.generated_graph(args.cache, args.hard_n, **HARD)
            for label, path in ((f"easy n={max(sizes)}", largest),
                                (f"hard n={args.hard_n} sigma_R=3 lc=1", hard)):
                budgets.append(_budget_row(label, path, folder, args))
                print(json.dumps(budgets[-1]), flush=True)
    growth = _growth(rows)
    command = "python benchmarks/scale.py " + " ".join(sys.argv[1:])
    steps = "; step seconds from one instrumented run" if rows else ""
    text = (f"Made by `{command.strip()}`: wall seconds of whole processes{steps}; chi2 = 2 x "
            "GTSAM error.\n\n" + _tables(rows, growth, budgets).lstrip("\n"))
    print(text)
    (RESULTS / f"{args.name}.md").write_text(text)
    result = {"command": command.strip(), "rows": rows, "growth": growth, "budget": budgets,
              "peak_floor_mb": processes.launcher_floor_mb(), "sesync": str(args.sesync),
              "sesync_threads": args.sesync_threads, "easy": EASY, "hard": HARD}
    print(f"wrote {write_result(args.name, result)}")


if __name__ == "__main__":
    main()
