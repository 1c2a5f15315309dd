"""rlpgo-eval: a trained agent against random actions and the edge-balancing rule."""

from __future__ import annotations

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import COUNT, SEED, OutputFile
from rlpgo_gtsam.rl.episode import PRESETS
from rlpgo_gtsam.rl.models import DEFAULT_PRESET_MODEL, model_path, resolve_model


@click.command(cls=RlpgoCommand)
@click.option("--model", default=None,
              help="Shipped model name or model file [default: the preset's shipped agent].")
@click.option("--preset", type=click.IntRange(1, len(PRESETS)), required=True,
              help="The paper's environment (Table I) whose generated graphs are evaluated.")
@click.option("--graphs", type=COUNT, default=50, show_default=True,
              help="Generated graphs to evaluate on, the same for the agent and both controls.")
@click.option("--seed", type=SEED, default=1000, show_default=True,
              help="Graph k is generated with seed + k; also seeds the random control.")
@click.option("--noisy-measurements", is_flag=True, help="Evaluate on noisy-measurement graphs.")
@click.option("--json", "json_path", type=OutputFile(),
              help="Also write the figures to this JSON file.")
def main(model, preset, graphs, seed, noisy_measurements, json_path):
    """Deterministic rollouts on fresh graphs of a preset; mean initial and best OC."""
    from rlpgo_gtsam.rl.evaluation import evaluate

    name = model or DEFAULT_PRESET_MODEL.format(preset=preset)
    run = RunFiles([model_path(name)])
    run.check(json_path)
    loaded = resolve_model(name)
    overrides = {"noisy_measurements": True} if noisy_measurements else {}
    result = evaluate(loaded, preset, graphs, seed, overrides)
    record = {"model": name, **result}
    initial = result["initial_oc_mean"]
    click.echo(f"model {name}, preset {preset}, {graphs} graphs, seed {seed}")
    click.echo(f"{'policy':<16}{'mean best OC':>14}{'/ initial':>11}")
    click.echo(f"{'initial':<16}{initial:>14.4f}{1.0:>11.3f}")
    for label, key in [("agent", "agent_best_oc_mean"), ("random", "random_best_oc_mean"),
                       ("edge balancing", "greedy_best_oc_mean")]:
        click.echo(f"{label:<16}{result[key]:>14.4f}{result[key] / initial:>11.3f}")
    if json_path is not None:
        keys = ["model", "preset", "graphs", "seed", "initial_oc_mean", "agent_best_oc_mean",
                "random_best_oc_mean", "greedy_best_oc_mean"]
        run.write_json(json_path, {k: record[k] for k in keys})


if __name__ == "__main__":
    main()
