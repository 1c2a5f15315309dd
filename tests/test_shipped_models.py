"""Every shipped agent loads safely and lowers the orientation cost on fresh graphs, through
the rollout and numpy policy that users run."""

import numpy as np
import pytest

from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.episode import BalancingPolicy
from rlpgo_gtsam.rl.evaluation import best_oc_ratios
from rlpgo_gtsam.rl.models import models_dir, resolve_model, shipped_models

SHIPPED = shipped_models()


def test_the_five_preset_agents_are_shipped():
    assert {f"preset{p}" for p in range(1, 6)} <= set(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_model_is_small_and_documented(name):
    path = models_dir() / f"{name}.zip"
    assert path.stat().st_size < 5_000_000
    model = resolve_model(name)
    for key in ("command", "seed", "episodes", "train_seconds", "hidden", "env"):
        assert key in model.metadata, key
    assert name in (models_dir() / "README.md").read_text()


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_model_lowers_oc_on_fresh_graphs(name):
    model = resolve_model(name)
    config = model.env_config
    # Training draws its graphs from one stream seeded by the run's seed (0): these differ.
    seeds = list(range(5000, 5010))
    initial, agent = best_oc_ratios(NumpyPolicy(model.actor), config, seeds)
    _, rule = best_oc_ratios(BalancingPolicy(config.action_range_rad), config, seeds)
    ratios = np.array(agent) / np.array(initial)
    # 50-graph evaluations (models/README.md): 0.16-0.49 of the initial OC, 0.59-0.86 of
    # the edge-balancing rule's; ten graphs leave some margin for their spread.
    assert np.mean(ratios) < 0.7, ratios
    assert np.mean(agent) < 1.05 * np.mean(rule), (agent, rule)


# Digests of (best orientations, best OC, final OC) of three batched rollouts of each shipped
# agent on its preset's graph of seed 5000, recorded with the code before issue 11's options
# (observation, reward, keep, ...): their defaults must reproduce old models bit for bit.
_ROLLOUT_DIGESTS = {
    "noisy1": "ad1eb8de241474ed", "preset1": "5e75454315966bab",
    "preset2": "c79c00f2f42165db", "preset3": "2867c2eeee82a128",
    "preset4": "7c2c6b02d91ab6a9", "preset5": "54446625b79366de",
}


@pytest.mark.parametrize("name", sorted(_ROLLOUT_DIGESTS))
def test_shipped_model_rollouts_are_bit_identical_to_before_the_new_options(name):
    import hashlib

    from rlpgo_gtsam.rl.episode import rollout
    from rlpgo_gtsam.rl.evaluation import evaluation_graph

    model = resolve_model(name)
    config = model.env_config
    graph = evaluation_graph(config, 5000)
    last = np.random.default_rng(1).uniform(-1.0, 1.0, (3, 2))
    last[0] = 0.0
    result = rollout(NumpyPolicy(model.actor), graph, graph.poses[:, 2], config.cycles,
                     config.action_range_rad, last)
    data = result.best_theta.tobytes() + result.best_oc.tobytes() + result.final_oc.tobytes()
    assert hashlib.sha256(data).hexdigest()[:16] == _ROLLOUT_DIGESTS[name]
