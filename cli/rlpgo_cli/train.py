"""rlpgo-train: train a recurrent SAC agent on one of the paper's training environments."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import COUNT, SEED, OutputFile
from rlpgo_gtsam.agent.config import SacConfig
from rlpgo_gtsam.episode import PRESETS
from rlpgo_gtsam.files import check_name
from rlpgo_gtsam.models import MAX_HIDDEN


@click.command(cls=RlpgoCommand)
@click.option("--preset", type=click.IntRange(1, len(PRESETS)), required=True,
              help="The paper's training environment (Table I).")
@click.option("--episodes", type=COUNT, default=300, show_default=True)
@click.option("--seed", type=SEED, default=0, show_default=True)
@click.option("--out", type=OutputFile(), default=None,
              help="Path stem of the outputs [default: models/presetP].")
@click.option("--resume", is_flag=True, help="Continue from <out>.train.pt.")
@click.option("--hidden", type=click.IntRange(4, MAX_HIDDEN), default=SacConfig.hidden,
              show_default=True, help="Width of the layers and LSTMs (the paper: 512).")
@click.option("--batch-size", type=click.IntRange(1, 4096), default=SacConfig.batch_size,
              show_default=True, help="Episodes per gradient step.")
@click.option("--gradient-steps", type=click.IntRange(1, 10_000), default=SacConfig.gradient_steps,
              show_default=True, help="Gradient steps after each episode.")
@click.option("--noisy-measurements", is_flag=True,
              help="Train on graphs with noisy measurements (not in the paper).")
@click.option("--validation-graphs", type=click.IntRange(0, 10_000), default=0, show_default=True,
              help="Ship the checkpoint that does best on this many validation graphs "
                   "(0: ship the last one).")
def main(preset, episodes, seed, out, resume, hidden, batch_size, gradient_steps,
         noisy_measurements, validation_graphs):
    """Train an agent; writes <out>.zip (the model), <out>.csv and <out>.png (the log)."""
    from rlpgo_gtsam.train import TrainConfig, train

    out = str(out or f"models/preset{preset}")
    stem = Path(out)
    outputs = [stem.with_name(stem.name + suffix) for suffix in (".zip", ".csv", ".png",
                                                                 ".train.pt")]
    if stem.parent.exists():  # train() creates a missing folder; its files are checked here
        RunFiles().check(*outputs)
    for path in outputs:
        check_name(path)
    config = TrainConfig(
        preset=preset, episodes=episodes, seed=seed, out=out,
        sac=SacConfig(hidden=hidden, batch_size=batch_size, gradient_steps=gradient_steps),
        env_overrides={"noisy_measurements": True} if noisy_measurements else {},
        validation_graphs=validation_graphs,
        command=shlex.join(["rlpgo-train", *sys.argv[1:]]),
    )
    with click.progressbar(length=episodes, label=f"preset {preset}", show_pos=True,
                           item_show_func=lambda text: text) as bar:
        def progress(episode_number, episode, seconds):
            bar.update(1, f"reward {episode.rewards.sum():8.1f}  OC {episode.initial_oc:.3f}"
                          f" -> {episode.best_oc:.3f}  {seconds:6.0f}s")

        path = train(config, resume=resume, on_episode=progress)
    click.echo(f"wrote {path}")


if __name__ == "__main__":
    main()
