"""rlpgo-init: write an initial guess for a planar or 3D g2o pose graph, or a PyFG graph
(same edges, new vertices)."""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.formats import check_graph_output, graph_text, input_group, is_pyfg
from rlpgo_cli.inputs import read_input
from rlpgo_cli.output import RunFiles, json_text
from rlpgo_cli.types import ITERATIONS, ROLLOUTS, SEED, FiniteFloat, OutputFile
from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import chi2
from rlpgo_gtsam.groups import SE2, SE3, Group
from rlpgo_gtsam.initializers import CLASSICAL, check_method, initializer_names, start_names
from rlpgo_gtsam.io import EDGE_LIST_LINE, edge_list_text
from rlpgo_gtsam.ranking import (
    MethodResult,
    best_of,
    compare_methods,
    comparison_methods,
    line_progress_options,
    ties,
    usable_rows,
)
from rlpgo_gtsam.residuals import variance_factor
from rlpgo_gtsam.rl.models import DEFAULT_MODEL, model_path
from rlpgo_gtsam.robust.settings import RobustSettings
from rlpgo_gtsam.staged import DEFAULT_BUDGET_S, DEFAULT_SEARCHES, staged_initialize

if TYPE_CHECKING:
    from rlpgo_gtsam.robust.results import Step

# --method all: every initializer, and the agent from each classical start; on a 3D graph
# the 3D rows (comparison_methods).
ALL = [*CLASSICAL, "fastsync", "certified", *(f"rl@{s}" for s in (*CLASSICAL, "certified"))]
# Options of the staged default and the methods, which --robust does not use.
NOT_ROBUST = ("budget", "model", "cycles", "episodes", "start", "iters", "seed")
# --false-rejections' default in --help: the library's (its settings import without the
# robust path)
FALSE_REJECTIONS_DEFAULT = RobustSettings.false_rejection_rate
# The agent's options (--start, read by --method rl alone, is checked on its own).
AGENT_OPTIONS = ("model", "cycles", "episodes", "seed")


def _progress_bar():
    """A callback drawing one stderr progress bar per agent rollout (long graphs only)."""
    bars: dict = {}

    def progress(done: int, total: int) -> None:
        if total < 20_000:  # small graphs finish in about a second
            return
        if "bar" not in bars:
            bars["bar"] = click.progressbar(length=total, label="agent",
                                            file=sys.stderr)
            bars["bar"].__enter__()
        bar = bars["bar"]
        bar.update(done - bar.pos)
        if done >= total:
            bar.__exit__(None, None, None)
            del bars["bar"]

    return progress


def _check_method_name(method: str, start: str) -> None:
    """A usage error for a --method that is no method of any group."""
    name = f"rl@{start}" if method == "rl" else method
    if method in ("auto", "all"):
        return
    try:
        check_method(name)
    except RlpgoError as error:
        raise click.BadParameter(str(error), param_hint="--method") from None


def _method_list(method: str, start: str, group: Group, input_path: Path) -> list[str]:
    """The methods --method runs on a graph of ``group``; a method that does not take it is
    an error that names the file."""
    if method == "auto":
        return ["certified", *(name for name, _ in DEFAULT_SEARCHES)]
    if method == "all":
        return ALL if group is SE2 else comparison_methods(group)
    try:
        check_method(method, group)
    except RlpgoError as error:
        raise RlpgoError(f"{input_path} holds a {group.kind} pose graph: {error}") from None
    return [f"rl@{start}" if method == "rl" else method]


def _check_agent_options(ctx: click.Context, input_path: Path, group: Group) -> None:
    """The agent's options name nothing on a graph the agent does not take (it is planar)."""
    given = [f"--{name}" for name in (*AGENT_OPTIONS, "start") if _given(ctx, name)]
    if given and "rl" not in initializer_names(group):
        raise RlpgoError(f"{input_path} holds a {group.kind} pose graph, and the agent is "
                         f"planar (it runs on 2D graphs only): {', '.join(given)} cannot apply")


