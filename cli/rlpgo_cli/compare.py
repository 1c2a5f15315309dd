"""rlpgo-compare: initial guesses side by side, each refined by the same GTSAM solver, on
planar or 3D g2o and PyFG files (each file gets the methods of its group)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.formats import input_group, read_truth
from rlpgo_cli.inputs import read_input
from rlpgo_cli.output import RunFiles, json_text
from rlpgo_cli.types import ITERATIONS, ROLLOUTS, SEED, OutputFile
from rlpgo_gtsam.accuracy import TrajectoryErrors, check_ground_truth, trajectory_errors
from rlpgo_gtsam.errors import OutputError, RlpgoError
from rlpgo_gtsam.graph import chi2, extract_pose_graph
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.initializers import CLASSICAL, check_method, start_names
from rlpgo_gtsam.ranking import (
    FROM_BEST,
    TIE_RELATIVE,
    MethodResult,
    compare_methods,
    comparison_methods,
    line_progress_options,
    tied_best,
)
from rlpgo_gtsam.rl.models import DEFAULT_MODEL, model_path
from rlpgo_gtsam.solvers import SOLVERS
from rlpgo_gtsam.synthetic import generate

# The classical rows (Shonan from the best of those before it) and the certified relaxation.
# Left out, each one name away (--methods ...,fastsync): GTSAM's fastSyncPose2, whose row
# never gave the lowest refined chi2 alone on 31 graphs (the shared 2D files, the sigma_t
# sweep, 18 generated graphs where the relaxation mostly fails: tied on 11 files, 1.5x and
# 6.4x the lowest on M3500C and MIT, 9.6-28x on the generated graphs;
# benchmarks/results/compare_wins.md), while its row costs 0.35 s on M3500 and 1.0 s on
# City10K, initialization and refinement (benchmarks/results/compare_fastsync_certified.txt);
# without it the comparison takes under 3x rlpgo-init there
# (benchmarks/results/compare_speed.md); and the agent (rl@certified): from the certified
# start it took 22 s on M3500 and 99 s on City10K, three quarters of the whole comparison,
# and lowered the refined chi2 on neither (nor on any graph in staged.py's table).
DEFAULT_METHODS = ",".join([*CLASSICAL, "certified"])
# What the default leaves out, the agent excepted (benchmarks/compare_speed.py --wins).
LEFT_OUT = ("fastsync",)
# On a 3D file: the 3D rows, certified first (--methods not given).
DEFAULT_METHODS_3D = comparison_methods(SE3)
# The graph compared when no file is given: the paper's n = 300 lawn mower with heavy
# rotation noise and noisy measurements, where odometry and the classical starts differ.
DEMO = dict(n=300, sigma_r=0.3, sigma_t=0.05, d=3.0, lc=0.5, noisy_measurements=True)


def _format(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def _certificate(row: MethodResult) -> str:
    certificate = None if row.init is None else row.init.certificate
    if certificate is None:
        return "-"
    return "yes" if certificate.certified else f"no ({certificate.suboptimality_bound:.3g})"


def _accuracy_cells(errors: TrajectoryErrors | None) -> str:
    """The APE and RPE columns of one row: rmse in metres, '-' without a refined result."""
    ape, rpe = (None, None) if errors is None else (errors.ape_rmse_m, errors.rpe_rmse_m)
    return f"{_format(ape, '.4g'):>10}{_format(rpe, '.4g'):>10}"


def method_width(methods: list[str]) -> int:
    """The method column's width: 14, or wider for longer names (``initialize_pose3``, a
    ``@best`` row)."""
    return max(14, *(len(m) + (5 if m in FROM_BEST else 0) + 2 for m in methods))


def _header(accuracy: bool, width: int = 14) -> str:
    """The table's two header lines; with ``accuracy``, the APE and RPE columns."""
    extra = f"{'APE m':>10}{'RPE m':>10}" if accuracy else ""
    header = (f"  {'method':<{width}}{'init chi2':>14}{'init s':>9}{'refined chi2':>15}"
              f"{'refine s':>10}{'iters':>7}{extra}  certified (bound)")
    return header + "\n" + "-" * len(header)


def _row(r: MethodResult, errors: TrajectoryErrors | None, accuracy: bool,
         width: int = 14) -> str:
    """One method's line, printed as soon as it is done (a failed one's seconds included).
    With ``accuracy``: the refined result's APE and RPE against the ground truth."""
    cells = _accuracy_cells(errors) if accuracy else ""
    return (f"  {r.method:<{width}}{_format(r.init_chi2, '.6g'):>14}"
            f"{_format(r.init_seconds, '.3f'):>9}{_format(r.refined_chi2, '.6g'):>15}"
            f"{_format(r.refine_seconds, '.3f'):>10}{_format(r.iters, 'd'):>7}{cells}  "
            f"{_certificate(r)}" + (f"  FAILED: {r.failure}" if r.failure else ""))


