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
    "OBSERVATION_SIZE",
    "OBSERVATION_SIZES",
    "CHOICES",
    "RichOrientationState",
    "make_state",
    "ACTION_SIZE",
    "OrientationState",
    "EdgeWalk",
    "Policy",
    "BalancingPolicy",
    "RandomPolicy",
    "Rollout",
    "rollout",
]

OBSERVATION_SIZE = 4
ACTION_SIZE = 2
# Observation kinds and their sizes: the paper's four numbers, or those plus the real cost's
# local view and the horizon (see EdgeWalk.observe).
OBSERVATION_SIZES = {"paper": OBSERVATION_SIZE, "rich": 12}
# The allowed values of EnvConfig's text fields (one source for the env, the model schema
# and the command).
CHOICES = {
    "observation": tuple(OBSERVATION_SIZES),
    "reward": ("oc", "chi2"),
    "keep": ("oc", "chi2"),
    "start": ("odometry", "certified"),
}


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
        observation: "paper" (the four numbers of the paper's state, default) or "rich"
            (those, the real cost's view of the current edge and its poses' other edges with
            positions from the last translation step, and the horizon; 12 numbers).
        reward: "oc" (the paper's 100 / (OC + 1) + bonus, default) or "chi2": 100 x the
            step's decrease of the log of the real cost (GTSAM's chi2 of the orientations
            with the translation step's positions).
        oc_shaping: with ``reward="chi2"``, this weight times the paper's reward is added
            (0: the real cost alone).
        keep: what a rollout hands over: "oc" (the lowest-OC orientations seen at any step,
            default) or "chi2" (the lowest-chi2 orientations among the ends of its cycles).
        sigma_r_max: if above ``sigma_r``, each generated graph draws its rotation noise
            uniformly from [sigma_r, sigma_r_max].
        start: where a generated graph's episode starts: "odometry" (the noisy dead
            reckoning, default) or "certified" (the orientations of certified + LM, the
            classical optimum that the staged default hands the agent).
    """

    n: int = 20
    sigma_r: float = 0.3
    sigma_t: float = 0.01
    d: float = 3.0
    lc: float = 0.5
    cycles: int = 7
    action_range_rad: float = 0.25
    noisy_measurements: bool = False
    observation: str = "paper"
    reward: str = "oc"
    oc_shaping: float = 0.0
    keep: str = "oc"
    sigma_r_max: float = 0.0
    start: str = "odometry"

    def __post_init__(self) -> None:
        for name, allowed in CHOICES.items():
            if getattr(self, name) not in allowed:
                raise RlpgoError(f"{name} must be one of {', '.join(allowed)}, "
                                 f"got {getattr(self, name)!r}")


PRESETS: dict[int, EnvConfig] = {
    1: EnvConfig(sigma_r=0.3, sigma_t=0.01, d=3.0, cycles=7, action_range_rad=0.25),
    2: EnvConfig(sigma_r=0.3, sigma_t=0.01, d=3.0, cycles=8, action_range_rad=0.25),
    3: EnvConfig(sigma_r=0.2, sigma_t=0.1495, d=1.0, cycles=5, action_range_rad=0.4),
    4: EnvConfig(sigma_r=0.2, sigma_t=0.1495, d=1.0, cycles=6, action_range_rad=0.25),
    5: EnvConfig(sigma_r=0.1, sigma_t=0.01, d=10.0, cycles=6, action_range_rad=0.25),
}


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


class RichOrientationState(OrientationState):
    """An :class:`OrientationState` that also keeps each edge's real cost, positions frozen.

    Positions come from the translation step of the orientations at the start and at each
    :meth:`recompute` (the walk calls it at the end of every cycle); between those they are
    held, so a rotation updates only its pose's edges. Per edge ``e = (i, j)`` it keeps
    ``c_e = e^T Lambda e`` with ``e = [R~^T (R_i^T (t_j - t_i) - t~), r_e]`` and its slopes
    ``dc_e/dtheta_i`` and ``dc_e/dtheta_j``; :attr:`chi2` is GTSAM's chi2 at the last
    translation step.
    """

    def __init__(self, graph: PoseGraph2D, theta: np.ndarray, translation) -> None:
        self.translation = translation
        info = graph.information
        self.info = [tuple(row) for row in info.reshape(-1, 9).tolist()]
        self.angle_sqrt_weight = np.sqrt(info[:, 2, 2]).tolist()
        self.t_measured = graph.measured[:, :2].tolist()
        self.cos_measured = np.cos(graph.measured[:, 2]).tolist()
        self.sin_measured = np.sin(graph.measured[:, 2]).tolist()
        super().__init__(graph, theta)

    def recompute(self) -> None:
        """Every residual and sum from scratch, and positions from the translation step."""
        super().recompute()
        xy, self.chi2 = self.translation.solve(np.array(self.theta))
        self.xy = xy.tolist()
        count = len(self.source)
        self.edge_cost, self.slope_i, self.slope_j = [0.0] * count, [0.0] * count, [0.0] * count
        for e in range(count):
            self._update_edge(e)

    def _update_edge(self, e: int) -> None:
        i, j = self.source[e], self.target[e]
        c, s = math.cos(self.theta[i]), math.sin(self.theta[i])
        dx = self.xy[j][0] - self.xy[i][0]
        dy = self.xy[j][1] - self.xy[i][1]
        lx, ly = c * dx + s * dy - self.t_measured[e][0], -s * dx + c * dy - self.t_measured[e][1]
        cm, sm = self.cos_measured[e], self.sin_measured[e]
        ux, uy, r = cm * lx + sm * ly, -sm * lx + cm * ly, self.residual[e]
        # d u / d theta_i = R~^T R_i^T K (t_j - t_i), K = [[0, 1], [-1, 0]].
        kx, ky = c * dy - s * dx, -s * dy - c * dx
        gx, gy = cm * kx + sm * ky, -sm * kx + cm * ky
        l00, l01, l02, l10, l11, l12, l20, l21, l22 = self.info[e]
        w0 = l00 * ux + l01 * uy + l02 * r
        w1 = l10 * ux + l11 * uy + l12 * r
        w2 = l20 * ux + l21 * uy + l22 * r
        self.edge_cost[e] = ux * w0 + uy * w1 + r * w2
        self.slope_i[e] = 2.0 * (w0 * gx + w1 * gy - w2)
        self.slope_j[e] = 2.0 * w2

    def rotate(self, pose: int, angle: float) -> None:
        super().rotate(pose, angle)
        for e in self.incident[pose]:
            self._update_edge(e)

    def real_slope(self, pose: int) -> float:
        """d(sum of the kept edge costs)/d(theta_pose), positions held."""
        total = 0.0
        for e in self.incident[pose]:
            total += self.slope_i[e] if self.source[e] == pose else self.slope_j[e]
        return total

    def neighbour_cost(self, pose: int, skip: int) -> float:
        """Mean kept cost of the edges of ``pose`` other than ``skip`` (0 if none)."""
        costs = [self.edge_cost[e] for e in self.incident[pose] if e != skip]
        return math.fsum(costs) / len(costs) if costs else 0.0


def make_state(graph: PoseGraph2D, theta: np.ndarray, observation: str = "paper",
               translation=None) -> OrientationState:
    """The orientation state an observation kind needs (``translation``: a
    :class:`~rlpgo_gtsam.translations.TranslationStep` of ``graph``, made if not given)."""
    if observation == "paper":
        return OrientationState(graph, theta)
    if translation is None:
        from rlpgo_gtsam.translations import TranslationStep

        translation = TranslationStep(graph)
    return RichOrientationState(graph, theta, translation)


class EdgeWalk:
    """The order in which the agent visits edges: every edge that touches no held pose.

    Held poses (the anchor and FIXed poses) never rotate. Step ``s`` acts on edge
    ``edges[s % len(edges)]``; one pass over them is a cycle.
    """

    def __init__(self, pose_graph: PoseGraph2D, observation: str = "paper",
                 cycles: int = 1) -> None:
        self.observation = observation
        self.cycles = cycles
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
        """The observation before step ``step``, rounded to float32 as the networks see it.

        "paper": mean chordal message, the edge's angle residual, the OC slopes of its two
        poses. "rich" adds, with positions from the last translation step (a
        :class:`RichOrientationState`): the information-weighted angle residual, the
        whitened norm of the edge's full residual, asinh of the real cost's slopes at i and
        j, asinh of the mean cost of the other edges of i and of j, the fraction of the
        cycle done and the fraction of the episode done (the horizon).
        """
        length = len(self.edge_list)
        k = step % length
        i, j = self.pairs[k]
        e = self.edge_list[k]
        values = [state.mean_message, state.residual[e], state.gradient(i), state.gradient(j)]
        if self.observation == "rich":
            values += [
                state.angle_sqrt_weight[e] * state.residual[e],
                math.sqrt(max(state.edge_cost[e], 0.0)),
                math.asinh(state.real_slope(i)), math.asinh(state.real_slope(j)),
                math.asinh(state.neighbour_cost(i, e)), math.asinh(state.neighbour_cost(j, e)),
                k / length, step / (length * self.cycles),
            ]
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
        best_chi2: with ``keep="chi2"``, (B,) the chi2 (orientations + translation step) of
            ``best_theta``; None with ``keep="oc"``.
    """

    best_theta: np.ndarray
    best_oc: np.ndarray
    final_oc: np.ndarray
    initial_oc: float
    best_chi2: np.ndarray | None = None


def rollout(
    policy: Policy,
    pose_graph: PoseGraph2D,
    start_theta: np.ndarray,
    cycles: int,
    action_range_rad: float,
    last_actions: np.ndarray,
    progress: Callable[[int, int], None] | None = None,
    *,
    observation: str = "paper",
    keep: str = "oc",
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
        observation: the policy's observation kind (the model's ``EnvConfig.observation``).
        keep: "oc" hands over each episode's lowest-OC orientations seen at any step; "chi2"
            its lowest-chi2 orientations among the ends of its cycles (the model's
            ``EnvConfig.keep``).
    """
    if cycles < 1:
        raise RlpgoError(f"cycles must be >= 1, got {cycles}")
    for name, value in (("observation", observation), ("keep", keep)):
        if value not in CHOICES[name]:
            raise RlpgoError(f"{name} must be one of {', '.join(CHOICES[name])}, got {value!r}")
    walk = EdgeWalk(pose_graph, observation, cycles)
    batch = len(last_actions)
    translation = None
    if observation != "paper" or keep == "chi2":
        from rlpgo_gtsam.translations import TranslationStep

        translation = TranslationStep(pose_graph)
    states = [make_state(pose_graph, start_theta, observation, translation)
              for _ in range(batch)]
    best_chi2 = np.full(batch, np.inf) if keep == "chi2" else None
    kept = [None] * batch
    initial_oc = states[0].oc
    last_action = np.asarray(last_actions, dtype=np.float64)
    recurrent = policy.initial_state(batch)
    total = len(walk) * cycles
    report_every = max(total // 100, 1)
    for step in range(total):
        observation = np.array([walk.observe(state, step) for state in states])
        action, recurrent = policy.step(observation, last_action, recurrent)
        for state, row in zip(states, action, strict=True):
            walk.act(state, step, row, action_range_rad)
        last_action = action
        if best_chi2 is not None and (step + 1) % len(walk) == 0:
            for b, state in enumerate(states):
                theta = np.array(state.theta)
                cost = state.chi2 if isinstance(state, RichOrientationState) else \
                    translation.chi2(theta)
                if cost < best_chi2[b]:
                    best_chi2[b], kept[b] = cost, theta
        if progress is not None and (step + 1) % report_every == 0:
            progress(step + 1, total)
    return Rollout(
        best_theta=np.array(kept if best_chi2 is not None else
                            [state.best_orientations() for state in states]),
        best_oc=np.array([state.best_oc for state in states]),
        final_oc=np.array([state.oc for state in states]),
        initial_oc=initial_oc,
        best_chi2=best_chi2,
    )
