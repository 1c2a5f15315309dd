"""Process to process: ``rlpgo-init FILE -o OUT`` against SE-Sync + GTSAM LM30, each side run
as a user runs it, idle and beside one busy core; where the time of ``rlpgo-init`` goes, step
by step; and large graphs with ``--budget``.

    python benchmarks/process.py files [--sesync BIN] [--sets 2d,3d,generated]
        [--files Intel.g2o,...] [--sigmas 0.3,0.5] [--seeds 1,2,3] [--repeats 3]
        [--loads idle,busy] [--no-phases] [--bytecode cached|none] [--cache DIR] [--name process]
    python benchmarks/process.py scale [--sesync BIN] [--sizes 10000,100000,200000]
        [--repeats 1] [--budget 30] [--hard-n 2000] [--no-budget | --budget-only] [--name scale]

``files``. Cases: the shared planar and 3D files, and generated 1000-pose graphs with heavy
rotation noise, where the relaxation is not certified (``rlpgo-generate --n 1000 --sigma-r S
--noisy-measurements --seed K``, made once into ``--cache`` and reused). Each side is timed as
processes (:func:`benchmarks.harness.run`: wall seconds from the fork to the exit, peak
resident set and CPU seconds from ``wait4``):

- ours: ``rlpgo-init FILE -o OUT``, the console script of this environment (OUT removed
  before each run): interpreter start-up, imports, reading, the default, writing, exit.
- the baseline, two processes one after the other: ``sesync_rounded FILE REC.json`` (SE-Sync
  with its default options, BLAS on ``--sesync-threads`` threads, 1 by default: the faster
  and steadier setting for SE-Sync), then ``python benchmarks/sesync/lm30.py FILE REC.json
  OUT`` (import GTSAM, ``gtsam.readG2o``, LM30 from SE-Sync's estimate with our LM settings,
  ``gtsam.writeG2o``). The driver also reads the file and computes the certificate's
  smallest eigenvalue, work SE-Sync alone does not do: "SE-Sync call s" is the driver's own
  timing of the ``SESync()`` call, and ``ratio_call`` in the JSON divides by it + LM30.

Each case and load runs ``--repeats`` times, the two sides in turn (who goes first alternates);
a figure is the median over the repeats; ratio = ours / (SE-Sync + LM30). ``busy``: one Python
busy loop runs from half a second before each measured run (for the baseline: before SE-Sync
until LM30 exits). chi2 = 2 x GTSAM error of the input graph at what each side wrote (ours at
full precision; the baseline's as ``lm30.py`` computed it before GTSAM's 6-digit writer).
Certified: ours from the command's ``certificate:`` line, SE-Sync's from its record.
Phases (unless ``--no-phases``): one more run of ours per case, idle, instrumented (the
``probe`` mode below). ``--bytecode cached`` (the default) runs the Python processes as an
installed package does, its modules compiled once beforehand.

``scale``. Generated graphs of ``--sizes`` poses (``rlpgo-generate --n N --sigma-r 0.05
--sigma-t 0.05 --d 3 --lc 0.3 --noisy-measurements --seed 1``): ``rlpgo-init FILE -o OUT``
(median of ``--repeats``), one instrumented run, and with the driver SE-Sync + LM30 as above.
Growth: the exponent k in seconds ~ edges^k between consecutive sizes (1 is linear). Budget
rows: ``rlpgo-init FILE -o OUT --budget B`` once on the largest graph and on a hard one
(``rlpgo-generate --n 2000 --sigma-r 3.0 --lc 1.0 --noisy-measurements --seed 1``); "within"
is wall seconds <= 1.2 B, start-up and exit included.

``python -X importtime benchmarks/process.py probe RECORD -- RLPGO_INIT_ARGS...`` runs the
``rlpgo-init`` entry point with a wrapper around each name the command module calls for a
step (:data:`STEP_NAMES`; a step the command makes under another name, or inside another
step, shows "-" and its time counts in that step or in "other"), the peak
(VmHWM) after each, and markers on stderr, so that ``-X importtime`` attributes the imports
made lazily inside a step to that step. "start-up" runs from the fork to the probe's first
line and includes this file's own standard-library imports, which the command makes anyway.

Prints the tables, writes ``benchmarks/results/<name>.json`` and ``.md``. Without a SE-Sync
driver (``--sesync`` or ``$RLPGO_SESYNC_BINARY``) the baseline's columns are left empty.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import cell, chi2_of, graph_size, median, run_init  # noqa: E402

EASY = {"sigma_r": 0.05, "sigma_t": 0.05, "d": 3.0, "lc": 0.3, "seed": 1}
HARD = {"sigma_r": 3.0, "lc": 1.0, "seed": 1}
GROWTH = ("total", "read", "certified", "LM", "write", "SE-Sync", "LM30", "peak MB")




# --- probe: the instrumented rlpgo-init -------------------------------------------------

MARKER = "rlpgo-probe: "  # the probe's lines on stderr: "begin STEP", "end STEP", "end import"
STEP_NAMES = {
    "read": ("read_input", "read_g2o"),
    "extraction": ("extract_pose_graph", "PoseGraph2D", "PoseGraph3D"),  # classes: from_gtsam
    "default": ("staged_initialize",),
    "write": ("pose_graph_text", "g2o_text"),  # the text; RunFiles.write_together writes it
    "input chi2": ("chi2",),
}
STEPS = ("start-up", "import", "read", "extraction", "certified", "LM", "default rest",
         "write", "input chi2", "other", "exit")
"""The phases of one ``rlpgo-init`` run, in order."""


class _Timed:
    """Wraps a callable: adds its seconds to ``seconds[step]``, notes the peak after it, and
    hands its result to ``seen`` (if given)."""

    def __init__(self, function, step: str, seconds: dict, peaks: dict, seen=None) -> None:
        self.function, self.step, self.seconds, self.peaks, self.seen = \
            function, step, seconds, peaks, seen

    def __call__(self, *args, **kwargs):
        os.write(2, f"{MARKER}begin {self.step}\n".encode())
        start = time.monotonic()
        try:
            result = self.function(*args, **kwargs)
        finally:
            self.seconds[self.step] = self.seconds.get(self.step, 0.0) + time.monotonic() - start
            self.peaks[self.step] = harness.vmhwm_mb()
            os.write(2, f"{MARKER}end {self.step}\n".encode())
        if self.seen is not None:
            self.seen(result)
        return result


class _Extraction:
    """Stands for a pose-graph class in the command's module: ``from_gtsam`` is timed, every
    other attribute is the class's own."""

    def __init__(self, cls, timed_call: _Timed) -> None:
        self._cls, self.from_gtsam = cls, timed_call

    def __getattr__(self, name: str):
        return getattr(self._cls, name)