def _best_line(results: list[MethodResult]) -> str:
    """After the rows: the lowest refined chi2's method, or the methods tied for it
    (within a relative :data:`~rlpgo_gtsam.ranking.TIE_RELATIVE`)."""
    best = tied_best(results)
    if not best:
        return "* no method gave a refined result"
    if len(best) == 1:
        return f"* lowest refined chi2: {best[0].method}"
    return (f"= {len(best)} methods tie for the lowest refined chi2 (within a relative "
            f"{TIE_RELATIVE:g}): {', '.join(r.method for r in best)}")


def _methods(text: str, start: str) -> list[str]:
    """The --methods list, each a method of some group (a usage error otherwise); ``rl`` is
    ``rl@<start>``."""
    methods = [m.strip() for m in text.split(",") if m.strip()]
    if not methods:
        raise click.BadParameter("give at least one method", param_hint="--methods")
    methods = [f"rl@{start}" if m == "rl" else m for m in methods]
    for method in methods:
        try:
            check_method(method)
        except RlpgoError as error:
            raise click.BadParameter(str(error), param_hint="--methods") from None
    return methods


def _methods_for(path: Path, group: Group, given: list[str] | None) -> list[str]:
    """The methods run on the file at ``path``: the --methods given, each checked against
    the file's group (an error that names the file), or that group's default."""
    if given is None:
        return DEFAULT_METHODS_3D if group is SE3 else _methods(DEFAULT_METHODS, "odometry")
    for method in given:
        try:
            check_method(method, group)
        except RlpgoError as error:
            raise RlpgoError(f"{path} holds a {group.kind} pose graph: {error}") from None
    return given


@click.command(cls=RlpgoCommand)
@click.argument("files", nargs=-1, type=click.Path(path_type=Path))
@click.option("--solver", type=click.Choice(SOLVERS), default="lm", show_default=True,
              help="GTSAM solver run after each initializer.")
@click.option("--iters", type=ITERATIONS, default=30, show_default=True,
              help="Iteration cap of the solver.")
@click.option("--methods", default=DEFAULT_METHODS, show_default=True,
              help="Comma-separated initializers to compare (a 3D file's default: "
                   + ",".join(DEFAULT_METHODS_3D) + "). In the default rows Shonan starts "
                   "from the best row before it (shonan@best); a method named here runs as "
                   "named.")
@click.option("--json", "json_path", type=OutputFile(),
              help="Write every row as a JSON list of records.")
@click.option("--plot", "plot_dir", type=click.Path(path_type=Path),
              help="Write one PNG per file: the initial guess and each refined trajectory.")
@click.option("--seed", type=SEED, default=1, show_default=True,
              help="Seed of the generated graph used when no FILE is given.")
@click.option("--model", default=DEFAULT_MODEL, show_default=True,
              help="Agent of the rl methods: a shipped model name or a model file.")
@click.option("--episodes", type=ROLLOUTS, default=1, show_default=True,
              help="Rollouts of the rl methods (lowest chi2 kept).")
@click.option("--start", type=click.Choice(start_names(SE2)), default="odometry",
              show_default=True, help="Start of method rl (rl@<start> names it per method).")
@click.option("--cycles", type=click.IntRange(1, 10_000), default=None,
              help="Passes over the edges of the rl methods [default: the model's test cycles].")
@click.option("--ground-truth", "truth_path", type=click.Path(path_type=Path),
              help="True poses of the one FILE (a g2o file whose vertex lines hold a pose for "
                   "each of its ids, edges not needed; or a PyFG file, its pose vertices, "
                   "such as rlpgo-generate --ground-truth writes): adds evo's APE and RPE "
                   "(rmse, m) of "
                   "each refined result. With no FILE, the generated graph's own are used.")