def _ranking(results: list[MethodResult]) -> list[tuple[str, MethodResult]]:
    """Rows by refined chi2 with their rank; rows that tie (:func:`~rlpgo_gtsam.ranking.ties`)
    share a rank, shown as ``=k``, in the order they ran (the first is the one
    written); failed rows last, unranked."""
    usable = usable_rows(results)
    refined = {id(r): float(r.refined_chi2) for r in usable if r.refined_chi2 is not None}
    ordered = sorted(usable, key=lambda r: refined[id(r)])
    groups: list[list[MethodResult]] = []
    for r in ordered:
        if groups and ties(refined[id(r)], refined[id(groups[-1][0])]):
            groups[-1].append(r)
        else:
            groups.append([r])
    ranked: list[tuple[str, MethodResult]] = []
    for group in groups:
        label = f"={len(ranked) + 1}" if len(group) > 1 else str(len(ranked) + 1)
        ranked.extend((label, r) for r in sorted(group, key=results.index))
    return ranked + [("-", r) for r in results if r not in usable]


def _row_header(width: int) -> str:
    return f"{'method':<{width}}{'guess chi2':>14}{'result chi2':>14}{'seconds':>9}"


def _print_row(row: MethodResult, width: int = 14) -> None:
    """One method's row of --method all, printed as soon as the method is done."""
    guess = "-" if row.init_chi2 is None else f"{row.init_chi2:.6g}"
    result = "-" if row.refined_chi2 is None else f"{row.refined_chi2:.6g}"
    tail = f"  FAILED: {row.failure}" if row.failure else ""
    click.echo(f"{row.method:<{width}}{guess:>14}{result:>14}{row.seconds:>9.2f}{tail}")


def _stages_budget(budget: float, command_began: float) -> float:
    """What --budget leaves the stages: the whole budget less the time spent so far (options,
    reading, extraction) and as much again for writing the guess, which costs about what
    reading did; at least a tenth of the budget, so that a run always has a guess."""
    spent = time.perf_counter() - command_began
    return max(budget - 2.0 * spent, 0.1 * budget)


def _print_progress(method: str, line: str) -> None:
    click.echo(f"  {method}: {line}")


def _given(ctx: click.Context, name: str) -> bool:
    """Whether the user gave option ``name`` (not its default)."""
    return ctx.get_parameter_source(name) not in (
        None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)


def _check_method_options(ctx: click.Context, method: str) -> None:
    """A usage error for options that would change nothing: agent options when no method
    of the run is the agent (rl, rl@<start>, all on a planar graph), --start without
    --method rl, --budget without --method auto."""

    agent = method in ("all", "rl") or method.startswith("rl@")
    unused = [] if agent else [f"--{name}" for name in AGENT_OPTIONS if _given(ctx, name)]
    if method != "rl" and _given(ctx, "start"):
        unused.append("--start")
    if method != "auto" and _given(ctx, "budget"):
        raise click.UsageError(f"--budget bounds --method auto; --method {method} runs "
                               "every method it names to its end")
    if unused:
        runs = "runs no agent" if method == "auto" else f"{method} is not the agent"
        raise click.UsageError(f"{', '.join(unused)}: options of the agent (--method rl, "
                               f"rl@<start>, all); --method {method}: {runs}")


def _check_robust_options(ctx: click.Context, robust: bool, method: str, refine: str,
                          outliers_out: Path | None) -> None:
    """Usage errors for options that do not go with --robust, or need it."""

    if not robust:
        if outliers_out is not None:
            raise click.UsageError("--outliers-out lists the edges --robust rejects: give "
                                   "--robust too")
        if _given(ctx, "trust_odometry"):
            raise click.UsageError("--trust-odometry/--no-trust-odometry apply only with --robust")
        if _given(ctx, "covariance_scale"):
            raise click.UsageError("--covariance-scale applies only with --robust (the tests "
                                   "that judge loop closures)")
        if _given(ctx, "false_rejections"):
            raise click.UsageError("--false-rejections applies only with --robust (the tests "
                                   "that judge loop closures)")
        return
    if method != "auto":
        raise click.UsageError(f"--robust is its own method: it does not combine with --method "
                               f"{method}")
    refused = [f"--{name}" for name in NOT_ROBUST if _given(ctx, name)]
    if refine != "none" and _given(ctx, "refine"):
        refused.append(f"--refine {refine}")
    if refused:
        raise click.UsageError(f"{', '.join(refused)}: not used with --robust (it writes "
                               "GNC-LM's guess, already refined on the edges it kept)")


