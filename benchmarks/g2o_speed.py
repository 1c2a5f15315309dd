"""g2o reading and writing against GTSAM's own: seconds (wall and CPU) and peak memory.

    python benchmarks/g2o_speed.py [--sizes 10000,100000,200000] [--repeats 3] [--folder DIR]

Each size is a generated lawn-mower graph (sigma 0.05, d 3, lc 0.3, noisy measurements,
seed 1: what ``rlpgo-generate --n N --sigma-r 0.05 --sigma-t 0.05 --d 3 --lc 0.3
--noisy-measurements --seed 1`` writes; kept in --folder as g2o_speed_N.g2o when given, and
reused from there). In one process, each
repetition runs ``read_g2o`` and ``gtsam.readG2o(path, False)`` alternately, then
``write_g2o`` and ``gtsam.writeG2o`` of the graph ``read_g2o`` gave; each is reported as its
best over the repetitions, in wall seconds and in CPU seconds (``time.process_time``, the
fairer figure on a shared machine). Our read is split into parsing (the file's table) and
building the GTSAM graph. Peak memory is the maximum resident set of a fresh process that
imports, then reads the file once (each reader in its own process; VmHWM, as
ru_maxrss survives exec), and its growth over the same process before the read.
Writes benchmarks/results/g2o_speed.json and prints a table.
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


def _peak_mb() -> float:
    """The process's peak resident set, MB. Linux keeps ru_maxrss across fork and exec, so
    a child started by a large parent would report the parent's size: the high-water mark
    of /proc/self/status (VmHWM, reset by exec) is taken where it exists."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _peak(reader: str, path: str) -> dict:
    """Read ``path`` once with ``reader`` in this (fresh) process; its peak memory."""
    import gtsam

    from rlpgo_gtsam.g2o import read_g2o

    before = _peak_mb()
    graph, _values = read_g2o(path) if reader == "ours" else gtsam.readG2o(path, False)
    return {"peak_mb": _peak_mb(), "growth_mb": _peak_mb() - before, "factors": graph.size()}


def _timed(call) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    call()
    return time.perf_counter() - wall, time.process_time() - cpu


def _measure(path: Path, repeats: int, folder: Path) -> dict:
    import gtsam

    from rlpgo_gtsam import g2o

    names = ("read", "gtsam_read", "parse", "build", "write", "gtsam_write")
    wall = {name: [] for name in names}
    cpu = {name: [] for name in names}

    def record(name: str, call) -> None:
        w, c = _timed(call)
        wall[name].append(w)
        cpu[name].append(c)

    graph, values = g2o.read_g2o(path)
    tables = []
    for _ in range(repeats):
        record("read", lambda: g2o.read_g2o(path))
        record("gtsam_read", lambda: gtsam.readG2o(str(path), False))
        record("parse", lambda: tables.append(g2o._read_table(path, fast=True)))
        record("build", lambda: g2o._build(path, tables.pop()))
        record("write", lambda: g2o.write_g2o(folder / "ours.g2o", graph, values))
        record("gtsam_write", lambda: gtsam.writeG2o(graph, values, str(folder / "gtsam.g2o")))
    row = {"poses": values.size(), "edges": graph.size(), "bytes": path.stat().st_size}
    for name in names:
        row[f"{name}_wall_s"] = min(wall[name])
        row[f"{name}_cpu_s"] = min(cpu[name])
    for kind in ("wall", "cpu"):
        row[f"read_ratio_{kind}"] = row[f"read_{kind}_s"] / row[f"gtsam_read_{kind}_s"]
        row[f"write_ratio_{kind}"] = row[f"write_{kind}_s"] / row[f"gtsam_write_{kind}_s"]
    return row


def _graph_file(size: int, folder: Path) -> Path:
    from rlpgo_gtsam import generate, write_g2o

    path = folder / f"g2o_speed_{size}.g2o"
    if not path.exists():
        sample = generate(size, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(1),
                          noisy_measurements=True)
        write_g2o(path, sample.graph, sample.initial)
    return path


def _run(folder: Path, sizes: list[int], repeats: int) -> list[dict]:
    rows = []
    for size in sizes:
        path = _graph_file(size, folder)
        row = _measure(path, repeats, folder)
        for reader in ("ours", "gtsam"):  # each in a fresh process
            out = subprocess.run(
                [sys.executable, __file__, "--peak", reader, "--file", str(path)],
                capture_output=True, text=True, check=True, cwd=ROOT,
            )
            peak = json.loads(out.stdout.strip().splitlines()[-1])
            row[f"{reader}_read_peak_mb"] = peak["peak_mb"]
            row[f"{reader}_read_growth_mb"] = peak["growth_mb"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _table(rows: list[dict]) -> str:
    header = (f"{'poses':>7}{'edges':>8} | {'read':>6}{'gtsam':>7}{'ratio':>6} "
              f"{'parse':>6}{'build':>6} | {'write':>6}{'gtsam':>7}{'ratio':>6} | "
              f"{'read wall':>9}{'gtsam':>7}{'write wall':>11}{'gtsam':>7} | "
              f"{'peak MB':>8}{'gtsam':>7}")
    lines = ["CPU seconds (best of the repetitions); wall seconds; peak RSS of one read", header]
    for r in rows:
        lines.append(
            f"{r['poses']:>7}{r['edges']:>8} | {r['read_cpu_s']:>6.2f}{r['gtsam_read_cpu_s']:>7.2f}"
            f"{r['read_ratio_cpu']:>6.2f} {r['parse_cpu_s']:>6.2f}{r['build_cpu_s']:>6.2f} | "
            f"{r['write_cpu_s']:>6.2f}{r['gtsam_write_cpu_s']:>7.2f}{r['write_ratio_cpu']:>6.2f} | "
            f"{r['read_wall_s']:>9.2f}{r['gtsam_read_wall_s']:>7.2f}{r['write_wall_s']:>11.2f}"
            f"{r['gtsam_write_wall_s']:>7.2f} | {r['ours_read_peak_mb']:>8.0f}"
            f"{r['gtsam_read_peak_mb']:>7.0f}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000,200000")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--folder", type=Path, help="keep the generated files here")
    parser.add_argument("--peak", help=argparse.SUPPRESS)
    parser.add_argument("--file", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.peak:
        print(json.dumps(_peak(args.peak, args.file)))
        return
    sizes = [int(s) for s in args.sizes.split(",")]
    if args.folder:
        args.folder.mkdir(parents=True, exist_ok=True)
        rows = _run(args.folder, sizes, args.repeats)
    else:
        with tempfile.TemporaryDirectory() as folder:
            rows = _run(Path(folder), sizes, args.repeats)
    table = _table(rows)
    print(table)
    sys.path.insert(0, str(ROOT))
    from benchmarks.common import write_result

    command = "python benchmarks/g2o_speed.py " + " ".join(sys.argv[1:])
    result = {"command": command.strip(), "rows": rows, "table": table}
    print(f"wrote {write_result('g2o_speed', result)}")


if __name__ == "__main__":
    main()
