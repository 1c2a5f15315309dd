"""The graph encoder, the recurrent policy and the recurrent twin Q networks.

Every network sees the environment's observation through its own :class:`GraphEncoder`
(trained jointly), and a recurrent branch over ``[state, last action]`` whose LSTM state is
passed in and returned, never kept inside the module.

Shapes: ``B`` sequences (episodes) of ``T`` steps; observations ``(B, T, 4)``
(:data:`~rlpgo_gtsam.rl.episode.OBSERVATION_SIZE`), actions ``(B, T, 2)``; LSTM state a
pair of ``(1, B, hidden)`` tensors.
"""

from __future__ import annotations

import torch
from torch import nn

from rlpgo_gtsam.rl.episode import ACTION_SIZE, OBSERVATION_SIZE

ENCODING_SIZE = 20
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0

LstmState = tuple[torch.Tensor, torch.Tensor]


class GraphEncoder(nn.Module):
    """The paper's encoder on the kept graph value, beside the edge-local observations.

    The paper's messages ``beta * ||R_i R~_ij - R_j||_F``, summed per node and averaged over
    nodes, are ``beta`` times observation 0; the learnable ``beta`` and the Linear(1 -> 20)
    layer give the 20-number encoding. Observations 1..3 (residual, slopes) pass through.
    """

    def __init__(self) -> None:
        super().__init__()
        self.beta = nn.Parameter(torch.ones(1))
        self.linear = nn.Linear(1, ENCODING_SIZE)

    @property
    def state_size(self) -> int:
        return ENCODING_SIZE + OBSERVATION_SIZE - 1

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        graph_value = self.beta * observation[..., :1]
        return torch.cat([self.linear(graph_value), observation[..., 1:]], dim=-1)


class _RecurrentTrunk(nn.Module):
    """Encoder, an FC branch on ``fc_input`` and an LSTM branch on [state, last action]."""

    def __init__(self, hidden: int, fc_extra: int) -> None:
        super().__init__()
        self.encoder = GraphEncoder()
        state = self.encoder.state_size
        self.fc = nn.Linear(state + fc_extra, hidden)
        self.recurrent_in = nn.Linear(state + ACTION_SIZE, hidden)
        self.lstm = nn.LSTM(hidden, hidden, batch_first=True)
        self.hidden = hidden

    def memory(
        self, observation: torch.Tensor, last_action: torch.Tensor, lstm_state: LstmState | None
    ) -> tuple[torch.Tensor, torch.Tensor, LstmState]:
        """Encoded state (B, T, S) and LSTM outputs (B, T, hidden), and the new LSTM state."""
        state = self.encoder(observation)
        recurrent = torch.relu(self.recurrent_in(torch.cat([state, last_action], dim=-1)))
        output, lstm_state = self.lstm(recurrent, lstm_state)
        return state, output, lstm_state


class Actor(nn.Module):
    """Gaussian policy squashed by tanh; actions in [-1, 1]^2."""

    def __init__(self, hidden: int = 512) -> None:
        super().__init__()
        self.trunk = _RecurrentTrunk(hidden, fc_extra=0)
        self.head = nn.Sequential(
            nn.Linear(2 * hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU()
        )
        self.mean = nn.Linear(hidden, ACTION_SIZE)
        self.log_std = nn.Linear(hidden, ACTION_SIZE)

    def forward(
        self, observation: torch.Tensor, last_action: torch.Tensor,
        lstm_state: LstmState | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, LstmState]:
        """Mean and clamped log-std of the pre-tanh Gaussian, and the new LSTM state."""
        state, memory, lstm_state = self.trunk.memory(observation, last_action, lstm_state)
        features = torch.cat([torch.relu(self.trunk.fc(state)), memory], dim=-1)
        features = self.head(features)
        log_std = self.log_std(features).clamp(LOG_STD_MIN, LOG_STD_MAX)
        return self.mean(features), log_std, lstm_state

    def sample(
        self, observation: torch.Tensor, last_action: torch.Tensor,
        lstm_state: LstmState | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, LstmState]:
        """A reparameterized action, its log-probability (..., 1), and the new LSTM state."""
        mean, log_std, lstm_state = self(observation, last_action, lstm_state)
        normal = torch.distributions.Normal(mean, log_std.exp())
        raw = normal.rsample()
        action = torch.tanh(raw)
        log_prob = normal.log_prob(raw) - torch.log(1.0 - action.pow(2) + 1e-6)
        return action, log_prob.sum(-1, keepdim=True), lstm_state

    def deterministic(
        self, observation: torch.Tensor, last_action: torch.Tensor,
        lstm_state: LstmState | None = None,
    ) -> tuple[torch.Tensor, LstmState]:
        """tanh of the mean: the evaluation policy."""
        mean, _, lstm_state = self(observation, last_action, lstm_state)
        return torch.tanh(mean), lstm_state


class QNetwork(nn.Module):
    """Q(s_t, a | history): the action enters the FC branch, the history the LSTM branch."""

    def __init__(self, hidden: int = 512) -> None:
        super().__init__()
        self.trunk = _RecurrentTrunk(hidden, fc_extra=ACTION_SIZE)
        self.head = nn.Sequential(
            nn.Linear(2 * hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
            nn.Linear(hidden, 1),
        )

    def memory(self, observation: torch.Tensor, last_action: torch.Tensor):
        """Encoded states and LSTM outputs over whole sequences, from a zero LSTM state."""
        state, memory, _ = self.trunk.memory(observation, last_action, None)
        return state, memory

    def value(self, state: torch.Tensor, memory: torch.Tensor, action: torch.Tensor):
        """Q values (B, T, 1) for the given actions, reusing the sequence's memory."""
        fc = torch.relu(self.trunk.fc(torch.cat([state, action], dim=-1)))
        return self.head(torch.cat([fc, memory], dim=-1))
