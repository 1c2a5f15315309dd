"""The certified relaxation and the staged default on the shared files, in process, against
GTSAM's LM30, GTSAM's own initializers and SE-Sync + LM30 measured in the same run.

    python benchmarks/certified.py [--files M3500,...] [--generated] [--budget 120]
        [--sesync BIN] [--gtsam-staircase]
    python benchmarks/certified.py --dim 3 [--files tinyGrid3D,...] [--repeats 3]
        [--time-limit 120] [--sesync BIN] [--gtsam-staircase]
    python benchmarks/certified.py --dim 3 --generated [--n 500,1000] [--sigma-r 0.3,0.4]
        [--seeds 0,1,2] [--sesync BIN]

Planar (``--dim 2``, results ``certified``). Per shared file: the ``certified`` initializer's
seconds, its certificate (certified, bounds, lambda_min; in the relaxation's cost) and chi2
after LM30; the default behind ``rlpgo-init`` (``staged_initialize``): its seconds and the
chi2 it hands over; chordal + LM30; GTSAM LM30 from the file's vertices, the baseline of
every ratio; with a SE-Sync driver, SE-Sync's seconds and its rounded estimate + LM30.
``--generated`` adds two 1000-pose graphs of the generator with heavy rotation noise.

3D (``--dim 3``, results ``certified_3d``). Per file of SE-Sync's seven: the certified
initializer (status, rank, CPU seconds) and chi2 after GTSAM's LM30 from its estimate;
GTSAM's InitializePose3 + LM30; SE-Sync + LM30. Both sides are timed warm, as medians of
``--repeats`` runs after one untimed run of the first case (the runs give the same estimate;
chi2 and certificates are the first run's). Graphs are read by ``gtsam.readG2o(path, True)``:
the graph SE-Sync's figures were refined on. ``--generated`` (results
``certified_3d_generated``) runs the generator's hard 3D graphs instead, and there also the
commands process to process: ``rlpgo-init FILE -o OUT`` against SE-Sync's driver then
``benchmarks/sesync/lm30.py``.

``--gtsam-staircase`` adds GTSAM's ``RiemannianStaircaseOptimizer`` on the rotations (where the
wheel has it; :func:`benchmarks.harness.gtsam_staircase`): its certificate, rank and seconds,
and the chi2 of LM30 from its rotations with the translations solved; ``--gtsam-staircase se``
builds the whole SE(d) problem as GTSAM's CertifiablePoseGraphOptimizationPose2/3 notebooks
do (:func:`benchmarks.harness.gtsam_se_staircase`) and refines its rounded estimate. SE-Sync
runs through its driver (``--sesync`` or ``$RLPGO_SESYNC_BINARY``, default options, BLAS on
one thread); without it its columns are left empty. chi2 = 2 x GTSAM error.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import cell, median  # noqa: E402

LOWEST_KNOWN = {"M3500": 137.9, "M3500A": 912.2, "M3500B": 2055.4, "M3500C": 2556.4,
                "City10K": 512.0, "Intel": 212.7, "MIT": 41.21, "FR079": 37.57}
GENERATED_2D = [(0.4, 11), (0.5, 12)]  # (sigma_R, seed): 1000 poses, noisy measurements
GENERATED_3D = (0.1, 1.0, 0.5)  # sigma_t (m), d (m), lc of the generated 3D graphs
MARGIN = 1e-4  # chi2 at or below SE-Sync + LM30 (+0.01%)
COMMAND_TIMEOUT = 600.0  # seconds per process of the generated graphs' commands


def _timed(function):
    gc.collect()
    return harness.timed(function)


def _staircase_anchor(graph, values, pose_graph, form: str = "rotations") -> dict:
    """GTSAM's staircase on the rotations, then the translations solved and LM30 (the
    project's in the plane, GTSAM's in 3D, as the other columns of the dimension); ``form``
    ``se``: on the whole SE(d) problem as GTSAM's CertifiablePoseGraphOptimization notebooks
    build it (:func:`benchmarks.harness.gtsam_se_staircase`), its rounded estimate + LM30."""
    from rlpgo_gtsam import poses_with_rotations, refine

    if form == "se":
        found = harness.gtsam_se_staircase(graph, values)
        if found is None:
            return {"gtsam_staircase": "not in this gtsam"}
        row = {f"gtsam_staircase_{k}": found.get(k) for k in
               ("certified", "rank", "seconds", "wall_seconds", "failure")}
        if found.get("values") is not None:
            row["gtsam_staircase_lm30_chi2"] = refine(graph, found["values"], "lm", 30).chi2
        return row
    found = harness.gtsam_staircase(graph, values)
    if found is None:
        return {"gtsam_staircase": "not in this gtsam"}
    row = {f"gtsam_staircase_{k}": v for k, v in found.items() if k != "rotations"}
    if found["rotations"] is not None:
        matrices = np.array([found["rotations"][int(k)] for k in pose_graph.keys])
        rotations = (np.arctan2(matrices[:, 1, 0], matrices[:, 0, 0])
                     if pose_graph.dimension == 2 else matrices)
        start = pose_graph.to_values(poses_with_rotations(pose_graph, rotations))
        row["gtsam_staircase_lm30_chi2"] = (refine(graph, start, "lm", 30).chi2
                                            if pose_graph.dimension == 2 else
                                            harness.gtsam_lm(graph, start)[0])
    return row


# --- the plane ----------------------------------------------------------------------------------

def _planar_case(name: str, graph, values, path: Path, args) -> dict:
    from rlpgo_gtsam import extract_pose_graph, make_initializer, refine, staged_initialize

    pose_graph = extract_pose_graph(graph, values)
    row: dict = {"file": name, "poses": pose_graph.num_poses, "edges": pose_graph.num_edges}
    lm30, row["lm30_seconds"] = _timed(lambda: refine(graph, values, "lm", 30))
    row["lm30_chi2"] = lm30.chi2
    certified = make_initializer("certified").run(pose_graph)
    certificate = certified.certificate
    row.update(
        certified_seconds=certified.seconds, certified=certificate.certified,
        lower_bound=certificate.lower_bound, estimate_cost=certificate.estimate_cost,
        suboptimality_bound=certificate.suboptimality_bound,
        min_eigenvalue=certificate.min_eigenvalue, tolerance=certificate.tolerance,
        rank=certificate.rank, certified_guess_chi2=certified.chi2,
        certified_lm30_chi2=refine(graph, certified.values, "lm", 30).chi2)
    chordal = make_initializer("chordal").initialize(graph, values)
    row["chordal_lm30_chi2"] = refine(graph, chordal, "lm", 30).chi2
    budget = {} if args.budget is None else {"budget_s": args.budget}
    staged, row["default_seconds"] = _timed(lambda: staged_initialize(
        graph, values, pose_graph=pose_graph, **budget))
    row.update(default_chi2=staged.best.refined_chi2, default_method=staged.best.method,
               default_stages=[r.method for r in staged.rows], default_stopped=staged.stopped,
               default_over_lm30=row["default_seconds"] / row["lm30_seconds"])
    if args.sesync:
        from benchmarks.sesync.runner import run_sesync, to_values

        run = run_sesync(args.sesync, path)
        sesync_lm30, lm_seconds = _timed(lambda: refine(graph, to_values(run.ids, run.poses),
                                                        "lm", 30))
        row.update(sesync_seconds=run.seconds, sesync_certified=run.certified,
                   sesync_bound=run.suboptimality_bound, sesync_lm30_chi2=sesync_lm30.chi2,
                   sesync_lm30_seconds=lm_seconds,
                   default_over_sesync_lm30=row["default_seconds"] / (run.seconds + lm_seconds))
    if args.gtsam_staircase:
        row.update(_staircase_anchor(graph, values, pose_graph, args.gtsam_staircase))
    return row


def planar(args) -> tuple[list[dict], str]:
    import rlpgo_gtsam.relaxation  # noqa: F401  (SciPy's import is not the method's time)
    from rlpgo_gtsam import generate, write_g2o

    rows = []
    for name in args.files.split(","):
        path = harness.graph_file(name)
        rows.append(_planar_case(name, *harness.read_graph(path), path, args))
        print(rows[-1], flush=True)
    if args.generated:
        with tempfile.TemporaryDirectory() as folder:
            for sigma_r, seed in GENERATED_2D:
                sample = generate(1000, sigma_r, 0.05, 3.0, 0.5, np.random.default_rng(seed),
                                  noisy_measurements=True)
                path = Path(folder) / f"generated_{seed}.g2o"
                write_g2o(path, sample.graph, sample.initial)
                rows.append(_planar_case(f"generated n=1000 sigma_R={sigma_r} seed={seed}",
                                         *harness.read_graph(path), path, args))
                print(rows[-1], flush=True)
    return rows, _planar_table(rows, bool(args.sesync))


def _planar_table(rows: list[dict], sesync: bool) -> str:
    header = ["file", "poses", "certified", "bound", "lambda_min", "certified s / LM30 s",
              "certified + LM30", "chordal + LM30", "default chi2", "default s / LM30 s",
              "default stages", "lowest known"]
    if sesync:
        header += ["SE-Sync certified", "SE-Sync + LM30", "default s / (SE-Sync + LM30) s"]
    lines = ["chi2 = 2 x GTSAM error; bounds in the relaxation's cost.", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        cells = [r["file"], r["poses"], cell(bool(r["certified"])),
                 f"{r['suboptimality_bound']:.3g}", f"{r['min_eigenvalue']:.2g}",
                 f"{r['certified_seconds'] / r['lm30_seconds']:.2f}",
                 f"{r['certified_lm30_chi2']:.6g}", f"{r['chordal_lm30_chi2']:.6g}",
                 f"{r['default_chi2']:.6g}", f"{r['default_over_lm30']:.2f}",
                 ", ".join(r["default_stages"]),
                 LOWEST_KNOWN.get(r["file"].removesuffix(".g2o"), "-")]
        if sesync:
            cells += [cell(bool(r["sesync_certified"])), f"{r['sesync_lm30_chi2']:.6g}",
                      f"{r['default_over_sesync_lm30']:.2f}"]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return "\n".join(lines) + "\n"


# --- 3D -----------------------------------------------------------------------------------------

def _sesync(graph, path: Path, binary: str | None, repeats: int = 1) -> dict:
    """SE-Sync's figures for one file: the driver's run, then GTSAM LM30 from its
    re-anchored estimate (seconds: medians of ``repeats`` runs); all None without a driver."""
    row: dict = dict.fromkeys(("sesync_seconds", "sesync_certified", "sesync_status",
                               "sesync_rank", "sesync_bound", "sesync_failure",
                               "sesync_lm30_chi2", "sesync_lm30_seconds",
                               "sesync_lm30_failure"))
    if binary is None:
        return row
    from benchmarks.sesync.runner import run_sesync, to_values

    runs, lm30 = [], []
    for _ in range(repeats):
        try:
            runs.append(run_sesync(binary, path))
        except RuntimeError as error:
            row["sesync_failure"] = str(error)
            return row
        lm30.append(harness.gtsam_lm(graph, to_values(runs[-1].ids, runs[-1].poses)))
    run, (chi2, _, failure) = runs[0], lm30[0]
    row.update(sesync_seconds=median([r.seconds for r in runs]), sesync_certified=run.certified,
               sesync_status=run.status, sesync_rank=run.rank,
               sesync_bound=run.suboptimality_bound, sesync_lm30_chi2=chi2,
               sesync_lm30_seconds=median([seconds for _, seconds, _ in lm30]),
               sesync_lm30_failure=failure, sesync_runs_seconds=[r.seconds for r in runs])
    return row


def _spatial_ours(graph, pose_graph, time_limit: float, repeats: int = 1) -> dict:
    """The certified initializer + LM30 (CPU seconds: medians of ``repeats`` runs) and
    GTSAM's InitializePose3 + LM30: chi2, CPU seconds, certificate."""
    from rlpgo_gtsam import RlpgoError, make_initializer

    runs = []  # (certified seconds, its result, LM30's chi2, seconds, failure)
    for _ in range(repeats):
        start = time.process_time()
        certified = make_initializer("certified", time_limit_s=time_limit).run(pose_graph)
        runs.append((time.process_time() - start, certified,
                     *harness.gtsam_lm(graph, certified.values)))
    _, certified, chi2, _, failure = runs[0]
    row = {"certified_seconds": median([r[0] for r in runs]),
           "certificate": certified.certificate.record(),
           "certified_chi2_before_lm": certified.chi2, "certified_lm30_chi2": chi2,
           "certified_lm30_seconds": median([r[3] for r in runs]),
           "certified_lm30_failure": failure,
           "in_process_seconds": median([r[0] + r[3] for r in runs]),
           "in_process_runs_seconds": [r[0] + r[3] for r in runs]}
    start = time.process_time()
    try:
        initial = make_initializer("initialize_pose3").run(pose_graph)
        row["initialize_pose3_seconds"] = time.process_time() - start
        chi2, seconds, failure = harness.gtsam_lm(graph, initial.values)
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


