"""The SE(3) certified relaxation and GTSAM's InitializePose3 on SE-Sync's seven 3D files,
each refined by GTSAM LM30, against SE-Sync + LM30 measured in the same run; with
``--generated``, on the project's hard 3D graphs instead.

    python benchmarks/pose3.py [--files tinyGrid3D,...] [--time-limit 120] [--sesync BIN]
        [--repeats 3]
    python benchmarks/pose3.py --generated [--n 500,1000] [--sigma-r 0.3,0.4] [--seeds 0,1,2]
        [--sesync BIN] [--repeats 3]

Per file: ``certified3d`` (status, rank, CPU seconds) and chi2 after LM30 from its estimate;
``InitializePose3`` (with a prior on the first pose) + LM30: chi2 and seconds; the in-process
CPU seconds (``time.process_time``) of certified + LM30 against SE-Sync's wall seconds + LM30.
Both sides are timed warm and by the median of ``--repeats`` runs (default 3): before the
first row, the first case is run once untimed (ours, InitializePose3 and the SE-Sync driver:
imports, first calls and the driver's first load are not charged to it); then certified3d +
LM30 and SE-Sync + LM30 each run ``--repeats`` times on each case, their seconds the medians
(the runs give the same estimate; chi2 and certificates are the first run's); InitializePose3
runs once. Seconds are printed with 3 significant digits.
On a generated graph the commands run too, process to process: ``rlpgo-init FILE -o OUT``
(the staged default, the project's LM30) against SE-Sync's driver then
``benchmarks/sesync/lm30.py`` (LM30 with the settings ``rlpgo-init`` uses), their chi2 and
wall seconds in the last two columns.
SE-Sync runs through its driver (``benchmarks/sesync``: ``--sesync`` or
``$RLPGO_SESYNC_BINARY``, default options, BLAS on one thread): its seconds are the driver's
wall time of the whole ``SESync()`` call, its certificate the driver's (verification passed
and suboptimality bound about 0), and its rounded estimate, moved onto the file's first
vertex, is refined by the same LM30 as ours. Without the driver the SE-Sync columns are left
empty. Graphs are read by ``gtsam.readG2o(path, True)``: the graph SE-Sync's figures were
refined on, and the graph :func:`rlpgo_gtsam.g2o3d.read_g2o3d` makes (cubicle's indefinite
informations are GTSAM's partial Cholesky factors of them; the extraction weighs those
edges by the printed matrices it reads back from them, as SE-Sync reads the file:
``weighed_printed`` counts them; docs/pose3.md has the rule). chi2 = 2 x GTSAM error, first
pose fixed. Prints a markdown table, writes ``benchmarks/results/pose3.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.process import check_binaries, chi2_of, run_baseline, run_ours  # noqa: E402
from benchmarks.sesync.runner import run_sesync, to_values  # noqa: E402
from rlpgo_gtsam.errors import RlpgoError, one_line  # noqa: E402
from rlpgo_gtsam.g2o3d import write_g2o3d  # noqa: E402
from rlpgo_gtsam.graph3d import PoseGraph3D  # noqa: E402
from rlpgo_gtsam.initializers3d import Certified3D, InitializePose3  # noqa: E402
from rlpgo_gtsam.synthetic import generate3d  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DATA = ROOT.parent / "shared" / "datasets" / "3d"
FILES = ["tinyGrid3D", "smallGrid3D", "parking-garage", "sphere2500", "torus3D", "cubicle",
         "sphere_bignoise_vertex3"]
MARGIN = 1e-4  # chi2 at or below SE-Sync + LM30 (+0.01%)
COMMAND_TIMEOUT = 600.0  # seconds per process of the generated graphs' commands
# The generated family: sigma_t (m), d (m), lc; noisy measurements
GENERATED = (0.1, 1.0, 0.5)


def _lm30(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> tuple[float | None, float,
                                                                          str | None]:
    """chi2 after GTSAM LM30 (first pose fixed), its CPU seconds, and a failure if any."""
    key = min(values.keys())
    fixed = gtsam.NonlinearFactorGraph(graph)
    fixed.add(gtsam.PriorFactorPose3(key, values.atPose3(key),
                                     gtsam.noiseModel.Constrained.All(6)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(30)
    start = time.process_time()
    try:
        result = gtsam.LevenbergMarquardtOptimizer(fixed, values, params).optimize()
    except RuntimeError as error:
        return None, time.process_time() - start, one_line(error)
    return 2.0 * graph.error(result), time.process_time() - start, None


def _sesync(graph: gtsam.NonlinearFactorGraph, path: Path, binary: Path | None,
            repeats: int = 1) -> dict:
    """SE-Sync's figures for one file: the driver's run, then the same LM30 as ours from its
    re-anchored estimate (seconds: medians of ``repeats`` runs); all None without a driver."""
    row: dict = dict.fromkeys(("sesync_seconds", "sesync_certified", "sesync_status",
                               "sesync_rank", "sesync_bound", "sesync_failure",
                               "sesync_lm30_chi2", "sesync_lm30_seconds",
                               "sesync_lm30_failure"))
    if binary is None:
        return row
    runs, lm30 = [], []
    for _ in range(repeats):
        try:
            runs.append(run_sesync(binary, path))
        except RuntimeError as error:
            row["sesync_failure"] = one_line(error)
            return row
        lm30.append(_lm30(graph, to_values(runs[-1].ids, runs[-1].poses)))
    run, (chi2, _, failure) = runs[0], lm30[0]
    row.update(sesync_seconds=_median([r.seconds for r in runs]),
               sesync_certified=run.certified, sesync_status=run.status, sesync_rank=run.rank,
               sesync_bound=run.suboptimality_bound, sesync_lm30_chi2=chi2,
               sesync_lm30_seconds=_median([seconds for _, seconds, _ in lm30]),
               sesync_lm30_failure=failure, sesync_runs_seconds=[r.seconds for r in runs])
    return row


def _median(values: list[float]) -> float:
    return float(np.median(values))


def _ours(graph: gtsam.NonlinearFactorGraph, pose_graph: PoseGraph3D,
          time_limit: float, repeats: int = 1) -> dict:
    """certified3d + LM30 (seconds: medians of ``repeats`` runs) and InitializePose3 + LM30:
    chi2, CPU seconds, certificate."""
    row: dict = {}
    runs = []  # (certified seconds, its result, LM30's chi2, seconds, failure)
    for _ in range(repeats):
        start = time.process_time()
        certified = Certified3D(time_limit_s=time_limit).run(pose_graph)
        runs.append((time.process_time() - start, certified,
                     *_lm30(graph, certified.values)))
    _, certified, chi2, _, failure = runs[0]
    row["certified_seconds"] = _median([r[0] for r in runs])
    row["certificate"] = certified.certificate.record()
    row["certified_chi2_before_lm"] = certified.chi2
    row.update(certified_lm30_chi2=chi2, certified_lm30_seconds=_median([r[3] for r in runs]),
               certified_lm30_failure=failure,
               in_process_seconds=_median([r[0] + r[3] for r in runs]),
               in_process_runs_seconds=[r[0] + r[3] for r in runs])
    start = time.process_time()
    try:
        initial = InitializePose3().run(pose_graph)
        row["initialize_pose3_seconds"] = time.process_time() - start
        chi2, seconds, failure = _lm30(graph, initial.values)
        row.update(initialize_pose3_lm30_chi2=chi2, initialize_pose3_failure=failure)
        row["initialize_pose3_seconds"] += seconds
    except RlpgoError as error:
        row.update(initialize_pose3_seconds=time.process_time() - start,
                   initialize_pose3_lm30_chi2=None, initialize_pose3_failure=str(error))
    return row


def _targets(row: dict) -> dict:
    """Whether ours met SE-Sync + LM30's chi2 (+MARGIN) and certified where SE-Sync did."""
    ours, theirs = row["certified_lm30_chi2"], row["sesync_lm30_chi2"]
    return {"chi2_target_met": None if theirs is None else
            ours is not None and ours <= theirs * (1 + MARGIN),
            "certified_target_met": None if row["sesync_certified"] is None else
            row["certificate"]["certified"] or not row["sesync_certified"]}


