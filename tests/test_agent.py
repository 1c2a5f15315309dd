"""The agent: networks, numpy inference, episode replay, SAC updates and training."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import torch

from rlpgo_gtsam.errors import ModelError, RlpgoError
from rlpgo_gtsam.rl.agent.buffer import EpisodeBatch, EpisodeReplay
from rlpgo_gtsam.rl.agent.checkpoint import load_model
from rlpgo_gtsam.rl.agent.config import SacConfig
from rlpgo_gtsam.rl.agent.inference import NumpyPolicy
from rlpgo_gtsam.rl.agent.networks import Actor, GraphEncoder, QNetwork
from rlpgo_gtsam.rl.agent.sac import SacAgent, run_episode
from rlpgo_gtsam.rl.env import PoseGraphEnv
from rlpgo_gtsam.rl.episode import PRESETS
from rlpgo_gtsam.rl.train import CSV_FIELDS, TrainConfig, train


@pytest.fixture(autouse=True)
def _one_thread():
    """Small networks: one torch thread is faster than contending for the cores."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _inputs(batch: int, steps: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Observations on the environment's scales and last actions in [-1, 1]."""
    generator = torch.Generator().manual_seed(seed)
    observation = torch.randn(batch, steps, 4, generator=generator)
    observation[..., 0] = observation[..., 0].abs() * 2.0  # mean message >= 0
    observation[..., 1] = observation[..., 1].clamp(-np.pi, np.pi)
    observation[..., 2:] *= 5.0  # slopes
    last_action = torch.rand(batch, steps, 2, generator=generator) * 2.0 - 1.0
    return observation, last_action


# --- networks and numpy inference ---------------------------------------------------------


def test_numpy_policy_matches_actor_step_by_step():
    torch.manual_seed(0)
    actor = Actor(32)
    with torch.no_grad():
        actor.trunk.encoder.beta.fill_(1.7)  # not the initial 1: beta must be applied
    observation, last_action = _inputs(3, 30)
    with torch.no_grad():
        whole, _ = actor.deterministic(observation, last_action)
        stepped, torch_state = [], None
        for t in range(30):
            action, torch_state = actor.deterministic(
                observation[:, t : t + 1], last_action[:, t : t + 1], torch_state
            )
            stepped.append(action)
    assert torch.allclose(torch.cat(stepped, dim=1), whole, atol=1e-6)

    policy = NumpyPolicy(actor)
    state = policy.initial_state(3)
    actions = []
    for t in range(30):
        action, state = policy.step(observation[:, t].numpy(), last_action[:, t].numpy(), state)
        assert action.shape == (3, 2)
        actions.append(action)
    actions = np.stack(actions, axis=1)
    assert np.max(np.abs(actions - whole.numpy())) < 1e-5
    # The carried LSTM state is the actor's.
    assert np.max(np.abs(state[0] - torch_state[0][0].numpy())) < 1e-5
    assert np.max(np.abs(state[1] - torch_state[1][0].numpy())) < 1e-5
    # The state matters: the same input from a fresh state gives another action.
    fresh, _ = policy.step(observation[:, -1].numpy(), last_action[:, -1].numpy(),
                           policy.initial_state(3))
    assert np.max(np.abs(fresh - actions[:, -1])) > 1e-4


def test_numpy_policy_initial_state_is_zero_and_fresh():
    policy = NumpyPolicy(Actor(8))
    h, c = policy.initial_state(4)
    assert h.shape == c.shape == (4, 8)
    assert not np.any(h) and not np.any(c)
    assert h is not c


@pytest.mark.parametrize("scale", [1.0, 100.0], ids=["normal", "saturating"])
def test_actor_sample_shapes_range_and_finite_log_prob(scale):
    torch.manual_seed(0)
    actor = Actor(16)
    observation, last_action = _inputs(4, 9, seed=1)
    action, log_prob, (h, c) = actor.sample(observation * scale, last_action)
    assert action.shape == (4, 9, 2)
    assert log_prob.shape == (4, 9, 1)
    assert h.shape == c.shape == (1, 4, 16)
    assert torch.all(action.abs() <= 1.0)
    assert torch.all(torch.isfinite(log_prob))
    assert torch.all(torch.isfinite(action))


def test_actor_sample_is_reparameterized():
    torch.manual_seed(0)
    actor = Actor(8)
    observation, last_action = _inputs(2, 5)
    action, log_prob, _ = actor.sample(observation, last_action)
    (action.sum() + log_prob.sum()).backward()
    assert actor.mean.weight.grad is not None and torch.any(actor.mean.weight.grad != 0)
    assert actor.log_std.weight.grad is not None and torch.any(actor.log_std.weight.grad != 0)