def _default_record(result) -> dict:
    """What the probe keeps of the default's result: its stages' seconds and how it ended."""
    rows = list(getattr(result, "rows", []))
    return {"certified_s": sum(getattr(r, "init_seconds", None) or 0.0 for r in rows),
            "lm_s": sum(getattr(r, "refine_seconds", None) or 0.0 for r in rows),
            "stages": [getattr(r, "method", "?") for r in rows],
            "certified": getattr(result, "certified", None),
            "stopped": getattr(result, "stopped", None),
            "library_seconds": getattr(result, "seconds", None)}


def _wrap_steps(command, seconds: dict, peaks: dict, default: dict) -> None:
    """Put a :class:`_Timed` around each name of :data:`STEP_NAMES` the command module has."""
    for step, names in STEP_NAMES.items():
        for name in names:
            original = getattr(command, name, None)
            if original is None:
                continue
            if step == "extraction" and isinstance(original, type):
                setattr(command, name, _Extraction(
                    original, _Timed(original.from_gtsam, step, seconds, peaks)))
            else:
                seen = (lambda result: default.update(_default_record(result))) \
                    if step == "default" else None
                setattr(command, name, _Timed(original, step, seconds, peaks, seen))
    files = getattr(command, "RunFiles", None)
    for method in ("write_g2o", "write_together"):
        if files is not None and hasattr(files, method):
            timed_call = _Timed(getattr(files, method), "write", seconds, peaks)
            setattr(files, method, lambda self, *a, _t=timed_call, **k: _t(self, *a, **k))


