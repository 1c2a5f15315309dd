"""g2o reading and writing against GTSAM's own, 2D and 3D: CPU and wall seconds, peak memory.

    python benchmarks/g2o_speed.py [--sizes 10000,100000,200000] [--sizes-3d 10000,100000]
                                   [--repeats 3] [--folder DIR]

Each size is a generated graph, noisy measurements, seed 1: in 2D the lawn mower (sigma 0.05,
d 3, lc 0.3: what ``rlpgo-generate --n N --sigma-r 0.05 --sigma-t 0.05 --d 3 --lc 0.3
--noisy-measurements --seed 1`` writes), in 3D its layered sibling (the same with
``--dim 3``); kept in --folder as g2o_speed_N.g2o / g2o_speed_3d_N.g2o when given, and reused
from there. In one process, each repetition runs ``read_g2o`` and
``gtsam.readG2o(path, is3D)`` one after the other, then our writer and ``gtsam.writeG2o`` of
the graph our reader gave; each is reported as its best over the repetitions, in CPU seconds
(``time.process_time``, the fairer figure on a shared machine) and wall seconds, and the
ratio ours / GTSAM's. Our read is split into parsing (the file's table) and building the
GTSAM graph. Peak memory is the maximum resident set of a fresh process that imports, then
reads the file once (each reader in its own process; VmHWM, as ru_maxrss survives exec), and
its growth over the same process before the read.
Prints a table, writes ``benchmarks/results/g2o_speed.json`` and ``.md``.
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
    """The process's peak resident set, MB: VmHWM (exec resets it; ``ru_maxrss`` would carry
    a large parent's), else ``ru_maxrss``."""
    from benchmarks.harness import vmhwm_mb

    peak = vmhwm_mb()
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 if peak is None else peak


def _io(dim: int):
    """(read, parse, build, write): our reader, its two halves (the file's table, then the
    GTSAM graph from it) and our writer, for files of ``dim``."""
    from rlpgo_gtsam import read_g2o, write_g2o
    from rlpgo_gtsam.io.formats import PLANAR, SPATIAL
    from rlpgo_gtsam.io.read import build, read_table

    form = PLANAR if dim == 2 else SPATIAL
    return (read_g2o, lambda path: read_table(path, form, fast=True),
            lambda path, table: build(path, table, form), write_g2o)


def _peak(reader: str, path: str, dim: int) -> dict:
    """Read ``path`` once with ``reader`` in this (fresh) process; its peak memory."""
    import gtsam

    read = _io(dim)[0]
    before = _peak_mb()
    graph, _values = read(path) if reader == "ours" else gtsam.readG2o(path, dim == 3)
    return {"peak_mb": _peak_mb(), "growth_mb": _peak_mb() - before, "factors": graph.size()}


