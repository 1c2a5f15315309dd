"""Training one agent on a preset's generated graphs: TrainConfig + train().

Logs go to a CSV (episode, reward, initial OC, best OC, final OC, seconds), to TensorBoard
when it is installed, and to a PNG of the reward curve; nothing is printed (a caller may
pass ``on_episode`` to show progress). The training state is checkpointed to
``<out>.train.pt`` so that ``resume=True`` continues an interrupted run; the shipped model
``<out>.zip`` holds the actor only.

Outputs are written only at checkpoints, all together (``files.write_together``): the
files on disk always belong to one run and one checkpoint. A new run
(``resume=False``) on an ``out`` that holds an earlier run's files replaces them at its first
checkpoint; stopped before that, it leaves them as they were.
"""

from __future__ import annotations

import csv
import io
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from rlpgo_gtsam.errors import ModelError, RlpgoError
from rlpgo_gtsam.files import write_together
from rlpgo_gtsam.rl.agent.checkpoint import check_env_config, model_bytes
from rlpgo_gtsam.rl.agent.config import SacConfig
from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.agent.sac import Episode, SacAgent, run_episode
from rlpgo_gtsam.rl.env import PoseGraphEnv
from rlpgo_gtsam.rl.episode import PRESETS, EnvConfig
from rlpgo_gtsam.rl.evaluation import initial_and_best_oc

__all__ = ["TrainConfig", "train", "CSV_FIELDS", "VALIDATION_SEED"]

CSV_FIELDS = ["episode", "reward", "initial_oc", "best_oc", "final_oc", "seconds"]
# Generator seeds of the validation graphs: 10000 + k (neither the environment's streams nor
# rlpgo-eval's default 1000 + k use them).
VALIDATION_SEED = 10_000