def _spatial_case(name: str, args, repeats: int = 1) -> dict:
    import gtsam

    from rlpgo_gtsam import extract_pose_graph

    path = harness.graph_file(name)
    graph, values = gtsam.readG2o(str(path), True)
    pose_graph = extract_pose_graph(graph, values)
    row: dict = {"file": name, "poses": pose_graph.num_poses, "edges": pose_graph.num_edges,
                 "weighed_printed": int(np.any(pose_graph.weighed != pose_graph.information,
                                               axis=(1, 2)).sum())}
    row.update(_spatial_ours(graph, pose_graph, args.time_limit, repeats))
    row.update(_sesync(graph, path, args.sesync, repeats))
    row.update(_targets(row))
    if args.gtsam_staircase:
        row.update(_staircase_anchor(graph, values, pose_graph, args.gtsam_staircase))
    return row


def _generated_case(n: int, sigma_r: float, seed: int, args, folder: Path,
                    repeats: int = 1) -> dict:
    """One generated 3D graph: ours, SE-Sync + LM30 on its g2o file, LM30 from the ground
    truth (the lowest chi2 known for the graph) and the two commands as processes."""
    from rlpgo_gtsam import SE3, extract_pose_graph, generate, write_g2o

    sigma_t, d, lc = GENERATED_3D
    sample = generate(n, sigma_r, sigma_t, d, lc, np.random.default_rng(seed),
                      noisy_measurements=True, group=SE3)
    graph, name = sample.graph, f"gen3d_n{n}_r{sigma_r:g}_s{seed}"
    pose_graph = extract_pose_graph(graph, sample.initial)
    row: dict = {"file": name, "poses": n, "edges": pose_graph.num_edges, "sigma_r": sigma_r,
                 "sigma_t": sigma_t, "d": d, "lc": lc, "seed": seed}
    row.update(_spatial_ours(graph, pose_graph, args.time_limit, repeats))
    row["truth_lm30_chi2"] = harness.gtsam_lm(graph, sample.ground_truth)[0]
    path = folder / f"{name}.g2o"
    write_g2o(path, graph, sample.initial)
    row.update(_sesync(graph, path, args.sesync, repeats))
    row.update(_targets(row))
    ours = harness.run_init(path, folder / "command.g2o", COMMAND_TIMEOUT)
    row.update(command_chi2=harness.chi2_of(graph, folder / "command.g2o", 3),
               command_seconds=ours["seconds"], command_failure=ours["failure"],
               command_baseline_chi2=None, command_baseline_seconds=None)
    if args.sesync is not None:
        base = harness.run_baseline(path, folder, args.sesync, "1", COMMAND_TIMEOUT, busy=False)
        if base.get("lm30_failure", base["sesync_failure"]) is None:
            row.update(command_baseline_chi2=base["lm30_chi2"],
                       command_baseline_seconds=base["sesync_seconds"] + base["lm30_seconds"])
    return row


