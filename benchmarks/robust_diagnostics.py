"""Why the robust path decides as it does: what any test could reject, what it still misses,
how it behaves when the covariances are wrong, and the fit behind its hint.

    python benchmarks/robust_diagnostics.py limits [--cases MIT,Intel]
        [--modes random,local,group,localgroup] [--fraction 0.1] [--probability 0.9999]
        [--oracle]
    python benchmarks/robust_diagnostics.py floor [--rows robust_noise_2d] [--n 300]
        [--fraction 0.1]
    python benchmarks/robust_diagnostics.py covariance [--cases M3500,...,gen] [--factors 2,4,10]
    python benchmarks/robust_diagnostics.py fit [--cases gen,MIT,Intel,FR079,M3500,City10K]
        [--fractions 0.05,0.1,0.2,0.3]

Every subcommand takes ``--name`` and writes ``benchmarks/results/<name>.md`` (and, but for
``limits``, ``.json``). The cases and wrong closures are ``benchmarks/robust.py policies``'.

``limits``. Per case and policy every wrong closure is tested against the outlier-free
graph's optimum with the map's own uncertainty: ``b^T (I + A P A^T)^-1 b`` (whitened residual
``b`` and Jacobian ``A`` from GTSAM's linearization, ``P`` GTSAM's joint marginal of its two
poses). A wrong closure below the chi-square bar (3 dof at ``--probability``: 21.1 at 0.9999)
fits the right map as well as a true one may: no single-closure test at that probability
rejects it, so ``1 - passing / wrong`` bounds their recall. ``--oracle`` adds the best any
single-closure test that knows the right map can do: each true closure's leave-out innovation
``b^T (I - A P A^T)^-1 b``, and over all bars the largest min(precision, recall); per case
also the true closures' spread and what a bar scaled by the variance factor of their median
would reject.

``floor``. For every row of a ``robust.py noise`` result (``--rows``) below precision or
recall 0.98, the same graph is made again and ``robust_initialize`` run; each wrong closure
it kept and each true one it rejected is scored at the outlier-free graph's optimum by the
verify step's own statistic. A kept wrong closure within the bar (chi-square, 0.9999, the
group's dof) is one no test on the stated covariances can reject; a rejected true one with
p < 0.05 there is one its own noise put in the tail; a row whose every miss is one of these
is at the floor.

``covariance``. Clean maps whose covariances understate the noise: every between factor's
information times F. The closures rejected as stated and told ``covariance_scale=F``; the
chi2 told over F against the clean optimum; the estimate of F a user can make on a map
believed clean (the variance factor of least squares, chi2 / (dof x (edges - poses + 1)),
:func:`rlpgo_gtsam.residuals.variance_factor`) and the closures rejected when told it (at
least 1) and twice it.

``fit``. Without wrong closures and with each policy and fraction: the closures rejected, the
recall, the wrong ones kept and the kept edges' variance factor, which ``rlpgo-init --robust``
compares with ``LOOSE_FIT`` (over ``--covariance-scale``) to print its hint.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness  # noqa: E402
from benchmarks.harness import RESULTS, scores  # noqa: E402
from benchmarks.robust import POLICIES, clean_case, corrupted, noise_graph  # noqa: E402


def _settings():
    """The robust path's default settings."""
    from rlpgo_gtsam.robust.settings import RobustSettings

    return RobustSettings()


# --- limits -------------------------------------------------------------------------------------

def innovation(factor, optimum: gtsam.Values, marginals: gtsam.Marginals,
               held_out: bool = False) -> float:
    """The closure's chi2 against the map: a closure outside the graph the marginals belong
    to, ``b^T (I + A P A^T)^-1 b``; ``held_out``, one of its edges against the map made
    without it, ``b^T (I - A P A^T)^-1 b``."""
    jacobian, b = factor.linearize(optimum).jacobian()
    joint = marginals.jointMarginalCovariance(gtsam.KeyVector(factor.keys())).fullMatrix()
    spread = jacobian @ joint @ jacobian.T
    return float(b @ np.linalg.solve(np.eye(3) + (-spread if held_out else spread), b))


def best_split(wrong: np.ndarray, true: np.ndarray) -> tuple[float, float, float, float]:
    """(min(precision, recall), precision, recall, bar) of the best bar: closures at or above
    it rejected."""
    best = (-1.0, 0.0, 0.0, 0.0)
    for bar in np.unique(np.concatenate([wrong, true])):
        hit, false = int((wrong >= bar).sum()), int((true >= bar).sum())
        precision = hit / (hit + false) if hit + false else 1.0
        recall = hit / len(wrong)
        if min(precision, recall) > best[0]:
            best = (min(precision, recall), precision, recall, float(bar))
    return best