# --robust's hint: the kept edges' variance factor above this (over --covariance-scale). On
# the robust benchmark's cases with their covariances as given (benchmarks/robust_fit.py, 102
# runs) it was at most 1.07 where no wrong closure was kept (gen), and 1.61, 1.78 and 3.10 on
# MIT's `local` runs at 5, 20 and 30%, which kept 2, 8 and 17.
LOOSE_FIT = 1.5


def _describe_step(step: Step) -> str:
    """One line on a step of the robust path (``RobustResult.steps``)."""
    from rlpgo_gtsam.robust.results import AllEdgesStep, JudgedStep  # a robust run's only

    if isinstance(step, AllEdgesStep):
        if step.skipped:  # not needed
            return f"step {step.name}: skipped: {step.skipped}"
        verdict = "every edge fits, nothing rejected" if step.passed else "not every edge fits"
        worst = step.worst_edge_chi2
        judged = "" if worst is None else f", worst edge chi2 {worst:.4g}"
        return (f"step {step.name}: certified {step.certified}{judged}: {verdict}; "
                f"{step.seconds:.2f} s")
    if not isinstance(step, JudgedStep):
        return f"step {step.name}: {step.seconds:.2f} s"
    shown = ("step", "seconds", "judged", "kept", "rejected")
    text = (f"step {step.name}: kept {step.kept} of {step.judged} edges judged, rejected "
            f"{step.rejected}; {step.seconds:.2f} s")
    return text + "".join(f"; {key.replace('_', ' ')} {value}"
                          for key, value in step.record().items()
                          if key not in shown and value is not None)


def _few(indices: list[int], limit: int = 5) -> str:
    shown = ", ".join(str(k) for k in indices[:limit])
    return shown + (f", ... ({len(indices)})" if len(indices) > limit else "")


def _print_notes(notes: list[str]) -> None:
    for note in notes:
        click.echo(f"note: {note}")