def spatial(args) -> tuple[list[dict], str]:
    rows = []
    if args.generated:
        cases = [(n, sigma_r, seed) for n in map(int, args.n.split(","))
                 for sigma_r in map(float, args.sigma_r.split(","))
                 for seed in map(int, args.seeds.split(","))]
        with tempfile.TemporaryDirectory(prefix="certified_3d_generated_") as folder:
            _generated_case(*cases[0], args, Path(folder))  # warm-up, untimed
            for case in cases:
                rows.append(_generated_case(*case, args, Path(folder), args.repeats))
                print(json.dumps({k: v for k, v in rows[-1].items() if k != "certificate"}),
                      flush=True)
        return rows, _generated_table(rows)
    files = args.files.split(",")
    _spatial_case(files[0], args)  # warm-up, untimed
    for file in files:
        rows.append(_spatial_case(file, args, args.repeats))
        print(json.dumps({k: v for k, v in rows[-1].items() if k != "certificate"}), flush=True)
    return rows, _spatial_table(rows)


def _number(value) -> str:
    return "-" if value is None else f"{value:.6g}"


def _sesync_cells(r: dict) -> tuple[str, str, str]:
    """SE-Sync's certificate (rank), its + LM30 chi2, and its seconds (+ LM30 CPU s)."""
    if r["sesync_failure"] is not None:
        return f"fails: {r['sesync_failure'][:60]}", "-", "-"
    if r["sesync_certified"] is None:
        return "-", "-", "-"
    certified = f"{cell(bool(r['sesync_certified']))} ({r['sesync_rank']})"
    if r["sesync_lm30_chi2"] is None:
        return certified, f"fails: {r['sesync_lm30_failure'][:60]}", \
            f"{r['sesync_seconds']:.3g}"
    return (certified, f"{r['sesync_lm30_chi2']:.6g}",
            f"{r['sesync_seconds']:.3g} (+{r['sesync_lm30_seconds']:.3g})")


