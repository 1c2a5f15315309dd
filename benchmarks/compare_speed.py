"""``rlpgo-compare FILE`` against ``rlpgo-init FILE -o OUT``, process to process as a user runs
them, with the time each row of the comparison took and whether the rows came out as each
method finished; and which methods of the comparison ever give its lowest refined chi2.

    python benchmarks/compare_speed.py [--files M3500.g2o,City10K.g2o] [--repeats 3]
        [--all-file MIT.g2o] [--timeout 600] [--name compare_speed]
    python benchmarks/compare_speed.py --wins [--methods ...] [--name compare_wins]

Speed. Each repeat runs, for every file in turn, ``rlpgo-init FILE -o OUT`` (the default,
OUT removed first) and ``rlpgo-compare FILE`` (its default methods), then
``rlpgo-compare FILE1 FILE2 ...`` (every file in one process): the console scripts of this
environment, each its own process, its stdout read line by line as it comes. A figure is
the median over the repeats of the wall seconds from the start of the process to its exit;
ratio = compare / init (for the run over every file: / the sum of the inits). The compare
rows (method, init s + refine s) are read from its table; a run "streamed" when each row
arrived at least half its own seconds after the row before it (rows held back to the end
arrive together). With ``--all-file``, ``rlpgo-init FILE --method all`` runs once and its
rows are checked the same way.

Bytecode as an installed package has it (:func:`benchmarks.harness.cache_bytecode`).
The machine's other load shows in every figure; init and compare of one file run back to
back, so their ratio is steadier than either.

Wins (``--wins``). In one process, ``compare_methods`` with ``--methods`` (by default
the comparison's default methods and those left out of it but for the agent) on the shared
2D files, SE-Sync's sigma_t sweep files and the arena's generated graphs of 300 and 500
poses (``benchmarks/arena.py``'s settings, where the relaxation mostly fails to certify):
per graph each row's refined chi2 and seconds; per method the graphs where it alone gave
the lowest refined chi2 (lower than every other row beyond the tie tolerance,
``ranking.ties``), where it tied for it, and where it failed.

Prints the tables, writes ``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import DATASETS  # noqa: E402

FILES = "M3500.g2o,City10K.g2o"
SIGMA_T_SWEEP = ("0.01", "0.03", "0.05", "0.1", "0.2")
WIN_GENERATED = [(n, sigma_r, seed) for n, sigma_r in
                 [(300, 0.4), (300, 0.5), (300, 0.6), (500, 0.4), (500, 0.5), (500, 0.6)]
                 for seed in (101, 102, 103)]


def timed_lines(command: list[str], timeout_s: float) -> dict:
    """Run ``command`` as a process, stdout read line by line: the wall seconds from its
    start to its exit, its exit status, and each stdout line with the seconds it arrived."""
    began = time.monotonic()
    with tempfile.TemporaryFile() as errors:
        process = subprocess.Popen([str(part) for part in command], stdout=subprocess.PIPE,
                                   stderr=errors, stdin=subprocess.DEVNULL, text=True)
        lines = []
        for line in process.stdout:
            lines.append((time.monotonic() - began, line.rstrip("\n")))
            if time.monotonic() - began > timeout_s:
                process.kill()
                break
        code = process.wait()
        seconds = time.monotonic() - began
        errors.seek(0)
        stderr = errors.read().decode(errors="replace")
    return {"seconds": seconds, "returncode": code, "lines": lines,
            "failure": None if code == 0 else f"exit status {code}: {stderr.strip()[-300:]}"}


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def compare_rows(lines: list[tuple[float, str]]) -> list[dict]:
    """The rows of ``rlpgo-compare``'s tables: method, init s, refine s, their sum and when
    the line arrived (a row is a line between a table's dashes and its '*' / '=' line that
    is not an indented progress line)."""
    rows, inside = [], False
    for arrived, line in lines:
        if line.startswith("---"):
            inside = True
        elif inside and (line.startswith("* ") or line.startswith("= ")):
            inside = False
        elif inside and line.startswith("  ") and not line.startswith("    "):
            cells = line.split()
            init_s, refine_s = _number(cells[2]), _number(cells[4])
            rows.append({"method": cells[0], "init_s": init_s, "refine_s": refine_s,
                         "seconds": (init_s or 0.0) + (refine_s or 0.0), "arrived_s": arrived,
                         "failed": "FAILED" in line})
    return rows


def init_all_rows(lines: list[tuple[float, str]]) -> list[dict]:
    """The rows of ``rlpgo-init --method all``: between its header and its ranking line,
    not indented (a progress line is)."""
    rows, inside = [], False
    for arrived, line in lines:
        if line.startswith("method "):
            inside = True
        elif line.startswith("ranking:"):
            inside = False
        elif inside and line.strip() and not line.startswith(" "):  # not a progress line
            cells = line.split()
            rows.append({"method": cells[0], "seconds": _number(cells[3]) or 0.0,
                         "arrived_s": arrived, "failed": "FAILED" in line})
    return rows


def streamed(rows: list[dict]) -> bool:
    """Whether each row arrived at least half its own seconds after the one before it."""
    return all(later["arrived_s"] - earlier["arrived_s"] >= 0.5 * later["seconds"]
               for earlier, later in itertools.pairwise(rows))


def measure_speed(args) -> dict:
    files = args.files.split(",")
    paths = [harness.shared_file(name) for name in files]
    init, compare = harness.command_path("rlpgo-init"), harness.command_path("rlpgo-compare")
    runs: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory(prefix="rlpgo_compare_speed_") as folder:
        out = Path(folder) / "out.g2o"
        for repeat in range(args.repeats):
            for name, path in zip(files, paths, strict=True):
                out.unlink(missing_ok=True)
                runs.setdefault(f"init {name}", []).append(
                    timed_lines([init, path, "-o", out], args.timeout))
                runs.setdefault(f"compare {name}", []).append(
                    timed_lines([compare, path], args.timeout))
            if len(files) > 1:
                runs.setdefault("compare all files", []).append(
                    timed_lines([compare, *paths], args.timeout))
            print(f"repeat {repeat + 1}: " + ", ".join(
                f"{key} {value[-1]['seconds']:.2f} s" for key, value in runs.items()), flush=True)
        method_all = None
        if args.all_file:
            out.unlink(missing_ok=True)
            done = timed_lines([init, harness.shared_file(args.all_file), "-o", out,
                                "--method", "all"], args.timeout)
            rows = init_all_rows(done["lines"])
            method_all = {"file": args.all_file, "seconds": done["seconds"],
                          "failure": done["failure"], "rows": rows, "streamed": streamed(rows)}
    table = []
    for name in [*files, "all files"] if len(files) > 1 else files:
        compare_runs = runs[f"compare {name}"]
        init_runs = [r for f in (files if name == "all files" else [name])
                     for r in runs[f"init {f}"]]
        init_s = (sum(harness.median([r["seconds"] for r in runs[f"init {f}"] if not r["failure"]])
                      for f in files) if name == "all files" else
                  harness.median([r["seconds"] for r in init_runs if not r["failure"]]))
        compare_s = harness.median([r["seconds"] for r in compare_runs if not r["failure"]])
        rows = [compare_rows(r["lines"]) for r in compare_runs]
        table.append({
            "file": name, "init_seconds": init_s, "compare_seconds": compare_s,
            "ratio": None if not init_s or compare_s is None else compare_s / init_s,
            "init_seconds_all": [r["seconds"] for r in init_runs],
            "compare_seconds_all": [r["seconds"] for r in compare_runs],
            "failures": [r["failure"] for r in [*init_runs, *compare_runs] if r["failure"]],
            "methods": list(dict.fromkeys(row["method"] for row in rows[-1])),
            # per method, its rows' seconds in one run (every file's, summed), median of runs
            "row_seconds": {method: harness.median([
                sum(x["seconds"] for x in run if x["method"] == method) for run in rows])
                for method in dict.fromkeys(row["method"] for row in rows[-1])},
            "runs_rows": rows,
            "streamed": all(streamed(run) for run in rows),
            "first_row_s": harness.median([run[0]["arrived_s"] for run in rows if run]),
            "last_row_s": harness.median([run[-1]["arrived_s"] for run in rows if run])})
        print(json.dumps(table[-1]), flush=True)
    return {"rows": table, "method_all": method_all, "repeats": args.repeats}


def speed_text(result: dict) -> str:
    lines = [f"Wall seconds of whole processes (start to exit), medians of {result['repeats']}; "
             "ratio = compare / init (the run over every file: / the sum of the inits).", "",
             "| file | rlpgo-init s | rlpgo-compare s | ratio | rows streamed | first row s | "
             "last row s | rows: init s + refine s (all files: summed over them), median |",
             "|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        cells = ", ".join(f"{m} {s:.2f}" for m, s in r["row_seconds"].items() if s is not None)
        lines.append("| " + " | ".join([
            r["file"], _cell(r["init_seconds"]), _cell(r["compare_seconds"]),
            _cell(r["ratio"]), "yes" if r["streamed"] else "no", _cell(r["first_row_s"]),
            _cell(r["last_row_s"]), cells]) + " |")
    every = result.get("method_all")
    if every:
        lines += ["", f"`rlpgo-init {every['file']} -o OUT --method all`: "
                  f"{every['seconds']:.2f} s, {len(every['rows'])} rows, streamed: "
                  f"{'yes' if every['streamed'] else 'no'} (each row's arrival, s: " + ", ".join(
                      f"{r['method']} {r['arrived_s']:.2f}" for r in every["rows"]) + ")"
                  + ("" if every["failure"] is None else f"; {every['failure']}")]
    return "\n".join(lines) + "\n"


def _cell(value: float | None, spec: str = ".2f") -> str:
    return "-" if value is None else format(value, spec)


def _win_cases() -> list[tuple[str, object]]:
    """(name, a call that returns (graph, values)) of each graph of the wins measurement."""
    import numpy as np

    from rlpgo_gtsam import generate, read_g2o

    cases = [(f"{name}.g2o", lambda name=name: read_g2o(harness.shared_file(name)))
             for name in harness.FILES_2D]
    cases += [(f"sigma_t_{s}.g2o", lambda s=s: read_g2o(
        DATASETS / "paper_sigma_t_sweep" / f"sigma_t_{s}.g2o")) for s in SIGMA_T_SWEEP]

    def generated(n: int, sigma_r: float, seed: int):
        sample = generate(n, sigma_r, 0.05, 3.0, 0.5, np.random.default_rng(seed),
                          noisy_measurements=True)
        return sample.graph, sample.initial

    cases += [(f"generated n={n} sigma_R={sigma_r} seed={seed}",
               lambda n=n, sigma_r=sigma_r, seed=seed: generated(n, sigma_r, seed))
              for n, sigma_r, seed in WIN_GENERATED]
    return cases


def measure_wins(args) -> dict:
    from rlpgo_gtsam.ranking import compare_methods, ties, usable_rows

    methods = args.methods.split(",")
    graphs = []
    for name, read in _win_cases():
        graph, values = read()
        rows = compare_methods(graph, values, methods, "lm", 30, dataset=name)
        usable = usable_rows(rows)
        record = {"case": name, "rows": [{
            "method": r.method, "refined_chi2": r.refined_chi2, "seconds": r.seconds,
            "failure": r.failure, "certified": None if r.init is None or
            r.init.certificate is None else bool(r.init.certificate.certified)} for r in rows]}
        for r, row in zip(rows, record["rows"], strict=True):
            others = [o.refined_chi2 for o in usable if o is not r]
            lowest = r in usable and all(ties(r.refined_chi2, c) for c in others)
            row["lowest"] = lowest  # tied for the lowest, or alone
            row["alone"] = lowest and not any(ties(c, r.refined_chi2) for c in others)
        graphs.append(record)
        print(name + ": " + ", ".join(
            f"{row['method']} {_cell(row['refined_chi2'], '.6g')}"
            f"{' (alone lowest)' if row['alone'] else ''} {row['seconds']:.2f} s"
            for row in record["rows"]), flush=True)
    summary = {}
    for index, method in enumerate(r["method"] for r in graphs[0]["rows"]):
        rows = [g["rows"][index] for g in graphs]
        summary[method] = {"alone_lowest": [g["case"] for g, r in zip(graphs, rows, strict=True)
                                            if r["alone"]],
                           "tied_lowest": sum(r["lowest"] and not r["alone"] for r in rows),
                           "failed": sum(r["failure"] is not None for r in rows),
                           "seconds": sum(r["seconds"] for r in rows)}
    return {"methods": methods, "graphs": graphs, "summary": summary}


def wins_text(result: dict) -> str:
    lines = [f"Each method's guess refined by LM30 (`compare_methods`), "
             f"{len(result['graphs'])} graphs; lowest = the lowest refined chi2 of the graph's "
             "rows (ties within a relative 1e-6).", "",
             "| method | alone lowest (graphs) | tied for the lowest | failed | seconds, all "
             "graphs |", "|---|---|---|---|---|"]
    for method, s in result["summary"].items():
        alone = f"{len(s['alone_lowest'])}" + (f" ({', '.join(s['alone_lowest'])})"
                                               if s["alone_lowest"] else "")
        lines.append(f"| {method} | {alone} | {s['tied_lowest']} | {s['failed']} | "
                     f"{s['seconds']:.1f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", default=FILES, help="shared files, comma-separated")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--all-file", default="MIT.g2o",
                        help="the file of the --method all streaming check ('' to skip)")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per process")
    parser.add_argument("--wins", action="store_true",
                        help="measure which methods give the lowest refined chi2 instead")
    parser.add_argument("--methods", default=None,
                        help="--wins: the methods [default: the comparison's default methods "
                        "and those left out of it, the agent excepted]")
    parser.add_argument("--name", default=None,
                        help="results file name [default: compare_speed, compare_wins]")
    args = parser.parse_args()
    if args.wins:
        from rlpgo_cli.compare import DEFAULT_METHODS, LEFT_OUT

        args.methods = args.methods or ",".join([*DEFAULT_METHODS.split(","), *LEFT_OUT])
        result, name = measure_wins(args), args.name or "compare_wins"
        text = wins_text(result)
    else:
        harness.cache_bytecode()
        result, name = measure_speed(args), args.name or "compare_speed"
        text = speed_text(result)
    print(text)
    print(f"wrote {harness.write_result(name, harness.command_line(), result, text)}")


if __name__ == "__main__":
    main()
