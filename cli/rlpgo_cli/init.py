"""rlpgo-init: write an initial guess for a g2o pose graph (same edges, new vertices)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import ITERATIONS, ROLLOUTS, SEED, FiniteFloat, OutputFile
from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.g2o import EDGE_LIST_LINE, edge_list_text, g2o_text, read_g2o, read_g2o_lines
from rlpgo_gtsam.graph import PoseGraph2D, chi2
from rlpgo_gtsam.initializers import CLASSICAL, check_method, start_names
from rlpgo_gtsam.ranking import (
    MethodResult,
    best_of,
    compare_methods,
    line_progress_options,
    ties,
    usable_rows,
)
from rlpgo_gtsam.rl.models import DEFAULT_MODEL, model_path
from rlpgo_gtsam.robust import robust_initialize
from rlpgo_gtsam.staged import DEFAULT_BUDGET_S, DEFAULT_SEARCHES, staged_initialize

# --method all: every initializer, and the agent from each classical start.
ALL = [*CLASSICAL, "fastsync", "certified", *(f"rl@{s}" for s in (*CLASSICAL, "certified"))]
# Options of the staged default and the methods, which --robust does not use.
NOT_ROBUST = ("budget", "model", "cycles", "episodes", "start", "iters", "seed")
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


def _method_list(method: str, start: str) -> list[str]:
    if method == "auto":
        return ["certified", *(name for name, _ in DEFAULT_SEARCHES)]
    if method == "all":
        return ALL
    name = f"rl@{start}" if method == "rl" else method
    try:
        check_method(name)
    except RlpgoError as error:
        raise click.BadParameter(str(error), param_hint="--method") from None
    return [name]


def _ranking(results: list[MethodResult]) -> list[tuple[str, MethodResult]]:
    """Rows by refined chi2 with their rank; rows that tie (:func:`~rlpgo_gtsam.ranking.ties`)
    share a rank, shown as ``=k``, in the order they ran (the first is the one
    written); failed rows last, unranked."""
    usable = usable_rows(results)
    ordered = sorted(usable, key=lambda r: r.refined_chi2)
    groups: list[list[MethodResult]] = []
    for r in ordered:
        if groups and ties(r.refined_chi2, groups[-1][0].refined_chi2):
            groups[-1].append(r)
        else:
            groups.append([r])
    ranked: list[tuple[str, MethodResult]] = []
    for group in groups:
        label = f"={len(ranked) + 1}" if len(group) > 1 else str(len(ranked) + 1)
        ranked.extend((label, r) for r in sorted(group, key=results.index))
    return ranked + [("-", r) for r in results if r not in usable]


ROW_HEADER = f"{'method':<14}{'guess chi2':>14}{'result chi2':>14}{'seconds':>9}"


def _print_row(row: MethodResult) -> None:
    """One method's row of --method all, printed as soon as the method is done."""
    guess = "-" if row.init_chi2 is None else f"{row.init_chi2:.6g}"
    result = "-" if row.refined_chi2 is None else f"{row.refined_chi2:.6g}"
    tail = f"  FAILED: {row.failure}" if row.failure else ""
    click.echo(f"{row.method:<14}{guess:>14}{result:>14}{row.seconds:>9.2f}{tail}")


def _print_progress(method: str, line: str) -> None:
    click.echo(f"  {method}: {line}")


def _given(ctx: click.Context, name: str) -> bool:
    """Whether the user gave option ``name`` (not its default)."""
    return ctx.get_parameter_source(name) not in (
        None, click.core.ParameterSource.DEFAULT, click.core.ParameterSource.DEFAULT_MAP)


def _check_method_options(ctx: click.Context, methods: list[str], method: str) -> None:
    """A usage error for options that would change nothing: agent options when no method
    of the run is the agent, --start without --method rl, --budget without --method auto."""

    unused = [] if any(m.partition("@")[0] == "rl" for m in methods) else \
        [f"--{name}" for name in AGENT_OPTIONS if _given(ctx, name)]
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


def _describe_step(step: dict) -> str:
    """One line on a step of the robust path (``RobustResult.steps``)."""
    shown = ("step", "seconds", "judged", "kept", "rejected")
    if "kept" not in step and step.get("skipped"):  # the all-edges check, not needed
        return f"step {step.get('step')}: skipped: {step['skipped']}"
    if "kept" not in step:  # the all-edges check
        verdict = "every edge fits, nothing rejected" if step.get("passed") else \
            "not every edge fits"
        worst = step.get("worst_edge_chi2")
        judged = "" if worst is None else f", worst edge chi2 {worst:.4g}"
        return (f"step {step.get('step')}: certified {step.get('certified')}{judged}: "
                f"{verdict}; {step.get('seconds', 0.0):.2f} s")
    text = (f"step {step.get('step')}: kept {step.get('kept')} of {step.get('judged')} edges "
            f"judged, rejected {step.get('rejected')}; {step.get('seconds', 0.0):.2f} s")
    return text + "".join(f"; {key.replace('_', ' ')} {value}" for key, value in step.items()
                          if key not in shown and value is not None)


def _few(indices: list[int], limit: int = 5) -> str:
    shown = ", ".join(str(k) for k in indices[:limit])
    return shown + (f", ... ({len(indices)})" if len(indices) > limit else "")


