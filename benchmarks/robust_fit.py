"""How well the edges ``--robust`` keeps fit their covariances, on Vertigo's policies: the
evidence behind its hint (``rlpgo_cli.init.LOOSE_FIT``).

    python benchmarks/robust_fit.py [--cases gen,MIT,Intel,FR079,M3500,City10K]
        [--fractions 0.05,0.1,0.2,0.3] [--name robust_fit]

Per case (:mod:`benchmarks.robust`'s, covariances as the file gives them), without wrong
closures and with each policy and fraction of them: the closures ``robust_initialize``
rejected, its recall, the wrong closures it kept, and the kept edges' variance factor
(:func:`rlpgo_gtsam.residuals.variance_factor`), which ``rlpgo-init --robust`` compares with 1.5
(over ``--covariance-scale``) to print its hint where it rejected any. Rows are checkpointed
to ``benchmarks/results/<name>.json``; the table goes to ``<name>.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlpgo_cli.init import LOOSE_FIT  # noqa: E402

from benchmarks.common import write_rows  # noqa: E402
from benchmarks.robust import clean_case, corrupted, scores  # noqa: E402
from rlpgo_gtsam.graph3d import extract_pose_graph  # noqa: E402
from rlpgo_gtsam.residuals import variance_factor  # noqa: E402
from rlpgo_gtsam.robust import robust_initialize  # noqa: E402

MODES = ("random", "local", "group", "localgroup")


def row(name: str, mode: str, fraction: float, graph, values, wrong: list[int]) -> dict:
    result = robust_initialize(graph, values)
    g = extract_pose_graph(graph, values)
    fit = variance_factor(g, result.chi2, g.num_edges - len(result.rejected))
    return {"case": name, "mode": mode, "fraction": fraction, "wrong": len(wrong),
            "rejected": len(result.rejected), "recall": scores(result.rejected, wrong)[1],
            "wrong_kept": len(set(wrong) - set(result.rejected)), "chi2": result.chi2,
            "variance_factor": fit, "hint": bool(result.rejected) and fit > LOOSE_FIT}


def table(rows: list[dict]) -> str:
    lines = ["| case | policy | fraction | wrong | rejected | recall | wrong kept | kept edges' "
             "variance factor | hint |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['mode']} | {r['fraction']:g} | {r['wrong']} | "
                     f"{r['rejected']} | {r['recall']:.3f} | {r['wrong_kept']} | "
                     f"{r['variance_factor']:.3g} | {'yes' if r['hint'] else ''} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default="gen,MIT,Intel,FR079,M3500,City10K")
    parser.add_argument("--fractions", default="0.05,0.1,0.2,0.3")
    parser.add_argument("--name", default="robust_fit")
    args = parser.parse_args()
    command = "python benchmarks/robust_fit.py " + " ".join(sys.argv[1:])
    rows: list[dict] = []
    for name in args.cases.split(","):
        graph, values, optimum, _ = clean_case(name)
        cases = [("clean", 0.0, graph, [])]
        for fraction in map(float, args.fractions.split(",")):
            for mode in MODES:
                cases.append((mode, fraction, *corrupted(name, graph, optimum, fraction, mode)))
        for mode, fraction, judged, wrong in cases:
            rows.append(row(name, mode, fraction, judged, values, wrong))
            print(json.dumps(rows[-1]), flush=True)
            write_rows(args.name, command, rows, table(rows))
    print(table(rows))


if __name__ == "__main__":
    main()
