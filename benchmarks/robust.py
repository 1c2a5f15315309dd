"""Wrong loop closures: what the robust path rejects, the map it hands over and what it costs,
on Vertigo's four policies, against GTSAM's anchors, as commands, in 3D and as noise grows.

    python benchmarks/robust.py policies [--cases gen,MIT,Intel,FR079,M3500,City10K]
        [--modes random,local,group,localgroup] [--fractions 0.05,0.1,0.2,0.3]
        [--clean all|none] [--anchor-timeout 60] [--robust-timeout 300] [--append]
    python benchmarks/robust.py commands [--cases MIT,Intel,FR079,gen] [--modes ...]
        [--fractions 0.05,0.1,0.2 | --ratios 0.1,1,9] [--repeats 3] [--loads idle,busy]
    python benchmarks/robust.py 3d [--clean tinyGrid3D,...|none] [--cases sphere2500,torus3D,gen]
        [--modes random,uniform] [--fractions 0.05,0.1]
    python benchmarks/robust.py noise [--dims 2,3] [--sigmas 0.05,0.1,0.2,0.3] [--spacings 1,3]
        [--modes ...] [--fraction 0.1] [--seeds 1,2,3] [--n 300]
    python benchmarks/robust.py rates [--cases M3500,Intel,City10K,MIT,FR079,gen]
        [--cases-3d sphere2500,torus3D,gen3d] [--ratios 0.1,0.33,1,3,9]
        [--modes random,local,group,localgroup,uniform] [--seeds 1] [--anchor-timeout 60]
        [--robust-timeout 300] [--append]

Every subcommand takes ``--name`` (the results file, ``benchmarks/results/<name>.json`` and
``.md``, checkpointed as rows finish).

``policies``. Per case (a shared planar file, or ``gen``: the generator's 1000-pose lawn mower,
noisy measurements, sigma_R 0.01 rad, sigma_t 0.05 m, d 1 m, lc 0.5, seed 7) and per policy
and fraction (``int(fraction x edges)`` wrong closures, groups of 5, seed 1; on shared files
:func:`~rlpgo_gtsam.add_outliers` around the clean optimum, certified + LM 100):
``robust_initialize``'s precision and recall; the closures it names doubtful (how many of them
are wrong, of the wrong ones it kept); the chi2 of its values refined by LM 100 on the
outlier-free graph over that graph's optimum; its seconds and "x clean", over the clean
default's (certified + LM30 on the outlier-free graph, the faster of two runs right before
the row). The robust path runs in a forked process, twice: the second call's seconds are the
row's (warm, as the clean default is; the first call in a forked child also pays for the
pages it touches that the parent owns), the first call's are kept as ``first_call_s``. Then
the anchors, each in a forked process capped at ``--anchor-timeout`` seconds, from the
certified estimate of all edges: GTSAM's ``GncLMOptimizer`` (TLS, the odometry chain known
inliers; precision and recall of weights < 0.5) and GTSAM's LM with every closure under the
DCS m-estimator, each scored by the same chi2 ratio. ``--anchor-timeout 0`` leaves the
anchors out, ``--robust-timeout 0`` the robust path. ``--clean all`` first runs every shared
file and the clean generated graph without wrong closures (nothing must be rejected).
``--append`` adds the rows to those of the results file of the same name.

``commands``. The two commands a user types, each a process (wall seconds from the fork to
the exit): ``rlpgo-init CLEAN.g2o -o OUT`` and ``rlpgo-init --robust BAD.g2o -o OUT`` on
``policies``' graphs (the same seeds, written as g2o with the clean graph's values), medians
of ``--repeats`` runs, alternating; "x clean" is the robust command's median over the clean
one's. Each load of ``--loads`` gives a row: ``idle``, or ``busy``: one CPU-bound process
beside both commands. The robust command's "rejected N of M" is kept as a check that it ran.

``3d``. SE-Sync's seven 3D files clean: the rejections of ``robust_initialize`` (0 expected),
its chi2 against the clean default's (``staged_initialize``), both in CPU seconds. Then wrong
closures (``add_outliers`` around the clean optimum, seed 1; ``gen``: ``generate`` in SE3 with
1000 poses, sigma_R 0.05 rad, sigma_t 0.1 m, d 1 m, lc 0.5, noisy measurements, seed 7):
precision, recall, the result + LM30 on the outlier-free graph over its optimum, CPU seconds
over the clean default's.

``noise``. The generator's graphs as rotation noise grows: per dimension, sigma_R, spacing d,
policy and seed, ``--n`` poses (sigma_t 0.05 m, lc 0.5, noisy measurements) with
``--fraction`` wrong closures, and the same graph without them (same seed: the wrong closures
come after it): precision, recall, chi2 ratio (its values + LM 100 on the outlier-free graph
over the clean default + LM 100), seconds; on the clean twin, how many closures it rejected.

``rates``. The field's protocol: wrong closures as a ratio of the true loop closures (the
between factors off the odometry chain): ``round(ratio x true)`` of them, ratios 0.1, 0.33,
1, 3 and 9 being 9, 25, 50, 75 and 90% of all closures wrong, added by
:func:`~rlpgo_gtsam.add_outliers` (``count=``) around the outlier-free optimum with each seed
of ``--seeds``, under Vertigo's four policies and ``uniform`` (random pose pairs measured as
uniformly random relative poses). Cases: planar as ``policies`` builds them (``gen`` its
generated graph, here given wrong closures like a shared file), 3D as ``3d`` does
(``gen3d``: its generated graph). Per row: the rate (wrong over all closures); precision;
recall over all wrong closures and over the detectable ones, those whose chi2 at the
outlier-free optimum exceeds the robust path's inlier bar (the chi-square quantile at
``RobustSettings.inlier_probability`` = 0.9999 for the edge's dimension: 21.1 planar, 27.9 in
3D; no test on the file's covariances can tell the others from true closures); F1 of each;
the APE (translation RMSE after alignment, metres) and the chi2 ratio of the result refined
by LM 100 on the outlier-free graph, against its optimum; the robust path's seconds in its
forked process and x clean (as ``policies``: the second call, over the clean default beside
the row); the number of ambiguous alternatives it reports. Anchors as in ``policies`` (GNC-LM
(TLS) from the certified estimate of all edges, DCS) with the same scores; DCS rejects
nothing, so its rejections are the closures, true or wrong, that misfit its map beyond the
same bar. The table ends, per dimension, with the rows of F1 >= 0.99 whose chi2 lies within
0.1% of the optimum and the rows within the time bounds (x clean <= 5 up to ratio 1, <= 10 up
to 9), then the published figures as the project's reference notes give them.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import re
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import RESULTS, scores  # noqa: E402

GEN = (1000, 0.01, 0.05, 1.0, 0.5)  # n, sigma_R, sigma_t, d, lc of the planar ``gen`` case
GEN_3D = (1000, 0.05, 0.1, 1.0, 0.5)
SIGMA_T, LC = 0.05, 0.5  # of the ``noise`` graphs
SEED = 1  # of the wrong closures added to a shared file
_REJECTED = re.compile(r"rejected (\d+) of (\d+) loop closures")


# --- the cases ----------------------------------------------------------------------------------

def clean_case(name: str):
    """(graph, values, optimum values, optimum chi2) of an outlier-free planar case: a shared
    file or ``gen``; the optimum is certified + LM 100."""
    from rlpgo_gtsam import extract_pose_graph, generate, make_initializer, refine

    if name == "gen":
        sample = generate(*GEN, np.random.default_rng(7), noisy_measurements=True)
        graph, values = sample.graph, sample.initial
    else:
        graph, values = harness.read_graph(harness.shared_file(name))
    g = extract_pose_graph(graph, values)
    best = refine(graph, make_initializer("certified").run(g).values, "lm", 100, pose_graph=g)
    return graph, values, best.values, best.chi2


def corrupted(name: str, graph, optimum, fraction: float, mode: str):
    """(graph with wrong closures, their factor indices) of a planar case."""
    from rlpgo_gtsam import add_outliers, generate

    if name == "gen":
        sample = generate(*GEN, np.random.default_rng(7), noisy_measurements=True,
                          outliers=fraction, outlier_mode=mode)
        return sample.graph, sample.outlier_edges
    return add_outliers(graph, optimum, fraction, np.random.default_rng(SEED), mode)


def clean_default_seconds(graph, values) -> float:
    """Wall seconds of the clean default: certified + LM30."""
    from rlpgo_gtsam import extract_pose_graph, make_initializer, refine

    began = time.perf_counter()
    g = extract_pose_graph(graph, values)
    refine(graph, make_initializer("certified").run(g).values, "lm", 30, pose_graph=g)
    return time.perf_counter() - began


def ratio(clean_graph, values, optimum_chi2: float) -> float | None:
    """chi2 of LM 100 on the outlier-free graph from ``values``, over its optimum."""
    from rlpgo_gtsam import refine

    return None if values is None else refine(clean_graph, values, "lm", 100).chi2 / optimum_chi2


# --- policies -----------------------------------------------------------------------------------

def _in_child(kind: str, graph, values, queue) -> None:
    import gtsam

    from rlpgo_gtsam import extract_pose_graph, make_initializer, robust_initialize
    from rlpgo_gtsam.graph import odometry_edges
    from rlpgo_gtsam.solvers import solver_params

    if kind == "robust":
        first = robust_initialize(graph, values)  # pays for the parent's pages (docstring)
        result = robust_initialize(graph, values)
        if result.rejected != first.rejected:
            raise SystemExit("the robust path decided differently on a second call")
        queue.put((result.values, (result.rejected, len(result.ambiguous), result.seconds,
                                   first.seconds, [k for k, _ in result.doubtful])))
        return
    g = extract_pose_graph(graph, values)
    start = make_initializer("certified").run(g).values
    chain = odometry_edges(g)
    between = [k for k in range(graph.size())
               if isinstance(graph.at(k), gtsam.BetweenFactorPose2 | gtsam.BetweenFactorPose3)]
    params = solver_params("lm", 100)
    if kind == "gnc":
        known = [between[e] for e in np.flatnonzero(chain).tolist()]
        result, rejected = harness.gnc(graph, start, known, params)
        queue.put((result, sorted(set(rejected) & set(between))))
    else:
        closures = [between[e] for e in np.flatnonzero(~chain).tolist()]
        queue.put((harness.dcs(graph, start, closures, params), None))


def in_child(kind: str, graph, values, timeout: float):
    """(values or None, extra or None, seconds, status) of ``kind`` in a forked process."""
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    began = time.perf_counter()
    process = context.Process(target=_in_child, args=(kind, graph, values, queue))
    process.start()
    try:
        result, extra = queue.get(timeout=timeout)
        status = "ok"
    except Exception:  # noqa: BLE001 - a timeout or a crash of the child
        result, extra, status = None, None, f"no result in {timeout:g} s"
    process.join(1)
    if process.is_alive():
        process.kill()
    return result, extra, time.perf_counter() - began, status


def _clean_row(name: str) -> dict:
    from rlpgo_gtsam import robust_initialize

    graph, values, _, best = clean_case(name)
    result = robust_initialize(graph, values)
    return {"case": name, "mode": "clean", "fraction": 0.0, "wrong": 0,
            "rejected": len(result.rejected), "robust_chi2": result.chi2, "optimum_chi2": best,
            "seconds": result.seconds, "clean_default_s": clean_default_seconds(graph, values)}


def clean_default_beside(graph, values) -> float:
    """The clean default's seconds beside a row, the faster of two runs: a load that comes
    and goes over the run is then in both figures of a ratio."""
    return min(clean_default_seconds(graph, values) for _ in range(2))


def robust_fields(bad, values, wrong, timeout: float, fit):
    """The robust path on ``bad`` from ``values`` in a forked process (see ``policies``):
    (the row's fields, ``fit(its values)`` among them, its values, its rejections); the last
    two None where it gave no result."""
    found, extra, seconds, status = in_child("robust", bad, values, timeout)
    fields = {"status": status, "seconds": seconds}
    if extra is None:
        return fields, None, None
    rejected, ambiguous, seconds, first_s, doubtful = extra
    precision, recall = scores(rejected, wrong)
    fields |= {"rejected": len(rejected), "precision": precision, "recall": recall,
               **fit(found), "seconds": seconds, "first_call_s": first_s,
               "ambiguous": ambiguous, "doubtful": len(doubtful),
               "doubtful_wrong": len(set(doubtful) & set(wrong)),
               "kept_wrong": len(set(wrong) - set(rejected))}
    return fields, found, rejected


def anchor_fields(bad, values, wrong, timeout: float, fit):
    """GNC-LM (TLS) and DCS on ``bad`` (see ``policies``), each in a forked process: (the
    row's fields, prefixed ``gnc_`` and ``dcs_``, ``fit(its values)`` among them; per kind,
    (its values, its rejections), None where it gave none)."""
    fields: dict = {}
    found = {}
    for kind in ("gnc", "dcs"):
        values_a, rejected_a, seconds_a, status = in_child(kind, bad, values, timeout)
        fields |= {f"{kind}_{key}": value for key, value in fit(values_a).items()}
        fields[f"{kind}_s"], fields[f"{kind}_status"] = seconds_a, status
        if rejected_a is not None:
            fields[f"{kind}_precision"], fields[f"{kind}_recall"] = scores(rejected_a, wrong)
        found[kind] = (values_a, rejected_a)
    return fields, found


def _policy_row(name: str, case, fraction: float, mode: str, args) -> dict:
    graph, values, optimum, best = case
    bad, wrong = corrupted(name, graph, optimum, fraction, mode)
    row = {"case": name, "mode": mode, "fraction": fraction, "wrong": len(wrong),
           "clean_default_s": clean_default_beside(graph, values)}

    def fit(found) -> dict:
        return {"ratio": ratio(graph, found, best)}

    if args.robust_timeout > 0:
        row |= robust_fields(bad, values, wrong, args.robust_timeout, fit)[0]
    if args.anchor_timeout > 0:
        row |= anchor_fields(bad, values, wrong, args.anchor_timeout, fit)[0]
    return row


def policies(args, rows: list[dict], save) -> None:
    if args.clean == "all":
        for name in [*harness.FILES_2D, "gen"]:
            rows.append(_clean_row(name))
            print(rows[-1], flush=True)
            save()
    for name in args.cases.split(","):
        case = clean_case(name)
        for fraction in map(float, args.fractions.split(",")):
            for mode in args.modes.split(","):
                rows.append(_policy_row(name, case, fraction, mode, args))
                print({k: (round(v, 4) if isinstance(v, float) else v)
                       for k, v in rows[-1].items()}, flush=True)
                save()


def _f(value, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def policies_table(rows: list[dict]) -> str:
    lines = ["| case | policy | fraction | wrong | rejected | precision | recall | chi2 ratio "
             "| s | x clean | doubtful (wrong, of kept wrong) | GNC ratio | GNC P/R | GNC s | "
             "DCS ratio | DCS s |", "|---" * 16 + "|"]
    for r in rows:
        if r["mode"] == "clean":
            lines.append(f"| {r['case']} | clean | 0 | 0 | {r['rejected']} | - | - | "
                         f"{r['robust_chi2'] / r['optimum_chi2']:.5f} | {r['seconds']:.1f} | "
                         f"{r['seconds'] / r['clean_default_s']:.1f} | | | | | | |")
            continue
        gnc_pr = (f"{r['gnc_precision']:.2f}/{r['gnc_recall']:.2f}"
                  if "gnc_precision" in r else r.get("gnc_status", "-"))
        anchors = (f"{_f(r.get('gnc_ratio'), 4)} | {gnc_pr} | {_f(r.get('gnc_s'), 1)} | "
                   f"{_f(r.get('dcs_ratio'), 4)} | {_f(r.get('dcs_s'), 1)}")
        start = f"| {r['case']} | {r['mode']} | {r['fraction']:g} | {r['wrong']} |"
        if "precision" not in r:  # the robust path left out, or past its cap
            lines.append(f"{start} {r.get('status', '-')} | - | - | - | "
                         f"{_f(r.get('seconds'), 1)} | - | - | {anchors} |")
            continue
        doubtful = f"{r['doubtful']} ({r['doubtful_wrong']} of {r['kept_wrong']})"
        lines.append(f"{start} {r['rejected']} | {r['precision']:.3f} | {r['recall']:.3f} | "
                     f"{_f(r['ratio'], 4)} | {r['seconds']:.1f} | "
                     f"{r['seconds'] / r['clean_default_s']:.1f} | {doubtful} | {anchors} |")
    return "\n".join(lines) + "\n"


# --- commands -----------------------------------------------------------------------------------

def _timed_command(command: list[str], out: Path) -> tuple[float, str]:
    out.unlink(missing_ok=True)
    done = harness.run(command, 600.0)
    if done.failure is not None or done.seconds is None:
        raise SystemExit(f"{' '.join(command)}: {done.failure}")
    return done.seconds, done.stdout


def _command_row(init: str, clean: Path, bad: Path, out: Path, repeats: int, load: str) -> dict:
    """The two commands ``repeats`` times each, alternating, under ``load``."""
    if load not in ("idle", "busy"):
        raise SystemExit(f"--loads: idle or busy, not {load!r}")
    clean_s, robust_s, said = [], [], ""
    with harness.competing(load == "busy"):
        for repeat in range(repeats):
            for which in ("clean", "robust") if repeat % 2 == 0 else ("robust", "clean"):
                if which == "clean":
                    clean_s.append(_timed_command([init, str(clean), "-o", str(out)], out)[0])
                else:
                    seconds, said = _timed_command([init, "--robust", str(bad), "-o", str(out)],
                                                   out)
                    robust_s.append(seconds)
    found = _REJECTED.search(said)
    row = {"load": load, "rejected": int(found.group(1)) if found else None,
           "clean_s": harness.median(clean_s), "robust_s": harness.median(robust_s),
           "clean_all": clean_s, "robust_all": robust_s}
    return row | {"x_clean": row["robust_s"] / row["clean_s"]}


def commands(args, rows: list[dict], save) -> None:
    """``--fractions`` of the edges as ``policies`` corrupts them, or with ``--ratios`` wrong
    closures per true one as ``rates`` adds them (the first seed)."""
    from rlpgo_gtsam import add_outliers, write_g2o

    init = harness.command_path("rlpgo-init")
    ratios = [float(r) for r in args.ratios.split(",")] if args.ratios else []
    with tempfile.TemporaryDirectory(prefix="rlpgo_robust_commands_") as folder:
        work, out = Path(folder), Path(folder) / "out.g2o"
        for name in args.cases.split(","):
            graph, values, optimum, _ = clean_case(name)
            closures = rate_case(name, 2).closures if ratios else []
            clean = work / f"{name}.g2o"
            write_g2o(clean, graph, values)
            levels = [("ratio", r) for r in ratios] or [
                ("fraction", f) for f in map(float, args.fractions.split(","))]
            for kind, level in levels:
                for mode in args.modes.split(","):
                    if kind == "ratio":
                        bad_graph, wrong = add_outliers(
                            graph, optimum, None, np.random.default_rng(SEED), mode,
                            count=round(level * len(closures)))
                    else:
                        bad_graph, wrong = corrupted(name, graph, optimum, level, mode)
                    bad = work / f"{name}_{mode}_{level}.g2o"
                    write_g2o(bad, bad_graph, values)  # policies' start: the clean values
                    for load in args.loads.split(","):
                        rows.append({"case": name, "mode": mode, kind: level,
                                     "wrong": len(wrong)}
                                    | _command_row(init, clean, bad, out, args.repeats, load))
                        print(json.dumps(rows[-1]), flush=True)
                        save()


def commands_table(rows: list[dict]) -> str:
    kind = "ratio" if rows and "ratio" in rows[0] else "fraction"
    lines = ["Wall seconds of whole processes, medians.", "",
             f"| case | policy | {kind} | load | wrong | rejected | clean command s | "
             "--robust command s | x clean |", "|---" * 9 + "|"]
    lines += [f"| {r['case']} | {r['mode']} | {r[kind]:g} | {r['load']} | {r['wrong']} | "
              f"{r['rejected']} | {r['clean_s']:.2f} | {r['robust_s']:.2f} | "
              f"{r['x_clean']:.2f} |" for r in rows]
    return "\n".join(lines) + "\n"


# --- 3d -----------------------------------------------------------------------------------------

def clean_case_3d(name: str):
    """(graph, values, clean default's chi2 and CPU seconds, optimum values and chi2)."""
    from rlpgo_gtsam import SE3, generate, refine, staged_initialize
    from rlpgo_gtsam.solvers import solver_params

    if name == "gen":
        sample = generate(*GEN_3D, np.random.default_rng(7), noisy_measurements=True, group=SE3)
        graph, values = sample.graph, sample.initial
    else:
        graph, values = harness.read_graph(harness.shared_file(name))
    began = time.process_time()
    default = staged_initialize(graph, values)
    seconds = time.process_time() - began
    params = solver_params("lm", 200)
    params.setRelativeErrorTol(1e-12)
    best = refine(graph, default.values, params)
    return graph, values, default.best.refined_chi2, seconds, best.values, best.chi2


def _robust_cpu(graph, values):
    from rlpgo_gtsam import robust_initialize

    began = time.process_time()
    result = robust_initialize(graph, values)
    return result, time.process_time() - began


def spatial(args, rows: dict[str, list[dict]], save) -> None:
    from rlpgo_gtsam import SE3, add_outliers, generate, refine

    for name in [] if args.clean == "none" else args.clean.split(","):
        graph, values, default_chi2, default_s, _, _ = clean_case_3d(name)
        result, seconds = _robust_cpu(graph, values)
        rows["clean"].append({
            "case": name, "rejected": len(result.rejected), "robust_chi2": result.chi2,
            "default_chi2": default_chi2, "relative": result.chi2 / default_chi2 - 1.0,
            "robust_s": seconds, "default_s": default_s, "x_default": seconds / default_s,
            "stopped": result.stopped, "steps": [step.record() for step in result.steps]})
        save()
    for name in [c for c in args.cases.split(",") if c]:
        graph, values, _, default_s, optimum, optimum_chi2 = clean_case_3d(name)
        for mode in args.modes.split(","):
            for fraction in map(float, args.fractions.split(",")):
                if name == "gen":
                    sample = generate(*GEN_3D, np.random.default_rng(7),
                                      noisy_measurements=True, outliers=fraction,
                                      outlier_mode=mode, group=SE3)
                    bad, wrong = sample.graph, sample.outlier_edges
                else:
                    bad, wrong = add_outliers(graph, optimum, fraction,
                                              np.random.default_rng(SEED), mode)
                result, seconds = _robust_cpu(bad, values)
                precision, recall = scores(result.rejected, wrong)
                after = refine(graph, result.values, "lm", 30).chi2
                rows["wrong"].append({
                    "case": name, "mode": mode, "fraction": fraction, "wrong": len(wrong),
                    "rejected": len(result.rejected), "precision": precision, "recall": recall,
                    "clean_chi2_after_lm30": after, "optimum_chi2": optimum_chi2,
                    "ratio": after / optimum_chi2, "robust_s": seconds, "default_s": default_s,
                    "x_default": seconds / default_s, "stopped": result.stopped,
                    "steps": [step.record() for step in result.steps]})
                save()


def spatial_table(rows: dict[str, list[dict]]) -> str:
    lines = ["| file | rejected | robust chi2 | clean default chi2 | relative | robust CPU s | "
             "default CPU s | x default |", "|---" * 8 + "|"]
    lines += [f"| {r['case']} | {r['rejected']} | {r['robust_chi2']:.6g} | "
              f"{r['default_chi2']:.6g} | {r['relative']:+.1e} | {r['robust_s']:.2f} | "
              f"{r['default_s']:.2f} | {r['x_default']:.1f} |" for r in rows["clean"]]
    lines += ["", "| case | mode | wrong | rejected | precision | recall | chi2 + LM30 on clean "
              "/ optimum | robust CPU s | default CPU s | x default |", "|---" * 10 + "|"]
    lines += [f"| {r['case']} | {r['mode']} | {r['wrong']} ({r['fraction']:.0%}) | "
              f"{r['rejected']} | {r['precision']:.4f} | {r['recall']:.4f} | {r['ratio']:.4f} "
              f"| {r['robust_s']:.2f} | {r['default_s']:.2f} | {r['x_default']:.1f} |"
              for r in rows["wrong"]]
    return "\n".join(lines) + "\n"


# --- noise --------------------------------------------------------------------------------------

def noise_graph(dim: int, n: int, sigma_r: float, d: float, seed: int, **outliers):
    """The ``noise`` subcommand's generated graph (``outliers``: its wrong closures)."""
    from rlpgo_gtsam import SE2, SE3, generate

    return generate(n, sigma_r, SIGMA_T, d, LC, np.random.default_rng(seed),
                    noisy_measurements=True, group=SE2 if dim == 2 else SE3, **outliers)


def noise(args, rows: list[dict], save) -> None:
    from rlpgo_gtsam import extract_pose_graph, refine, robust_initialize, staged_initialize

    for dim in map(int, args.dims.split(",")):
        for sigma in map(float, args.sigmas.split(",")):
            for d in map(float, args.spacings.split(",")):
                for seed in map(int, args.seeds.split(",")):
                    clean = noise_graph(dim, args.n, sigma, d, seed)
                    start = staged_initialize(clean.graph, clean.initial).values
                    best = refine(clean.graph, start, "lm", 100,
                                  pose_graph=extract_pose_graph(clean.graph, clean.initial)).chi2
                    clean_rejected = len(robust_initialize(clean.graph, clean.initial).rejected)
                    for mode in args.modes.split(","):
                        bad = noise_graph(dim, args.n, sigma, d, seed, outliers=args.fraction,
                                          outlier_mode=mode)
                        result = robust_initialize(bad.graph, bad.initial)
                        precision, recall = scores(result.rejected, bad.outlier_edges)
                        rows.append({
                            "dim": dim, "sigma_r": sigma, "d": d, "mode": mode, "seed": seed,
                            "wrong": len(bad.outlier_edges), "rejected": len(result.rejected),
                            "precision": precision, "recall": recall,
                            "ratio": refine(clean.graph, result.values, "lm", 100).chi2 / best,
                            "seconds": result.seconds, "clean_rejected": clean_rejected,
                            "doubtful": len(result.doubtful)})
                        print(noise_table(rows[-1:]).splitlines()[-1], flush=True)
                        save()


def noise_table(rows: list[dict]) -> str:
    lines = ["| dim | sigma_R | d | policy | seed | wrong | rejected | precision | recall | "
             "chi2 ratio | s | clean graph: rejected |", "|---" * 12 + "|"]
    lines += [f"| {r['dim']} | {r['sigma_r']:g} | {r['d']:g} | {r['mode']} | {r['seed']} | "
              f"{r['wrong']} | {r['rejected']} | {r['precision']:.3f} | {r['recall']:.3f} | "
              f"{r['ratio']:.4f} | {r['seconds']:.2f} | {r['clean_rejected']} |" for r in rows]
    return "\n".join(lines) + "\n"


# --- rates --------------------------------------------------------------------------------------

# Published figures, quoted from the project's reference notes (REFERENCE.md, "Wrong loop
# closures as front ends make them"), which ask that the papers' tables be checked before
# these are quoted as final.
PUBLISHED = (
    "IPC/TACO: F1 about 0.91 at 50% and 0.89 at 100% random outliers; GNC's precision falls "
    "below 0.5 past 50% (as the reference notes give them; check the papers' tables).",
    "riSAM (rpl-cmu/risam; GTSAM-based, incremental GNC): tested to 90% outliers (no F1 "
    "figure in the reference notes).",
    "GNC: reported robust to 70-80% outliers from a good start.",
)
TIME_BOUNDS = ((1.0, 5.0), (9.0, 10.0))  # (ratio up to, x clean at most)


@dataclass(frozen=True)
class RateCase:
    """An outlier-free case of ``rates``: the graph, its start, its optimum (values, chi2),
    the factor indices of its true loop closures (between factors off the odometry chain)."""

    name: str
    dim: int
    graph: Any
    values: Any
    optimum: Any
    best: float
    closures: list[int]


def rate_case(name: str, dim: int) -> RateCase:
    """A shared file or a generated graph (``gen``: :data:`GEN`, ``gen3d``: :data:`GEN_3D`)
    with its optimum as ``policies`` (planar) and ``3d`` compute it."""
    import gtsam

    from rlpgo_gtsam import extract_pose_graph
    from rlpgo_gtsam.graph import odometry_edges

    if dim == 2:
        graph, values, optimum, best = clean_case(name)
    else:
        graph, values, _, _, optimum, best = clean_case_3d("gen" if name == "gen3d" else name)
    between = [k for k in range(graph.size())
               if isinstance(graph.at(k), gtsam.BetweenFactorPose2 | gtsam.BetweenFactorPose3)]
    chain = odometry_edges(extract_pose_graph(graph, values))
    return RateCase(name, dim, graph, values, optimum, best,
                    [between[e] for e in np.flatnonzero(~chain).tolist()])


def misfits(graph, values, factors) -> list[int]:
    """The factors of ``factors`` whose chi2 at ``values`` (2 x GTSAM's error) exceeds the
    robust path's inlier bar: the chi-square quantile at ``RobustSettings.inlier_probability``
    (0.9999) for the factor's dimension (21.1 planar, 27.9 in 3D)."""
    from rlpgo_gtsam.robust.settings import RobustSettings
    from rlpgo_gtsam.robust.statistics import chi2_quantile

    probability = RobustSettings().inlier_probability
    return [k for k in factors
            if 2.0 * graph.at(k).error(values) > chi2_quantile(probability, graph.at(k).dim())]


def f1(precision: float | None, recall: float | None) -> float | None:
    """The harmonic mean of precision and recall (0 where both are 0)."""
    if precision is None or recall is None:
        return None
    return 0.0 if precision + recall == 0 else 2.0 * precision * recall / (precision + recall)


def _rate_row(case: RateCase, wanted: float, mode: str, seed: int, args) -> dict:
    from rlpgo_gtsam import add_outliers, refine
    from rlpgo_gtsam.accuracy import trajectory_errors

    count = round(wanted * len(case.closures))
    bad, wrong = add_outliers(case.graph, case.optimum, None, np.random.default_rng(seed), mode,
                              count=count)
    detectable = misfits(bad, case.optimum, wrong)
    row: dict[str, Any] = {
        "dim": case.dim, "case": case.name, "mode": mode, "ratio": wanted, "seed": seed,
        "true": len(case.closures), "wrong": len(wrong),
        "rate": len(wrong) / (len(wrong) + len(case.closures)), "detectable": len(detectable),
        "clean_default_s": clean_default_beside(case.graph, case.values)}

    def fit(found) -> dict:
        if found is None:
            return {"chi2_ratio": None, "ape_m": None}
        refined = refine(case.graph, found, "lm", 100)
        return {"chi2_ratio": refined.chi2 / case.best,
                "ape_m": trajectory_errors(refined.values, case.optimum).ape_rmse_m}

    def scored(prefix: str, rejected) -> dict:
        precision, recall = scores(rejected, wrong)
        detected = scores(rejected, detectable)[1]
        return {f"{prefix}precision": precision, f"{prefix}recall": recall,
                f"{prefix}recall_detectable": detected, f"{prefix}f1": f1(precision, recall),
                f"{prefix}f1_detectable": f1(precision, detected)}

    if args.robust_timeout > 0:
        fields, _, rejected = robust_fields(bad, case.values, wrong, args.robust_timeout, fit)
        row |= fields
        if rejected is not None:
            row |= scored("", rejected) | {"x_clean": row["seconds"] / row["clean_default_s"]}
    if args.anchor_timeout > 0:
        fields, found = anchor_fields(bad, case.values, wrong, args.anchor_timeout, fit)
        row |= fields
        values_dcs = found["dcs"][0]
        if values_dcs is not None:  # DCS rejects nothing: the closures that misfit its map
            found["dcs"] = (values_dcs, misfits(bad, values_dcs, [*case.closures, *wrong]))
        for kind, (_, rejected_a) in found.items():
            if rejected_a is not None:
                row |= scored(f"{kind}_", rejected_a)
    return row


def rates(args, rows: list[dict], save) -> None:
    cases = [(name, 2) for name in args.cases.split(",") if name]
    cases += [(name, 3) for name in args.cases_3d.split(",") if name]
    for name, dim in cases:
        case = rate_case(name, dim)
        for wanted in harness.numbers(args.ratios, float):
            for mode in args.modes.split(","):
                for seed in harness.numbers(args.seeds):
                    rows.append(_rate_row(case, wanted, mode, seed, args))
                    print({k: (round(v, 4) if isinstance(v, float) else v)
                           for k, v in rows[-1].items()}, flush=True)
                    save()


def _within_time(row: dict) -> bool | None:
    """Whether the row's x clean is within :data:`TIME_BOUNDS` (None: no bound, or the robust
    path left out; a run past its cap is not within)."""
    bound = next((most for up_to, most in TIME_BOUNDS if row["ratio"] <= up_to), None)
    if bound is None or "status" not in row:
        return None
    if row.get("x_clean") is None:
        return False
    return bool(row["x_clean"] <= bound)


def _anchor_cells(row: dict, kind: str) -> str:
    scored = (f"{row[kind + '_precision']:.2f}/{row[kind + '_recall']:.2f}/"
              f"{row[kind + '_f1']:.2f}" if kind + "_f1" in row
              else row.get(kind + "_status", "-"))
    return (f"{scored} | {_f(row.get(kind + '_chi2_ratio'), 4)} | "
            f"{harness.cell(row.get(kind + '_ape_m'), '.3g')}")


def rates_table(rows: list[dict]) -> str:
    lines = ["Wrong loop closures as a ratio of the true ones (rate: their share of all "
             "closures). Recall and F1 over all wrong closures and over the detectable ones "
             "(misfitting the outlier-free optimum beyond the chi-square bar at 0.9999); APE "
             "(translation RMSE, m) and chi2 after LM 100 on the outlier-free graph, against "
             "its optimum; s in the robust path's process, x clean over the clean default "
             "beside the row. Anchors from the certified estimate of all edges: GNC-LM (TLS) "
             "and DCS (its rejections: the closures misfitting its map beyond the same bar), "
             "P/R/F1.", ""]
    for dim in sorted({r["dim"] for r in rows}):
        part = [r for r in rows if r["dim"] == dim]
        lines += [f"### {'planar' if dim == 2 else '3D'}", "",
                  "| case | policy | seed | ratio | rate | true | wrong (detectable) | "
                  "precision | recall | recall det. | F1 | F1 det. | APE m | chi2 ratio | s | "
                  "x clean | ambiguous | GNC P/R/F1 | GNC ratio | GNC APE m | DCS P/R/F1 | "
                  "DCS ratio | DCS APE m |", "|---" * 23 + "|"]
        for r in part:
            start = (f"| {r['case']} | {r['mode']} | {r['seed']} | {r['ratio']:g} | "
                     f"{r['rate']:.0%} | {r['true']} | {r['wrong']} ({r['detectable']}) |")
            anchors = f"{_anchor_cells(r, 'gnc')} | {_anchor_cells(r, 'dcs')} |"
            if "precision" not in r:  # the robust path left out, or past its cap
                lines.append(f"{start} {r.get('status', '-')} |" + " - |" * 9 + f" {anchors}")
                continue
            lines.append(
                f"{start} {r['precision']:.3f} | {r['recall']:.3f} | "
                f"{r['recall_detectable']:.3f} | {r['f1']:.3f} | {r['f1_detectable']:.3f} | "
                f"{harness.cell(r['ape_m'], '.3g')} | {_f(r['chi2_ratio'], 5)} | "
                f"{r['seconds']:.1f} | "
                f"{r['x_clean']:.1f} | {r['ambiguous']} | {anchors}")
        good = [r for r in part if r.get("f1") is not None and r["chi2_ratio"] is not None
                and r["chi2_ratio"] <= 1.001]
        timed = [r for r in part if _within_time(r) is not None]
        lines += ["", f"Summary ({'planar' if dim == 2 else '3D'}): "
                  f"{sum(r['f1'] >= 0.99 for r in good)} of {len(part)} rows with F1 >= 0.99 "
                  f"and chi2 within 0.1% of the optimum "
                  f"({sum(r['f1_detectable'] >= 0.99 for r in good)} with F1 over the "
                  f"detectable ones); {sum(bool(_within_time(r)) for r in timed)} of "
                  f"{len(timed)} rows within the time bounds (x clean <= 5 at ratio <= 1, "
                  "<= 10 up to 9).", ""]
    lines += ["Published figures:", ""] + [f"- {line}" for line in PUBLISHED]
    return "\n".join(lines) + "\n"


# --- the command line ---------------------------------------------------------------------------

POLICIES = "random,local,group,localgroup"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("policies", help="Vertigo's policies, the robust path and the anchors")
    p.add_argument("--cases", default="gen,MIT,Intel,FR079,M3500,City10K")
    p.add_argument("--modes", default=POLICIES)
    p.add_argument("--fractions", default="0.05,0.1,0.2,0.3")
    p.add_argument("--clean", default="all", choices=["all", "none"])
    p.add_argument("--anchor-timeout", type=float, default=60.0, help="0: no anchors")
    p.add_argument("--robust-timeout", type=float, default=300.0, help="0: no robust path")
    p.add_argument("--append", action="store_true",
                   help="add the rows to those of the results file of the same name")
    p.set_defaults(name="robust_policies")
    c = sub.add_parser("commands", help="rlpgo-init --robust against rlpgo-init, processes")
    c.add_argument("--cases", default="MIT,Intel,FR079,gen")
    c.add_argument("--modes", default=POLICIES)
    c.add_argument("--fractions", default="0.05,0.1,0.2")
    c.add_argument("--ratios", default="",
                   help="wrong closures per true one instead of --fractions (as rates adds "
                        "them)")
    c.add_argument("--repeats", type=int, default=3)
    c.add_argument("--loads", default="idle")
    c.set_defaults(name="robust_commands")
    s = sub.add_parser("3d", help="SE-Sync's 3D files, clean and with wrong closures")
    s.add_argument("--clean", default=",".join(harness.FILES_3D))
    s.add_argument("--cases", default="sphere2500,torus3D,gen")
    s.add_argument("--modes", default="random,uniform")
    s.add_argument("--fractions", default="0.05,0.1")
    s.set_defaults(name="robust3d")
    n = sub.add_parser("noise", help="generated graphs as the rotation noise grows")
    n.add_argument("--dims", default="2,3")
    n.add_argument("--sigmas", default="0.05,0.1,0.2,0.3")
    n.add_argument("--spacings", default="1,3")
    n.add_argument("--modes", default=POLICIES)
    n.add_argument("--fraction", type=float, default=0.1)
    n.add_argument("--seeds", default="1,2,3")
    n.add_argument("--n", type=int, default=300)
    n.set_defaults(name="robust_noise")
    r = sub.add_parser("rates", help="wrong closures as a ratio of the true ones, to 90%%")
    r.add_argument("--cases", default="Intel,gen",
                   help="planar: M3500, Intel, City10K, MIT, FR079 (shared files), gen")
    r.add_argument("--cases-3d", default="gen3d",
                   help="3D: sphere2500, torus3D (SE-Sync's files), gen3d; '' for none")
    r.add_argument("--ratios", default="0.1,0.33,1,3,9",
                   help="wrong closures per true one (9: 90%% of all closures wrong)")
    r.add_argument("--modes", default=f"{POLICIES},uniform")
    r.add_argument("--seeds", default=str(SEED))
    r.add_argument("--anchor-timeout", type=float, default=60.0, help="0: no anchors")
    r.add_argument("--robust-timeout", type=float, default=300.0, help="0: no robust path")
    r.add_argument("--append", action="store_true",
                   help="add the rows to those of the results file of the same name")
    r.set_defaults(name="robust_rates")
    for each in (p, c, s, n, r):
        each.add_argument("--name", default=each.get_default("name"), help="results file name")
    return parser


def main() -> None:
    args = _parser().parse_args()
    command = harness.command_line()
    rows: list[dict] | dict[str, list[dict]] = []
    if getattr(args, "append", False) and (RESULTS / f"{args.name}.json").is_file():
        earlier = json.loads((RESULTS / f"{args.name}.json").read_text())
        rows, command = earlier["rows"], f"{earlier['command']} && {command}"
    run, table = {"policies": (policies, policies_table), "commands": (commands, commands_table),
                  "3d": (spatial, spatial_table), "noise": (noise, noise_table),
                  "rates": (rates, rates_table)}[args.command]
    if args.command == "3d":
        rows = {"clean": [], "wrong": []}

    def save() -> None:
        harness.write_result(args.name, command, {"rows": rows}, table(rows))

    run(args, rows, save)
    save()
    print(table(rows))


if __name__ == "__main__":
    main()
