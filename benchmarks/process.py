"""Process to process: ``rlpgo-init FILE -o OUT`` against SE-Sync + GTSAM LM30, each side run
as a user runs it, on an idle machine and beside one competing CPU-bound process; and where
the time of ``rlpgo-init`` goes, step by step.

    python benchmarks/process.py [--sesync BIN]
        [--sets 2d,3d,generated] [--files Intel.g2o,...] [--sigmas 0.3,0.5] [--seeds 1,2,3]
        [--repeats 3] [--loads idle,busy] [--cache DIR] [--timeout 600] [--no-phases]
        [--name process]

Cases: the shared 2D files (``../shared/datasets/*.g2o``), SE-Sync's 3D files
(``../shared/datasets/3d/*.g2o``) and generated 1000-pose graphs with heavy rotation noise,
where the relaxation is not certified (``rlpgo-generate --n 1000 --sigma-r S
--noisy-measurements --seed K``, made once into ``--cache``, a folder outside the
repository, and reused).

Each side is timed as processes (``benchmarks/processes.py``: wall seconds from the fork to
the exit, peak resident set from ``wait4``):

- ours: ``rlpgo-init FILE -o OUT``, the console script of this environment (OUT removed
  before each run): interpreter start-up, imports, reading, the certified stage, LM30,
  writing at full precision, exit.
- the baseline, two processes one after the other: ``sesync_rounded FILE REC.json`` (SE-Sync
  with its default options, BLAS pinned to ``--sesync-threads`` threads, 1 by default as
  ``benchmarks/sesync/runner.py`` does: the faster and steadier setting for SE-Sync), then
  ``python benchmarks/sesync/lm30.py FILE REC.json OUT`` (import GTSAM, ``gtsam.readG2o``,
  LM30 from SE-Sync's estimate with our LM settings, ``gtsam.writeG2o``), on 2D and 3D
  files alike (the driver reads ``EDGE_SE3:QUAT`` files too). The driver reads the file
  itself and, after SE-Sync's call, computes the certificate matrix's smallest eigenvalue
  for its record, work SE-Sync alone does not do, counted against the baseline:
  the column "SE-Sync call s" is the driver's own timing of the ``SESync()`` call alone, and
  ``ratio_call`` in the JSON divides by that call + the LM30 process instead.
- 3D: ``rlpgo-init`` refuses 3D files until its 3D command lands; those rows show its
  one-line error.

Each case and load runs ``--repeats`` times, the two sides in turn (which goes first
alternates from one repeat to the next); a figure is the
median over the repeats, the baseline's of each repeat's sum; ratio = ours / (SE-Sync +
LM30). ``busy``: one Python busy loop runs from half a second before each measured run
(for the baseline: before SE-Sync, until LM30 exits) and is killed after it.

chi2 = 2 x GTSAM error of the input graph: ours read back from OUT (written at full
precision); the baseline's as ``lm30.py`` computed it before writing (in the JSON also as
written: GTSAM's writer keeps 6 significant digits, which raises it). Certified: ours from
the command's ``certificate:`` line, SE-Sync's from its record (certified: verification
passed and suboptimality bound about 0).

Phases (unless ``--no-phases``): one more run of ours per case, idle, instrumented
(``processes.probe``: timestamps around each step, peak memory after it, ``-X importtime``
for the modules imported lazily inside the steps). Its total is one run, not a median, and
carries the probe's small overhead.

Bytecode (``--bytecode``, cached by default): the Python processes run as an installed
package does, its modules compiled once beforehand (``cache_bytecode``); ``none``
keeps the environment's PYTHONDONTWRITEBYTECODE, under which every start compiles them
(about 0.1 s for ``rlpgo-init``, less for ``lm30.py``). CPU: user + system seconds of each
process (``wait4``), medians like the wall seconds.

Prints the tables, writes ``benchmarks/results/<name>.json`` and ``.md``. SE-Sync is left
out, its columns empty, when no binary is given or found (``$RLPGO_SESYNC_BINARY``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import processes  # noqa: E402
from benchmarks.common import DATASETS, RESULTS, write_result  # noqa: E402

FILES_2D = ["M3500.g2o", "M3500A.g2o", "M3500B.g2o", "M3500C.g2o", "Intel.g2o", "MIT.g2o",
            "City10K.g2o", "FR079.g2o"]
FILES_3D = ["tinyGrid3D.g2o", "smallGrid3D.g2o", "parking-garage.g2o", "sphere2500.g2o",
            "torus3D.g2o", "cubicle.g2o", "sphere_bignoise_vertex3.g2o"]
LM30 = Path(__file__).resolve().parent / "sesync" / "lm30.py"
ROOT = Path(__file__).resolve().parents[1]


def _cases(args, cache: Path) -> list[dict]:
    cases = []
    sets = args.sets.split(",")
    wanted = set(args.files.split(",")) if args.files else None
    if "2d" in sets:
        cases += [{"case": name, "path": DATASETS / name, "dim": 2} for name in FILES_2D]
    if "3d" in sets:
        cases += [{"case": name, "path": DATASETS / "3d" / name, "dim": 3} for name in FILES_3D]
    if wanted is not None:
        cases = [c for c in cases if c["case"] in wanted]
    if "generated" in sets:
        for sigma in (float(s) for s in args.sigmas.split(",")):
            for seed in (int(s) for s in args.seeds.split(",")):
                path = processes.generated_graph(cache, 1000, sigma, seed)
                cases.append({"case": f"n=1000 sigma_R={sigma:g} seed={seed}", "path": path,
                              "dim": 2})
    return cases


def graph_size(path: Path, dim: int) -> tuple[int, int]:
    vertex = "VERTEX_SE2" if dim == 2 else "VERTEX_SE3"
    poses = edges = 0
    with path.open() as handle:
        for line in handle:
            poses += line.startswith(vertex)
            edges += line.startswith("EDGE_")
    return poses, edges


def chi2_of(graph, path: Path, dim: int) -> float | None:
    """2 x GTSAM error of ``graph`` at the poses of the g2o file ``path``."""
    import gtsam

    if not path.is_file():
        return None
    _, values = gtsam.readG2o(str(path), dim == 3)
    return 2.0 * graph.error(values)


def run_ours(path: Path, out: Path, timeout: float, options: tuple[str, ...] = ()) -> dict:
    """``rlpgo-init PATH -o OUT [OPTIONS]`` as a process (OUT removed first): its seconds,
    peak, failure and what it printed (:func:`processes.init_outcome`)."""
    out.unlink(missing_ok=True)
    done = processes.run([processes.command_path("rlpgo-init"), path, "-o", out, *options],
                         timeout)
    return {"seconds": done.seconds, "cpu_seconds": done.cpu_seconds, "peak_mb": done.peak_mb,
            "failure": done.failure, **processes.init_outcome(done.stdout)}


def _sesync_env(threads: str) -> dict[str, str]:
    from benchmarks.sesync.runner import THREAD_VARIABLES

    env = dict(os.environ)
    if threads != "default":
        env.update({name: threads for name in THREAD_VARIABLES})
    return env


def run_baseline(path: Path, folder: Path, sesync: str, threads: str, timeout: float,
                 busy: bool) -> dict:
    """The baseline as two processes (module docstring): ``sesync_rounded`` with BLAS at
    ``threads``, then ``lm30.py`` writing ``folder/sesync_lm30.g2o``; with ``busy``, beside one
    competing process."""
    record, out = folder / "sesync.json", folder / "sesync_lm30.g2o"
    for file in (record, out):
        file.unlink(missing_ok=True)
    with processes.competing(busy):
        sesync_run = processes.run([sesync, path, record], timeout, env=_sesync_env(threads))
        lm30 = None
        if sesync_run.failure is None:
            lm30 = processes.run([sys.executable, LM30, path, record, out], timeout)
    row = {"sesync_seconds": sesync_run.seconds, "sesync_peak_mb": sesync_run.peak_mb,
           "sesync_cpu_seconds": sesync_run.cpu_seconds, "sesync_failure": sesync_run.failure}
    if sesync_run.failure is None:
        data = json.loads(record.read_text())
        row.update(sesync_call_seconds=data["seconds"], sesync_certified=data["certified"],
                   sesync_status=data["status"], sesync_bound=data["suboptimality_bound"])
    if lm30 is not None:
        row.update(lm30_seconds=lm30.seconds, lm30_peak_mb=lm30.peak_mb,
                   lm30_cpu_seconds=lm30.cpu_seconds, lm30_failure=lm30.failure)
        if lm30.failure is None:
            line = json.loads(lm30.stdout.strip().splitlines()[-1])
            row.update(lm30_chi2=line["chi2"], lm30_iterations=line["iterations"],
                       lm30_steps=line["seconds"])
    return row


def median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def cache_bytecode() -> None:
    """Let the measured Python processes (ours and ``lm30.py``) use cached bytecode, as a user's
    do (pip compiles a package's modules at install; site-packages already hold theirs): no
    PYTHONDONTWRITEBYTECODE in their environment, and this checkout's modules compiled now
    into their ``__pycache__`` folders (ignored by git), so no measured run compiles them.
    Without it, each start compiles the package's own modules again (about 0.1 s)."""
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    folders = [str(ROOT / name) for name in ("rlpgo_gtsam", "cli", "benchmarks")]
    subprocess.run([sys.executable, "-m", "compileall", "-q", *folders], check=True,
                   stdout=subprocess.DEVNULL)


def _measure(case: dict, load: str, folder: Path, args) -> dict:
    import gtsam

    busy = load == "busy"
    ours_runs, base_runs = [], []
    has_baseline = bool(args.sesync)
    for repeat in range(args.repeats):
        sides = ["ours", "baseline"] if has_baseline else ["ours"]
        for side in sides if repeat % 2 == 0 else sides[::-1]:  # who goes first alternates
            if side == "ours":
                with processes.competing(busy):
                    ours_runs.append(run_ours(case["path"], folder / "ours.g2o", args.timeout))
            else:
                base_runs.append(run_baseline(case["path"], folder, args.sesync,
                                              args.sesync_threads, args.timeout, busy))
    graph, _ = gtsam.readG2o(str(case["path"]), case["dim"] == 3)
    last = ours_runs[-1]
    row = {"case": case["case"], "dim": case["dim"], "load": load, "repeats": args.repeats,
           "ours_seconds": median([r["seconds"] for r in ours_runs if r["failure"] is None]),
           "ours_seconds_all": [r["seconds"] for r in ours_runs],
           "ours_cpu_seconds": median([r["cpu_seconds"] for r in ours_runs
                                       if r["failure"] is None]),
           "ours_peak_mb": median([r["peak_mb"] for r in ours_runs]),
           "ours_failure": last["failure"], "ours_certified": last["certified"],
           "ours_certificate": last["certificate"], "ours_stopped": last["stopped"],
           "ours_last_line": last["last"],
           "ours_chi2": chi2_of(graph, folder / "ours.g2o", case["dim"]) if last["failure"] is None
           else None}
    if base_runs:
        complete = [r for r in base_runs if r["sesync_failure"] is None and
                    r.get("lm30_failure", "no run") is None]
        for key in ("sesync_seconds", "sesync_call_seconds", "lm30_seconds", "sesync_peak_mb",
                    "lm30_peak_mb"):
            row[key] = median([r.get(key) for r in complete])
        row["baseline_seconds_all"] = [r["sesync_seconds"] + r["lm30_seconds"]
                                       for r in complete]
        row["baseline_seconds"] = median(row["baseline_seconds_all"])
        row["baseline_cpu_seconds"] = median([
            r["sesync_cpu_seconds"] + r["lm30_cpu_seconds"] for r in complete
            if r.get("sesync_cpu_seconds") is not None and r.get("lm30_cpu_seconds") is not None])
        final = base_runs[-1]
        for key in ("sesync_failure", "lm30_failure", "sesync_certified", "sesync_status",
                    "sesync_bound", "lm30_chi2", "lm30_iterations", "lm30_steps"):
            row[key] = final.get(key)
        if final.get("lm30_failure", "no run") is None:
            row["lm30_chi2_as_written"] = chi2_of(graph, folder / "sesync_lm30.g2o",
                                                  case["dim"])
        if row["ours_seconds"] is not None and row["baseline_seconds"]:
            row["ratio"] = row["ours_seconds"] / row["baseline_seconds"]
            if row.get("sesync_call_seconds") is not None:
                row["ratio_call"] = row["ours_seconds"] / (
                    median([r["sesync_call_seconds"] + r["lm30_seconds"] for r in complete]))
    return row


def cell(value, digits: str = ".2f") -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return format(value, digits)


def _timing_table(rows: list[dict]) -> str:
    head = ["case", "poses", "edges", "load", "ours s", "SE-Sync s", "SE-Sync call s",
            "LM30 s", "SE-Sync + LM30 s", "ours / (SE-Sync + LM30)", "ours chi2",
            "SE-Sync + LM30 chi2", "certified (ours / SE-Sync)", "peak MB (ours / SE-Sync / LM30)",
            "CPU s (ours / SE-Sync + LM30)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        ours = cell(r["ours_seconds"]) if r["ours_failure"] is None else \
            f"fails: {r['ours_failure'][:80]}"
        sesync = cell(r.get("sesync_seconds"))
        if r.get("sesync_failure"):
            sesync = f"fails: {r['sesync_failure'][:60]}"
        lines.append("| " + " | ".join([
            r["case"], str(r["poses"]), str(r["edges"]), r["load"], ours, sesync,
            cell(r.get("sesync_call_seconds")), cell(r.get("lm30_seconds")),
            cell(r.get("baseline_seconds")), cell(r.get("ratio")),
            cell(r["ours_chi2"], ".6g"), cell(r.get("lm30_chi2"), ".6g"),
            f"{cell(r['ours_certified'])} / {cell(r.get('sesync_certified'))}",
            " / ".join(cell(r.get(k), ".0f") for k in ("ours_peak_mb", "sesync_peak_mb",
                                                         "lm30_peak_mb")),
            f"{cell(r.get('ours_cpu_seconds'))} / {cell(r.get('baseline_cpu_seconds'))}"])
            + " |")
    return "\n".join(lines)


def _phase_table(phases: list[dict]) -> str:
    steps = [s for s in processes.STEPS if s not in ("input chi2", "other")]
    head = ["case", "total s", *steps, "other", "lazy imports (inside the steps)",
            "peak MB"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for p in phases:
        seconds = p["seconds"]
        other = None if seconds["other"] is None else \
            seconds["other"] + (seconds["input chi2"] or 0.0)
        lazy = cell(p["lazy_imports_s"])
        by_step = [(step, sum(s for _, s in items)) for step, items in p["imports"].items()
                   if step != "import"]
        by_step = [f"{step} {s:.2f}" for step, s in sorted(by_step, key=lambda i: -i[1])
                   if s >= 0.005]
        if by_step:
            lazy += f" ({', '.join(by_step)})"
        total = cell(p["total"]) + ("" if p["failure"] is None else " (fails)")
        lines.append("| " + " | ".join([p["case"], total, *(cell(seconds[s]) for s in steps),
                                         cell(other), lazy, cell(p["peak_mb"], ".0f")]) + " |")
    return "\n".join(lines)


def add_common_options(parser: argparse.ArgumentParser, name: str) -> None:
    """The options process.py and scale.py share: the SE-Sync driver and its threads, the
    cache of generated graphs, the time limit per process, the results' name."""
    parser.add_argument("--sesync", help="the sesync_rounded driver (default: "
                        "$RLPGO_SESYNC_BINARY; without one the baseline is left out)")
    parser.add_argument("--sesync-threads", default="1",
                        help="BLAS/OpenMP threads of the SE-Sync driver, or 'default'")
    parser.add_argument("--cache", type=Path,
                        default=Path(tempfile.gettempdir()) / "rlpgo_benchmark_graphs",
                        help="generated graphs are kept here and reused")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per process")
    parser.add_argument("--name", default=name, help="results file name")


def check_binaries(parser: argparse.ArgumentParser, args: argparse.Namespace,
                   options: tuple[str, ...]) -> None:
    """``--sesync`` defaults to ``$RLPGO_SESYNC_BINARY``; a binary given must exist."""
    from benchmarks.sesync.runner import default_binary

    args.sesync = args.sesync or default_binary()
    for option in options:
        path = getattr(args, option)
        if path is not None and not Path(path).is_file():
            parser.error(f"--{option.replace('_', '-')}: {path} not found")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_common_options(parser, "process")
    parser.add_argument("--sets", default="2d,3d,generated")
    parser.add_argument("--files", help="only these shared files (2D and 3D names)")
    parser.add_argument("--sigmas", default="0.3,0.5")
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--loads", default="idle,busy")
    parser.add_argument("--no-phases", action="store_true")
    parser.add_argument("--bytecode", choices=("cached", "none"), default="cached",
                        help="cached: the Python processes run with bytecode caching on and "
                        "this checkout compiled first, as an installed package is; none: as "
                        "the environment says (PYTHONDONTWRITEBYTECODE compiles every module "
                        "at every start)")
    args = parser.parse_args()
    check_binaries(parser, args, ("sesync",))
    if args.bytecode == "cached":
        cache_bytecode()
    print(f"SE-Sync driver: {args.sesync or 'none (baseline left out)'}", flush=True)
    rows, phases = [], []
    with tempfile.TemporaryDirectory(prefix="rlpgo_process_") as name:
        folder = Path(name)
        for case in _cases(args, args.cache):
            poses, edges = graph_size(case["path"], case["dim"])
            for load in args.loads.split(","):
                row = {**_measure(case, load, folder, args), "poses": poses, "edges": edges}
                rows.append(row)
                print(json.dumps(row), flush=True)
            if not args.no_phases:
                phase = processes.probe([str(case["path"]), "-o", str(folder / "probe.g2o"),
                                         "--overwrite"], args.timeout)
                phase.pop("stdout")
                phases.append({"case": case["case"], **phase})
                print(json.dumps(phases[-1]), flush=True)
    command = "python benchmarks/process.py " + " ".join(sys.argv[1:])
    text = (f"Made by `{command.strip()}`: seconds are wall seconds of whole processes, "
            f"medians of {args.repeats}; chi2 = 2 x GTSAM error.\n\n" + _timing_table(rows)
            + "\n")
    if phases:
        text += ("\nWhere the time of `rlpgo-init FILE -o OUT` goes (one instrumented run, "
                 "idle; seconds):\n\n" + _phase_table(phases) + "\n")
    print(text)
    (RESULTS / f"{args.name}.md").write_text(text)
    result = {"command": command.strip(), "rows": rows, "phases": phases,
              "peak_floor_mb": processes.launcher_floor_mb(), "sesync": str(args.sesync),
              "sesync_threads": args.sesync_threads}
    print(f"wrote {write_result(args.name, result)}")


if __name__ == "__main__":
    main()
