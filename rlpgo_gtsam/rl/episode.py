"""The agent's walk over a graph: incremental orientation state, observations, one rollout.

This module is the one implementation of an RL-PGO episode's mechanics. :func:`rollout`
runs a batch of deterministic episodes with any policy that has the numpy step interface
(the shipped agent's :class:`~rlpgo_gtsam.rl.agent.inference.NumpyPolicy`, the edge-balancing
rule, random actions); :class:`RLInitializer`, evaluation, training validation and the tests
all call it. The gymnasium environment (:mod:`rlpgo_gtsam.rl.env`) wraps the same state for
training. Nothing here imports torch, gymnasium or GTSAM.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.se2 import CHORDAL_ROOT, CHORDAL_SCALE, angle_residuals, wrap

__all__ = [
    "EnvConfig",
    "PRESETS",
    "generated_graph",
    "OBSERVATION_SIZE",
    "ACTION_SIZE",
    "OrientationState",
    "EdgeWalk",
    "Policy",
    "BalancingPolicy",
    "RandomPolicy",
    "Rollout",
    "rollout",
]

OBSERVATION_SIZE = 4  # see EdgeWalk.observe
ACTION_SIZE = 2


@dataclass(frozen=True)
class EnvConfig:
    """Parameters of the training graphs and of an episode (the paper's Table I).

    Attributes:
        n: poses per generated graph.
        sigma_r: rotation noise of the generator, radians.
        sigma_t: translation noise of the generator, metres.
        d: spacing of the lawn-mower path, metres.
        lc: fraction of loop-closure candidates kept.
        cycles: passes over the edges per episode.
        action_range_rad: the largest rotation one action applies to a pose.
        noisy_measurements: generate graphs with noisy measurements (not in the paper).
    """

    n: int = 20
    sigma_r: float = 0.3
    sigma_t: float = 0.01
    d: float = 3.0
    lc: float = 0.5
    cycles: int = 7
    action_range_rad: float = 0.25
    noisy_measurements: bool = False


PRESETS: dict[int, EnvConfig] = {
    1: EnvConfig(sigma_r=0.3, sigma_t=0.01, d=3.0, cycles=7, action_range_rad=0.25),
    2: EnvConfig(sigma_r=0.3, sigma_t=0.01, d=3.0, cycles=8, action_range_rad=0.25),
    3: EnvConfig(sigma_r=0.2, sigma_t=0.1495, d=1.0, cycles=5, action_range_rad=0.4),
    4: EnvConfig(sigma_r=0.2, sigma_t=0.1495, d=1.0, cycles=6, action_range_rad=0.25),
    5: EnvConfig(sigma_r=0.1, sigma_t=0.01, d=10.0, cycles=6, action_range_rad=0.25),
}


def generated_graph(config: EnvConfig, rng: np.random.Generator) -> PoseGraph2D:
    """A lawn-mower graph of ``config`` drawn from ``rng`` (GTSAM is imported on first use)."""
    from rlpgo_gtsam.synthetic import generate

    sample = generate(config.n, config.sigma_r, config.sigma_t, config.d, config.lc, rng,
                      noisy_measurements=config.noisy_measurements)
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial)


class OrientationState:
    """Orientations of a graph with incrementally kept residuals and orientation cost.

    Kept per edge: the angle residual r_e = wrap(theta_j - theta_i - theta~_ij) and the
    chordal cost 8 sin^2(r_e / 2); kept in total: their sum (OC^2) and the sum of the
    chordal messages ||R_i R~_ij - R_j||_F = sqrt(8) |sin(r_e / 2)|. :meth:`rotate` touches
    the edges incident to one pose only. The configuration with the lowest OC seen is kept
    through an undo log of the changes made since it, not by copying all orientations.
    """

    def __init__(self, graph: PoseGraph2D, theta: np.ndarray) -> None:
        self.num_poses = graph.num_poses
        self.source = graph.edges[:, 0].tolist()
        self.target = graph.edges[:, 1].tolist()
        self.measured = graph.measured[:, 2].tolist()
        incident: list[list[int]] = [[] for _ in range(graph.num_poses)]
        for e, (i, j) in enumerate(zip(self.source, self.target, strict=True)):
            incident[i].append(e)
            incident[j].append(e)
        self.incident = incident
        self.set_orientations(theta)

    def set_orientations(self, theta: np.ndarray) -> None:
        """Start over from the given orientations (recomputes every edge once)."""
        self.theta = [float(t) for t in wrap(np.asarray(theta, dtype=float))]
        self.recompute()
        self.best_cost_sq = self.cost_sq
        self._undo: list[tuple[int, float]] = []

    def recompute(self) -> None:
        """Recompute every residual and both sums from scratch (no drift)."""
        theta = np.array(self.theta)
        edges = np.column_stack([self.source, self.target])
        residual = angle_residuals(theta, edges, np.array(self.measured))
        half_sin = np.abs(np.sin(0.5 * residual))
        self.residual = residual.tolist()
        self.message = (CHORDAL_ROOT * half_sin).tolist()
        self.cost = (CHORDAL_SCALE * half_sin**2).tolist()
        self.cost_sq = math.fsum(self.cost)
        self.message_sum = math.fsum(self.message)

    @property
    def oc(self) -> float:
        """The orientation cost: sqrt of the summed chordal costs."""
        return math.sqrt(max(self.cost_sq, 0.0))

    @property
    def best_oc(self) -> float:
        return math.sqrt(max(self.best_cost_sq, 0.0))

    @property
    def mean_message(self) -> float:
        """The encoder's graph value: node sums of chordal messages, averaged over nodes."""
        return self.message_sum / self.num_poses

    def rotate(self, pose: int, angle: float) -> None:
        """R_pose <- R_pose Exp(angle), updating the incident edges only."""
        old = self.theta[pose]
        self._undo.append((pose, old))
        self.theta[pose] = (old + angle + math.pi) % (2.0 * math.pi) - math.pi
        theta, residual, cost, message = self.theta, self.residual, self.cost, self.message
        root, scale = CHORDAL_ROOT, CHORDAL_SCALE  # locals: the loop runs per incident edge
        for e in self.incident[pose]:
            r = theta[self.target[e]] - theta[self.source[e]] - self.measured[e]
            r = (r + math.pi) % (2.0 * math.pi) - math.pi
            s = abs(math.sin(0.5 * r))
            new_message, new_cost = root * s, scale * s * s
            self.cost_sq += new_cost - cost[e]
            self.message_sum += new_message - message[e]
            residual[e], cost[e], message[e] = r, new_cost, new_message

    def gradient(self, pose: int) -> float:
        """d(OC^2)/d(theta_pose), summed over the edges incident to ``pose``."""
        total = 0.0
        for e in self.incident[pose]:
            slope = 4.0 * math.sin(self.residual[e])
            total += slope if self.target[e] == pose else -slope
        return total

    def mark_best(self) -> bool:
        """Keep the current configuration if its OC is the lowest seen; True if it is."""
        if self.cost_sq < self.best_cost_sq:
            self.best_cost_sq = self.cost_sq
            self._undo.clear()
            return True
        return False

    def best_orientations(self) -> np.ndarray:
        """The orientations of the lowest-OC configuration seen (the state is unchanged)."""
        theta = list(self.theta)
        for pose, old in reversed(self._undo):
            theta[pose] = old
        return np.array(theta)


class EdgeWalk:
    """The order in which the agent visits edges: every edge that touches no held pose.

    Held poses (the anchor and FIXed poses) never rotate. Step ``s`` acts on edge
    ``edges[s % len(edges)]``; one pass over them is a cycle.
    """

    def __init__(self, pose_graph: PoseGraph2D) -> None:
        held = pose_graph.held[0]
        free = ~np.isin(pose_graph.edges, held).any(axis=1)
        self.edges = np.flatnonzero(free)
        if len(self.edges) == 0:
            raise RlpgoError("every edge touches a held pose: nothing for the agent to do")
        self.pairs = pose_graph.edges[self.edges].tolist()
        self.edge_list = self.edges.tolist()

    def __len__(self) -> int:
        return len(self.edge_list)

    def observe(self, state: OrientationState, step: int) -> list[float]:
        """The observation before step ``step``, rounded to float32 as the networks see it:
        the mean chordal message, the edge's angle residual, the OC slopes of its two poses
        (:data:`OBSERVATION_SIZE` numbers)."""
        k = step % len(self.edge_list)
        i, j = self.pairs[k]
        e = self.edge_list[k]
        values = [state.mean_message, state.residual[e], state.gradient(i), state.gradient(j)]
        return np.array(values, dtype=np.float32).tolist()

    def act(self, state: OrientationState, step: int, action: np.ndarray, scale: float) -> None:
        """Apply ``action`` (clipped to [-1, 1], times ``scale`` radians) at step ``step``."""
        i, j = self.pairs[step % len(self.edge_list)]
        a0, a1 = np.clip(np.asarray(action, dtype=float), -1.0, 1.0).tolist()
        state.rotate(i, a0 * scale)
        state.rotate(j, a1 * scale)
        state.mark_best()
        if (step + 1) % len(self.edge_list) == 0:
            state.recompute()  # once per cycle: clears rounding drift of the kept sums


class Policy(Protocol):
    """A batched deterministic policy with an explicit recurrent state."""

    def initial_state(self, batch: int) -> Any: ...

    def step(self, observation: np.ndarray, last_action: np.ndarray,
             state: Any) -> tuple[np.ndarray, Any]: ...


class BalancingPolicy:
    """The edge-balancing rule: on residual r, rotate i by +r/2 and j by -r/2 (clipped).

    It zeroes each residual it visits; an agent that does not beat it has learned nothing
    worth shipping.
    """

    def __init__(self, action_range_rad: float) -> None:
        self.scale = 0.5 / action_range_rad

    def initial_state(self, batch: int) -> None:
        return None

    def step(self, observation: np.ndarray, last_action: np.ndarray, state: None):
        half = np.clip(observation[:, 1] * self.scale, -1.0, 1.0)
        return np.column_stack([half, -half]), state


class RandomPolicy:
    """Uniformly random actions in [-1, 1] from ``rng``."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def initial_state(self, batch: int) -> None:
        return None

    def step(self, observation: np.ndarray, last_action: np.ndarray, state: None):
        return self.rng.uniform(-1.0, 1.0, (len(observation), 2)), state


@dataclass
class Rollout:
    """What :func:`rollout` returns, one entry per episode of the batch.

    Attributes:
        best_theta: (B, n) the lowest-OC orientations each episode reached.
        best_oc: (B,) their orientation costs.
        final_oc: (B,) the orientation cost after the last step.
        initial_oc: the orientation cost of the start.
    """

    best_theta: np.ndarray
    best_oc: np.ndarray
    final_oc: np.ndarray
    initial_oc: float


def rollout(
    policy: Policy,
    pose_graph: PoseGraph2D,
    start_theta: np.ndarray,
    cycles: int,
    action_range_rad: float,
    last_actions: np.ndarray,
    progress: Callable[[int, int], None] | None = None,
) -> Rollout:
    """Run ``len(last_actions)`` deterministic episodes of ``cycles`` passes, batched.

    Args:
        policy: the batched policy.
        pose_graph: the graph; its held poses never rotate.
        start_theta: (n,) orientations every episode starts from.
        cycles: passes over the agent's edges.
        action_range_rad: radians of a full action.
        last_actions: (B, 2) the "last action" each episode starts with.
        progress: called with (steps done, steps in all) about a hundred times.

    Each episode hands over the lowest-OC orientations it saw at any step.
    """
    if cycles < 1:
        raise RlpgoError(f"cycles must be >= 1, got {cycles}")
    walk = EdgeWalk(pose_graph)
    states = [OrientationState(pose_graph, start_theta) for _ in range(len(last_actions))]
    initial_oc = states[0].oc
    last_action = np.asarray(last_actions, dtype=np.float64)
    recurrent = policy.initial_state(len(states))
    total = len(walk) * cycles
    report_every = max(total // 100, 1)
    for step in range(total):
        observation = np.array([walk.observe(state, step) for state in states])
        action, recurrent = policy.step(observation, last_action, recurrent)
        for state, row in zip(states, action, strict=True):
            walk.act(state, step, row, action_range_rad)
        last_action = action
        if progress is not None and (step + 1) % report_every == 0:
            progress(step + 1, total)
    return Rollout(
        best_theta=np.array([state.best_orientations() for state in states]),
        best_oc=np.array([state.best_oc for state in states]),
        final_oc=np.array([state.oc for state in states]),
        initial_oc=initial_oc,
    )