def _initialize_pose3(r: dict) -> str:
    chi2 = r["initialize_pose3_lm30_chi2"]
    text = _number(chi2) if chi2 is not None else f"fails: {r['initialize_pose3_failure'][:40]}"
    return f"{text} ({r['initialize_pose3_seconds']:.3g})"


def _spatial_table(rows: list[dict]) -> str:
    lines = ["| file | poses | certified (rank, CPU s) | + LM30 chi2 | SE-Sync certified (rank) "
             "| SE-Sync + LM30 chi2 | in-process CPU s (certified + LM30) | SE-Sync s (+ LM30 "
             "CPU s) | InitializePose3 + LM30 chi2 (CPU s) |", "|---" * 9 + "|"]
    for r in rows:
        cert = r["certificate"]
        ours = "failed" if r["certified_lm30_chi2"] is None else f"{r['certified_lm30_chi2']:.6g}"
        sesync_certified, sesync_chi2, sesync_seconds = _sesync_cells(r)
        lines.append(
            f"| {r['file']} | {r['poses']} | {cert['status']} ({cert['rank']}, "
            f"{r['certified_seconds']:.3g}) | {ours} | {sesync_certified} | {sesync_chi2} | "
            f"{r['in_process_seconds']:.3g} | {sesync_seconds} | {_initialize_pose3(r)} |")
    return "\n".join(lines) + "\n"