def _probe(argv: list[str]) -> int:
    started = time.monotonic()
    record_path, args = argv[0], argv[2:]  # argv[1] is "--"
    import importlib

    here = Path(__file__).resolve().parent
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != here]  # not a user's
    sys.argv = ["rlpgo-init", *args]
    launch = importlib.import_module("rlpgo_cli.launch")
    importer = getattr(launch, "_import", None)  # as the command imports itself
    command = importer("init", True) if importer else importlib.import_module("rlpgo_cli.init")
    imported = time.monotonic()
    os.write(2, f"{MARKER}end import\n".encode())
    seconds: dict[str, float] = {}
    peaks: dict[str, float | None] = {"import": harness.vmhwm_mb()}
    default: dict = {}
    _wrap_steps(command, seconds, peaks, default)
    main_began = time.monotonic()

    def write_record(code: object) -> None:
        Path(record_path).write_text(json.dumps({
            "started": started, "imported": imported, "main_began": main_began,
            "main_ended": time.monotonic(), "seconds": seconds, "peaks_mb": peaks,
            "peak_mb": harness.vmhwm_mb(), "default": default,
            "exit_code": code if isinstance(code, int) or code is None else 1}))

    leave = getattr(launch, "_leave", None)
    if leave is not None:  # the command ends the process itself: the record first
        def record_and_leave(code: object) -> None:
            write_record(code)
            leave(code)

        launch._leave = record_and_leave
    code: int | str | None = 0
    try:
        launch.init()
    except SystemExit as stop:
        code = stop.code
    write_record(code)
    return code if isinstance(code, int) else (0 if code is None else 1)


def imports_by_step(stderr: str) -> dict[str, list[tuple[str, float]]]:
    """The top-level ``-X importtime`` lines of a probe's stderr as (module, cumulative
    seconds), slowest first, per step: ``import`` before the marker of the eager imports,
    a step's name between its begin and end markers, ``other`` elsewhere."""
    found: dict[str, list[tuple[str, float]]] = {}
    step = "import"
    for line in stderr.splitlines():
        if line.startswith(MARKER):
            words = line[len(MARKER):].split(maxsplit=1)
            step = words[1] if words[0] == "begin" else "other"
            continue
        parts = line.split("|")
        if not line.startswith("import time:") or len(parts) != 3:
            continue
        if parts[2].startswith(" ") and not parts[2].startswith("  "):
            try:
                found.setdefault(step, []).append((parts[2].strip(), int(parts[1]) / 1e6))
            except ValueError:
                continue  # the header line
    return {key: sorted(items, key=lambda item: -item[1]) for key, items in found.items()}


def probe(args: Sequence[str], timeout_s: float) -> dict:
    """Run ``rlpgo-init ARGS`` instrumented (module docstring) and return its phases:
    ``seconds`` per step of :data:`STEPS` (None where the step was not seen), ``total`` (wall
    seconds, start to exit), ``peaks_mb`` after each step, ``peak_mb``, ``imports`` (five a
    step), ``lazy_imports_s`` (the imports after the eager ones), the default's record and
    ``failure`` (None if it exited 0)."""
    with tempfile.TemporaryDirectory(prefix="rlpgo_probe_") as folder:
        record_path = Path(folder) / "probe.json"
        done = harness.run([sys.executable, "-X", "importtime", __file__, "probe",
                            str(record_path), "--", *args], timeout_s)
        record = json.loads(record_path.read_text()) if record_path.is_file() else None
    result = {"total": done.seconds, "peak_mb": done.peak_mb, "failure": done.failure}
    if record is None or done.started is None or done.ended is None:
        return {**result, "seconds": dict.fromkeys(STEPS), "peaks_mb": {}, "default": {},
                "imports": {}, "lazy_imports_s": None}
    steps, default = record["seconds"], record["default"]
    seconds: dict[str, float | None] = dict.fromkeys(STEPS)
    seconds["start-up"] = record["started"] - done.started
    seconds["import"] = record["imported"] - record["started"]
    for step in ("read", "extraction", "write", "input chi2"):
        seconds[step] = steps.get(step)
    if "default" in steps and default:
        seconds["certified"] = default["certified_s"]
        seconds["LM"] = default["lm_s"]
        seconds["default rest"] = steps["default"] - default["certified_s"] - default["lm_s"]
    seconds["other"] = (record["main_ended"] - record["main_began"] - sum(steps.values())
                        + record["main_began"] - record["imported"])  # the probe's wrapping
    seconds["exit"] = done.ended - record["main_ended"]
    imports = imports_by_step(done.stderr)
    return {**result, "seconds": seconds, "peaks_mb": record["peaks_mb"],
            "peak_mb": record["peak_mb"] or done.peak_mb, "default": default,
            "imports": {step: items[:5] for step, items in imports.items()},
            "lazy_imports_s": sum(s for step, items in imports.items() if step != "import"
                                  for _, s in items)}


