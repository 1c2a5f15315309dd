"""Training graphs matched to where the agent runs: generated graphs with the classical
optimum's orientations as their episodes' start, computed once and cached.

The staged default hands the agent the best classical result after a failed certificate;
an agent trained from dead reckoning never sees such a start. A pool entry is a generated
graph (seeded, so it is regenerated rather than stored) and the orientations of certified +
LM on it (chordal + LM where the certified stage fails); the cache file keeps the
orientations and chi2 of every entry under a key of everything that made them.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from rlpgo_gtsam.errors import RlpgoError
from rlpgo_gtsam.graph import PoseGraph2D
from rlpgo_gtsam.rl.episode import EnvConfig

__all__ = ["PoolEntry", "training_graph", "classical_start", "build_pool", "POOL_LM_ITERS"]

POOL_LM_ITERS = 100
_CACHE_VERSION = 1


@dataclass(frozen=True)
class PoolEntry:
    """One training graph and its episodes' start.

    Attributes:
        pose_graph: the generated graph.
        start_theta: (n,) orientations of the classical optimum (certified + LM).
        start_chi2: chi2 of that optimum.
        seed: the generator seed that made the graph.
        sigma_r: the rotation noise it was drawn with.
    """

    pose_graph: PoseGraph2D
    start_theta: np.ndarray
    start_chi2: float
    seed: int
    sigma_r: float


def training_graph(config: EnvConfig, rng: np.random.Generator) -> tuple[PoseGraph2D, float]:
    """A generated graph of ``config`` and its rotation noise, drawn from ``rng``.

    With ``sigma_r_max > sigma_r`` the noise is drawn first, uniform in the range; otherwise
    ``rng`` feeds the generator alone (the paper's environment's stream).
    """
    from rlpgo_gtsam.synthetic import generate

    sigma_r = config.sigma_r
    if config.sigma_r_max > config.sigma_r:
        sigma_r = float(rng.uniform(config.sigma_r, config.sigma_r_max))
    sample = generate(config.n, sigma_r, config.sigma_t, config.d, config.lc, rng,
                      noisy_measurements=config.noisy_measurements)
    return PoseGraph2D.from_gtsam(sample.graph, sample.initial), sigma_r


def classical_start(pose_graph: PoseGraph2D) -> tuple[np.ndarray, float]:
    """Orientations and chi2 of certified + LM (chordal + LM if the certified stage fails)."""
    from rlpgo_gtsam.initializers import make_initializer
    from rlpgo_gtsam.solvers import refine

    try:
        start = make_initializer("certified").run(pose_graph)
    except RlpgoError:
        start = make_initializer("chordal").run(pose_graph)
    refined = refine(pose_graph.graph, start.values, "lm", POOL_LM_ITERS, pose_graph=pose_graph)
    return pose_graph.poses_of(refined.values)[:, 2], float(refined.chi2)


def _key(config: EnvConfig, seeds: Sequence[int]) -> str:
    fields = {k: v for k, v in asdict(config).items()
              if k in ("n", "sigma_r", "sigma_t", "d", "lc", "noisy_measurements",
                       "sigma_r_max")}
    return json.dumps({"version": _CACHE_VERSION, "env": fields, "seeds": list(seeds),
                       "lm_iters": POOL_LM_ITERS}, sort_keys=True)


def build_pool(
    config: EnvConfig,
    seeds: Sequence[int],
    cache: str | os.PathLike[str] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[PoolEntry]:
    """One entry per seed: the graph of ``training_graph(config, default_rng(seed))`` and
    its classical start. With ``cache``, starts are read from it when it was made by the
    same config and seeds, and written to it (atomically) otherwise."""
    from rlpgo_gtsam.files import write_bytes

    key = _key(config, seeds)
    stored = None
    if cache is not None and Path(cache).is_file():
        try:
            with np.load(cache, allow_pickle=False) as data:
                if str(data["key"]) == key:
                    stored = (data["start_theta"], data["start_chi2"])
        except (OSError, ValueError, KeyError):
            stored = None  # an unreadable or foreign cache is rebuilt
    entries = []
    for k, seed in enumerate(seeds):
        pose_graph, sigma_r = training_graph(config, np.random.default_rng(seed))
        if stored is not None:
            theta, cost = stored[0][k], float(stored[1][k])
        else:
            theta, cost = classical_start(pose_graph)
        entries.append(PoolEntry(pose_graph, np.asarray(theta, float), cost, int(seed),
                                 sigma_r))
        if progress is not None:
            progress(k + 1, len(seeds))
    if cache is not None and stored is None:
        buffer = io.BytesIO()
        np.savez(buffer, key=np.array(key), start_theta=np.array([e.start_theta for e in entries]),
                 start_chi2=np.array([e.start_chi2 for e in entries]))
        write_bytes(cache, buffer.getvalue())
    return entries
