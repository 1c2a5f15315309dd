"""Clean maps whose covariances understate the noise: what ``--robust`` rejects, as stated and
told the factor (``covariance_scale``).

    python benchmarks/robust_covariance.py [--cases M3500,...,gen] [--factors 2,4,10]
        [--name robust_covariance]

Per case (a shared planar file, or ``gen``: the robust benchmark's generated 1000-pose graph,
:mod:`benchmarks.robust`) and factor F, every between factor's information is multiplied by
F (covariances F times too small, as an optimistic front end states them; the graph has no
wrong closure). Columns: the closures ``robust_initialize`` rejects as stated and with
``covariance_scale=F``; the chi2 of the second over F against the clean default's (certified
+ LM to convergence on the graph as it was); and the estimate of F a user can make on a map
believed clean, chi2 / (dof x (edges - poses + 1)) of the clean default on the scaled graph
(the variance factor of least squares: :func:`rlpgo_gtsam.residuals.variance_factor`), and
the closures rejected when told that estimate (at least 1) and twice it. Seconds of the
first two runs. Rows are checkpointed to ``benchmarks/results/<name>.json``; the table goes
to ``<name>.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.common import write_rows  # noqa: E402
from benchmarks.robust import FILES, clean_case  # noqa: E402
from rlpgo_gtsam.graph3d import extract_pose_graph  # noqa: E402
from rlpgo_gtsam.residuals import variance_factor  # noqa: E402
from rlpgo_gtsam.robust import robust_initialize  # noqa: E402
from rlpgo_gtsam.synthetic import scaled_informations  # noqa: E402


def row(name: str, factor: float, graph, values, optimum_chi2: float) -> dict:
    scaled = scaled_informations(graph, factor)
    began = time.perf_counter()
    stated = robust_initialize(scaled, values)
    stated_s = time.perf_counter() - began
    began = time.perf_counter()
    told = robust_initialize(scaled, values, covariance_scale=factor)
    told_s = time.perf_counter() - began
    estimate = factor * variance_factor(extract_pose_graph(graph, values), optimum_chi2)
    # told the estimate (at least 1: below, the covariances overstate the noise), and twice it
    told_estimate = [len(robust_initialize(scaled, values, covariance_scale=k * max(estimate, 1.0)
                                           ).rejected) for k in (1.0, 2.0)]
    return {"case": name, "factor": factor, "rejected_as_stated": len(stated.rejected),
            "seconds_as_stated": stated_s, "rejected_told": len(told.rejected),
            "seconds_told": told_s, "told_chi2_over_factor": told.chi2 / factor,
            "optimum_chi2": optimum_chi2, "estimated_factor": estimate,
            "rejected_told_estimate": told_estimate[0],
            "rejected_told_twice_estimate": told_estimate[1]}


def table(rows: list[dict]) -> str:
    lines = ["| case | F | rejected as stated | rejected, told F | chi2 told / F | clean "
             "optimum chi2 | F estimated | rejected, told the estimate / twice it | seconds "
             "stated / told |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['factor']:g} | {r['rejected_as_stated']} | "
                     f"{r['rejected_told']} | {r['told_chi2_over_factor']:.6g} | "
                     f"{r['optimum_chi2']:.6g} | {r['estimated_factor']:.3g} | "
                     f"{r['rejected_told_estimate']} / {r['rejected_told_twice_estimate']} | "
                     f"{r['seconds_as_stated']:.2f} / {r['seconds_told']:.2f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join([*FILES, "gen"]))
    parser.add_argument("--factors", default="2,4,10")
    parser.add_argument("--name", default="robust_covariance")
    args = parser.parse_args()
    command = "python benchmarks/robust_covariance.py " + " ".join(sys.argv[1:])
    rows: list[dict] = []
    for name in args.cases.split(","):
        graph, values, _, optimum_chi2 = clean_case(name)
        for factor in map(float, args.factors.split(",")):
            rows.append(row(name, factor, graph, values, optimum_chi2))
            print(json.dumps(rows[-1]), flush=True)
            write_rows(args.name, command, rows, table(rows))
    print(table(rows))


if __name__ == "__main__":
    main()