def _true_closures(name: str, graph, values, optimum, marginals, bar: float) -> tuple:
    """The true closures' leave-out innovations, the variance factor of their median, and a
    line saying how they spread."""
    from rlpgo_gtsam import extract_pose_graph
    from rlpgo_gtsam.graph import odometry_edges
    from rlpgo_gtsam.robust.statistics import chi2_quantile

    closures = np.flatnonzero(~odometry_edges(extract_pose_graph(graph, values)))
    true = np.array([innovation(graph.at(int(k)), optimum, marginals, held_out=True)
                     for k in closures])
    factor = float(np.median(true)) / chi2_quantile(0.5, 3)
    return true, factor, (
        f"{name}: {len(true)} true closures, innovations median {np.median(true):.2f}, 99th "
        f"percentile {np.percentile(true, 99):.2f}, largest {true.max():.2f}; variance factor "
        f"from the median {factor:.3f}: bar {factor * bar:.2f} rejects "
        f"{int((true >= factor * bar).sum())} of them")


def limits(args) -> tuple[dict | None, str]:
    from rlpgo_gtsam.robust.statistics import chi2_quantile

    bar = chi2_quantile(args.probability or _settings().inlier_probability, 3)
    lines = []
    for name in args.cases.split(","):
        graph, values, optimum, _ = clean_case(name)
        pinned = gtsam.NonlinearFactorGraph(graph)
        anchor = int(min(optimum.keys()))
        pinned.add(gtsam.PriorFactorPose2(anchor, optimum.atPose2(anchor),
                                          gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)))
        marginals = gtsam.Marginals(pinned, optimum)
        true = None
        if args.oracle:
            true, factor, line = _true_closures(name, graph, values, optimum, marginals, bar)
            lines.append(line)
            print(line, flush=True)
        for mode in args.modes.split(","):
            bad, wrong = corrupted(name, graph, optimum, args.fraction, mode)
            found = np.array([innovation(bad.at(k), optimum, marginals) for k in wrong])
            passing = int((found < bar).sum())
            lines.append(f"{name} {mode} {args.fraction:g}: {passing} of {len(wrong)} wrong "
                         f"closures fit the right map (innovation < {bar:.1f}; lowest "
                         f"{found.min():.1f}): recall of single-closure tests at most "
                         f"{1 - passing / len(wrong):.3f}")
            if true is not None:
                both, precision, recall, cut = best_split(found, true)
                lines.append(f"  oracle: {len(true)} true closures; best bar {cut:.1f}: "
                             f"precision {precision:.3f}, recall {recall:.3f} (min {both:.3f}); "
                             f"the scaled bar passes {int((found < factor * bar).sum())} wrong "
                             "closures")
            print("\n".join(lines[-2 if true is not None else -1:]), flush=True)
    return None, "```text\n" + "\n".join(lines) + "\n```\n"


# --- floor --------------------------------------------------------------------------------------

def statistics_at_optimum(bad, clean, edges_of_interest: list[int]) -> dict[int, float]:
    """Per factor index of ``bad.graph`` in ``edges_of_interest``: the verify step's
    statistic at the outlier-free graph's optimum (its wrong closures left out)."""
    from rlpgo_gtsam import extract_pose_graph, refine, staged_initialize
    from rlpgo_gtsam.groups import group_of
    from rlpgo_gtsam.robust.innovation import innovation_draws, set_statistics
    from rlpgo_gtsam.robust.problem import Problem, edge_factor_indices

    if not edges_of_interest:
        return {}
    g = extract_pose_graph(bad.graph, bad.initial)
    factor_of_edge = edge_factor_indices(bad.graph, g.num_edges, group_of(g).between_factor)
    problem = Problem(bad.graph, g, factor_of_edge, _settings())
    edge_of = {int(f): e for e, f in enumerate(factor_of_edge.tolist())}
    optimum = refine(clean.graph, staged_initialize(clean.graph, clean.initial).values, "lm",
                     100).values
    kept = np.ones(g.num_edges, bool)
    kept[[edge_of[f] for f in bad.outlier_edges]] = False
    draws = innovation_draws(problem, optimum, kept)
    found = set_statistics(problem, draws, [np.array([edge_of[f]]) for f in edges_of_interest])
    return dict(zip(edges_of_interest, found.chi2.tolist(), strict=True))