def _run_robust(input_path: Path, output: Path, outliers_out: Path | None,
                trust_odometry: bool) -> None:
    run = RunFiles([input_path])
    run.check(output, outliers_out)  # fail before the work, not after
    graph, values, lines = read_g2o_lines(input_path)
    began = time.perf_counter()
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    result = robust_initialize(graph, values, trust_odometry=trust_odometry,
                               pose_graph=pose_graph)
    for step in result.steps:
        click.echo(_describe_step(step))
    for kept, other in result.ambiguous:
        click.echo(f"ambiguous: {len(kept)} loop closures kept conflict with {len(other)} "
                   "others that agree among themselves and are nearly as well supported; the "
                   f"map's fit decided (kept factors {_few(kept)}; the others {_few(other)})")
    files = [(output, g2o_text(graph, result.values).encode())]  # every edge, new vertices
    if outliers_out is not None:
        listed = edge_list_text(graph, result.rejected, lines, g2o_name=input_path.name,
                                title="edges that rlpgo-init --robust judged wrong")
        # a file name that is not UTF-8 comes back as the bytes it was
        files.append((outliers_out, listed.encode("utf-8", "surrogateescape")))
    run.write_together(files)  # the guess and its list, or neither
    seconds = time.perf_counter() - began
    judged = pose_graph.num_edges - len(result.trusted)
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
@click.argument("input_path", metavar="INPUT.g2o", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=OutputFile(), required=True,
              help="g2o file to write (never the input).")
@click.option("--method", default="auto", show_default=True,
              help="auto (certify, then refine), all (every method, keep the lowest chi2), rl, "
                   "rl@<start>, or one initializer: " + ", ".join(
                       [*CLASSICAL, "fastsync", "certified"]) + ".")
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
                   f"'{EDGE_LIST_LINE}' (L: the edge's line in INPUT.g2o, from 1), after one "
                   "'#' line.")
@click.option("--model", default=DEFAULT_MODEL, show_default=True,
              help="[agent] A shipped model name or a model file (--method rl, rl@<start>, "
                   "all).")
@click.option("--cycles", type=click.IntRange(1, 10_000), default=None,
              help="[agent] Passes over the edges [default: the model's test cycles].")
@click.option("--episodes", type=ROLLOUTS, default=1, show_default=True,
              help="[agent] Rollouts differing in their initial last action; lowest chi2 "
                   "kept.")
@click.option("--start", type=click.Choice(start_names()), default="odometry",
              show_default=True,
              help="[agent] Orientations the agent starts from (with --method rl).")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="[agent] Seed of the rollouts' initial last actions.")
@click.pass_context
def main(ctx, input_path, output, method, budget, model, cycles, episodes, start, refine,
         iters, seed, robust, trust_odometry, outliers_out):
    """Write an initial guess for INPUT.g2o to OUTPUT.

    The default, --method auto, runs the certified SE(2) relaxation, refines its estimate
    with --refine and writes it; the certificate says whether it is the global optimum (if
    not, a hint follows when wrong loop closures are likely). No search runs after it: on
    graphs it did not certify, none lowered the chi2 (rlpgo_gtsam/staged.py). --budget
    bounds the whole run. --method all runs every initializer, prints each row as it is
    done, then the ranking. The paper's behaviour is --method rl --start odometry --refine
    none. --robust rejects wrong loop closures and writes the guess from the edges kept.
    """
    _check_robust_options(ctx, robust, method, refine, outliers_out)
    if robust:
        _run_robust(input_path, output, outliers_out, trust_odometry)
        return
    methods = _method_list(method, start)
    _check_method_options(ctx, methods, method)
    run = RunFiles([input_path])
    uses_agent = any(m.partition("@")[0] == "rl" for m in methods)
    if uses_agent:
        run.add_input(model_path(model))
    run.check(output)  # fail before minutes of work, not after
    if uses_agent:
        from rlpgo_gtsam.rl.models import resolve_model

        resolve_model(model)  # a bad --model is an error, not a row of failed methods
    graph, values = read_g2o(input_path)
    began = time.perf_counter()
    pose_graph = PoseGraph2D.from_gtsam(graph, values)
    solver = None if refine == "none" else refine
    options = line_progress_options(_print_progress)
    options["rl"] = {"model": model, "cycles": cycles, "episodes": episodes, "seed": seed,
                     "progress": _progress_bar()}
    if method == "auto":
        staged = staged_initialize(graph, values, solver=solver or "lm",
                                   iters=iters if solver else 0, budget_s=budget,
                                   options=options, dataset=input_path.name,
                                   pose_graph=pose_graph, on_stage=_print_stage)
        click.echo(f"stopped: {staged.stopped}")
        if staged.hint is not None:
            click.echo(f"hint: {staged.hint}")
        results, chosen = staged.rows, staged.best
    else:
        several = len(methods) > 1
        if several:
            click.echo(ROW_HEADER)
        results = compare_methods(graph, values, methods, solver, iters,
                                  dataset=input_path.name, options=options,
                                  pose_graph=pose_graph,
                                  on_row=_print_row if several else None)
        chosen = best_of(results)
        if several:
            click.echo("ranking: " + ", ".join(f"{rank} {r.method}" for rank, r in
                                               _ranking(results)))
        elif chosen.init.certificate is not None:
            click.echo(f"certificate: {chosen.init.certificate.describe()}")
    run.write_g2o(output, graph, chosen.refined)
    seconds = time.perf_counter() - began
    step = "" if solver is None else f" + {solver.upper()}{iters}"
    if chosen.cut is not None:
        step += f" (cut after {chosen.iters})"
    click.echo(f"input chi2 {chi2(graph, values):.6g}; {chosen.method}{step}: chi2 "
               f"{chosen.refined_chi2:.6g}; {seconds:.2f} s; wrote {output}")


if __name__ == "__main__":
    main()
