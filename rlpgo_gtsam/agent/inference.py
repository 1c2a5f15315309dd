"""Fast deterministic inference: the actor as a fused numpy step, batched over rollouts.

A rollout steps the LSTM once per edge, tens of thousands of times on a large graph; a
torch forward pass per step costs far more in Python and dispatch overhead than its
arithmetic. :class:`NumpyPolicy` copies the actor's weights once and evaluates
``tanh(mean)`` for a batch of B rollouts with a handful of numpy calls per step.
"""

from __future__ import annotations

import numpy as np
import torch

from rlpgo_gtsam.agent.networks import Actor

__all__ = ["NumpyPolicy"]


def _array(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().cpu().numpy().astype(np.float64)


class NumpyPolicy:
    """The deterministic policy of an :class:`Actor`, one batched step at a time.

    The LSTM state ``(h, c)`` (each ``(B, hidden)``) is passed in and returned.
    """

    def __init__(self, actor: Actor) -> None:
        trunk = actor.trunk
        self.hidden = trunk.hidden
        self.beta = trunk.encoder.beta.item()
        self.enc_w = _array(trunk.encoder.linear.weight)[:, 0]
        self.enc_b = _array(trunk.encoder.linear.bias)
        self.fc_w, self.fc_b = _array(trunk.fc.weight).T, _array(trunk.fc.bias)
        self.rec_w = _array(trunk.recurrent_in.weight).T
        self.rec_b = _array(trunk.recurrent_in.bias)
        lstm = trunk.lstm
        self.w_ih = _array(lstm.weight_ih_l0).T
        self.w_hh = _array(lstm.weight_hh_l0).T
        self.b_lstm = _array(lstm.bias_ih_l0) + _array(lstm.bias_hh_l0)
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
        encoded = np.concatenate(
            [(self.beta * observation[:, :1]) * self.enc_w + self.enc_b, observation[:, 1:]],
            axis=1,
        )
        fc = np.maximum(encoded @ self.fc_w + self.fc_b, 0.0)
        recurrent = np.maximum(
            np.concatenate([encoded, last_action], axis=1) @ self.rec_w + self.rec_b, 0.0
        )
        gates = recurrent @ self.w_ih + h @ self.w_hh + self.b_lstm
        n = self.hidden
        i = 1.0 / (1.0 + np.exp(-gates[:, :n]))
        f = 1.0 / (1.0 + np.exp(-gates[:, n : 2 * n]))
        g = np.tanh(gates[:, 2 * n : 3 * n])
        o = 1.0 / (1.0 + np.exp(-gates[:, 3 * n :]))
        c = f * c + i * g
        h = o * np.tanh(c)
        features = np.concatenate([fc, h], axis=1)
        features = np.maximum(features @ self.h1_w + self.h1_b, 0.0)
        features = np.maximum(features @ self.h2_w + self.h2_b, 0.0)
        return np.tanh(features @ self.mean_w + self.mean_b), (h, c)