def test_deterministic_is_tanh_of_the_mean():
    torch.manual_seed(0)
    actor = Actor(8)
    observation, last_action = _inputs(2, 5)
    with torch.no_grad():
        mean, log_std, _ = actor(observation, last_action)
        action, _ = actor.deterministic(observation, last_action)
    assert torch.allclose(action, torch.tanh(mean))
    assert torch.all((log_std >= -20.0) & (log_std <= 2.0))


def test_q_network_shapes():
    torch.manual_seed(0)
    q = QNetwork(8)
    observation, last_action = _inputs(3, 6)
    state, memory = q.memory(observation, last_action)
    assert state.shape == (3, 6, GraphEncoder().state_size)
    assert memory.shape == (3, 6, 8)
    assert q.value(state, memory, last_action).shape == (3, 6, 1)


# --- episode replay -------------------------------------------------------------------------


def _fake_episode(k: int, steps: int) -> dict[str, np.ndarray]:
    """Episode ``k`` whose every array encodes (episode, step): 1000 k + step + 1."""
    code = 1000.0 * k + np.arange(steps + 1) + 1.0
    return {
        "observations": np.repeat(code[:, None], 4, axis=1),
        "last_actions": np.repeat(-code[:, None], 2, axis=1),
        "actions": np.repeat(code[:-1, None], 2, axis=1) + 0.5,
        "rewards": code[:-1],
    }


def test_episode_replay_sample_shapes_mask_and_dones():
    lengths = [3, 12, 40]
    window, burn_in, batch_size = 10, 4, 400
    replay = EpisodeReplay(10, np.random.default_rng(0))
    episodes = [_fake_episode(k, steps) for k, steps in enumerate(lengths)]
    for episode in episodes:
        replay.add(**episode)
    assert len(replay) == 3

    batch, mask = replay.sample(batch_size, window, burn_in)
    assert batch.observations.shape == (batch_size, window + 1, 4)
    assert batch.last_actions.shape == (batch_size, window + 1, 2)
    assert batch.actions.shape == (batch_size, window, 2)
    assert batch.rewards.shape == (batch_size, window, 1)
    assert batch.dones.shape == (batch_size, window, 1)
    assert mask.shape == (batch_size, window, 1)
    for tensor in (batch.observations, batch.last_actions, batch.actions, batch.rewards,
                   batch.dones, mask):
        assert tensor.dtype == torch.float32

    cases = set()
    for b in range(batch_size):
        rewards = batch.rewards[b, :, 0].numpy()
        length = int(np.count_nonzero(rewards))
        k, first = divmod(int(rewards[0]) - 1, 1000)
        steps = lengths[k]
        start, end = first, first + length
        assert length == min(window, steps - start)
        # The window's contents are the episode's, in order, and zero after its end.
        expected = episodes[k]
        assert np.array_equal(rewards[:length], expected["rewards"][start:end])
        assert not np.any(rewards[length:])
        assert np.array_equal(batch.actions[b, :length].numpy(), expected["actions"][start:end])
        assert np.array_equal(batch.observations[b, : length + 1].numpy(),
                              expected["observations"][start : end + 1])
        assert np.array_equal(batch.last_actions[b, : length + 1].numpy(),
                              expected["last_actions"][start : end + 1])
        assert not np.any(batch.observations[b, length + 1 :].numpy())
        # Mask: whole window from an episode's start; else zero over the burn-in; zero
        # after the end.
        m = mask[b, :, 0].numpy()
        masked_from = 0 if start == 0 else min(burn_in, length)
        assert not np.any(m[:masked_from])
        assert np.all(m[masked_from:length] == 1.0)
        assert not np.any(m[length:])
        # Dones: 1 on the episode's last real step and on the padding, 0 elsewhere.
        d = batch.dones[b, :, 0].numpy()
        episode_ends = end == steps
        assert d[length - 1] == (1.0 if episode_ends else 0.0)
        assert not np.any(d[: length - 1])
        assert np.all(d[length:] == 1.0)
        cases.add((start == 0, episode_ends, start > 0 and length < burn_in))
    # Every kind of window was drawn: opening, mid-episode, closing, shorter than burn-in.
    assert (True, True, False) in cases  # the whole 3-step episode
    assert (True, False, False) in cases
    assert (False, False, False) in cases
    assert (False, True, False) in cases
    assert (False, True, True) in cases