def _timed(call) -> tuple[float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    call()
    return time.perf_counter() - wall, time.process_time() - cpu


def _measure(path: Path, dim: int, repeats: int, folder: Path) -> dict:
    import gtsam

    read, table, build, write = _io(dim)
    names = ("read", "gtsam_read", "parse", "build", "write", "gtsam_write")
    wall = {name: [] for name in names}
    cpu = {name: [] for name in names}

    def record(name: str, call) -> None:
        w, c = _timed(call)
        wall[name].append(w)
        cpu[name].append(c)

    graph, values = read(path)
    tables = []
    for _ in range(repeats):
        record("read", lambda: read(path))
        record("gtsam_read", lambda: gtsam.readG2o(str(path), dim == 3))
        record("parse", lambda: tables.append(table(path)))
        record("build", lambda: build(path, tables.pop()))
        record("write", lambda: write(folder / "ours.g2o", graph, values))
        record("gtsam_write", lambda: gtsam.writeG2o(graph, values, str(folder / "gtsam.g2o")))
    row = {"dim": dim, "poses": values.size(), "edges": graph.size(),
           "bytes": path.stat().st_size}
    for name in names:
        row[f"{name}_wall_s"] = min(wall[name])
        row[f"{name}_cpu_s"] = min(cpu[name])
    for kind in ("wall", "cpu"):
        row[f"read_ratio_{kind}"] = row[f"read_{kind}_s"] / row[f"gtsam_read_{kind}_s"]
        row[f"write_ratio_{kind}"] = row[f"write_{kind}_s"] / row[f"gtsam_write_{kind}_s"]
    return row


def _graph_file(size: int, dim: int, folder: Path) -> Path:
    from rlpgo_gtsam import SE2, SE3, generate, write_g2o

    path = folder / (f"g2o_speed_{size}.g2o" if dim == 2 else f"g2o_speed_3d_{size}.g2o")
    if not path.exists():
        sample = generate(size, 0.05, 0.05, 3.0, 0.3, np.random.default_rng(1),
                          noisy_measurements=True, group=SE2 if dim == 2 else SE3)
        write_g2o(path, sample.graph, sample.initial)
    return path


def _run(folder: Path, sizes: dict[int, list[int]], repeats: int) -> list[dict]:
    rows = []
    for dim, dim_sizes in sizes.items():
        for size in dim_sizes:
            path = _graph_file(size, dim, folder)
            row = _measure(path, dim, repeats, folder)
            for reader in ("ours", "gtsam"):  # each in a fresh process
                out = subprocess.run(
                    [sys.executable, __file__, "--peak", reader, "--file", str(path),
                     "--dim", str(dim)],
                    capture_output=True, text=True, check=True, cwd=ROOT,
                )
                peak = json.loads(out.stdout.strip().splitlines()[-1])
                row[f"{reader}_read_peak_mb"] = peak["peak_mb"]
                row[f"{reader}_read_growth_mb"] = peak["growth_mb"]
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def _table(rows: list[dict]) -> str:
    header = (f"{'dim':>3}{'poses':>8}{'edges':>8} | {'read':>6}{'gtsam':>7}{'ratio':>6} "
              f"{'parse':>6}{'build':>6} | {'write':>6}{'gtsam':>7}{'ratio':>6} | "
              f"{'read wall':>9}{'gtsam':>7}{'write wall':>11}{'gtsam':>7} | "
              f"{'peak MB':>8}{'gtsam':>7}")
    lines = ["CPU seconds (best of the repetitions), ratio ours / GTSAM's; wall seconds; "
             "peak RSS of one read", header]
    for r in rows:
        lines.append(
            f"{r['dim']:>3}{r['poses']:>8}{r['edges']:>8} | {r['read_cpu_s']:>6.2f}"
            f"{r['gtsam_read_cpu_s']:>7.2f}{r['read_ratio_cpu']:>6.2f} {r['parse_cpu_s']:>6.2f}"
            f"{r['build_cpu_s']:>6.2f} | {r['write_cpu_s']:>6.2f}{r['gtsam_write_cpu_s']:>7.2f}"
            f"{r['write_ratio_cpu']:>6.2f} | {r['read_wall_s']:>9.2f}{r['gtsam_read_wall_s']:>7.2f}"
            f"{r['write_wall_s']:>11.2f}{r['gtsam_write_wall_s']:>7.2f} | "
            f"{r['ours_read_peak_mb']:>8.0f}{r['gtsam_read_peak_mb']:>7.0f}"
        )
    return "\n".join(lines)


def _sizes(text: str) -> list[int]:
    return [int(s) for s in text.split(",") if s]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="10000,100000,200000", help="2D sizes ('' for none)")
    parser.add_argument("--sizes-3d", default="10000,100000", help="3D sizes ('' for none)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--folder", type=Path, help="keep the generated files here")
    parser.add_argument("--name", default="g2o_speed", help="results file name")
    parser.add_argument("--peak", help=argparse.SUPPRESS)
    parser.add_argument("--file", help=argparse.SUPPRESS)
    parser.add_argument("--dim", type=int, default=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    if args.peak:
        print(json.dumps(_peak(args.peak, args.file, args.dim)))
        return
    sizes = {2: _sizes(args.sizes), 3: _sizes(args.sizes_3d)}
    if args.folder:
        args.folder.mkdir(parents=True, exist_ok=True)
        rows = _run(args.folder, sizes, args.repeats)
    else:
        with tempfile.TemporaryDirectory() as folder:
            rows = _run(Path(folder), sizes, args.repeats)
    table = _table(rows)
    print(table)
    from benchmarks import harness

    path = harness.write_result(args.name, harness.command_line(), {"rows": rows},
                                f"```text\n{table}\n```")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
