"""Replay of whole episodes, sampled as sequences for the recurrent networks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["EpisodeBatch", "EpisodeReplay"]


@dataclass
class EpisodeBatch:
    """A batch of ``B`` windows of ``T`` steps cut from stored episodes.

    Attributes:
        observations: (B, T + 1, 4) the observation before each step and after the last
            (:data:`~rlpgo_gtsam.rl.episode.OBSERVATION_SIZE` numbers each).
        last_actions: (B, T + 1, 2) the action before each observation (index 0: the
            episode's initial "last action").
        actions: (B, T, 2) the action taken at each step.
        rewards: (B, T, 1).
        dones: (B, T, 1) 1.0 on the episode's final step (no bootstrap past it) and on
            the padding after it.
    """

    observations: torch.Tensor
    last_actions: torch.Tensor
    actions: torch.Tensor
    rewards: torch.Tensor
    dones: torch.Tensor


class EpisodeReplay:
    """A ring buffer of whole episodes (their lengths vary with the sampled graph)."""

    def __init__(self, capacity: int, rng: np.random.Generator) -> None:
        self.capacity = capacity
        self.rng = rng
        self.episodes: list[dict[str, np.ndarray]] = []
        self.position = 0

    def __len__(self) -> int:
        return len(self.episodes)

    def add(self, observations, last_actions, actions, rewards) -> None:
        """Store one finished episode (arrays of T + 1, T + 1, T and T rows)."""
        episode = {
            "observations": np.asarray(observations, np.float32),
            "last_actions": np.asarray(last_actions, np.float32),
            "actions": np.asarray(actions, np.float32),
            "rewards": np.asarray(rewards, np.float32).reshape(-1, 1),
        }
        if len(self.episodes) < self.capacity:
            self.episodes.append(episode)
        else:
            self.episodes[self.position] = episode
        self.position = (self.position + 1) % self.capacity

    def sample(
        self, batch_size: int, window: int, burn_in: int
    ) -> tuple[EpisodeBatch, torch.Tensor]:
        """``batch_size`` windows of ``window`` steps from random episodes and offsets.

        The LSTMs run over each window from a zero state; the first ``burn_in`` steps of a
        window that does not open its episode only warm that state up: the returned
        (B, window, 1) mask is zero there, and after an episode's end.
        """
        width = self.episodes[0]["observations"].shape[1]
        observations = np.zeros((batch_size, window + 1, width), np.float32)
        last_actions = np.zeros((batch_size, window + 1, 2), np.float32)
        actions = np.zeros((batch_size, window, 2), np.float32)
        rewards = np.zeros((batch_size, window, 1), np.float32)
        dones = np.ones((batch_size, window, 1), np.float32)
        mask = np.zeros((batch_size, window, 1), np.float32)
        for b, k in enumerate(self.rng.integers(len(self.episodes), size=batch_size)):
            episode = self.episodes[k]
            steps = len(episode["actions"])
            start = int(self.rng.integers(steps))
            end = min(start + window, steps)
            length = end - start
            observations[b, : length + 1] = episode["observations"][start : end + 1]
            last_actions[b, : length + 1] = episode["last_actions"][start : end + 1]
            actions[b, :length] = episode["actions"][start:end]
            rewards[b, :length] = episode["rewards"][start:end]
            dones[b, :length] = 0.0
            if end == steps:
                dones[b, length - 1] = 1.0
            mask[b, (0 if start == 0 else min(burn_in, length)) : length] = 1.0
        batch = EpisodeBatch(*(torch.from_numpy(a) for a in (observations, last_actions, actions,
                                                               rewards, dones)))
        return batch, torch.from_numpy(mask)