def _command_cell(chi2, seconds, failure=None) -> str:
    if failure is not None:
        return f"fails: {failure[:40]}"
    return "-" if chi2 is None else f"{chi2:.9g} ({seconds:.3g})"


def _generated_table(rows: list[dict]) -> str:
    lines = ["| graph | edges | certified (rank, bound, CPU s) | + LM30 chi2 | CPU s (+ LM30) "
             "| SE-Sync (rank, bound, s) | + LM30 chi2 | s (+ LM30) | InitializePose3 + LM30 "
             "chi2 (CPU s) | truth + LM30 chi2 | rlpgo-init chi2 (s) | SE-Sync + lm30.py chi2 "
             "(s) |", "|---" * 12 + "|"]
    for r in rows:
        cert = r["certificate"]
        if r["sesync_status"] is None:
            sesync, sesync_s = r["sesync_failure"] or "-", "-"
        else:
            sesync = (f"{'certified' if r['sesync_certified'] else r['sesync_status']} "
                      f"({r['sesync_rank']}, {r['sesync_bound']:.3g}, "
                      f"{r['sesync_seconds']:.3g})")
            sesync_s = f"{r['sesync_seconds'] + (r['sesync_lm30_seconds'] or 0.0):.3g}"
        lines.append(
            f"| {r['file']} | {r['edges']} | {cert['status']} ({cert['rank']}, "
            f"{cert['suboptimality_bound']:.3g}, {r['certified_seconds']:.3g}) | "
            f"{_number(r['certified_lm30_chi2'])} | {r['in_process_seconds']:.3g} | {sesync} | "
            f"{_number(r['sesync_lm30_chi2'])} | {sesync_s} | {_initialize_pose3(r)} | "
            f"{_number(r['truth_lm30_chi2'])} | "
            f"{_command_cell(r['command_chi2'], r['command_seconds'], r['command_failure'])} | "
            f"{_command_cell(r['command_baseline_chi2'], r['command_baseline_seconds'])} |")
    return "\n".join(lines) + "\n"