@click.pass_context
def main(ctx, files, solver, iters, methods, json_path, plot_dir, seed, model, episodes, start,
         cycles, truth_path):
    """Compare initial guesses for the graphs in FILES (g2o, planar or 3D; PyFG, .pyfg).

    Each method's guess is refined by the same GTSAM solver; costs are g2o chi2
    (2 x GTSAM error). A 3D file's default methods are the 3D rows, certified first.
    With no FILE, a generated lawn-mower graph is compared.
    """
    given = ctx.get_parameter_source("methods") not in (
        None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)
    method_list = _methods(methods, start)
    run = RunFiles(files)
    if truth_path is not None:
        if len(files) != 1:
            raise click.UsageError("--ground-truth needs exactly one FILE (with none, the "
                                   "generated graph's own ground truth is used)")
        run.add_input(truth_path)
    uses_agent = any(m.partition("@")[0] == "rl" for m in method_list)
    if uses_agent:
        run.add_input(model_path(model))
    plots = []
    folders = [] if plot_dir is None else [plot_dir]  # made with the files, not before
    if plot_dir is not None:
        if plot_dir.exists() and not plot_dir.is_dir():
            raise OutputError(f"{plot_dir}: exists and is not a folder")
        names = [path.stem for path in files] or ["generated"]
        plots = [plot_dir / f"{name}.png" for name in names]
        if len(set(plots)) < len(plots):
            raise OutputError(f"{plot_dir}: two FILES have the same name; their plots would "
                              "overwrite each other")
    # One check of every output: a PNG that is an input or is also --json is refused.
    run.check(*plots, json_path, folders=folders)
    groups = [input_group(path) for path in files]
    per_file = [_methods_for(path, group, method_list if given else None)
                for path, group in zip(files, groups, strict=True)]
    three = [path for path, group in zip(files, groups, strict=True) if group is SE3]
    if plot_dir is not None and three:
        raise RlpgoError(f"{three[0]} holds a 3D pose graph: --plot is planar so far "
                         "(plots of 2D graphs)")
    read = [read_input(path) for path in files]  # all validated before any run
    for one in read:
        for note in one.notes:
            click.echo(f"note: {note}")
    inputs = [(path.name, one.graph, one.values, one.read_extraction)
              for path, one in zip(files, read, strict=True)]
    truth = None if truth_path is None else read_truth(truth_path)
    if not inputs:
        demo = generate(rng=np.random.default_rng(seed), **DEMO)
        settings = " ".join(f"{key}={value}" for key, value in DEMO.items())
        inputs = [(f"generated lawn mower ({settings} seed={seed}; rlpgo-generate's model)",
                   demo.graph, demo.initial, None)]
        per_file = [method_list if given else _methods(DEFAULT_METHODS, "odometry")]
        truth = demo.ground_truth
    if truth is not None:  # its poses checked before any run
        try:
            check_ground_truth(inputs[0][2], truth)
        except RlpgoError as error:
            raise RlpgoError(f"{truth_path}: {error}" if truth_path else str(error)) from None
    # a long method's progress, indented under the rows: "    certified: rank 2 ..."
    options = line_progress_options(lambda method, line: click.echo(f"    {method}: {line}"))
    options["rl"] = {"model": model, "episodes": episodes, "cycles": cycles}
    records, failed = [], False
    pngs: list[tuple[Path, bytes]] = []
    for index, (name, graph, values, extraction) in enumerate(inputs):
        pose_graph = extraction if extraction is not None else extract_pose_graph(graph, values)
        click.echo(f"\n{name}: {pose_graph.sizes()}, {solver.upper()}{iters}")
        width = method_width(per_file[index])
        click.echo(_header(truth is not None, width))
        accuracy: list[TrajectoryErrors | None] = []

        def show(row: MethodResult,
                 accuracy: list[TrajectoryErrors | None] = accuracy,
                 width: int = width) -> None:
            errors = None
            if truth is not None and row.refined is not None and not row.failure:
                errors = trajectory_errors(row.refined, truth)
            accuracy.append(errors)
            click.echo(_row(row, errors, truth is not None, width))

        # a method asked for by name is the method run; the default rows start Shonan from
        # the best so far (FROM_BEST)
        results = compare_methods(graph, values, per_file[index], solver, iters, dataset=name,
                                  options=options, pose_graph=pose_graph, on_row=show,
                                  start_from_best=() if given else FROM_BEST)
        click.echo(_best_line(results))
        for r in results:
            if r.init is not None and r.init.certificate is not None:
                click.echo(f"  certificate ({r.method}): {r.init.certificate.describe()}")
        for r, errors in zip(results, accuracy, strict=True):
            record = {**r.record(), "dimension": pose_graph.dimension}
            if truth is not None:
                record["accuracy"] = None if errors is None else errors.record()
            records.append(record)
        failed = failed or any(r.failure for r in results)
        if plots and not failed:  # a failed run writes no plot: none is drawn
            from rlpgo_gtsam.plotting import Panel, plot_trajectories

            best = tied_best(results)
            panels = [Panel("initial guess", values, chi2(graph, values))] + [
                Panel(f"{r.method} + {solver.upper()}{iters}", r.refined, r.refined_chi2,
                      r in best)
                for r in results if r.refined is not None
            ]
            pngs.append((plots[index], plot_trajectories(
                pose_graph, panels, title=f"{name}: each method's guess refined by "
                f"{solver.upper()}{iters}")))
    if failed:  # a run that fails writes nothing
        written = " (nothing written)" if plots or json_path is not None else ""
        raise RlpgoError(f"at least one method failed (see FAILED above){written}")
    # the records and the plots together: every file or none
    outputs = [(path, data) for path, data in pngs]
    if json_path is not None:
        outputs.append((json_path, json_text(records).encode()))
    if outputs:
        run.write_together(outputs, folders)


if __name__ == "__main__":
    main()
