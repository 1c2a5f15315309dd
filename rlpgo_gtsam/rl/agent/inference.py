"""Fast deterministic inference: the actor as a fused numpy step, batched over rollouts.

A rollout steps the LSTM once per edge, tens of thousands of times on a large graph; a
torch forward pass per step costs far more in Python and dispatch overhead than its
arithmetic. :class:`NumpyPolicy` copies the actor's weights once and evaluates
``tanh(mean)`` for a batch of B rollouts with a handful of numpy calls per step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

if TYPE_CHECKING:  # the policy reads an actor's weights but never needs torch itself
    import torch

    from rlpgo_gtsam.rl.agent.networks import Actor

__all__ = ["NumpyPolicy"]


def _array(tensor: torch.Tensor | torch.nn.Module) -> np.ndarray:
    # a module's attributes are typed Tensor | Module; every one read here is a Tensor
    return cast("torch.Tensor", tensor).detach().cpu().numpy().astype(np.float64)


class NumpyPolicy:
    """The deterministic policy of an :class:`Actor`, one batched step at a time.

    The affine maps that follow each other are folded once: the encoder's Linear(1 -> 20)
    into the FC branch and the recurrent branch's input layer, both branches into one
    (4 observations + 2 last actions -> 2 hidden) matrix, and the LSTM's input and recurrent
    weights into one. The LSTM state ``(h, c)`` (each ``(B, hidden)``) is passed in and
    returned.
    """

    def __init__(self, actor: Actor) -> None:
        trunk = actor.trunk
        n = self.hidden = trunk.hidden
        beta = trunk.encoder.beta.item()
        enc_w = _array(trunk.encoder.linear.weight)[:, 0] * beta  # (20,)
        enc_b = _array(trunk.encoder.linear.bias)
        encoding = enc_w.shape[0]

        def fold(weight: torch.Tensor, bias: torch.Tensor) -> tuple:
            # The layer reads [obs0 * enc_w + enc_b (20), obs1..3, extra inputs]; folded, it
            # reads [obs0, obs1..3, extra inputs]: rows (20 + 3 + extra) -> (4 + extra).
            w = _array(weight).T  # (20 + 3 + extra, n)
            folded = np.vstack([enc_w @ w[:encoding], w[encoding:]])  # (4 + extra, n)
            return folded, _array(bias) + enc_b @ w[:encoding]

        fc_w, fc_b = fold(trunk.fc.weight, trunk.fc.bias)  # extra: none
        rec_w, rec_b = fold(trunk.recurrent_in.weight, trunk.recurrent_in.bias)  # 2 last actions
        inputs = rec_w.shape[0]  # 4 observations + 2 last actions = 6
        self.in_w = np.zeros((inputs, 2 * n))
        self.in_w[: fc_w.shape[0], :n] = fc_w
        self.in_w[:, n:] = rec_w
        self.in_b = np.concatenate([fc_b, rec_b])
        lstm = trunk.lstm
        self.lstm_w = np.vstack([_array(lstm.weight_ih_l0).T, _array(lstm.weight_hh_l0).T])
        self.lstm_b = _array(lstm.bias_ih_l0) + _array(lstm.bias_hh_l0)
        self.h1_w, self.h1_b = _array(actor.head[0].weight).T, _array(actor.head[0].bias)
        self.h2_w, self.h2_b = _array(actor.head[2].weight).T, _array(actor.head[2].bias)
        self.mean_w, self.mean_b = _array(actor.mean.weight).T, _array(actor.mean.bias)

    def initial_state(self, batch: int) -> tuple[np.ndarray, np.ndarray]:
        zeros = np.zeros((batch, self.hidden))
        return zeros, zeros.copy()

    def step(
        self, observation: np.ndarray, last_action: np.ndarray,
        state: tuple[np.ndarray, np.ndarray],
    ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """Actions (B, 2) for observations (B, 4) and last actions (B, 2)."""
        h, c = state
        n = self.hidden
        branches = np.concatenate([observation, last_action], axis=1) @ self.in_w + self.in_b
        np.maximum(branches, 0.0, out=branches)
        gates = np.concatenate([branches[:, n:], h], axis=1) @ self.lstm_w + self.lstm_b
        sigmoid = 1.0 / (1.0 + np.exp(-gates))
        c = sigmoid[:, n : 2 * n] * c + sigmoid[:, :n] * np.tanh(gates[:, 2 * n : 3 * n])
        h = sigmoid[:, 3 * n :] * np.tanh(c)
        branches[:, n:] = h
        features = np.maximum(branches @ self.h1_w + self.h1_b, 0.0)
        features = np.maximum(features @ self.h2_w + self.h2_b, 0.0)
        return np.tanh(features @ self.mean_w + self.mean_b), (h, c)
