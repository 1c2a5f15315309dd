"""rlpgo-train: train a recurrent SAC agent on one of the paper's training environments."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from rlpgo_cli.errors import RlpgoCommand
from rlpgo_cli.output import RunFiles
from rlpgo_cli.types import COUNT, SEED, FiniteFloat, OutputFile
from rlpgo_gtsam.files import check_name
from rlpgo_gtsam.rl.agent.config import SacConfig
from rlpgo_gtsam.rl.episode import PRESETS, EnvConfig
from rlpgo_gtsam.rl.models import MAX_HIDDEN

_ENV_FIELDS = {name: type(value) for name, value in
               ((f, getattr(EnvConfig(), f)) for f in EnvConfig.__dataclass_fields__)}


class EnvSetting(click.ParamType):
    """``KEY=VALUE`` for one EnvConfig field, the value read as that field's type (ranges
    are checked with the model schema's, before the progress bar shows)."""

    name = "key=value"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        key, sep, text = str(value).partition("=")
        if not sep or key not in _ENV_FIELDS:
            self.fail(f"{value!r}: expected KEY=VALUE with KEY one of "
                      f"{', '.join(_ENV_FIELDS)}", param, ctx)
        kind = _ENV_FIELDS[key]
        if kind is bool:
            if text.lower() not in ("true", "false", "1", "0"):
                self.fail(f"{key}: expected true or false, got {text!r}", param, ctx)
            return key, text.lower() in ("true", "1")
        try:
            number = int(text) if kind is int else FiniteFloat(0.0, 1e6).convert(text, param,
                                                                                   ctx)
        except ValueError:
            self.fail(f"{key}: expected an integer, got {text!r}", param, ctx)
        if kind is int and not 1 <= number <= 1_000_000:
            self.fail(f"{key}: expected an integer in 1..1000000, got {number}", param, ctx)
        return key, number


@click.command(cls=RlpgoCommand)
@click.option("--preset", type=click.IntRange(1, len(PRESETS)), required=True,
              help="The paper's training environment (Table I).")
@click.option("--episodes", type=COUNT, default=300, show_default=True,
              help="Episodes to collect in all, the random warm-up ones included.")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Seeds torch, the training graphs and the replay sampling.")
@click.option("--out", type=OutputFile(), default=None,
              help="Path stem of the outputs [default: runs/presetP]; existing outputs (a "
                   "shipped model included) are refused unless --overwrite or --resume.")
@click.option("--resume", is_flag=True,
              help="Continue from <out>.train.pt, replacing that run's outputs.")
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
@click.option("--env", "env_settings", type=EnvSetting(), multiple=True,
              help="Override one field of the preset's environment, KEY=VALUE (repeatable): "
                   "n, sigma_r, sigma_t, d, lc, cycles, action_range_rad, "
                   "noisy_measurements; e.g. --env n=200 --env cycles=2.")
@click.option("--reward-scale", type=FiniteFloat(0.0, 1e6, min_open=True),
              default=SacConfig.reward_scale, show_default=True,
              help="Rewards are multiplied by this in the critic targets.")
def main(preset, episodes, seed, out, resume, hidden, batch_size, gradient_steps,
         noisy_measurements, validation_graphs, env_settings, reward_scale):
    """Train an agent; writes <out>.zip (the model), <out>.csv and <out>.png (the log)."""
    from rlpgo_gtsam.rl.train import TrainConfig, train

    out = str(out or f"runs/preset{preset}")
    stem = Path(out)
    outputs = [stem.with_name(stem.name + suffix) for suffix in (".zip", ".csv", ".png",
                                                                 ".train.pt")]
    if stem.parent.exists():  # train() creates a missing folder; its files are checked here
        RunFiles(overwrite=True if resume else None).check(*outputs)
    for path in outputs:
        check_name(path)
    env_overrides = {"noisy_measurements": True} if noisy_measurements else {}
    env_overrides |= dict(env_settings)
    config = TrainConfig(
        preset=preset, episodes=episodes, seed=seed, out=out,
        sac=SacConfig(hidden=hidden, batch_size=batch_size, gradient_steps=gradient_steps,
                      reward_scale=reward_scale),
        env_overrides=env_overrides,
        validation_graphs=validation_graphs,
        command=shlex.join(["rlpgo-train", *sys.argv[1:]]),
    )
    from rlpgo_gtsam.rl.agent.checkpoint import check_env_config

    check_env_config(config.env_config, outputs[0])  # before the progress bar shows
    with click.progressbar(length=episodes, label=f"preset {preset}", show_pos=True,
                           item_show_func=lambda text: text) as bar:
        def progress(episode_number, episode, seconds):
            bar.update(1, f"reward {episode.rewards.sum():8.1f}  OC {episode.initial_oc:.3f}"
                          f" -> {episode.best_oc:.3f}  {seconds:6.0f}s")

        path = train(config, resume=resume, on_episode=progress)
    click.echo(f"wrote {path}")


if __name__ == "__main__":
    main()
