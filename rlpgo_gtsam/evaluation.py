"""Deterministic evaluation of an agent on fresh generated graphs, with two controls.

The controls see the same graphs: uniformly random actions of the same range, and the
hand-written edge-balancing rule (on edge (i, j) with residual r, rotate i by +r/2 and j by
-r/2, clipped to the range), which zeroes each residual it visits. An agent that does not
beat the rule has learned nothing worth shipping.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rlpgo_gtsam.agent.checkpoint import LoadedModel
from rlpgo_gtsam.agent.sac import run_episode
from rlpgo_gtsam.env import PRESETS, PoseGraphEnv

__all__ = ["evaluate", "balancing_episode"]


def balancing_episode(env: PoseGraphEnv, seed: int | None = None,
                      options: dict | None = None) -> float:
    """Run the edge-balancing rule for one episode; returns its best OC."""
    observation, info = env.reset(seed=seed, options=options)
    scale = 0.5 / env.config.action_range_rad
    done = False
    while not done:
        half = float(np.clip(observation[1] * scale, -1.0, 1.0))
        observation, _, done, _, info = env.step(np.array([half, -half], np.float32))
    return info["best_oc"]


def evaluate(model: LoadedModel, preset: int, graphs: int, seed: int,
             overrides: dict | None = None) -> dict:
    """Mean initial OC, and mean best OC of the agent, random actions and the rule.

    Graph ``k`` is the preset's generator seeded with ``seed + k``, the same for all three.
    The environment takes the preset's parameters, with the model's action range (what
    the agent was trained with) and the given overrides.
    """
    config = replace(PRESETS[preset], action_range_rad=model.env_config.action_range_rad,
                     **(overrides or {}))
    env = PoseGraphEnv(preset, **{**config.__dict__})
    rng = np.random.default_rng(seed)
    initial, agent, random, greedy = [], [], [], []
    for k in range(graphs):
        episode = run_episode(env, model.actor, rng, deterministic=True, seed=seed + k,
                              initial_last_action=np.zeros(2, np.float32))
        initial.append(episode.initial_oc)
        agent.append(episode.best_oc)
        random.append(run_episode(env, None, rng, seed=seed + k).best_oc)
        greedy.append(balancing_episode(env, seed=seed + k))
    return {
        "preset": preset,
        "graphs": graphs,
        "seed": seed,
        "initial_oc_mean": float(np.mean(initial)),
        "agent_best_oc_mean": float(np.mean(agent)),
        "random_best_oc_mean": float(np.mean(random)),
        "greedy_best_oc_mean": float(np.mean(greedy)),
    }