# --- files and scale --------------------------------------------------------------------

def _measure(case: dict, load: str, folder: Path, args) -> dict:
    import gtsam

    busy = load == "busy"
    ours_runs, base_runs = [], []
    has_baseline = bool(args.sesync)
    for repeat in range(args.repeats):
        sides = ["ours", "baseline"] if has_baseline else ["ours"]
        for side in sides if repeat % 2 == 0 else sides[::-1]:  # who goes first alternates
            if side == "ours":
                with harness.competing(busy):
                    ours_runs.append(run_init(case["path"], folder / "ours.g2o", args.timeout))
            else:
                base_runs.append(harness.run_baseline(case["path"], folder, args.sesync,
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
    steps = [s for s in STEPS if s not in ("input chi2", "other")]
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


def _size_row(n: int, path: Path, folder: Path, args) -> dict:
    import gtsam

    poses, edges = graph_size(path)
    out = folder / "ours.g2o"
    runs = [run_init(path, out, args.timeout) for _ in range(args.repeats)]
    graph, _ = gtsam.readG2o(str(path), False)
    last = runs[-1]
    row = {"n": n, "poses": poses, "edges": edges, "file_mb": path.stat().st_size / 2**20,
           "ours_seconds": median([r["seconds"] for r in runs if r["failure"] is None]),
           "ours_seconds_all": [r["seconds"] for r in runs],
           "ours_peak_mb": median([r["peak_mb"] for r in runs]),
           "ours_failure": last["failure"], "ours_certified": last["certified"],
           "ours_stopped": last["stopped"], "ours_last_line": last["last"],
           "ours_chi2": chi2_of(graph, out, 2) if last["failure"] is None else None}
    row["phases"] = probe([str(path), "-o", str(folder / "probe.g2o"), "--overwrite"],
                          args.timeout)
    if args.sesync:
        base = harness.run_baseline(path, folder, args.sesync, args.sesync_threads,
                                    args.timeout, False)
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
    poses, edges = graph_size(path)
    run = run_init(path, folder / "budget.g2o", args.timeout, ("--budget", f"{args.budget:g}"))
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


def _cases(args) -> list[dict]:
    """The cases of ``files``: shared files of ``--sets`` (only ``--files`` if given), then
    the generated graphs."""
    sets = args.sets.split(",")
    wanted = set(args.files.split(",")) if args.files else None
    cases = []
    for dim, names in ((2, harness.FILES_2D), (3, harness.FILES_3D)):
        if f"{dim}d" in sets:
            cases += [{"case": f"{name}.g2o", "path": harness.shared_file(name), "dim": dim}
                      for name in names]
    if wanted is not None:
        cases = [c for c in cases if c["case"] in wanted]
    if "generated" in sets:
        for sigma in (float(s) for s in args.sigmas.split(",")):
            for seed in (int(s) for s in args.seeds.split(",")):
                path = harness.generated_graph(args.cache, 1000, sigma, seed)
                cases.append({"case": f"n=1000 sigma_R={sigma:g} seed={seed}", "path": path,
                              "dim": 2})
    return cases


def files(args) -> tuple[dict, str]:
    if args.bytecode == "cached":
        harness.cache_bytecode()
    rows, phases = [], []
    with tempfile.TemporaryDirectory(prefix="rlpgo_process_") as name:
        folder = Path(name)
        for case in _cases(args):
            poses, edges = graph_size(case["path"])
            for load in args.loads.split(","):
                rows.append({**_measure(case, load, folder, args), "poses": poses,
                             "edges": edges})
                print(json.dumps(rows[-1]), flush=True)
            if not args.no_phases:
                phase = probe([str(case["path"]), "-o", str(folder / "probe.g2o"),
                               "--overwrite"], args.timeout)
                phases.append({"case": case["case"], **phase})
                print(json.dumps(phases[-1]), flush=True)
    text = (f"Seconds are wall seconds of whole processes, medians of {args.repeats}; chi2 = "
            "2 x GTSAM error.\n\n" + _timing_table(rows) + "\n")
    if phases:
        text += ("\nWhere the time of `rlpgo-init FILE -o OUT` goes (one instrumented run, "
                 "idle; seconds):\n\n" + _phase_table(phases) + "\n")
    return {"rows": rows, "phases": phases}, text


def scale(args) -> tuple[dict, str]:
    if args.no_budget and args.budget_only:
        raise SystemExit("--no-budget and --budget-only leave nothing to run")
    sizes = [int(s) for s in args.sizes.split(",")]
    rows, budgets = [], []
    with tempfile.TemporaryDirectory(prefix="rlpgo_scale_") as name:
        folder = Path(name)
        for n in [] if args.budget_only else sizes:
            path = harness.generated_graph(args.cache, n, **EASY)
            rows.append(_size_row(n, path, folder, args))
            print(json.dumps(rows[-1]), flush=True)
        if not args.no_budget:
            largest = harness.generated_graph(args.cache, max(sizes), **EASY)
            hard = harness.generated_graph(args.cache, args.hard_n, **HARD)
            for label, path in ((f"easy n={max(sizes)}", largest),
                                (f"hard n={args.hard_n} sigma_R=3 lc=1", hard)):
                budgets.append(_budget_row(label, path, folder, args))
                print(json.dumps(budgets[-1]), flush=True)
    growth = _growth(rows)
    steps = "; step seconds from one instrumented run" if rows else ""
    text = (f"Wall seconds of whole processes{steps}; chi2 = 2 x GTSAM error.\n\n"
            + _tables(rows, growth, budgets).lstrip("\n"))
    return {"rows": rows, "growth": growth, "budget": budgets, "easy": EASY, "hard": HARD}, text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    files_parser = commands.add_parser("files", help="the shared and generated files")
    files_parser.add_argument("--sets", default="2d,3d,generated")
    files_parser.add_argument("--files", help="only these shared files (2D and 3D names)")
    files_parser.add_argument("--sigmas", default="0.3,0.5")
    files_parser.add_argument("--seeds", default="1,2,3")
    files_parser.add_argument("--repeats", type=int, default=3)
    files_parser.add_argument("--loads", default="idle,busy")
    files_parser.add_argument("--no-phases", action="store_true")
    files_parser.add_argument("--bytecode", choices=("cached", "none"), default="cached",
                              help="cached: this checkout compiled first and bytecode caching "
                              "on, as an installed package is; none: as the environment says")
    scale_parser = commands.add_parser("scale", help="large generated graphs and --budget")
    scale_parser.add_argument("--sizes", default="10000,100000,200000")
    scale_parser.add_argument("--repeats", type=int, default=1)
    scale_parser.add_argument("--budget", type=float, default=30.0)
    scale_parser.add_argument("--hard-n", type=int, default=2000)
    scale_parser.add_argument("--no-budget", action="store_true")
    scale_parser.add_argument("--budget-only", action="store_true",
                              help="only the budget rows (the easy graph: the largest size)")
    for sub, name in ((files_parser, "process"), (scale_parser, "scale")):
        sub.add_argument("--sesync", help="the sesync_rounded driver (default: "
                         "$RLPGO_SESYNC_BINARY; without one the baseline is left out)")
        sub.add_argument("--sesync-threads", default="1",
                         help="BLAS/OpenMP threads of the SE-Sync driver, or 'default'")
        sub.add_argument("--cache", type=Path,
                         default=Path(tempfile.gettempdir()) / "rlpgo_benchmark_graphs",
                         help="generated graphs are kept here and reused")
        sub.add_argument("--timeout", type=float, default=600.0, help="seconds per process")
        sub.add_argument("--name", default=name, help="results file name")
    args = parser.parse_args()
    args.sesync = harness.sesync_binary(args.sesync)
    print(f"SE-Sync driver: {args.sesync or 'none (baseline left out)'}", flush=True)
    data, text = files(args) if args.command == "files" else scale(args)
    print(text)
    command = harness.command_line()
    data |= {"peak_floor_mb": harness.launcher_floor_mb(), "sesync": args.sesync,
             "sesync_threads": args.sesync_threads}
    print(f"wrote {harness.write_result(args.name, command, data, text)}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "probe":
        sys.exit(_probe(sys.argv[2:]))
    main()
