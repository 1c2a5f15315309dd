"""Landmark graphs: the default (``staged_initialize``) against GTSAM 4.3's certified solver and
GTSAM's LM, in process and process to process.

    python benchmarks/landmarks.py [--planar 100,500,800] [--spatial 100,300]
        [--sigma-r 0.1,0.3] [--seed 1] [--files victoriaPark_reduced_1k.g2o,...]
        [--repeats 3] [--no-processes] [--name landmarks]
    python benchmarks/landmarks.py lm INPUT.g2o OUTPUT.g2o [ITERATIONS]

Graphs: generated lawn mowers with points measured by bearing and range
(:func:`rlpgo_gtsam.synthetic.generate_landmarks`: ``--sigma-r`` rotation noise, sigma_t
0.05 m, d 3 m, lc 0.3, one point per :data:`POSES_PER_POINT` poses with the default
:class:`~rlpgo_gtsam.synthetic.LandmarkSettings`, noisy measurements, ``--seed``), planar
(``--planar`` poses) and in space (``--spatial``), and the gtsam wheel's landmark files
(``--files``: Victoria Park and cityTrees, ``LANDMARK2`` lines; known_landmark_localization_20,
``EDGE_SE3_TRACKXYZ``), read by the package's reader.

In process, per graph (timed warm: one untimed run of a small graph first; seconds are
medians of ``--repeats`` runs, chi2 and certificates the first run's):

- ours: ``staged_initialize(graph, values)`` from the odometry guess (the generator's
  ``.initial``: chained odometry, each point at its first sighting; a file's vertices):
  certified, the relaxation's seconds (its certificate's), the certified stage's seconds
  (chordal start, staircase, translations and points, rounding), the whole call's seconds
  and chi2 after its LM30.
- GTSAM's ``RiemannianStaircaseOptimizer`` on the SE(d) problem built as GTSAM's
  ``CertifiableLandmarkSLAMPose2/3`` notebooks build it, from the same guess
  (:func:`benchmarks.harness.gtsam_se_staircase`): certified, final rank, its ``totalTime``
  and its wall seconds with building the problem and the notebooks' rounding; chi2 of the
  rounded estimate and after GTSAM's LM30 from it (the refinement ours gets).
- GTSAM's LM100 (default parameters, first pose held) from the odometry guess and, on
  generated graphs, from the ground truth: seconds (wall) and chi2.
- ``best``: ours <= min(every other chi2) x (1 + 1e-4).
- ratio: our certified stage over GTSAM's staircase wall seconds (each from the graph and
  the guess to a rounded estimate); the JSON has the relaxation-only ratio too (our
  certificate's seconds over GTSAM's ``totalTime``).

Process to process (unless ``--no-processes``; :func:`benchmarks.harness.run`, fork to
exit): ``rlpgo-init FILE -o OUT`` against ``python benchmarks/landmarks.py lm FILE OUT 100``
(import, the package's reader, the same GTSAM LM100 from the file's vertices, the package's
writer: GTSAM's own ``readG2o`` reads neither ``EDGE_SE2_XY`` nor ``LANDMARK2``); the
generated graphs are written once into a temporary folder. chi2 = 2 x GTSAM error of the
input graph at what each wrote. Median of ``--repeats`` runs each, the two in turn.

Prints the tables, writes ``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import cell, chi2_cell, median, numbers  # noqa: E402

WHEEL_FILES = ("victoriaPark_reduced_1k.g2o", "cityTrees_reduced_1k.g2o",
               "known_landmark_localization_20.g2o")
GENERATOR = {"sigma_t": 0.05, "d": 3.0, "lc": 0.3}  # the generated graphs' other settings
POSES_PER_POINT = 4  # points placed: poses / this
MARGIN = 1e-4  # ours counts as best at or below the lowest other chi2 (+0.01%)
LM_ITERATIONS = 100  # GTSAM's LM from the odometry guess and from the truth
REFINE_ITERATIONS = 30  # after GTSAM's staircase: the refinement the default gets
COMMAND_TIMEOUT = 300.0  # seconds per process


# --- the cases ----------------------------------------------------------------------------------

def _generated(dim: int, n: int, sigma_r: float, seed: int):
    import numpy as np

    from rlpgo_gtsam.groups import SE2, SE3
    from rlpgo_gtsam.synthetic import LandmarkSettings, generate_landmarks

    return generate_landmarks(n, sigma_r, GENERATOR["sigma_t"], GENERATOR["d"],
                              GENERATOR["lc"], np.random.default_rng(seed),
                              LandmarkSettings(max(1, n // POSES_PER_POINT)),
                              noisy_measurements=True, group=SE3 if dim == 3 else SE2)


def _cases(args):
    """(name, dim, graph, values, truth or None, path or None) of every graph, in order."""
    for dim, sizes in ((2, args.planar), (3, args.spatial)):
        for n in sizes:
            for sigma_r in args.sigma_r:
                sample = _generated(dim, n, sigma_r, args.seed)
                name = f"{'planar' if dim == 2 else 'spatial'} n{n} r{sigma_r:g}"
                yield name, dim, sample.graph, sample.initial, sample.ground_truth, None
    import gtsam

    for name in args.files:
        path = harness.example_file(name)
        graph, values = harness.read_graph(path)
        dim = 3 if gtsam.utilities.allPose3s(values).size() else 2
        yield name.removesuffix(".g2o"), dim, graph, values, None, path


def _ours(graph, values) -> tuple[dict, float]:
    from rlpgo_gtsam import staged_initialize

    run, seconds = harness.collected_timed(lambda: staged_initialize(graph, values))
    stage, certificate = run.rows[0], run.certificate
    row = {"ours_certified": run.certified, "ours_stopped": run.stopped,
           "ours_certificate": None if certificate is None else certificate.describe(),
           "ours_certificate_record": None if certificate is None else certificate.record(),
           "ours_chi2": 2.0 * graph.error(run.values)}
    times = {"ours_relaxation_seconds": None if certificate is None else certificate.seconds,
             "ours_stage_seconds": stage.init_seconds,
             "ours_refine_seconds": stage.refine_seconds, "ours_seconds": seconds}
    return row, times


def _staircase(graph, values) -> tuple[dict, dict]:
    found = harness.gtsam_se_staircase(graph, values)
    if found is None:
        return {"gtsam_failure": "not in this gtsam"}, {}
    if found["failure"] is not None:
        return {"gtsam_failure": found["failure"]}, {}
    row = {"gtsam_certified": found["certified"], "gtsam_rank": found["rank"],
           "gtsam_ranks": found["ranks"], "gtsam_min_eigenvalue": found["min_eigenvalue"],
           "gtsam_cost": found["cost"], "gtsam_failure": None}
    rounded = found["values"]
    if rounded is None:
        row["gtsam_failure"] = "no rounded solution"
    else:
        row["gtsam_rounded_chi2"] = 2.0 * graph.error(rounded)
        chi2, _, failure = harness.gtsam_lm(graph, rounded, REFINE_ITERATIONS)
        row.update(gtsam_lm30_chi2=chi2, gtsam_lm30_failure=failure)
    times = {"gtsam_seconds": found["seconds"], "gtsam_wall_seconds": found["wall_seconds"]}
    return row, times


def _lm(graph, start, label: str) -> tuple[dict, dict]:
    (chi2, _, failure), seconds = harness.collected_timed(
        lambda: harness.gtsam_lm(graph, start, LM_ITERATIONS))
    return {f"{label}_chi2": chi2, f"{label}_failure": failure}, {f"{label}_seconds": seconds}


def in_process(graph, values, truth, repeats: int) -> dict:
    """The in-process columns of one graph (module docstring): the first run's figures, the
    medians of the seconds."""

    def parts() -> list[tuple[dict, dict]]:
        found = [_ours(graph, values), _staircase(graph, values), _lm(graph, values, "odometry")]
        if truth is not None:
            found.append(_lm(graph, truth, "truth"))
        return found

    others = ("gtsam_lm30_chi2", "odometry_chi2", "truth_chi2")
    return harness.repeated_row(parts, repeats, others, MARGIN)


# --- processes ----------------------------------------------------------------------------------

def _chi2_at(graph, path: Path) -> float | None:
    """2 x GTSAM error of ``graph`` at the values of the g2o file ``path`` (None if absent)."""
    if not path.is_file():
        return None
    return 2.0 * graph.error(harness.read_graph(path)[1])


def processes(graph, path: Path, folder: Path, repeats: int) -> dict:
    """``rlpgo-init PATH -o OUT`` against this file's ``lm`` command, ``repeats`` times each
    in turn (who goes first alternates): medians of seconds, chi2 at what each wrote."""
    ours_out, lm_out = folder / "ours.g2o", folder / "lm.g2o"
    ours_runs, lm_runs = [], []
    for repeat in range(repeats):
        def ours() -> None:
            ours_runs.append(harness.run_init(path, ours_out, COMMAND_TIMEOUT))

        def lm() -> None:
            lm_out.unlink(missing_ok=True)
            lm_runs.append(harness.run([sys.executable, __file__, "lm", path, lm_out,
                                        str(LM_ITERATIONS)], COMMAND_TIMEOUT))

        for step in ((ours, lm) if repeat % 2 == 0 else (lm, ours)):
            step()
    first = ours_runs[0]
    row = {"process_ours_seconds": median([r["seconds"] for r in ours_runs]),
           "process_ours_peak_mb": median([r["peak_mb"] for r in ours_runs]),
           "process_ours_failure": first["failure"],
           "process_ours_certified": first["certified"],
           "process_ours_chi2": _chi2_at(graph, ours_out),
           "process_lm_seconds": median([r.seconds for r in lm_runs]),
           "process_lm_peak_mb": median([r.peak_mb for r in lm_runs]),
           "process_lm_failure": lm_runs[0].failure,
           "process_lm_chi2": _chi2_at(graph, lm_out)}
    if row["process_ours_seconds"] and row["process_lm_seconds"]:
        row["process_ratio"] = row["process_ours_seconds"] / row["process_lm_seconds"]
    return row


def lm_command(input_path: str, output_path: str, iterations: int) -> int:
    """``lm INPUT OUTPUT [ITERATIONS]``: read INPUT with the package's reader, GTSAM's LM
    (:func:`benchmarks.harness.gtsam_lm_result`) from its vertices, write OUTPUT with the
    package's writer; one JSON line (chi2, failure)."""
    from rlpgo_gtsam import write_g2o

    graph, values = harness.read_graph(input_path)
    result, chi2, _, failure = harness.gtsam_lm_result(graph, values, iterations)
    if result is not None:
        write_g2o(output_path, graph, result)
    print(json.dumps({"chi2": chi2, "failure": failure}))
    return 0 if failure is None else 1


