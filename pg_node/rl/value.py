"""The critic: a state-value network V_w(s), the state-dependent baseline of eq. 64."""
from typing import Sequence

import numpy as np
from pg_node.rl.networks import activation, mlp
from pg_node.rl.normalization import RunningNorm
import torch
from torch import nn


class ValueFunction(nn.Module):
    """``V_w(s)``: an MLP from the (normalised) observation to one number."""

    def __init__(self, obs_dim: int, hidden: Sequence[int] = (64, 64), act: str = 'tanh',
                 normalize_obs: bool = True):
        super().__init__()
        self.obs_dim = int(obs_dim)
        self.obs_norm = RunningNorm(obs_dim, enabled=normalize_obs)
        self.net = mlp([obs_dim, *hidden, 1], activation(act))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Return V(obs) with the trailing unit dimension removed."""
        return self.net(self.obs_norm(obs)).squeeze(-1)

    @torch.no_grad()
    def value_numpy(self, obs: np.ndarray) -> np.ndarray:
        """Numpy in, numpy out: V for a batch of observations (any leading shape)."""
        o = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        lead = o.shape[:-1]
        return self(o.reshape(-1, self.obs_dim)).reshape(lead).double().numpy()