def _run_robust(input_path: Path, output: Path, outliers_out: Path | None,
                trust_odometry: bool, json_path: Path | None,
                covariance_scale: float = 1.0,
                false_rejections: float | None = None) -> None:
    # not on the default's path
    from rlpgo_gtsam.robust import robust_initialize

    if outliers_out is not None and is_pyfg(input_path):
        raise RlpgoError(f"--outliers-out lists edges by their g2o lines; {input_path} is a "
                         "PyFG file")
    run = RunFiles([input_path])
    run.check(output, outliers_out, json_path)  # fail before the work, not after
    read = read_input(input_path)
    graph, values, lines, notes = read.graph, read.values, read.lines, read.notes
    check_graph_output(output, graph)
    _print_notes(notes)
    began = time.perf_counter()
    pose_graph = read.pose_graph()
    rate = FALSE_REJECTIONS_DEFAULT if false_rejections is None else false_rejections
    if pose_graph.dimension == 3:  # the robust path takes what it can: its error otherwise
        try:
            result = robust_initialize(graph, values, trust_odometry=trust_odometry,
                                       covariance_scale=covariance_scale,
                                       false_rejection_rate=rate)
        except RlpgoError as error:
            raise RlpgoError(f"--robust on {input_path} (a 3D pose graph): {error}") from None
    else:
        result = robust_initialize(graph, values, trust_odometry=trust_odometry,
                                   pose_graph=pose_graph, covariance_scale=covariance_scale,
                                   false_rejection_rate=rate)
    for step in result.steps:
        click.echo(_describe_step(step))
    for kept, other in result.ambiguous:
        click.echo(f"ambiguous: {len(kept)} loop closures kept conflict with {len(other)} "
                   "others that agree among themselves and are nearly as well supported; the "
                   f"map's fit decided (kept factors {_few(kept)}; the others {_few(other)})")
    judged = pose_graph.num_edges - len(result.trusted)
    if result.doubtful:
        click.echo(f"doubtful: {len(result.doubtful)} of the {judged - len(result.rejected)} "
                   f"loop closures kept fit the map poorly (p < "
                   f"{RobustSettings.doubtful_below:g}; where the "
                   "covariances state "
                   "the noise, 1 in 20 true closures does too): not rejected, and not told "
                   "apart from wrong ones, worst first: factors "
                   f"{_few([k for k, _ in result.doubtful])}"
                   + ("; their p-values are in --json" if json_path is not None else ""))
    fit = variance_factor(pose_graph, result.chi2, pose_graph.num_edges - len(result.rejected))
    hint = None
    if result.rejected and fit is not None and fit > LOOSE_FIT * covariance_scale:
        hint = (f"the edges kept fit {fit / covariance_scale:.3g} times worse than their "
                "covariances say (chi2 over its degrees of freedom): wrong loop closures "
                "remain among them, or the covariances understate the noise and true ones "
                "were rejected; --covariance-scale says by how much (docs/robust.md)")
        click.echo(f"hint: {hint}")
    # every edge, new vertices
    files = [(output, graph_text(output, graph, result.values, pose_graph,
                                 read.times).encode())]
    if outliers_out is not None:
        listed = edge_list_text(graph, result.rejected, lines, g2o_name=input_path.name,
                                title="edges that rlpgo-init --robust judged wrong")
        # a file name that is not UTF-8 comes back as the bytes it was
        files.append((outliers_out, listed.encode("utf-8", "surrogateescape")))
    seconds = time.perf_counter() - began
    if json_path is not None:
        files.append((json_path, json_text({
            "input": str(input_path), "output": str(output), "dimension": pose_graph.dimension,
            "poses": pose_graph.num_poses, "edges": pose_graph.num_edges, "method": "robust",
            "input_chi2": chi2(graph, values), "chi2": result.chi2, "judged": judged,
            "variance_factor": fit, "covariance_scale": covariance_scale,
            "false_rejection_rate": rate, "hint": hint,  # the rate used, given or not
            "rejected": list(result.rejected),
            "doubtful": [{"factor": k, "p_value": p} for k, p in result.doubtful],
            "steps": [step.record() for step in result.steps], "seconds": seconds,
            "notes": notes}).encode()))
    run.write_together(files)  # the guess, its list and its record, or none
    what = "loop closures" if trust_odometry else "edges"
    also = "" if outliers_out is None else f" and {outliers_out}"
    click.echo(f"rejected {len(result.rejected)} of {judged} {what} as wrong; chi2 "
               f"{result.chi2:.6g} on the edges kept; {seconds:.2f} s; wrote {output}{also}")


def _print_stage(row: MethodResult, reason: str) -> None:
    guess = "-" if row.init_chi2 is None else f"{row.init_chi2:.6g}"
    result = "-" if row.refined_chi2 is None else f"{row.refined_chi2:.6g}"
    click.echo(f"stage {row.method}: guess chi2 {guess}, result chi2 {result}, "
               f"{row.seconds:.2f} s"
               f" ({reason})" + (f"  FAILED: {row.failure}" if row.failure else ""))
    if row.init is not None and row.init.certificate is not None:
        click.echo(f"  certificate: {row.init.certificate.describe()}")


@click.command(cls=RlpgoCommand)
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=OutputFile(), required=True,
              help="File to write (never the input): PyFG if its name ends in .pyfg, else "
                   "g2o (which has no line for ranges).")
@click.option("--method", default="auto", show_default=True,
              help="auto (certify, then refine), all (every method, keep the lowest chi2), rl, "
                   "rl@<start>, or one initializer: " + ", ".join(
                       [*CLASSICAL, "fastsync", "certified"]) + "; on a 3D graph auto, all "
                   "or one of " + ", ".join(initializer_names(SE3)) + ".")
@click.option("--budget", type=FiniteFloat(0.0, 1e6), default=DEFAULT_BUDGET_S,
              show_default=True,
              help="--method auto: the whole run's time limit, the certified stage's included; "
                   "cut short, it writes the best estimate so far and says what was cut.")
