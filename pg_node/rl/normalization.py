"""
Observation normalisation by a running mean and variance, kept inside the networks.

The statistics are torch buffers, so they travel in the ``state_dict`` of the policy (and of
the value function) and are saved and restored with the weights: a policy evaluated later,
or by another process, sees its inputs scaled exactly as in training.
"""
import numpy as np
import torch
from torch import nn


class RunningNorm(nn.Module):
    """
    Normalise inputs as ``clip((x - mean) / sqrt(var + eps), -clip, clip)``.

    ``update`` merges a batch into the running moments with the parallel algorithm of
    Chan et al. (the one SB3's ``RunningMeanStd`` uses); ``forward`` only reads them, so
    evaluation never changes the statistics.
    """

    def __init__(self, shape, clip: float = 10.0, eps: float = 1e-8, enabled: bool = True):
        super().__init__()
        self.register_buffer('mean', torch.zeros(shape, dtype=torch.float64))
        self.register_buffer('var', torch.ones(shape, dtype=torch.float64))
        self.register_buffer('count', torch.tensor(eps, dtype=torch.float64))
        self.clip = float(clip)
        self.eps = float(eps)
        self.enabled = bool(enabled)

    @torch.no_grad()
    def update(self, x) -> None:
        """Merge a batch ``x`` of shape ``(..., *shape)`` into the running statistics."""
        if not self.enabled:
            return
        x = torch.as_tensor(np.asarray(x), dtype=torch.float64).reshape(-1, *self.mean.shape)
        if x.shape[0] == 0:
            return
        b_mean = x.mean(0)
        b_var = x.var(0, unbiased=False)
        b_count = x.shape[0]
        delta = b_mean - self.mean
        tot = self.count + b_count
        new_mean = self.mean + delta * b_count / tot
        m2 = self.var * self.count + b_var * b_count + delta.pow(2) * self.count * b_count / tot
        self.mean.copy_(new_mean)
        self.var.copy_(m2 / tot)
        self.count.copy_(tot)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Return the normalised (and clipped) input, in the input's dtype."""
        if not self.enabled:
            return x
        mean = self.mean.to(x.dtype)
        std = torch.sqrt(self.var + self.eps).to(x.dtype)
        return torch.clamp((x - mean) / std, -self.clip, self.clip)
