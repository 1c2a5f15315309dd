"""Deterministic evaluation of an agent on fresh generated graphs, with two controls.

Every policy runs through :func:`~rlpgo_gtsam.rl.episode.rollout`, the code path users run:
the agent as the numpy policy (episode 0's initial last action, zeros), uniformly random
actions of the same range, and the edge-balancing rule (on edge (i, j) with residual r,
rotate i by +r/2 and j by -r/2, clipped to the range), which zeroes each residual it
visits. An agent that does not beat the rule has learned nothing worth shipping.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.rl.agent.checkpoint import LoadedModel
from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.episode import (
    PRESETS,
    BalancingPolicy,
    EnvConfig,
    RandomPolicy,
    generated_graph,
    rollout,
)

__all__ = ["evaluate", "evaluation_graph", "initial_and_best_oc"]


def evaluation_graph(config: EnvConfig, seed: int) -> PoseGraph2D:
    """The generated graph of ``config`` for ``seed`` (the one the environment draws after
    ``reset(seed=seed)``)."""
    return generated_graph(config, np.random.default_rng(seed))


def initial_and_best_oc(policy, config: EnvConfig,
                        seeds: list[int]) -> tuple[list[float], list[float]]:
    """The initial OC and the best OC (raw values, not ratios) of one deterministic rollout
    of ``config.cycles`` cycles per seed's graph, from its dead reckoning."""
    initial, best = [], []
    for seed in seeds:
        graph = evaluation_graph(config, seed)
        result = rollout(policy, graph, graph.poses[:, 2], config.cycles,
                         config.action_range_rad, np.zeros((1, 2)))
        initial.append(result.initial_oc)
        best.append(float(result.best_oc[0]))
    return initial, best


def evaluate(model: LoadedModel, preset: int, graphs: int, seed: int,
             overrides: dict | None = None) -> dict:
    """Mean initial OC, and mean best OC of the agent, random actions and the rule.

    Graph ``k`` is the preset's generator seeded with ``seed + k``, the same for all three.
    The environment takes the preset's parameters, with the model's action range (what the
    agent was trained with) and the given overrides.
    """
    config = replace(PRESETS[preset], action_range_rad=model.env_config.action_range_rad,
                     **(overrides or {}))
    seeds = [seed + k for k in range(graphs)]
    initial, agent = initial_and_best_oc(NumpyPolicy(model.actor), config, seeds)
    _, random = initial_and_best_oc(RandomPolicy(np.random.default_rng(seed)), config, seeds)
    _, greedy = initial_and_best_oc(BalancingPolicy(config.action_range_rad), config, seeds)
    return {
        "preset": preset,
        "graphs": graphs,
        "seed": seed,
        "initial_oc_mean": float(np.mean(initial)),
        "agent_best_oc_mean": float(np.mean(agent)),
        "random_best_oc_mean": float(np.mean(random)),
        "greedy_best_oc_mean": float(np.mean(greedy)),
    }
