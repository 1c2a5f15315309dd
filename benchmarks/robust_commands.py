"""``rlpgo-init --robust`` against the clean default as a user runs them: commands, not calls.

    python benchmarks/robust_commands.py [--cases MIT,Intel,FR079,gen]
        [--modes random,local,group,localgroup] [--fractions 0.05,0.1,0.2]
        [--repeats 3] [--loads idle,busy] [--name robust_commands]

``benchmarks/robust.py`` times the robust path in-process against the clean default in the
same process ("x clean"), which leaves out what every command pays alike (interpreter,
imports, reading, writing). This script times the two commands a user types, each a process
of its own (``benchmarks/processes.py``: wall seconds from the fork to the exit), on the same
graphs: per case (a shared file, or ``gen``, the generator's 1000-pose graph of
``robust.py``) the clean default ``rlpgo-init CLEAN.g2o -o OUT`` and, per policy and
fraction, ``rlpgo-init --robust BAD.g2o -o OUT`` on the graph with ``robust.py``'s wrong
closures (the same seeds) written as g2o with the clean graph's values (``robust.py``'s
start too). Figures are medians of
``--repeats`` runs, the two commands alternating; "x clean" is the robust command's median
over the clean command's. The robust command's "rejected N of M" line is kept beside the
number of wrong closures added, as a check that it ran the case (decisions themselves are
``robust.py``'s to score). Each load of ``--loads`` gives a row: ``idle``, or ``busy``: one
competing CPU-bound process runs beside both commands (``processes.competing``).

Prints the table, writes ``benchmarks/results/<name>.json`` and ``.md``. Run it on a quiet
machine: both figures are seconds of whole processes.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import processes  # noqa: E402
from benchmarks.common import write_result  # noqa: E402
from benchmarks.robust import clean_case, corrupted  # noqa: E402
from rlpgo_gtsam import write_g2o  # noqa: E402

_REJECTED = re.compile(r"rejected (\d+) of (\d+) loop closures")


def _timed(command: list[str], out: Path) -> tuple[float, str]:
    """Wall seconds of one run of ``command`` (its output file ``out`` removed first) and
    its stdout; a failed run ends the benchmark with its message."""
    out.unlink(missing_ok=True)
    run = processes.run(command, 600.0)
    if run.failure is not None:
        raise SystemExit(f"{' '.join(command)}: {run.failure}")
    return run.seconds, run.stdout


def _row(init: str, clean: Path, bad: Path, out: Path, repeats: int, load: str) -> dict:
    """The two commands ``repeats`` times each, alternating, under ``load``: medians, every
    run's seconds, and what the robust command said it rejected."""
    if load not in ("idle", "busy"):
        raise SystemExit(f"--loads: idle or busy, not {load!r}")
    clean_s, robust_s, said = [], [], ""
    with processes.competing(load == "busy"):
        for repeat in range(repeats):
            order = ("clean", "robust") if repeat % 2 == 0 else ("robust", "clean")
            for which in order:
                if which == "clean":
                    seconds, _ = _timed([init, str(clean), "-o", str(out)], out)
                    clean_s.append(seconds)
                else:
                    seconds, said = _timed([init, "--robust", str(bad), "-o", str(out)], out)
                    robust_s.append(seconds)
    found = _REJECTED.search(said)
    row = {"load": load, "rejected": int(found.group(1)) if found else None,
           "clean_s": statistics.median(clean_s), "robust_s": statistics.median(robust_s),
           "clean_all": clean_s, "robust_all": robust_s}
    return row | {"x_clean": row["robust_s"] / row["clean_s"]}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--cases", default="MIT,Intel,FR079,gen")
    parser.add_argument("--modes", default="random,local,group,localgroup")
    parser.add_argument("--fractions", default="0.05,0.1,0.2")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--loads", default="idle")
    parser.add_argument("--name", default="robust_commands")
    args = parser.parse_args()
    init = processes.command_path("rlpgo-init")
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="rlpgo_robust_commands_") as folder:
        work, out = Path(folder), Path(folder) / "out.g2o"
        for name in args.cases.split(","):
            graph, values, optimum, _ = clean_case(name)
            clean = work / f"{name}.g2o"
            write_g2o(clean, graph, values)
            for fraction in map(float, args.fractions.split(",")):
                for mode in args.modes.split(","):
                    bad_graph, wrong = corrupted(name, graph, optimum, fraction, mode)
                    bad = work / f"{name}_{mode}_{fraction}.g2o"
                    write_g2o(bad, bad_graph, values)  # robust.py's start: the clean values
                    for load in args.loads.split(","):
                        row = _row(init, clean, bad, out, args.repeats, load)
                        row = {"case": name, "mode": mode, "fraction": fraction,
                               "wrong": len(wrong)} | row
                        rows.append(row)
                        print(f"{name} {mode} {fraction:g} {load}: clean {row['clean_s']:.2f} "
                              f"s, robust {row['robust_s']:.2f} s, x clean "
                              f"{row['x_clean']:.2f}, rejected {row['rejected']} (wrong "
                              f"{row['wrong']})", flush=True)
    lines = ["| case | policy | fraction | load | wrong | rejected | clean command s | "
             "--robust command s | x clean |", "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['case']} | {r['mode']} | {r['fraction']:g} | {r['load']} | {r['wrong']} | "
              f"{r['rejected']} | {r['clean_s']:.2f} | {r['robust_s']:.2f} | "
              f"{r['x_clean']:.2f} |" for r in rows]
    table = "\n".join(lines) + "\n"
    print(table)
    write_result(args.name, {"rows": rows, "args": vars(args)})
    (Path(__file__).resolve().parent / "results" / f"{args.name}.md").write_text(
        f"Made by `python benchmarks/robust_commands.py --cases {args.cases} --modes "
        f"{args.modes} --fractions {args.fractions} --repeats {args.repeats} --loads "
        f"{args.loads} --name "
        f"{args.name}`: wall seconds of whole processes, medians.\n\n" + table)


if __name__ == "__main__":
    main()