def _case(name: str, time_limit: float, sesync: Path | None, repeats: int = 1) -> dict:
    path = DATA / f"{name}.g2o"
    graph, values = gtsam.readG2o(str(path), True)
    pose_graph = PoseGraph3D.from_gtsam(graph, values)
    row: dict = {"file": name, "poses": pose_graph.num_poses, "edges": pose_graph.num_edges,
                 "weighed_printed": int(np.any(pose_graph.weighed != pose_graph.information,
                                               axis=(1, 2)).sum())}
    row.update(_ours(graph, pose_graph, time_limit, repeats))
    row.update(_sesync(graph, path, sesync, repeats))
    row.update(_targets(row))
    return row


def _generated_case(n: int, sigma_r: float, seed: int, time_limit: float,
                    sesync: Path | None, folder: Path, repeats: int = 1) -> dict:
    """One generated graph: ours (:func:`_ours`), SE-Sync + LM30 on its g2o file, and LM30
    from the ground truth (a reference: the lowest chi2 known for the graph)."""
    sigma_t, d, lc = GENERATED
    sample = generate3d(n, sigma_r, sigma_t, d, lc, np.random.default_rng(seed),
                        noisy_measurements=True)
    graph = sample.graph
    pose_graph = PoseGraph3D.from_gtsam(graph, sample.initial)
    name = f"gen3d_n{n}_r{sigma_r:g}_s{seed}"
    row: dict = {"file": name, "poses": n, "edges": pose_graph.num_edges, "sigma_r": sigma_r,
                 "sigma_t": sigma_t, "d": d, "lc": lc, "seed": seed,
                 "command": f"generate3d({n}, {sigma_r:g}, {sigma_t:g}, {d:g}, {lc:g}, "
                            f"default_rng({seed}), noisy_measurements=True)"}
    row.update(_ours(graph, pose_graph, time_limit, repeats))
    row["truth_lm30_chi2"] = _lm30(graph, sample.ground_truth)[0]
    path = folder / f"{name}.g2o"
    write_g2o3d(path, graph, sample.initial)
    row.update(_sesync(graph, path, sesync, repeats))
    row.update(_targets(row))
    row.update(_commands(graph, path, folder, sesync))
    return row