@click.option("--refine", type=click.Choice(["none", "gn", "lm"]), default="lm",
              show_default=True, help="GTSAM refinement of the guess that is written. "
              "--robust writes GNC-LM's guess, already refined on the edges it kept: with it "
              "only none may be given, and changes nothing.")
@click.option("--iters", type=ITERATIONS, default=30, show_default=True,
              help="Iteration cap of the refinement.")
@click.option("--json", "json_path", type=OutputFile(),
              help="Also write the run as JSON: the input, the result's chi2 and its variance "
                   "factor (chi2 over its degrees of freedom: above 1, covariances that "
                   "understate the noise, or wrong closures), certificate status and seconds, "
                   "and every row (written with OUTPUT, or neither).")
@click.option("--robust", is_flag=True,
              help="Reject wrong loop closures instead of running --method: a start from the "
                   "closures that agree with each other, finished by GTSAM's GNC-LM. The "
                   "graph written keeps every edge of the input.")
@click.option("--trust-odometry/--no-trust-odometry", default=True, show_default=True,
              help="With --robust: the odometry chain (edges between ids adjacent in sorted "
                   "order, completed in file order to a spanning tree) is known inliers; "
                   "--no-trust-odometry judges it like loop closures.")
@click.option("--outliers-out", type=OutputFile(),
              help="With --robust: a text file listing the rejected edges, one a line as "
                   f"'{EDGE_LIST_LINE}' (L: the edge's line in INPUT, from 1; a g2o INPUT "
                   "only), after one '#' line.")
@click.option("--covariance-scale", type=FiniteFloat(0.0, 1e6, min_open=True), default=1.0,
              show_default=True,
              help="With --robust: how many times larger the edges' noise is than their "
                   "covariances say (a front end's optimistic covariances); the tests that "
                   "judge loop closures use each covariance times this. The map and its chi2 "
                   "are those of INPUT as written.")
@click.option("--false-rejections", type=FiniteFloat(0.0, 1.0, max_open=True), default=None,
              help="With --robust: the expected share of true loop closures among those it "
                   "rejects beyond the chi-square bar (adaptive Benjamini-Hochberg; default "
                   f"{FALSE_REJECTIONS_DEFAULT}, the library's); 0 rejects a closure only "
                   "past that bar.")
@click.option("--model", default=DEFAULT_MODEL, show_default=True,
              help="[agent] A shipped model name or a model file (--method rl, rl@<start>, "
                   "all).")
@click.option("--cycles", type=click.IntRange(1, 10_000), default=None,
              help="[agent] Passes over the edges [default: the model's test cycles].")
@click.option("--episodes", type=ROLLOUTS, default=1, show_default=True,
              help="[agent] Rollouts differing in their initial last action; lowest chi2 "
                   "kept.")
@click.option("--start", type=click.Choice(start_names(SE2)), default="odometry",
              show_default=True,
              help="[agent] Orientations the agent starts from (with --method rl).")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="[agent] Seed of the rollouts' initial last actions.")
