"""Where the range-aided relaxation is tight: the certified default on generated range-aided
graphs, planar and 3D, over odometry noise, range noise and how rigidly the ranges tie the
path down; each graph's result against GTSAM's LM from the odometry guess and from the truth.

    python benchmarks/range_tightness.py [--seeds 1,2,3] [--poses 100] [--poses-3d 60]
        [--name range_tightness]

Graphs (noisy measurements, 3 beacons, the first pose held by a prior):

- planar: :func:`rlpgo_gtsam.synthetic.generate_ranges` (a lawn mower of 1 m steps, no loop
  closures), odometry noise ``(sigma_r rad, sigma_t m)`` per step in :data:`ODOMETRY`, range
  noise in :data:`RANGE_SIGMAS` (metres), and three geometries (:data:`GEOMETRIES`): every
  pose ranges every beacon (``all``), every fifth pose does (``sparse``), or only poses
  within 10 m of a beacon (``near``);
- 3D: :func:`rlpgo_gtsam.synthetic.generate_helix_ranges` (a climbing helix, 8 pose-to-pose
  ranges besides the beacons'), odometry noise in :data:`ODOMETRY_3D`, the same range
  noise, every pose (``all``) or every fifth (``sparse``) ranging.

Per graph: ``staged_initialize(graph, guess, iters=100)`` (its certificate's status, rank,
gap = suboptimality bound / max(cost, 1) in the relaxation's units, seconds of the whole
call) and chi2 after it; GTSAM's LM100 from the guess and from the ground truth; ``best``:
ours at or below both (+0.01%). The table gives, per setting, how many seeds were certified,
the largest gap, and how many seeds ours was best on.

Prints the table, writes ``benchmarks/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import numbers  # noqa: E402

ODOMETRY = ((0.001, 0.005), (0.01, 0.05), (0.05, 0.1))  # planar (sigma_r rad, sigma_t m)
ODOMETRY_3D = ((0.002, 0.005), (0.02, 0.05), (0.05, 0.1))
RANGE_SIGMAS = (0.01, 0.1, 0.3, 1.0)
# planar geometries: (sensor range m, pose stride)
GEOMETRIES = {"all": (1000.0, 1), "sparse": (1000.0, 5), "near": (10.0, 1)}
GEOMETRIES_3D = {"all": 1, "sparse": 5}
BEACONS = 3
MARGIN = 1e-4  # ours counts as best at or below the lower LM chi2 (+0.01%)
LM_ITERATIONS = 100


def _planar(n: int, odometry: tuple[float, float], sigma_range: float, geometry: str,
            seed: int):
    import numpy as np

    from rlpgo_gtsam.synthetic import RangeSettings, generate_ranges

    sensor, stride = GEOMETRIES[geometry]
    return generate_ranges(n, odometry[0], odometry[1], 1.0, 0.0, np.random.default_rng(seed),
                           RangeSettings(BEACONS, sigma_range_m=sigma_range,
                                         sensor_range_m=sensor, pose_stride=stride),
                           noisy_measurements=True)


def _spatial(n: int, odometry: tuple[float, float], sigma_range: float, geometry: str,
             seed: int):
    import numpy as np

    from rlpgo_gtsam.synthetic import generate_helix_ranges

    return generate_helix_ranges(n, np.random.default_rng(seed), beacons=BEACONS,
                                 stride=GEOMETRIES_3D[geometry], rotation_sigma=odometry[0],
                                 translation_sigma=odometry[1], sigma_range_m=sigma_range)


def one(sample) -> dict:
    """The default and GTSAM's LM100 from the guess and the truth on one graph."""
    from rlpgo_gtsam import staged_initialize

    started = time.perf_counter()
    run = staged_initialize(sample.graph, sample.initial, iters=LM_ITERATIONS)
    seconds = time.perf_counter() - started
    c = run.certificate
    ours = 2.0 * sample.graph.error(run.values)
    guess, _, _ = harness.gtsam_lm(sample.graph, sample.initial, LM_ITERATIONS)
    truth, _, _ = harness.gtsam_lm(sample.graph, sample.ground_truth, LM_ITERATIONS)
    others = [x for x in (guess, truth) if x is not None]
    return {"status": str(c.status), "certified": run.certified, "rank": c.rank,
            "gap": c.suboptimality_bound / max(abs(c.estimate_cost), 1.0),
            "seconds": seconds, "chi2": ours, "lm_guess_chi2": guess, "lm_truth_chi2": truth,
            "best": bool(others) and ours <= min(others) * (1 + MARGIN)}


def sweep(args) -> list[dict]:
    rows = []
    cases = [("2D", args.poses, odometry, sigma, geometry, _planar)
             for odometry, sigma, geometry in itertools.product(ODOMETRY, RANGE_SIGMAS,
                                                                GEOMETRIES)]
    cases += [("3D", args.poses_3d, odometry, sigma, geometry, _spatial)
              for odometry, sigma, geometry in itertools.product(ODOMETRY_3D, RANGE_SIGMAS,
                                                                 GEOMETRIES_3D)]
    for dim, n, odometry, sigma, geometry, make in cases:
        runs = []
        for seed in args.seeds:
            result = one(make(n, odometry, sigma, geometry, seed))
            runs.append({"seed": seed, **result})
        rows.append({"dim": dim, "poses": n, "odometry": list(odometry), "sigma_range_m": sigma,
                     "geometry": geometry, "runs": runs})
        print(_line(rows[-1]), flush=True)
    return rows


def _line(row: dict) -> str:
    runs = row["runs"]
    certified = sum(r["certified"] for r in runs)
    best = sum(r["best"] for r in runs)
    ranks = ",".join(str(r["rank"]) for r in runs)
    gap = max(r["gap"] for r in runs)
    seconds = max(r["seconds"] for r in runs)
    return (f"| {row['dim']} | {row['poses']} | {row['odometry'][0]:g} / {row['odometry'][1]:g} "
            f"| {row['sigma_range_m']:g} | {row['geometry']} | {certified}/{len(runs)} | "
            f"{ranks} | {gap:.1e} | {best}/{len(runs)} | {seconds:.2f} |")


HEADER = ("| dim | poses | odometry sigma (rad / m) | range sigma (m) | geometry | certified "
          "| ranks | largest gap | ours best | slowest s |\n"
          "|---|---|---|---|---|---|---|---|---|---|")


def summary(rows: list[dict]) -> str:
    lines = []
    for dim in ("2D", "3D"):
        runs = [r for row in rows if row["dim"] == dim for r in row["runs"]]
        if runs:
            lines.append(f"- {dim}: certified on {sum(r['certified'] for r in runs)} of "
                         f"{len(runs)} graphs; ours at or below LM100 from the guess and from "
                         f"the truth on {sum(r['best'] for r in runs)} of {len(runs)}.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2,3", help="generator seeds (a list)")
    parser.add_argument("--poses", type=int, default=100, help="planar graphs' poses")
    parser.add_argument("--poses-3d", type=int, default=60, help="3D graphs' poses")
    parser.add_argument("--name", default="range_tightness", help="results file name")
    args = parser.parse_args()
    args.seeds = numbers(args.seeds)
    print(HEADER, flush=True)
    rows = sweep(args)
    table = "\n".join([HEADER, *(_line(row) for row in rows), "", summary(rows)])
    print("\n" + summary(rows))
    path = harness.write_result(args.name, harness.command_line(), {"rows": rows}, table)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