@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Attributes:
        preset: the paper's training environment, 1..5.
        episodes: episodes to collect in all (including warm-up).
        seed: seeds torch, the graphs and the replay sampling.
        out: path stem: writes ``<out>.zip``, ``<out>.csv``, ``<out>.png``, ``<out>.train.pt``.
        sac: the agent's hyper-parameters.
        env_overrides: environment parameters that replace the preset's
            (e.g. ``{"noisy_measurements": True}``).
        checkpoint_every: episodes between training checkpoints.
        validation_graphs: if > 0, at each checkpoint the deterministic policy runs on this
            many validation graphs (generator seeds ``VALIDATION_SEED + k``) and the shipped
            model is the checkpoint with the lowest mean best-OC / initial-OC; if 0, the
            last checkpoint is shipped.
        command: the command line that started the run, kept in the model's metadata.
    """

    preset: int = 1
    episodes: int = 300
    seed: int = 0
    out: str = "models/preset1"
    sac: SacConfig = field(default_factory=SacConfig)
    env_overrides: dict = field(default_factory=dict)
    checkpoint_every: int = 25
    validation_graphs: int = 0
    command: str = ""

    @property
    def env_config(self) -> EnvConfig:
        unknown = set(self.env_overrides) - set(EnvConfig.__dataclass_fields__)
        if unknown:
            raise RlpgoError(f"unknown environment parameter(s): {', '.join(sorted(unknown))}")
        return replace(PRESETS[self.preset], **self.env_overrides)


def train(
    config: TrainConfig,
    resume: bool = False,
    on_episode: Callable[[int, Episode, float], None] | None = None,
) -> Path:
    """Train, checkpoint and save the model; returns the path of the shipped ``.zip``."""
    torch.set_num_threads(1)
    out = Path(config.out)
    check_env_config(config.env_config, out.with_name(out.name + ".zip"))
    out.parent.mkdir(parents=True, exist_ok=True)
    paths = {s: out.with_name(out.name + s) for s in (".zip", ".csv", ".png", ".train.pt")}
    env = PoseGraphEnv(config.preset, **config.env_overrides)
    agent = SacAgent(config.sac, config.seed)
    rng = np.random.default_rng(config.seed)
    start_episode, elapsed, best_validation = 0, 0.0, float("inf")
    if resume and paths[".train.pt"].exists():
        state = _training_state(paths[".train.pt"], config)
        try:
            agent.load_state_dict(state["agent"])
        except (KeyError, TypeError, ValueError, RuntimeError) as error:
            first = " ".join(str(error).split())[:200]
            raise ModelError(f"{paths['.train.pt']}: training state does not fit this "
                             f"configuration: {first}") from None
        start_episode, elapsed = state["episode"], float(state["seconds"])
        best_validation = float(state.get("best_validation", float("inf")))
        rng = np.random.default_rng([config.seed, start_episode])
    elif resume:
        raise ModelError(f"{paths['.train.pt']}: nothing to resume")
    writer = _tensorboard(out)
    # The log is kept in memory and written atomically with each checkpoint, so that the zip,
    # the CSV and the training state on disk always belong to the same run and episode: an
    # interrupted run leaves the previous checkpoint's files as they were.
    rows = _log_rows(paths[".csv"], start_episode) if start_episode else []
    env.reset(seed=config.seed + start_episode)
    warmup = config.sac.warmup_episodes
    for episode_index in range(start_episode, config.episodes):
        began = time.perf_counter()
        # A resumed run starts with an empty replay (it is not checkpointed): it refills
        # from the current policy, sampled with replacement until it grows.
        episode = run_episode(env, None if episode_index < warmup else agent.actor, rng)
        agent.replay.add(episode.observations, episode.last_actions, episode.actions,
                         episode.rewards)
        losses = agent.update() if episode_index + 1 >= warmup else {}
        elapsed += time.perf_counter() - began
        reward = float(episode.rewards.sum())
        rows.append([episode_index + 1, f"{reward:.4f}", f"{episode.initial_oc:.6g}",
                     f"{episode.best_oc:.6g}", f"{episode.final_oc:.6g}", f"{elapsed:.2f}"])
        if writer is not None:
            writer.add_scalar("episode/reward", reward, episode_index + 1)
            writer.add_scalar("episode/best_oc_ratio",
                              episode.best_oc / max(episode.initial_oc, 1e-12),
                              episode_index + 1)
            if losses:  # "alpha" is the temperature after the round, not a loss
                writer.add_scalar("loss/q", losses["q_loss"], episode_index + 1)
                writer.add_scalar("loss/actor", losses["actor_loss"], episode_index + 1)
                writer.add_scalar("sac/alpha", losses["alpha"], episode_index + 1)
        if on_episode is not None:
            on_episode(episode_index + 1, episode, elapsed)
        done = episode_index + 1
        if done % config.checkpoint_every == 0 or done == config.episodes:
            metadata = _metadata(config, done, elapsed)
            files = []
            if config.validation_graphs:
                score = _validate(agent, config)
                if writer is not None:
                    writer.add_scalar("validation/best_oc_ratio", score, done)
                if score < best_validation:
                    best_validation = score
                    metadata |= {"validation_best_oc_ratio": score, "selected_episode": done}
                    files.append((paths[".zip"], model_bytes(agent.actor, config.env_config,
                                                             metadata)))
            else:
                files.append((paths[".zip"], model_bytes(agent.actor, config.env_config,
                                                         metadata)))
            buffer = io.BytesIO()
            torch.save({"agent": agent.state_dict(), "episode": done, "seconds": elapsed,
                        "best_validation": best_validation}, buffer)
            files += [(paths[".csv"], _log_text(rows).encode()),
                      (paths[".png"], _plot_rewards(rows, config)),
                      (paths[".train.pt"], buffer.getvalue())]
            write_together(files)  # all of a checkpoint's files, or none of them
    if writer is not None:
        writer.close()
    return paths[".zip"]


def _training_state(path: Path, config: TrainConfig) -> dict:
    """The checkpoint at ``path``, loaded without unpickling code and checked field by field.

    Raises:
        ModelError: unreadable, not a dict of the expected fields, or out of range.
    """
    try:
        state = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as error:  # torch raises UnpicklingError, RuntimeError, EOFError, ...
        first = " ".join(str(error).split())[:200] or type(error).__name__
        raise ModelError(f"{path}: not a readable training state ({first})") from None
    if not isinstance(state, dict) or not isinstance(state.get("agent"), dict):
        raise ModelError(f"{path}: not a training state (needs agent, episode, seconds)")
    episode, seconds = state.get("episode"), state.get("seconds")
    if not isinstance(episode, int) or type(episode) is bool or not 0 <= episode <= config.episodes:
        raise ModelError(f"{path}: episode must be an integer in 0..{config.episodes}, "
                         f"got {str(episode)[:40]}")
    if not isinstance(seconds, int | float) or type(seconds) is bool \
            or not 0 <= seconds < float("inf"):
        raise ModelError(f"{path}: seconds must be a finite number >= 0")
    best = state.get("best_validation", float("inf"))
    if type(best) not in (int, float) or best != best:
        raise ModelError(f"{path}: best_validation must be a number")
    return state


def _validate(agent: SacAgent, config: TrainConfig) -> float:
    """Mean best-OC / initial-OC of the deterministic policy on the validation graphs,
    through the rollout and numpy policy that users run."""
    seeds = [VALIDATION_SEED + k for k in range(config.validation_graphs)]
    initial, best = initial_and_best_oc(NumpyPolicy(agent.actor), config.env_config, seeds)
    return float(np.mean([b / max(i, 1e-12) for i, b in zip(initial, best, strict=True)]))


def _metadata(config: TrainConfig, episodes: int, seconds: float) -> dict:
    return {
        "preset": config.preset,
        "seed": config.seed,
        "episodes": episodes,
        "train_seconds": round(seconds, 1),
        "command": config.command,
        "sac": asdict(config.sac),
        "test_cycles": 2 * config.env_config.cycles,
    }


def _tensorboard(out: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is optional: pip install rlpgo-gtsam[train]
        return None
    return SummaryWriter(log_dir=str(out.parent / "runs" / out.name))


def _log_rows(path: Path, episodes: int) -> list[list]:
    """The rows of an earlier run's log up to ``episodes`` (those a resumed run keeps)."""
    try:
        with path.open(newline="") as handle:
            rows = list(csv.reader(handle))[1:]
    except OSError:
        return []
    return [row for row in rows if _log_row(row) and int(row[0]) <= episodes]


def _log_row(row: list[str]) -> bool:
    """A well-formed log row: an episode number and a number per other field (a
    hand-edited or truncated earlier log loses its bad rows, not the resumed run)."""
    if len(row) != len(CSV_FIELDS) or not (row[0].isdigit() and len(row[0]) <= 12):
        return False
    try:
        return all(math.isfinite(float(value)) for value in row[1:])
    except ValueError:
        return False


def _log_text(rows: list[list]) -> str:
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    writer.writerows(rows)
    return text.getvalue()


def _plot_rewards(rows: list[list], config: TrainConfig) -> bytes:
    """The PNG of the reward curve of the log ``rows``."""
    from rlpgo_gtsam.plotting import plot_training_curve

    records = [dict(zip(CSV_FIELDS, map(str, row), strict=True)) for row in rows]
    return plot_training_curve(records, title=f"preset {config.preset}, seed {config.seed}")