@click.pass_context
def main(ctx, input_path, output, method, budget, model, cycles, episodes, start, refine,
         iters, json_path, seed, robust, trust_odometry, outliers_out, covariance_scale,
         false_rejections):
    """Write an initial guess for INPUT (a g2o file, or a PyFG file, .pyfg, as CORA reads;
    planar or 3D) to OUTPUT.

    The default, --method auto, runs the certified SE(d) relaxation, refines its estimate
    with --refine and writes it; the certificate says whether it is the global optimum (if
    not, a hint follows when wrong loop closures are likely). No search runs after it: on
    graphs it did not certify, none lowered the chi2 (rlpgo_gtsam/staged.py). --budget
    bounds the whole run. --method all runs every initializer, prints each row as it is
    done, then the ranking. The paper's behaviour is --method rl --start odometry --refine
    none (planar graphs: the agent is planar). --robust rejects wrong loop closures and
    writes the guess from the edges kept. A 3D file (VERTEX_SE3:QUAT, EDGE_SE3:QUAT) is
    told from its lines and written back as one. A PyFG output keeps the input's
    timestamps.
    """
    command_began = time.perf_counter()
    _check_robust_options(ctx, robust, method, refine, outliers_out)
    if robust:
        _run_robust(input_path, output, outliers_out, trust_odometry, json_path,
                    covariance_scale, false_rejections)
        return
    _check_method_name(method, start)
    _check_method_options(ctx, method)
    group = input_group(input_path)
    _check_agent_options(ctx, input_path, group)
    methods = _method_list(method, start, group, input_path)
    run = RunFiles([input_path])
    uses_agent = any(m.partition("@")[0] == "rl" for m in methods)
    if uses_agent:
        run.add_input(model_path(model))
    run.check(output, json_path)  # fail before minutes of work, not after
    if uses_agent:
        from rlpgo_gtsam.rl.models import resolve_model

        resolve_model(model)  # a bad --model is an error, not a row of failed methods
    read = read_input(input_path)
    graph, values = read.graph, read.values
    check_graph_output(output, graph)
    _print_notes(read.notes)
    began = time.perf_counter()
    pose_graph = read.pose_graph()
    solver = None if refine == "none" else refine
    options = line_progress_options(_print_progress)
    options["rl"] = {"model": model, "cycles": cycles, "episodes": episodes, "seed": seed,
                     "progress": _progress_bar()}
    if method == "auto":
        stages_budget = _stages_budget(budget, command_began)
        staged = staged_initialize(graph, values, solver=solver or "lm",
                                   iters=iters if solver else 0,
                                   budget_s=stages_budget,
                                   options=options, dataset=input_path.name,
                                   pose_graph=pose_graph, on_stage=_print_stage)
        share = "" if "budget" not in staged.stopped else (
            f" (the stages' share of --budget {budget:g} s after reading {input_path.name},"
            " with as much again kept for writing)")
        click.echo(f"stopped: {staged.stopped}{share}")
        if staged.hint is not None:
            click.echo(f"hint: {staged.hint}")
        results, chosen = staged.rows, staged.best
    else:
        from rlpgo_cli.compare import method_width  # rlpgo-compare's table: not the default's

        several = len(methods) > 1
        width = method_width(methods)
        if several:
            click.echo(_row_header(width))
        results = compare_methods(graph, values, methods, solver, iters,
                                  dataset=input_path.name, options=options,
                                  pose_graph=pose_graph,
                                  on_row=functools.partial(_print_row, width=width)
                                  if several else None)
        chosen = best_of(results)
        if several:
            click.echo("ranking: " + ", ".join(f"{rank} {r.method}" for rank, r in
                                               _ranking(results)))
        elif chosen.init.certificate is not None:
            click.echo(f"certificate: {chosen.init.certificate.describe()}")
    files = [(output, graph_text(output, graph, chosen.refined, pose_graph,
                                 read.times).encode())]
    seconds = time.perf_counter() - began
    input_chi2 = chi2(graph, values)
    if json_path is not None:
        certificate = None if chosen.init is None else chosen.init.certificate
        files.append((json_path, json_text({
            "input": str(input_path), "output": str(output), "dimension": pose_graph.dimension,
            "poses": pose_graph.num_poses, "edges": pose_graph.num_edges, "method": method,
            "input_chi2": input_chi2, "result": chosen.method,
            "refine": solver, "iters": iters if solver else 0, "chi2": chosen.refined_chi2,
            "variance_factor": variance_factor(pose_graph, chosen.refined_chi2),
            "certified": staged.certified if method == "auto" else (
                None if certificate is None else bool(certificate.certified)),
            "status": None if certificate is None else str(certificate.status),
            "stopped": staged.stopped if method == "auto" else None,
            "hint": staged.hint if method == "auto" else None,
            "seconds": seconds, "notes": read.notes,
            "rows": [row.record() for row in results]}).encode()))
    run.write_together(files)  # the guess and its record, or neither
    step = "" if solver is None else f" + {solver.upper()}{iters}"
    if chosen.cut is not None:
        step += f" (cut after {chosen.iters})"
    click.echo(f"input chi2 {input_chi2:.6g}; {chosen.method}{step}: chi2 "
               f"{chosen.refined_chi2:.6g}; {seconds:.2f} s; wrote {output}")


if __name__ == "__main__":
    main()
