"""The RL-PGO training environment: a thin gymnasium wrapper over :mod:`rlpgo_gtsam.rl.episode`.

The orientation state, the edge order and the observation are the episode module's, the
same that :func:`~rlpgo_gtsam.rl.episode.rollout` uses at inference; this module adds the
reward, the generated training graphs and gymnasium's interface. A step costs O(degree) and
never calls GTSAM. Importing this module registers ``rlpgo/PoseGraph-v0``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import gtsam
import gymnasium as gym
import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.rl.episode import (
    PRESETS,
    EdgeWalk,
    EnvConfig,
    OrientationState,
    generated_graph,
)
from rlpgo_gtsam.translations import poses_with_rotations

__all__ = ["ENV_ID", "PoseGraphEnv"]

ENV_ID = "rlpgo/PoseGraph-v0"
_BONUS = 25.0
_UNBOUNDED = 1e9  # the slopes grow with a pose's degree: no useful finite bound
_BONUS_FACTOR = 10.0


class PoseGraphEnv(gym.Env):
    """Planar pose-graph orientation refinement, one edge at a time (RL-PGO).

    ## Description
    The agent visits the edges of a pose graph in graph order, skipping those that touch
    a held pose (the anchor, FIXed poses); one pass is a cycle, an episode is ``cycles``
    passes. On each edge (i, j) it rotates both poses. Translations do not move during an
    episode; after it, :meth:`best_values` recovers positions for the lowest-cost
    orientations seen.

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
    noisy dead-reckoned orientations. A fixed graph (``graph`` + ``values``, or
    ``pose_graph``): its values' orientations. ``options={"orientations": theta}``
    overrides either.

    ## Episode end
    ``terminated`` after the last edge of the last cycle (a fixed horizon, no bootstrap past
    it); never ``truncated``.

    ## Info
    ``oc``, ``best_oc``, ``initial_oc``, ``step``, ``cycle``, ``edge`` (index in the graph).

    ## Arguments
    - ``preset``: 1..5, the paper's Table I training environments (default 1).
    - ``n, sigma_r, sigma_t, d, lc, cycles, action_range_rad, noisy_measurements``:
      override any preset value (:class:`~rlpgo_gtsam.rl.episode.EnvConfig`).
    - ``graph``, ``values``: a GTSAM graph and values to wrap instead.
    - ``pose_graph``: the same, already extracted as a :class:`PoseGraph2D`.
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        preset: int | None = None,
        *,
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
        if (graph is None) != (values is None):
            raise RlpgoError("give both graph and values, or neither")
        if graph is not None and values is not None and pose_graph is None:
            pose_graph = PoseGraph2D.from_gtsam(graph, values)
        self._fixed = pose_graph is not None
        self.observation_space = gym.spaces.Box(
            np.array([0.0, -np.pi, -_UNBOUNDED, -_UNBOUNDED], np.float32),
            np.array([_UNBOUNDED, np.pi, _UNBOUNDED, _UNBOUNDED], np.float32))
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.pose_graph: PoseGraph2D | None = None
        if pose_graph is not None:
            self._load(pose_graph)

    def _load(self, pose_graph: PoseGraph2D) -> None:
        self.pose_graph = pose_graph
        self.walk = EdgeWalk(pose_graph)
        self.state = OrientationState(pose_graph, pose_graph.poses[:, 2])

    @property
    def steps_per_episode(self) -> int:
        return len(self.walk) * self.config.cycles

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if not self._fixed:
            self._load(generated_graph(self.config, self.np_random))
        if self.pose_graph is None:
            raise RlpgoError("no graph: give graph and values, or generate (preset)")
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
        self.walk.act(self.state, self._step, action, self.config.action_range_rad)
        oc = self.state.oc
        reward = 100.0 / (oc + 1.0)
        if oc < self._bonus_level / _BONUS_FACTOR:
            reward += _BONUS
            self._bonus_level /= _BONUS_FACTOR
        self._step += 1
        terminated = self._step >= self.steps_per_episode
        return self._observation(), reward, terminated, False, self._info()

    def _observation(self) -> np.ndarray:
        return np.array(self.walk.observe(self.state, self._step), dtype=np.float32)

    def _info(self) -> dict:
        return {
            "oc": self.state.oc,
            "best_oc": self.state.best_oc,
            "initial_oc": self.initial_oc,
            "step": self._step,
            "cycle": self._step // len(self.walk),
            "edge": self.walk.edge_list[self._step % len(self.walk)],
        }

    def best_orientations(self) -> np.ndarray:
        """Orientations of the lowest-OC configuration of the episode so far."""
        return self.state.best_orientations()

    def best_values(self) -> gtsam.Values:
        """The lowest-OC orientations with positions from the translation step."""
        if self.pose_graph is None:
            raise RlpgoError("reset the environment first")
        return self.pose_graph.to_values(
            poses_with_rotations(self.pose_graph, self.best_orientations()))


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="rlpgo_gtsam.rl.env:PoseGraphEnv")
