"""The agent's hyper-parameters, importable without torch (the CLI shows their defaults)."""

from __future__ import annotations

from dataclasses import dataclass

from rlpgo_gtsam.rl.episode import ACTION_SIZE

__all__ = ["SacConfig"]


@dataclass(frozen=True)
class SacConfig:
    """Hyper-parameters of the agent.

    Attributes:
        hidden: width of every layer and of the LSTMs (the paper: 512).
        learning_rate: Adam step size of all networks and of the temperature.
        batch_size: episodes per gradient step.
        gradient_steps: gradient steps after each collected episode.
        gamma: discount (the paper: 1.0; below 1 keeps the Q targets bounded).
        tau: Polyak factor of the target critics.
        reward_scale: rewards are multiplied by this inside the critic targets only.
        target_entropy: of the automatic temperature (the paper: -2, minus the action size).
        initial_alpha: the temperature at the start.
        window: steps per sampled sequence (a window cut from a stored episode).
        burn_in: steps at the start of a window that only warm up the LSTM state.
        replay_episodes: capacity of the episode replay.
        warmup_episodes: episodes of uniformly random actions before learning starts.
    """

    # networks and their optimizer
    hidden: int = 64
    learning_rate: float = 3e-4

    # updates: how many, on what
    batch_size: int = 64
    gradient_steps: int = 16
    window: int = 40
    burn_in: int = 10

    # soft actor-critic targets and temperature
    gamma: float = 0.99
    tau: float = 0.01
    reward_scale: float = 0.01
    target_entropy: float = -float(ACTION_SIZE)
    initial_alpha: float = 0.1

    # replay
    replay_episodes: int = 2000
    warmup_episodes: int = 10