def _commands(graph: gtsam.NonlinearFactorGraph, path: Path, folder: Path,
              sesync: Path | None) -> dict:
    """What a user's commands give on the file, process to process, idle: ``rlpgo-init
    FILE -o OUT`` (the staged default with the project's LM30) and SE-Sync's driver then
    ``benchmarks/sesync/lm30.py`` (GTSAM LM30 with the settings ``rlpgo-init`` uses): their
    chi2 (2 x GTSAM error of the file's graph at what each wrote) and wall seconds."""
    ours = run_ours(path, folder / "command.g2o", COMMAND_TIMEOUT)
    row = {"command_chi2": chi2_of(graph, folder / "command.g2o", 3),
           "command_seconds": ours["seconds"], "command_failure": ours["failure"],
           "command_baseline_chi2": None, "command_baseline_seconds": None}
    if sesync is not None:
        base = run_baseline(path, folder, str(sesync), "1", COMMAND_TIMEOUT, busy=False)
        if base.get("lm30_failure", base["sesync_failure"]) is None:
            row.update(command_baseline_chi2=base["lm30_chi2"],
                       command_baseline_seconds=base["sesync_seconds"] + base["lm30_seconds"])
    return row


def _sesync_cells(r: dict) -> tuple[str, str, str]:
    """SE-Sync's certificate (rank), its + LM30 chi2, and its seconds (+ LM30 CPU s)."""
    if r["sesync_failure"] is not None:
        return f"fails: {r['sesync_failure'][:60]}", "-", "-"
    if r["sesync_certified"] is None:
        return "-", "-", "-"
    certified = f"{'yes' if r['sesync_certified'] else 'no'} ({r['sesync_rank']})"
    if r["sesync_lm30_chi2"] is None:
        return certified, f"fails: {r['sesync_lm30_failure'][:60]}", \
            f"{r['sesync_seconds']:.3g}"
    return (certified, f"{r['sesync_lm30_chi2']:.6g}",
            f"{r['sesync_seconds']:.3g} (+{r['sesync_lm30_seconds']:.3g})")