# --- the command line ---------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    parser.add_argument("--files", help="shared files, paths or gtsam example files (default: "
                        "every shared file of the dimension)")
    parser.add_argument("--generated", action="store_true",
                        help="2D: add two generated graphs; 3D: the generated graphs instead")
    parser.add_argument("--budget", type=float,
                        help="2D: the default's budget, seconds (default: its own)")
    parser.add_argument("--time-limit", type=float, default=120.0,
                        help="3D: the staircase's time limit per file, seconds")
    parser.add_argument("--repeats", type=int, default=3,
                        help="3D: timed runs of ours and of SE-Sync per case (medians)")
    parser.add_argument("--n", default="500,1000", help="3D --generated: poses, a list")
    parser.add_argument("--sigma-r", default="0.3,0.4",
                        help="3D --generated: rotation noise per axis, radians, a list")
    parser.add_argument("--seeds", default="0,1,2", help="3D --generated: seeds, a list")
    parser.add_argument("--sesync", help="the sesync_rounded driver (default: "
                        "$RLPGO_SESYNC_BINARY; without one SE-Sync's columns are left empty)")
    parser.add_argument("--gtsam-staircase", nargs="?", const="rotations",
                        choices=["rotations", "se"],
                        help="add GTSAM's RiemannianStaircaseOptimizer: on the rotations, or "
                             "(se) on the whole SE(d) problem as its notebooks build it")
    parser.add_argument("--name", help="results file name (default: certified, certified_3d, "
                        "certified_3d_generated)")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be 1 or more")
    args.sesync = harness.sesync_binary(args.sesync)
    args.files = args.files or ",".join(harness.FILES_2D if args.dim == 2 else harness.FILES_3D)
    print(f"SE-Sync driver: {args.sesync or 'none (its columns left empty)'}", flush=True)
    rows, table = planar(args) if args.dim == 2 else spatial(args)
    name = args.name or ("certified" if args.dim == 2 else
                         "certified_3d_generated" if args.generated else "certified_3d")
    print(table)
    data = {"sesync": args.sesync, "rows": rows}
    if args.dim == 3:
        data |= {"repeats": args.repeats, "warm_up": "the first case, run once untimed"}
    print(f"wrote {harness.write_result(name, harness.command_line(), data, table)}")


if __name__ == "__main__":
    main()
