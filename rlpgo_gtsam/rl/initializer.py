"""RLInitializer: a trained agent's orientations, then the translation step.

    from rlpgo_gtsam import RLInitializer
    initial = RLInitializer(start="chordal").initialize(graph, values)

The agent walks the graph deterministically (tanh of the policy mean), ``cycles`` passes
over its edges, through :func:`~rlpgo_gtsam.rl.episode.rollout` and the numpy policy; the
lowest-OC orientations each rollout saw get positions from the linear translation step.
``episodes=k`` runs k rollouts that differ only in their initial "last action", batched,
and keeps the guess with the lowest chi2. What the call learned (every rollout's chi2, the
chosen one) comes back in :meth:`run`'s :class:`~rlpgo_gtsam.initializers.InitResult`.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D, chi2
from rlpgo_gtsam.initializers import Estimate, Initializer, start_names
from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.episode import rollout
from rlpgo_gtsam.rl.models import DEFAULT_MODEL, resolve_model
from rlpgo_gtsam.translations import poses_with_rotations

__all__ = ["RLInitializer", "MAX_EPISODES", "MAX_CYCLES"]

# Rollouts run batched: each holds the graph's state, so their number bounds the memory
# (the commands' --episodes and --cycles take the same ranges).
MAX_EPISODES = 100
MAX_CYCLES = 10_000


class RLInitializer(Initializer):
    """Bootstrap an initial guess with a trained RL-PGO agent.

    Args:
        model: a shipped model's name or a model file's path.
        cycles: passes over the edges; None means the model's test default (twice its
            training cycles, as in the paper).
        episodes: rollouts differing only in their initial last action; the lowest chi2 wins.
        start: the initializer whose orientations the agent starts from.
        seed: seeds the initial last actions (episode 0 always starts from zeros).
        progress: called with (steps done, steps in all) while rolling out.
    """

    def __init__(
        self,
        model: str | os.PathLike[str] = DEFAULT_MODEL,
        cycles: int | None = None,
        episodes: int = 1,
        start: str = "odometry",
        seed: int = 0,
        progress: Callable[[int, int], None] | None = None,
    ) -> None:
        if start not in start_names():
            raise RlpgoError(f"unknown start '{start}'; choose from {', '.join(start_names())}")
        if not 1 <= episodes <= MAX_EPISODES:
            raise RlpgoError(f"episodes must lie in 1 .. {MAX_EPISODES}, got {episodes}")
        if cycles is not None and not 1 <= cycles <= MAX_CYCLES:
            raise RlpgoError(f"cycles must lie in 1 .. {MAX_CYCLES}, got {cycles}")
        self.model = resolve_model(model)
        self.cycles = cycles or int(self.model.metadata.get(
            "test_cycles", 2 * self.model.env_config.cycles))
        self.episodes = episodes
        self.start = start
        self.name = f"rl@{start}"
        self.seed = seed
        self.progress = progress
        self.policy = NumpyPolicy(self.model.actor)

    def last_actions(self) -> np.ndarray:
        """(episodes, 2) initial last actions: zeros for episode 0, seeded uniform after."""
        last_actions = np.random.default_rng(self.seed).uniform(-1.0, 1.0, (self.episodes, 2))
        last_actions[0] = 0.0
        return last_actions

    def estimate(self, pose_graph: PoseGraph2D, start_poses: np.ndarray | None) -> Estimate:
        start_theta = pose_graph.poses[:, 2] if start_poses is None else start_poses[:, 2]
        config = self.model.env_config
        result = rollout(self.policy, pose_graph, start_theta, self.cycles,
                         config.action_range_rad, self.last_actions(), self.progress)
        guesses = [poses_with_rotations(pose_graph, theta) for theta in result.best_theta]
        costs = [chi2(pose_graph.factor_graph, pose_graph.to_values(poses)) for poses in guesses]
        chosen = int(np.argmin(costs))
        return Estimate(guesses[chosen], {
            "rollout_chi2": [float(c) for c in costs], "chosen_rollout": chosen,
            "cycles": self.cycles, "best_oc": float(result.best_oc[chosen]),
        })