def test_episode_replay_is_a_ring_buffer():
    replay = EpisodeReplay(2, np.random.default_rng(0))
    for k in range(3):
        replay.add(**_fake_episode(k, 5))
    assert len(replay) == 2
    batch, _ = replay.sample(50, 5, 1)
    episodes = {int(r) // 1000 for r in batch.rewards[:, 0, 0].tolist()}
    assert episodes == {1, 2}  # episode 0 was replaced by episode 2


# --- SAC --------------------------------------------------------------------------------


def _flat(module: torch.nn.Module) -> torch.Tensor:
    return torch.cat([p.detach().reshape(-1).clone() for p in module.parameters()])


def _constant(critic: QNetwork, value: float) -> None:
    """Make a critic output ``value`` whatever its input (last layer: zero weights)."""
    with torch.no_grad():
        critic.head[-1].weight.zero_()
        critic.head[-1].bias.fill_(value)


def test_critic_targets_bootstrap_from_the_lower_target_critic_and_stop_at_done():
    """With constant critics, the critic loss is known in closed form: it catches a dropped
    (1 - done), the online critics used as targets, max instead of min, a lost reward scale."""
    config = SacConfig(hidden=8, gamma=0.9, reward_scale=0.5)
    agent = SacAgent(config, seed=0)
    with torch.no_grad():
        agent.log_alpha.fill_(-40.0)  # alpha ~ 4e-18: the entropy term vanishes
    online, target_1, target_2 = 1.0, 3.0, 2.0
    for critic in (agent.q1, agent.q2):
        _constant(critic, online)
    _constant(agent.q1_target, target_1)
    _constant(agent.q2_target, target_2)
    steps = 5
    rewards = torch.tensor([[1.0], [2.0], [3.0], [4.0], [5.0]])
    dones = torch.tensor([[0.0], [0.0], [0.0], [1.0], [1.0]])  # ends at step 3, then padding
    mask = torch.tensor([[1.0], [1.0], [1.0], [1.0], [0.0]])
    batch = EpisodeBatch(
        observations=torch.randn(1, steps + 1, 4), last_actions=torch.zeros(1, steps + 1, 2),
        actions=torch.zeros(1, steps, 2), rewards=rewards[None], dones=dones[None],
    )
    losses = agent._gradient_step(batch, mask[None])
    target = rewards * 0.5 + 0.9 * (1.0 - dones) * min(target_1, target_2)
    expected = float((2.0 * (online - target) ** 2 * mask).sum() / mask.sum())
    assert losses["q_loss"] == pytest.approx(expected, rel=1e-6)


def test_one_gradient_round_learns_and_moves_the_targets():
    config = SacConfig(hidden=16, batch_size=4, gradient_steps=2, window=16, burn_in=4)
    agent = SacAgent(config, seed=0)
    env = PoseGraphEnv(1)
    rng = np.random.default_rng(0)
    for seed in range(3):
        episode = run_episode(env, None, rng, seed=seed)
        steps = len(episode.actions)
        assert episode.observations.shape == (steps + 1, 4)
        assert episode.last_actions.shape == (steps + 1, 2)
        assert episode.rewards.shape == (steps,)
        assert np.all(np.abs(episode.actions) <= 1.0)
        assert episode.best_oc <= episode.initial_oc
        agent.replay.add(episode.observations, episode.last_actions, episode.actions,
                         episode.rewards)

    before = {name: _flat(getattr(agent, name))
              for name in ("actor", "q1", "q2", "q1_target", "q2_target")}
    alpha = agent.alpha
    losses = agent.update()
    assert set(losses) == {"q_loss", "actor_loss", "alpha"}
    assert all(np.isfinite(value) for value in losses.values())
    assert agent.alpha != alpha
    after = {name: _flat(getattr(agent, name)) for name in before}
    assert not torch.equal(after["actor"], before["actor"])
    for critic in ("q1", "q2"):
        moved = (after[critic] - before[critic]).norm()
        target_moved = (after[critic + "_target"] - before[critic + "_target"]).norm()
        assert 0 < target_moved < moved
        assert torch.all(torch.isfinite(after[critic]))


def test_agent_state_dict_round_trip():
    config = SacConfig(hidden=8)
    first, second = SacAgent(config, seed=0), SacAgent(config, seed=1)
    assert not torch.equal(_flat(first.actor), _flat(second.actor))
    second.load_state_dict(first.state_dict())
    for name in ("actor", "q1", "q2", "q1_target", "q2_target"):
        assert torch.equal(_flat(getattr(first, name)), _flat(getattr(second, name)))
    assert second.alpha == first.alpha


def test_run_episode_with_a_policy_is_reproducible():
    torch.manual_seed(0)
    actor = Actor(8)
    env = PoseGraphEnv(1, n=8, cycles=2)
    first = run_episode(env, actor, np.random.default_rng(0), deterministic=True, seed=3)
    second = run_episode(env, actor, np.random.default_rng(0), deterministic=True, seed=3)
    assert np.array_equal(first.actions, second.actions)
    assert np.all(np.abs(first.actions) <= 1.0)
    assert np.array_equal(first.last_actions[1:], first.actions)


# --- training ---------------------------------------------------------------------------


def test_resume_without_a_checkpoint(tmp_path):
    config = TrainConfig(preset=1, episodes=2, out=str(tmp_path / "m"),
                         sac=SacConfig(hidden=8))
    with pytest.raises(ModelError, match="nothing to resume"):
        train(config, resume=True)
    assert not (tmp_path / "m.zip").exists()
    assert not (tmp_path / "m.csv").exists()


def _rows(path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.slow
def test_train_end_to_end_and_resume(tmp_path):
    sac = SacConfig(hidden=8, batch_size=4, gradient_steps=1, warmup_episodes=2, window=16,
                    burn_in=4)
    out = tmp_path / "m"
    config = TrainConfig(preset=1, episodes=12, out=str(out), sac=sac, checkpoint_every=6)
    seen = []
    path = train(config, on_episode=lambda index, episode, seconds: seen.append(index))
    assert path == tmp_path / "m.zip"
    assert seen == list(range(1, 13))
    for suffix in (".zip", ".csv", ".png", ".train.pt"):
        assert (tmp_path / ("m" + suffix)).is_file(), suffix
    lines = (tmp_path / "m.csv").read_text().splitlines()
    assert len(lines) == 13
    assert lines[0].split(",") == CSV_FIELDS
    rows = _rows(tmp_path / "m.csv")
    assert [int(row["episode"]) for row in rows] == list(range(1, 13))
    assert all(np.isfinite(float(row["reward"])) for row in rows)

    model = load_model(path)
    assert model.env_config == PRESETS[1]
    assert model.metadata["episodes"] == 12
    assert model.metadata["seed"] == 0
    assert model.actor.trunk.hidden == 8
    policy = NumpyPolicy(model.actor)
    action, _ = policy.step(np.zeros((1, 4)), np.zeros((1, 2)), policy.initial_state(1))
    assert np.all(np.isfinite(action))

    longer = TrainConfig(preset=1, episodes=14, out=str(out), sac=sac, checkpoint_every=6)
    train(longer, resume=True)
    rows = _rows(tmp_path / "m.csv")
    assert [int(row["episode"]) for row in rows] == list(range(1, 15))
    assert float(rows[-1]["seconds"]) >= float(rows[11]["seconds"])
    assert load_model(path).metadata["episodes"] == 14
    names = {p.name for p in tmp_path.iterdir()} - {"runs"}  # runs/: TensorBoard, if installed
    assert names == {"m.csv", "m.png", "m.train.pt", "m.zip"}  # no temporary files left


def test_validation_selects_the_best_checkpoint(tmp_path):
    """With validation graphs, the shipped model is the best-validating checkpoint."""
    config = TrainConfig(
        preset=1, episodes=4, out=str(tmp_path / "v"), checkpoint_every=2, validation_graphs=2,
        sac=SacConfig(hidden=8, batch_size=2, gradient_steps=1, warmup_episodes=1, window=8,
                      burn_in=2),
    )
    train(config)
    meta = load_model(tmp_path / "v.zip").metadata
    assert meta["selected_episode"] in (2, 4)
    assert 0.0 < meta["validation_best_oc_ratio"] <= 1.0 + 1e-9
    state = torch.load(tmp_path / "v.train.pt", weights_only=True)
    assert state["best_validation"] == pytest.approx(meta["validation_best_oc_ratio"])


def _train_actor(folder, seed: int) -> dict[str, torch.Tensor]:
    sac = SacConfig(hidden=8, batch_size=4, gradient_steps=2, warmup_episodes=1, window=16,
                    burn_in=4)
    train(TrainConfig(preset=1, episodes=3, seed=seed, out=str(folder / f"m{seed}"), sac=sac,
                      env_overrides={"n": 12}, checkpoint_every=3))
    return torch.load(folder / f"m{seed}.train.pt", weights_only=True)["agent"]["actor"]


def test_training_is_reproducible_from_its_seed(tmp_path):
    """The same seed trains the same weights (every random source is seeded); another seed
    trains others."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    first, again = _train_actor(tmp_path / "a", 0), _train_actor(tmp_path / "b", 0)
    other = _train_actor(tmp_path / "a", 1)
    assert all(torch.equal(first[k], again[k]) for k in first)
    assert not all(torch.equal(first[k], other[k]) for k in first)


def test_unknown_environment_overrides_are_refused(tmp_path):
    config = TrainConfig(preset=1, episodes=2, out=str(tmp_path / "m"),
                         env_overrides={"observation": "rich"})
    with pytest.raises(RlpgoError, match="unknown environment parameter.*observation"):
        train(config)
    assert list(tmp_path.iterdir()) == []