# --- tables -------------------------------------------------------------------------------------

def in_process_table(rows: list[dict]) -> str:
    lines = ["| graph | poses | points | factors | ours certified | relaxation s | certified "
             "stage s | whole s | ours chi2 | GTSAM staircase certified (rank) | its s | its "
             "wall s | rounded chi2 | + LM30 chi2 | stage / GTSAM wall | LM100 odometry s | "
             "chi2 | LM100 truth chi2 | ours best |", "|---" * 19 + "|"]
    for r in rows:
        gtsam = (f"{cell(r.get('gtsam_certified'))} ({r['gtsam_rank']})"
                 if r.get("gtsam_rank") is not None else r.get("gtsam_failure") or "-")
        lines.append(
            f"| {r['graph']} | {r['poses']} | {r['points']} | {r['factors']} | "
            f"{cell(r['ours_certified'])} | {cell(r['ours_relaxation_seconds'], '.3f')} | "
            f"{cell(r['ours_stage_seconds'], '.3f')} | {cell(r['ours_seconds'], '.3f')} | "
            f"{chi2_cell(r['ours_chi2'])} | {gtsam} | {cell(r.get('gtsam_seconds'), '.3f')} | "
            f"{cell(r.get('gtsam_wall_seconds'), '.3f')} | "
            f"{chi2_cell(r.get('gtsam_rounded_chi2'))} | "
            f"{chi2_cell(r.get('gtsam_lm30_chi2'), r.get('gtsam_lm30_failure'))} | "
            f"{cell(r.get('stage_over_gtsam'), '.3f')} | "
            f"{cell(r['odometry_seconds'], '.3f')} | "
            f"{chi2_cell(r['odometry_chi2'], r['odometry_failure'])} | "
            f"{chi2_cell(r.get('truth_chi2'), r.get('truth_failure'))} | "
            f"{cell(r['ours_best'])} |")
    return "\n".join(lines) + "\n"