def _floor_row(row: dict, args) -> dict:
    from rlpgo_gtsam import extract_pose_graph, robust_initialize
    from rlpgo_gtsam.groups import group_of
    from rlpgo_gtsam.robust.statistics import chi2_quantile, statistic_at

    shape = (row["dim"], args.n, row["sigma_r"], row["d"], row["seed"])
    clean = noise_graph(*shape)
    bad = noise_graph(*shape, outliers=args.fraction, outlier_mode=row["mode"])
    result = robust_initialize(bad.graph, bad.initial)
    wrong, rejected = set(bad.outlier_edges), set(result.rejected)
    kept_wrong, lost_true = sorted(wrong - rejected), sorted(rejected - wrong)
    score = statistics_at_optimum(bad, clean, kept_wrong + lost_true)
    dof = group_of(extract_pose_graph(bad.graph, bad.initial)).dof
    settings = _settings()
    bar = chi2_quantile(settings.inlier_probability, dof)
    tail = statistic_at(settings.doubtful_below, dof)
    fitting = sum(score[f] < bar for f in kept_wrong)
    in_tail = sum(score[f] > tail for f in lost_true)
    return {key: row[key] for key in ("dim", "sigma_r", "d", "mode", "seed")} | {
        "kept_wrong": len(kept_wrong), "kept_wrong_fitting": int(fitting),
        "rejected_true": len(lost_true), "rejected_true_in_tail": int(in_tail),
        "floor": fitting == len(kept_wrong) and in_tail == len(lost_true),
        "kept_wrong_statistics": [round(score[f], 1) for f in kept_wrong],
        "rejected_true_statistics": [round(score[f], 1) for f in lost_true]}


def floor_table(rows: list[dict]) -> str:
    lines = ["| dim | sigma_R | d | policy | seed | wrong kept | of them fitting the optimum | "
             "true rejected | of them p < 0.05 there | at the floor |", "|---" * 10 + "|"]
    lines += [f"| {r['dim']} | {r['sigma_r']:g} | {r['d']:g} | {r['mode']} | {r['seed']} | "
              f"{r['kept_wrong']} | {r['kept_wrong_fitting']} | {r['rejected_true']} | "
              f"{r['rejected_true_in_tail']} | {'yes' if r['floor'] else 'no'} |" for r in rows]
    totals = {key: sum(r[key] for r in rows) for key in
              ("kept_wrong", "kept_wrong_fitting", "rejected_true", "rejected_true_in_tail",
               "floor")}
    lines.append(f"\nrows below 0.98: {len(rows)}; at the floor: {totals['floor']}; wrong kept "
                 f"{totals['kept_wrong']} ({totals['kept_wrong_fitting']} fit the optimum); "
                 f"true rejected {totals['rejected_true']} ({totals['rejected_true_in_tail']} "
                 "with p < 0.05 there)")
    return "\n".join(lines) + "\n"


def floor(args) -> tuple[dict, str]:
    source = json.loads((RESULTS / f"{args.rows}.json").read_text())["rows"]
    rows = []
    for row in source:
        if min(row["precision"], row["recall"]) < 0.98:
            rows.append(_floor_row(row, args))
            print(floor_table(rows[-1:]).splitlines()[2], flush=True)
    return {"rows": rows}, floor_table(rows)


# --- covariance ---------------------------------------------------------------------------------

def _covariance_row(name: str, factor: float, graph, values, optimum_chi2: float) -> dict:
    from rlpgo_gtsam import extract_pose_graph, robust_initialize
    from rlpgo_gtsam.information import scaled_informations
    from rlpgo_gtsam.residuals import variance_factor

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


def covariance_table(rows: list[dict]) -> str:
    lines = ["| case | F | rejected as stated | rejected, told F | chi2 told / F | clean "
             "optimum chi2 | F estimated | rejected, told the estimate / twice it | seconds "
             "stated / told |", "|---" * 9 + "|"]
    lines += [f"| {r['case']} | {r['factor']:g} | {r['rejected_as_stated']} | "
              f"{r['rejected_told']} | {r['told_chi2_over_factor']:.6g} | "
              f"{r['optimum_chi2']:.6g} | {r['estimated_factor']:.3g} | "
              f"{r['rejected_told_estimate']} / {r['rejected_told_twice_estimate']} | "
              f"{r['seconds_as_stated']:.2f} / {r['seconds_told']:.2f} |" for r in rows]
    return "\n".join(lines) + "\n"


