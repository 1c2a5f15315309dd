"""Recurrent soft actor-critic (SAC) for the pose-graph environment, read top to bottom.

One update round runs after each episode (the paper's schedule; its code updated once per
environment step). Each gradient step samples windows cut from stored whole episodes, runs
every LSTM over them from a zero state (a short burn-in warms it up where a window starts
mid-episode), and applies the usual SAC losses at every step:

    y_t      = r_t * reward_scale
               + gamma * (1 - done_t) * (min_k Q'_k(s_{t+1}, a') - alpha log pi(a'|s_{t+1}))
    L_Q      = sum_k mean_t (Q_k(s_t, a_t) - y_t)^2
    L_pi     = mean_t alpha log pi(a|s_t) - min_k Q_k(s_t, a),   a ~ pi(.|s_t)
    L_alpha  = mean_t -log_alpha (log pi(a|s_t) + target_entropy)

``done_t`` is 1 on the episode's last step: nothing is bootstrapped past the fixed horizon
(the reference code never set it).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch

from rlpgo_gtsam.rl.agent.buffer import EpisodeBatch, EpisodeReplay
from rlpgo_gtsam.rl.agent.config import SacConfig
from rlpgo_gtsam.rl.agent.networks import Actor, QNetwork
from rlpgo_gtsam.rl.env import PoseGraphEnv
from rlpgo_gtsam.rl.episode import ACTION_SIZE

__all__ = ["SacAgent", "Episode", "run_episode"]


@dataclass
class Episode:
    """What one rollout produced (arrays as stored in the replay) and its outcome."""

    observations: np.ndarray
    last_actions: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    initial_oc: float
    best_oc: float
    final_oc: float


@torch.no_grad()
def run_episode(
    env: PoseGraphEnv,
    policy: Actor | None,
    rng: np.random.Generator,
    *,
    deterministic: bool = False,
    seed: int | None = None,
    options: dict | None = None,
) -> Episode:
    """Roll out one episode; ``policy=None`` takes uniformly random actions.

    The episode's initial "last action" is uniform in [-1, 1]^2 (inference's rollouts
    1..k-1 draw theirs from the same range). The LSTM state is carried from step to step
    here, one edge at a time.
    """
    observation, info = env.reset(seed=seed, options=options)
    last_action = rng.uniform(-1.0, 1.0, ACTION_SIZE).astype(np.float32)
    observations, last_actions, actions, rewards = [observation], [last_action], [], []
    lstm_state = None
    done = False
    while not done:
        if policy is None:
            action = rng.uniform(-1.0, 1.0, ACTION_SIZE).astype(np.float32)
        else:
            obs_t = torch.from_numpy(observation).view(1, 1, -1)
            last_t = torch.from_numpy(last_action).view(1, 1, -1)
            if deterministic:
                action_t, lstm_state = policy.deterministic(obs_t, last_t, lstm_state)
            else:
                action_t, _, lstm_state = policy.sample(obs_t, last_t, lstm_state)
            action = action_t.view(-1).numpy()
        observation, reward, done, _, info = env.step(action)
        observations.append(observation)
        actions.append(action)
        rewards.append(reward)
        last_action = action
        last_actions.append(action)
    return Episode(np.array(observations), np.array(last_actions), np.array(actions),
                   np.array(rewards, np.float32), info["initial_oc"], info["best_oc"], info["oc"])


class SacAgent:
    """Actor, twin critics with target copies, the temperature, and their optimizers."""

    def __init__(self, config: SacConfig, seed: int) -> None:
        torch.manual_seed(seed)
        self.config = config
        self.actor = Actor(config.hidden)
        self.q1 = QNetwork(config.hidden)
        self.q2 = QNetwork(config.hidden)
        self.q1_target, self.q2_target = copy.deepcopy(self.q1), copy.deepcopy(self.q2)
        self.q_optimizer = torch.optim.Adam(
            list(self.q1.parameters()) + list(self.q2.parameters()), lr=config.learning_rate
        )
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.learning_rate)
        self.log_alpha = torch.tensor([np.log(config.initial_alpha)], requires_grad=True)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=config.learning_rate)
        self.replay = EpisodeReplay(config.replay_episodes, np.random.default_rng(seed))

    @property
    def alpha(self) -> float:
        return self.log_alpha.exp().item()

    def update(self) -> dict[str, float]:
        """``gradient_steps`` SAC updates on sampled episodes; returns the last losses."""
        losses: dict[str, float] = {}
        for _ in range(self.config.gradient_steps):
            batch, mask = self.replay.sample(
                self.config.batch_size, self.config.window, self.config.burn_in
            )
            losses = self._gradient_step(batch, mask)
        return losses

    def _gradient_step(self, batch: EpisodeBatch, mask: torch.Tensor) -> dict[str, float]:
        c = self.config
        alpha = self.log_alpha.exp().detach()
        count = mask.sum()
        observations, last_actions = batch.observations, batch.last_actions

        # Critic targets: next actions from the current policy, values from the targets.
        with torch.no_grad():
            next_actions, next_log_prob, _ = self.actor.sample(observations, last_actions)
            state_1, memory_1 = self.q1_target.memory(observations, last_actions)
            state_2, memory_2 = self.q2_target.memory(observations, last_actions)
            next_q = torch.min(
                self.q1_target.value(state_1, memory_1, next_actions),
                self.q2_target.value(state_2, memory_2, next_actions),
            )[:, 1:] - alpha * next_log_prob[:, 1:]
            target = batch.rewards * c.reward_scale + c.gamma * (1.0 - batch.dones) * next_q

        # Critic loss on the actions taken.
        state_1, memory_1 = self.q1.memory(observations, last_actions)
        state_2, memory_2 = self.q2.memory(observations, last_actions)
        q1 = self.q1.value(state_1[:, :-1], memory_1[:, :-1], batch.actions)
        q2 = self.q2.value(state_2[:, :-1], memory_2[:, :-1], batch.actions)
        q_loss = (((q1 - target) ** 2 + (q2 - target) ** 2) * mask).sum() / count
        self.q_optimizer.zero_grad()
        q_loss.backward()
        self.q_optimizer.step()

        # Policy loss through the (fixed) critics.
        actions, log_prob, _ = self.actor.sample(observations[:, :-1], last_actions[:, :-1])
        q_pi = torch.min(
            self.q1.value(state_1[:, :-1].detach(), memory_1[:, :-1].detach(), actions),
            self.q2.value(state_2[:, :-1].detach(), memory_2[:, :-1].detach(), actions),
        )
        actor_loss = ((alpha * log_prob - q_pi) * mask).sum() / count
        self.actor_optimizer.zero_grad()
        actor_loss.backward()
        self.actor_optimizer.step()

        # Temperature.
        entropy_gap = log_prob.detach() + c.target_entropy
        alpha_loss = (-self.log_alpha * entropy_gap * mask).sum() / count
        self.alpha_optimizer.zero_grad()
        alpha_loss.backward()
        self.alpha_optimizer.step()

        # Target critics.
        with torch.no_grad():
            for net, target_net in ((self.q1, self.q1_target), (self.q2, self.q2_target)):
                for p, tp in zip(net.parameters(), target_net.parameters(), strict=True):
                    tp.mul_(1.0 - c.tau).add_(p, alpha=c.tau)
        return {"q_loss": q_loss.item(), "actor_loss": actor_loss.item(), "alpha": self.alpha}

    def state_dict(self) -> dict:
        """Everything needed to resume training (not shipped: see checkpoint.py)."""
        return {
            "actor": self.actor.state_dict(), "q1": self.q1.state_dict(),
            "q2": self.q2.state_dict(), "q1_target": self.q1_target.state_dict(),
            "q2_target": self.q2_target.state_dict(), "log_alpha": self.log_alpha.detach(),
            "q_optimizer": self.q_optimizer.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "alpha_optimizer": self.alpha_optimizer.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        for name in ("actor", "q1", "q2", "q1_target", "q2_target"):
            getattr(self, name).load_state_dict(state[name])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        for name in ("q_optimizer", "actor_optimizer", "alpha_optimizer"):
            getattr(self, name).load_state_dict(state[name])
