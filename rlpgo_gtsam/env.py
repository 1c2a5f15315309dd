"""The RL-PGO environment: an agent walks a pose graph edge by edge, rotating its two poses.

The orientation state is kept incrementally: a step rotates two poses and recomputes only
the residuals of the edges incident to them, so a step costs O(degree) and never calls
GTSAM. The graph, its measurements and the translation step after the episode stay GTSAM's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import gtsam
import gymnasium as gym
import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.g2o import read_g2o
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.initializers import poses_with_orientations
from rlpgo_gtsam.rotations import angle_residuals, wrap
from rlpgo_gtsam.synthetic import generate

__all__ = ["EnvConfig", "PRESETS", "PoseGraphEnv", "OrientationState", "OBSERVATION_SIZE"]

ENV_ID = "rlpgo/PoseGraph-v0"
OBSERVATION_SIZE = 4
_BONUS = 25.0
_UNBOUNDED = 1e9  # the slopes grow with a pose's degree: no useful finite bound
_BONUS_FACTOR = 10.0


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
        self.message = (math.sqrt(8.0) * half_sin).tolist()
        self.cost = (8.0 * half_sin**2).tolist()
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
        for e in self.incident[pose]:
            r = theta[self.target[e]] - theta[self.source[e]] - self.measured[e]
            r = (r + math.pi) % (2.0 * math.pi) - math.pi
            s = abs(math.sin(0.5 * r))
            new_message, new_cost = 2.8284271247461903 * s, 8.0 * s * s
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


class PoseGraphEnv(gym.Env):
    """Planar pose-graph orientation refinement, one edge at a time (RL-PGO).

    ## Description
    The agent visits the edges of a pose graph in graph order, skipping those that touch
    the fixed anchor pose; one pass is a cycle, an episode is ``cycles`` passes. On each
    edge (i, j) it rotates both poses. Translations do not move during an episode; after
    it, :meth:`best_values` recovers positions for the lowest-cost orientations seen.

    ## Observation
    ``Box((4,), float32)``, index 1 within [-pi, pi], the others effectively unbounded:

    | index | value |
    |---|---|
    | 0 | graph value of the encoder: sum over edges of ||R_i R~_ij - R_j||_F, over n |
    | 1 | angle residual Log(R~_ij^T R_i^T R_j) of the edge about to be acted on, radians |
    | 2 | d(OC^2)/d(theta_i) of that edge's first pose, over its incident edges |
    | 3 | d(OC^2)/d(theta_j) of its second pose |

    Index 0 is the input of the paper's graph encoder (its messages beta*c_e summed per
    node and averaged; beta and the linear layer belong to the agent); index 1 is the
    paper's residual; 2 and 3 are local slopes the paper's state does not have.

    ## Action
    ``Box(-1, 1, (2,), float32)``: R_i <- R_i Exp(a0 * range), R_j <- R_j Exp(a1 * range),
    ``range`` = ``action_range_rad``.

    ## Reward
    ``100 / (OC + 1)`` after the step, with OC = sqrt(sum_e ||R~_ij - R_i^T R_j||_F^2)
    (unweighted), plus 25 each time OC first falls below a tenth of the previous bonus
    level (the episode's initial OC, then a tenth of it, ...).

    ## Starting state
    Generated graphs (``preset`` / parameters): a new lawn-mower graph at every reset, the
    noisy dead-reckoned orientations. A fixed graph (``graph_file`` or ``graph`` +
    ``values``): its values' orientations, or ``options={"orientations": theta}``.

    ## Episode end
    ``terminated`` after the last edge of the last cycle (a fixed horizon, no bootstrap past
    it); never ``truncated``.

    ## Info
    ``oc``, ``best_oc``, ``initial_oc``, ``step``, ``cycle``, ``edge`` (index in the graph).

    ## Arguments
    - ``preset``: 1..5, the paper's Table I training environments (default 1).
    - ``n, sigma_r, sigma_t, d, lc, cycles, action_range_rad, noisy_measurements``:
      override any preset value.
    - ``graph_file``: a g2o file to wrap instead of generating graphs.
    - ``graph``, ``values``: a GTSAM graph and values to wrap instead.
    - ``pose_graph``: the same, already extracted as a :class:`PoseGraph2D`.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        preset: int | None = None,
        *,
        graph_file: str | None = None,
        graph: gtsam.NonlinearFactorGraph | None = None,
        values: gtsam.Values | None = None,
        pose_graph: PoseGraph2D | None = None,
        **overrides: Any,
    ) -> None:
        if preset is not None and preset not in PRESETS:
            raise RlpgoError(f"preset must be one of {sorted(PRESETS)}, got {preset}")
        base = PRESETS[preset or 1]
        unknown = set(overrides) - set(EnvConfig.__dataclass_fields__)
        if unknown:
            raise RlpgoError(f"unknown environment parameter(s): {', '.join(sorted(unknown))}")
        self.config = replace(base, **overrides)
        if self.config.cycles < 1:
            raise RlpgoError("cycles must be >= 1")
        if graph_file is not None:
            graph, values = read_g2o(graph_file)
        if (graph is None) != (values is None):
            raise RlpgoError("give both graph and values, or neither")
        if graph is not None and pose_graph is None:
            pose_graph = PoseGraph2D.from_gtsam(graph, values)
        self._fixed = pose_graph is not None
        self.observation_space = gym.spaces.Box(
            np.array([0.0, -np.pi, -_UNBOUNDED, -_UNBOUNDED], np.float32),
            np.array([_UNBOUNDED, np.pi, _UNBOUNDED, _UNBOUNDED], np.float32),
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.pose_graph: PoseGraph2D | None = None
        if pose_graph is not None:
            self._load(pose_graph)

    def _load(self, pose_graph: PoseGraph2D) -> None:
        self.pose_graph = pose_graph
        anchor = self.pose_graph.anchor
        edges = self.pose_graph.edges
        self.action_edges = np.flatnonzero((edges[:, 0] != anchor) & (edges[:, 1] != anchor))
        if len(self.action_edges) == 0:
            raise RlpgoError("every edge touches the anchor pose: nothing for the agent to do")
        self.state = OrientationState(self.pose_graph, self.pose_graph.poses[:, 2])
        self._pairs = edges[self.action_edges].tolist()

    @property
    def steps_per_episode(self) -> int:
        return len(self.action_edges) * self.config.cycles

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if not self._fixed:
            c = self.config
            sample = generate(c.n, c.sigma_r, c.sigma_t, c.d, c.lc, self.np_random,
                              noisy_measurements=c.noisy_measurements)
            self._load(PoseGraph2D.from_gtsam(sample.graph, sample.initial))
        assert self.pose_graph is not None
        orientations = (options or {}).get("orientations")
        if orientations is None:
            orientations = self.pose_graph.poses[:, 2]
        elif np.shape(orientations) != (self.pose_graph.num_poses,):
            raise RlpgoError(
                f"orientations must have shape ({self.pose_graph.num_poses},), "
                f"got {np.shape(orientations)}"
            )
        self.state.set_orientations(orientations)
        self.initial_oc = self.state.oc
        self._bonus_level = self.initial_oc
        self._step = 0
        return self._observation(), self._info()

    def step(self, action):
        a0, a1 = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        i, j = self._pairs[self._step % len(self._pairs)]
        scale = self.config.action_range_rad
        self.state.rotate(i, float(a0) * scale)
        self.state.rotate(j, float(a1) * scale)
        self.state.mark_best()
        oc = self.state.oc
        reward = 100.0 / (oc + 1.0)
        if oc < self._bonus_level / _BONUS_FACTOR:
            reward += _BONUS
            self._bonus_level /= _BONUS_FACTOR
        self._step += 1
        terminated = self._step >= self.steps_per_episode
        if self._step % len(self._pairs) == 0:
            self.state.recompute()  # once per cycle: clears rounding drift of the kept sums
        return self._observation(), reward, terminated, False, self._info()

    def _observation(self) -> np.ndarray:
        i, j = self._pairs[self._step % len(self._pairs)]
        e = int(self.action_edges[self._step % len(self._pairs)])
        state = self.state
        return np.array(
            [state.mean_message, state.residual[e], state.gradient(i), state.gradient(j)],
            dtype=np.float32,
        )

    def _info(self) -> dict:
        return {
            "oc": self.state.oc,
            "best_oc": self.state.best_oc,
            "initial_oc": self.initial_oc,
            "step": self._step,
            "cycle": self._step // len(self._pairs),
            "edge": int(self.action_edges[self._step % len(self._pairs)]),
        }

    def best_orientations(self) -> np.ndarray:
        """Orientations of the lowest-OC configuration of the episode so far."""
        return self.state.best_orientations()

    def best_values(self) -> gtsam.Values:
        """The lowest-OC orientations with positions from the translation step."""
        assert self.pose_graph is not None
        return poses_with_orientations(self.pose_graph, self.best_orientations())
