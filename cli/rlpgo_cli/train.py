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
from rlpgo_gtsam.rl.episode import CHOICES, PRESETS, EnvConfig
from rlpgo_gtsam.rl.models import MAX_HIDDEN

_ENV_FIELDS = {name: type(value) for name, value in
               ((f, getattr(EnvConfig(), f)) for f in EnvConfig.__dataclass_fields__)}


class EnvSetting(click.ParamType):
    """``KEY=VALUE`` for one EnvConfig field, the value read as that field's type."""

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
        if kind is str:
            if text not in CHOICES.get(key, ()):
                self.fail(f"{key}: expected one of {', '.join(CHOICES[key])}, got {text!r}",
                          param, ctx)
            return key, text
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
@click.option("--env", "env_settings", type=EnvSetting(), multiple=True,
              help="Override one training-environment field, KEY=VALUE (repeatable), e.g. "
                   "observation=rich, reward=chi2, oc_shaping=0.1, keep=chi2, n=200, "
                   "sigma_r=0.3, sigma_r_max=0.6, sigma_t=0.05, d=3, cycles=2, "
                   "start=certified, noisy_measurements=true.")
@click.option("--pool-graphs", type=click.IntRange(0, 100_000), default=0, show_default=True,
              help="Draw episodes from this many generated graphs with their classical "
                   "(certified + LM) starts, computed once and cached in <out>.pool.npz "
                   "(0: a new graph every episode).")
@click.option("--validation", "validation_metric", type=click.Choice(["oc", "chi2"]),
              default="oc", show_default=True,
              help="What validation measures: best-OC ratio from dead reckoning, or chi2 "
                   "after LM from the classical optimum (the arena's criterion).")
@click.option("--initial-last-action", type=click.Choice(["uniform", "zero"]),
              default="uniform", show_default=True,
              help="The last action a training episode starts with.")
@click.option("--reward-scale", type=FiniteFloat(0.0, 1e6, min_open=True),
              default=SacConfig.reward_scale, show_default=True,
              help="Rewards are multiplied by this in the critic targets.")
@click.option("--fresh-critic-features", is_flag=True,
              help="The actor loss uses the critics' features recomputed after their step.")
@click.option("--burn-in-prefix", is_flag=True,
              help="Burn-in steps come before each window and carry no gradients (R2D2).")
def main(preset, episodes, seed, out, resume, hidden, batch_size, gradient_steps,
         noisy_measurements, validation_graphs, env_settings, pool_graphs, validation_metric,
         initial_last_action, reward_scale, fresh_critic_features, burn_in_prefix):
    """Train an agent; writes <out>.zip (the model), <out>.csv and <out>.png (the log)."""
    from rlpgo_gtsam.rl.train import TrainConfig, train

    out = str(out or f"models/preset{preset}")
    stem = Path(out)
    outputs = [stem.with_name(stem.name + suffix) for suffix in (".zip", ".csv", ".png",
                                                                 ".train.pt")]
    if stem.parent.exists():  # train() creates a missing folder; its files are checked here
        RunFiles().check(*outputs)
    for path in outputs:
        check_name(path)
    env_overrides = {"noisy_measurements": True} if noisy_measurements else {}
    env_overrides |= dict(env_settings)
    config = TrainConfig(
        preset=preset, episodes=episodes, seed=seed, out=out,
        sac=SacConfig(hidden=hidden, batch_size=batch_size, gradient_steps=gradient_steps,
                      reward_scale=reward_scale, fresh_critic_features=fresh_critic_features,
                      burn_in_prefix=burn_in_prefix),
        env_overrides=env_overrides,
        validation_graphs=validation_graphs,
        command=shlex.join(["rlpgo-train", *sys.argv[1:]]),
        pool_graphs=pool_graphs, validation=validation_metric,
        initial_last_action=initial_last_action,
    )
    if validation_metric == "chi2" and not validation_graphs:
        raise click.UsageError("--validation chi2 needs --validation-graphs > 0")
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