def process_table(rows: list[dict]) -> str:
    lines = ["| graph | rlpgo-init s | certified | chi2 | peak MB | GTSAM LM100 process s | chi2 "
             "| peak MB | ours / LM100 |", "|---" * 9 + "|"]
    for r in rows:
        if "process_ours_seconds" not in r:
            continue
        ours_chi2 = chi2_cell(r["process_ours_chi2"], r["process_ours_failure"])
        lm_chi2 = chi2_cell(r["process_lm_chi2"], r["process_lm_failure"])
        lines.append(
            f"| {r['graph']} | {cell(r['process_ours_seconds'], '.3f')} | "
            f"{cell(r['process_ours_certified'])} | {ours_chi2} | "
            f"{cell(r['process_ours_peak_mb'], '.0f')} | {cell(r['process_lm_seconds'], '.3f')} "
            f"| {lm_chi2} | {cell(r['process_lm_peak_mb'], '.0f')} | "
            f"{cell(r.get('process_ratio'), '.2f')} |")
    return "\n".join(lines) + "\n"


# --- the command line ---------------------------------------------------------------------------

def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "lm":
        if len(sys.argv) not in (4, 5):
            raise SystemExit("usage: landmarks.py lm INPUT.g2o OUTPUT.g2o [ITERATIONS]")
        sys.exit(lm_command(sys.argv[2], sys.argv[3],
                            int(sys.argv[4]) if len(sys.argv) == 5 else LM_ITERATIONS))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--planar", default="100,500,800", help="generated planar graphs' poses")
    parser.add_argument("--spatial", default="100,300", help="generated 3D graphs' poses")
    parser.add_argument("--sigma-r", default="0.1,0.3",
                        help="generated graphs' rotation noise, radians (per axis in 3D), a list")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--files", default=",".join(WHEEL_FILES),
                        help="gtsam example files (or paths) with landmarks; '' for none")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per side (medians)")
    parser.add_argument("--no-processes", action="store_true")
    parser.add_argument("--name", default="landmarks", help="results file name")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be 1 or more")
    args.planar, args.spatial = numbers(args.planar), numbers(args.spatial)
    args.sigma_r = numbers(args.sigma_r, float)
    args.files = [name for name in args.files.split(",") if name.strip()]

    import rlpgo_gtsam.relaxation  # noqa: F401  (SciPy's import is not the method's time)
    from rlpgo_gtsam import extract_pose_graph, write_g2o

    warm = _generated(2, 20, 0.1, 0)
    in_process(warm.graph, warm.initial, None, 1)  # untimed: first calls pay for imports
    if not args.no_processes:
        harness.cache_bytecode()
    rows = []
    with tempfile.TemporaryDirectory(prefix="rlpgo_landmarks_") as temporary:
        folder = Path(temporary)
        for name, dim, graph, values, truth, path in _cases(args):
            g = extract_pose_graph(graph, values)
            row = {"graph": name, "dim": dim, "poses": g.num_poses,
                   "points": 0 if g.points is None else g.points.count,
                   "factors": graph.size()}
            row.update(in_process(graph, values, truth, args.repeats))
            if not args.no_processes:
                if path is None:
                    path = folder / f"{name.replace(' ', '_')}.g2o"
                    write_g2o(path, graph, values)
                row.update(processes(graph, path, folder, args.repeats))
            rows.append(row)
            print({k: v for k, v in row.items() if "certificate" not in k}, flush=True)
    table = ("In process (seconds: medians of the repeats; chi2 = 2 x GTSAM error):\n\n"
             + in_process_table(rows))
    if not args.no_processes:
        table += ("\nProcess to process (fork to exit; medians):\n\n" + process_table(rows))
    print(table)
    data = {"settings": {"generator": GENERATOR, "poses_per_point": POSES_PER_POINT,
                         "seed": args.seed, "lm_iterations": LM_ITERATIONS,
                         "staircase_refine_iterations": REFINE_ITERATIONS, "margin": MARGIN,
                         "repeats": args.repeats,
                         "warm_up": "a 20-pose planar landmark graph, run once untimed"},
            "peak_floor_mb": None if args.no_processes else harness.launcher_floor_mb(),
            "rows": rows}
    print(f"wrote {harness.write_result(args.name, harness.command_line(), data, table)}")


if __name__ == "__main__":
    main()