def _generated_table(rows: list[dict]) -> str:
    def number(value) -> str:
        return "-" if value is None else f"{value:.6g}"

    head = ("| graph | edges | certified3d (rank, bound, CPU s) | + LM30 chi2 | CPU s (+ LM30) "
            "| SE-Sync (rank, bound, s) | + LM30 chi2 | s (+ LM30) | InitializePose3 + LM30 "
            "chi2 (CPU s) | truth + LM30 chi2 | rlpgo-init chi2 (s) | SE-Sync + lm30.py chi2 "
            "(s) |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        cert = r["certificate"]
        if r["sesync_status"] is None:
            sesync, sesync_s = r["sesync_failure"] or "-", "-"
        else:
            sesync = (f"{'certified' if r['sesync_certified'] else r['sesync_status']} "
                      f"({r['sesync_rank']}, {r['sesync_bound']:.3g}, "
                      f"{r['sesync_seconds']:.3g})")
            sesync_s = f"{r['sesync_seconds'] + (r['sesync_lm30_seconds'] or 0.0):.3g}"
        init = r["initialize_pose3_lm30_chi2"]
        init = number(init) if init is not None else \
            f"fails: {r['initialize_pose3_failure'][:40]}"
        lines.append(
            f"| {r['file']} | {r['edges']} | {cert['status']} ({cert['rank']}, "
            f"{cert['suboptimality_bound']:.3g}, {r['certified_seconds']:.3g}) | "
            f"{number(r['certified_lm30_chi2'])} | {r['in_process_seconds']:.3g} | {sesync} | "
            f"{number(r['sesync_lm30_chi2'])} | {sesync_s} | {init} "
            f"({r['initialize_pose3_seconds']:.3g}) | {number(r['truth_lm30_chi2'])} | "
            f"{_command_cell(r['command_chi2'], r['command_seconds'], r['command_failure'])} | "
            f"{_command_cell(r['command_baseline_chi2'], r['command_baseline_seconds'])} |")
    return "\n".join(lines) + "\n"


def _command_cell(chi2: float | None, seconds: float | None,
                  failure: str | None = None) -> str:
    if failure is not None:
        return f"fails: {failure[:40]}"
    return "-" if chi2 is None else f"{chi2:.9g} ({seconds:.3g})"


def _table(rows: list[dict]) -> str:
    head = ("| file | poses | certified3d (rank, CPU s) | + LM30 chi2 | SE-Sync certified "
            "(rank) | SE-Sync + LM30 chi2 | in-process CPU s (certified + LM30) | SE-Sync s "
            "(+ LM30 CPU s) | InitializePose3 + LM30 chi2 (CPU s) |\n"
            "|---|---|---|---|---|---|---|---|---|")
    lines = [head]
    for r in rows:
        cert = r["certificate"]
        ours = "failed" if r["certified_lm30_chi2"] is None else f"{r['certified_lm30_chi2']:.6g}"
        init = r["initialize_pose3_lm30_chi2"]
        init = f"{init:.6g}" if init is not None else \
            f"fails: {r['initialize_pose3_failure'][:60]}"
        sesync_certified, sesync_chi2, sesync_seconds = _sesync_cells(r)
        lines.append(
            f"| {r['file']} | {r['poses']} | {cert['status']} ({cert['rank']}, "
            f"{r['certified_seconds']:.3g}) | {ours} | {sesync_certified} | {sesync_chi2} | "
            f"{r['in_process_seconds']:.3g} | {sesync_seconds} | {init} "
            f"({r['initialize_pose3_seconds']:.3g}) |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", default=",".join(FILES))
    parser.add_argument("--time-limit", type=float, default=120.0,
                        help="the staircase's time limit per file, seconds")
    parser.add_argument("--generated", action="store_true",
                        help="run the generated hard 3D graphs instead of SE-Sync's files")
    parser.add_argument("--n", default="500,1000", help="--generated: poses, a list")
    parser.add_argument("--sigma-r", default="0.3,0.4",
                        help="--generated: rotation noise per axis, radians, a list")
    parser.add_argument("--seeds", default="0,1,2", help="--generated: seeds, a list")
    parser.add_argument("--sesync", help="the sesync_rounded driver (default: "
                        "$RLPGO_SESYNC_BINARY; without one the SE-Sync columns are left empty)")
    parser.add_argument("--name", default=None,
                        help="results file name (default pose3, pose3_generated)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="timed runs of ours and of SE-Sync per case (the medians are "
                        "reported), after one untimed run of the first case")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be 1 or more")
    check_binaries(parser, args, ("sesync",))
    print(f"SE-Sync driver: {args.sesync or 'none (SE-Sync columns left empty)'}", flush=True)
    sesync = None if args.sesync is None else Path(args.sesync)
    rows = []
    if args.generated:
        cases = [(n, sigma_r, seed) for n in map(int, args.n.split(","))
                 for sigma_r in map(float, args.sigma_r.split(","))
                 for seed in map(int, args.seeds.split(","))]
        with tempfile.TemporaryDirectory(prefix="pose3_generated_") as folder:
            _generated_case(*cases[0], args.time_limit, sesync, Path(folder))  # warm-up
            for case in cases:
                rows.append(_generated_case(*case, args.time_limit, sesync, Path(folder),
                                            args.repeats))
                _print_row(rows[-1])
        table, name = _generated_table(rows), args.name or "pose3_generated"
    else:
        files = args.files.split(",")
        _case(files[0], args.time_limit, sesync)  # warm-up, untimed
        for file in files:
            rows.append(_case(file, args.time_limit, sesync, args.repeats))
            _print_row(rows[-1])
        table, name = _table(rows), args.name or "pose3"
    print(table)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(
        {"command": "python benchmarks/pose3.py " + " ".join(sys.argv[1:]),
         "sesync": None if sesync is None else str(sesync), "repeats": args.repeats,
         "warm_up": "the first case, run once untimed", "rows": rows},
        indent=2) + "\n")
    (RESULTS / f"{name}.md").write_text(table)


def _print_row(row: dict) -> None:
    print(json.dumps({k: v for k, v in row.items() if k != "certificate"}), flush=True)


if __name__ == "__main__":
    main()
