"""Score SE-Sync's rounded estimate with GTSAM on the shared benchmark files.

    python -m benchmarks.sesync.check_datasets [--binary PATH] [--iters 30] [FILE.g2o ...]

For each file: SE-Sync's seconds, whether it certified, its suboptimality bound, the g2o
chi2 of its (re-anchored) rounded estimate, and the chi2 after the project's LM
(``refine(graph, values, "lm", iters)``). Without files it runs the eight files of
the shared datasets README's table "The certified anchor: SE-Sync". Prints only.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from benchmarks.sesync.runner import default_binary, run_sesync, to_values

NAMES = ["M3500", "M3500A", "M3500B", "M3500C", "City10K", "Intel", "MIT", "FR079"]
DATASETS = Path(os.environ.get("RLPGO_DATASETS",
                               Path(__file__).resolve().parents[3] / "shared" / "datasets"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--binary", type=Path, default=default_binary())
    parser.add_argument("--iters", type=int, default=30)
    args = parser.parse_args(argv)
    if args.binary is None:
        parser.error("give --binary or set $RLPGO_SESYNC_BINARY")
    files = args.files or [DATASETS / f"{name}.g2o" for name in NAMES]

    from rlpgo_gtsam import chi2, read_g2o, refine

    print(f"| file | SE-Sync s | own s | certified | verified | rank | lambda_min | bound "
          f"| estimate chi2 | LM{args.iters} chi2 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for path in files:
        graph, _ = read_g2o(path)
        run = run_sesync(args.binary, path)
        values = to_values(run.ids, run.poses)
        start = chi2(graph, values)
        refined = refine(graph, values, "lm", args.iters)
        yes_no = {True: "yes", False: "no"}
        print(f"| {path.name} | {run.seconds:.3f} | {run.sesync_seconds:.3f} "
              f"| {yes_no[run.certified]} | {yes_no[run.verification_passed]} | {run.rank} "
              f"| {run.min_eigenvalue:.3g} "
              f"| {run.suboptimality_bound:.4g} | {start:.6g} | {refined.chi2:.6g} |",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