def covariance(args) -> tuple[dict, str]:
    rows = []
    for name in args.cases.split(","):
        graph, values, _, optimum_chi2 = clean_case(name)
        for factor in map(float, args.factors.split(",")):
            rows.append(_covariance_row(name, factor, graph, values, optimum_chi2))
            print(json.dumps(rows[-1]), flush=True)
    return {"rows": rows}, covariance_table(rows)


# --- fit ----------------------------------------------------------------------------------------

def _fit_row(name: str, mode: str, fraction: float, graph, values, wrong: list[int]) -> dict:
    from rlpgo_cli.init import LOOSE_FIT

    from rlpgo_gtsam import extract_pose_graph, robust_initialize
    from rlpgo_gtsam.residuals import variance_factor

    result = robust_initialize(graph, values)
    g = extract_pose_graph(graph, values)
    fit = variance_factor(g, result.chi2, g.num_edges - len(result.rejected))
    return {"case": name, "mode": mode, "fraction": fraction, "wrong": len(wrong),
            "rejected": len(result.rejected), "recall": scores(result.rejected, wrong)[1],
            "wrong_kept": len(set(wrong) - set(result.rejected)), "chi2": result.chi2,
            "variance_factor": fit, "hint": bool(result.rejected) and fit > LOOSE_FIT}


def fit_table(rows: list[dict]) -> str:
    lines = ["| case | policy | fraction | wrong | rejected | recall | wrong kept | kept edges' "
             "variance factor | hint |", "|---" * 9 + "|"]
    lines += [f"| {r['case']} | {r['mode']} | {r['fraction']:g} | {r['wrong']} | "
              f"{r['rejected']} | {r['recall']:.3f} | {r['wrong_kept']} | "
              f"{r['variance_factor']:.3g} | {'yes' if r['hint'] else ''} |" for r in rows]
    return "\n".join(lines) + "\n"


def fit(args) -> tuple[dict, str]:
    rows = []
    for name in args.cases.split(","):
        graph, values, optimum, _ = clean_case(name)
        cases = [("clean", 0.0, graph, [])]
        for fraction in map(float, args.fractions.split(",")):
            for mode in POLICIES.split(","):
                cases.append((mode, fraction, *corrupted(name, graph, optimum, fraction, mode)))
        for mode, fraction, judged, wrong in cases:
            rows.append(_fit_row(name, mode, fraction, judged, values, wrong))
            print(json.dumps(rows[-1]), flush=True)
    return {"rows": rows}, fit_table(rows)


# --- the command line ---------------------------------------------------------------------------

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    lim = sub.add_parser("limits", help="each wrong closure's innovation against the right map")
    lim.add_argument("--cases", default="MIT,Intel")
    lim.add_argument("--modes", default=POLICIES)
    lim.add_argument("--fraction", type=float, default=0.1)
    lim.add_argument("--probability", type=float,
                     help="of the chi-square bar (default: the robust path's, 0.9999)")
    lim.add_argument("--oracle", action="store_true")
    lim.set_defaults(name="robust_limits")
    flo = sub.add_parser("floor", help="whether each miss of robust.py noise is at the floor")
    flo.add_argument("--rows", default="robust_noise_2d",
                     help="a robust.py noise result, by its name under benchmarks/results")
    flo.add_argument("--n", type=int, default=300, help="poses, as robust.py noise ran")
    flo.add_argument("--fraction", type=float, default=0.1)
    flo.set_defaults(name="robust_floor")
    cov = sub.add_parser("covariance", help="covariances that understate the noise")
    cov.add_argument("--cases", default=",".join([*harness.FILES_2D, "gen"]))
    cov.add_argument("--factors", default="2,4,10")
    cov.set_defaults(name="robust_covariance")
    fi = sub.add_parser("fit", help="the kept edges' variance factor behind the hint")
    fi.add_argument("--cases", default="gen,MIT,Intel,FR079,M3500,City10K")
    fi.add_argument("--fractions", default="0.05,0.1,0.2,0.3")
    fi.set_defaults(name="robust_fit")
    for each in (lim, flo, cov, fi):
        each.add_argument("--name", default=each.get_default("name"), help="results file name")
    args = parser.parse_args()
    run = {"limits": limits, "floor": floor, "covariance": covariance, "fit": fit}
    data, text = run[args.command](args)
    print(text)
    harness.write_result(args.name, harness.command_line(), data, text)


if __name__ == "__main__":
    main()
