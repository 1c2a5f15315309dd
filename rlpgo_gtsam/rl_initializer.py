"""RLInitializer: a trained agent's orientations, the translation step, optional GN/LM.

    from rlpgo_gtsam import RLInitializer
    initial = RLInitializer(start="chordal", refine="lm").initialize(graph, values)

The agent walks the graph deterministically (tanh of the policy mean), ``cycles`` passes
over its edges; the lowest-OC orientations it reaches get positions from the linear
translation step. ``episodes=k`` runs k rollouts that differ only in their initial "last
action", batched through one numpy policy, and keeps the guess with the lowest chi2.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import gtsam
import numpy as np

from rlpgo_gtsam.agent.inference import NumpyPolicy
from rlpgo_gtsam.env import PoseGraphEnv
from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D, chi2
from rlpgo_gtsam.initializers import make_initializer, poses_with_orientations, register
from rlpgo_gtsam.models import resolve_model
from rlpgo_gtsam.solvers import SOLVERS
from rlpgo_gtsam.solvers import refine as refine_values

__all__ = ["RLInitializer", "DEFAULT_MODEL", "STARTS"]

DEFAULT_MODEL = "preset4"
STARTS = ("odometry", "lago", "chordal", "shonan")


class RLInitializer:
    """Bootstrap an initial guess with a trained RL-PGO agent.

    Args:
        model: a shipped model's name or a model file's path.
        cycles: passes over the edges; None means the model's test default (twice its
            training cycles, as in the paper).
        episodes: rollouts differing only in their initial last action; the lowest chi2 wins.
        start: the initializer whose orientations the agent starts from.
        refine: run GTSAM's "gn" or "lm" on the result, or None.
        iters: iteration cap of the refinement (default 30 for LM, 50 for GN).
        seed: seeds the initial last actions (episode 0 always starts from zeros).
        progress: called with (steps done, steps in all) while rolling out.
    """

    def __init__(
        self,
        model: str | os.PathLike[str] = DEFAULT_MODEL,
        cycles: int | None = None,
        episodes: int = 1,
        start: str = "odometry",
        refine: str | None = None,
        iters: int | None = None,
        seed: int = 0,
        progress: Callable[[int, int], None] | None = None,
    ) -> None:
        if start not in STARTS:
            raise RlpgoError(f"unknown start '{start}'; choose from {', '.join(STARTS)}")
        if refine is not None and refine not in SOLVERS:
            raise RlpgoError(f"unknown refinement '{refine}'; choose none, gn or lm")
        if episodes < 1:
            raise RlpgoError(f"episodes must be >= 1, got {episodes}")
        if cycles is not None and cycles < 1:
            raise RlpgoError(f"cycles must be >= 1, got {cycles}")
        self.model = resolve_model(model)
        self.cycles = cycles or int(self.model.metadata.get(
            "test_cycles", 2 * self.model.env_config.cycles))
        self.episodes = episodes
        self.start = start
        self.refine = refine
        self.iters = iters if iters is not None else (50 if refine == "gn" else 30)
        self.seed = seed
        self.progress = progress
        self.policy = NumpyPolicy(self.model.actor)
        self.last_chi2: float | None = None  # chi2 of the last guess, before refinement
        self.last_costs: list[float] = []  # chi2 of every rollout of the last call

    def initialize(
        self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
        start_values: gtsam.Values | None = None,
    ) -> gtsam.Values:
        """The agent's guess for ``graph`` (``values`` gives the anchor pose and the start).

        ``start_values``: the ``start`` initializer's result, if already computed.
        """
        pose_graph = PoseGraph2D.from_gtsam(graph, values)
        if start_values is None:
            start_values = make_initializer(self.start).initialize(graph, values)
        start_theta = PoseGraph2D.from_gtsam(graph, start_values).poses[:, 2]
        best_theta = self.rollout(pose_graph, start_theta)
        guesses = [poses_with_orientations(pose_graph, theta) for theta in best_theta]
        costs = [chi2(graph, guess) for guess in guesses]
        best = guesses[int(np.argmin(costs))]
        self.last_costs = [float(c) for c in costs]
        self.last_chi2 = float(min(costs))
        if self.refine is None:
            return best
        return refine_values(graph, best, self.refine, self.iters).values

    def rollout(self, pose_graph: PoseGraph2D, start_theta: np.ndarray) -> list[np.ndarray]:
        """Best-OC orientations of each of the ``episodes`` batched rollouts."""
        action_range = self.model.env_config.action_range_rad
        envs = [
            PoseGraphEnv(pose_graph=pose_graph, cycles=self.cycles, action_range_rad=action_range)
            for _ in range(self.episodes)
        ]
        rng = np.random.default_rng(self.seed)
        last_action = rng.uniform(-1.0, 1.0, (self.episodes, 2))
        last_action[0] = 0.0
        observation = np.stack(
            [env.reset(options={"orientations": start_theta})[0] for env in envs]
        ).astype(np.float64)
        state = self.policy.initial_state(self.episodes)
        total = envs[0].steps_per_episode
        report_every = max(total // 100, 1)
        for step in range(total):
            action, state = self.policy.step(observation, last_action, state)
            for b, env in enumerate(envs):
                observation[b] = env.step(action[b])[0]
            last_action = action
            if self.progress is not None and (step + 1) % report_every == 0:
                self.progress(step + 1, total)
        return [env.best_orientations() for env in envs]


register("rl", RLInitializer)
