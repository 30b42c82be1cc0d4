"""
The actor: a diagonal Gaussian policy pi_theta(u|s) over continuous joint torques.

The mean is an MLP of the (normalised) observation; the log standard deviation is a learned
parameter vector, or, with ``state_dependent_std``, a second head of the same MLP trunk.
The score ``grad_theta log pi_theta(u|s)`` that every estimator in the notes multiplies
(eqs. 14 and 17) is what autograd computes from :meth:`GaussianPolicy.log_prob`.
"""
from typing import Sequence, Tuple

import numpy as np
from pg_node.rl.networks import activation, mlp
from pg_node.rl.normalization import RunningNorm
from pg_node.rl.sampler import LOG_SQRT_2PI, LOG_STD_MAX, LOG_STD_MIN
import torch
from torch import nn
from torch.distributions import Normal


class GaussianPolicy(nn.Module):
    """Diagonal Gaussian policy ``u ~ N(mu_theta(s), diag(sigma_theta(s)^2))``."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int] = (64, 64),
                 act: str = 'tanh', log_std_init: float = 0.0,
                 state_dependent_std: bool = False, normalize_obs: bool = True):
        super().__init__()
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)
        self.state_dependent_std = bool(state_dependent_std)
        self.obs_norm = RunningNorm(obs_dim, enabled=normalize_obs)
        act_cls = activation(act)
        self.trunk = mlp([obs_dim, *hidden], act_cls, act_cls) if hidden else nn.Identity()
        width = hidden[-1] if hidden else obs_dim
        self.mu = nn.Linear(width, act_dim)
        # Small initial mean output, as SB3 and CleanRL do (orthogonal gain 0.01).
        nn.init.orthogonal_(self.mu.weight, gain=0.01)
        nn.init.zeros_(self.mu.bias)
        if self.state_dependent_std:
            self.log_std_head = nn.Linear(width, act_dim)
            nn.init.zeros_(self.log_std_head.weight)
            nn.init.constant_(self.log_std_head.bias, log_std_init)
        else:
            self.log_std = nn.Parameter(torch.full((act_dim,), float(log_std_init)))

    def mean_std(self, obs: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        """Return the mean and standard deviation of pi(.|obs), each ``(B, act_dim)``."""
        h = self.trunk(self.obs_norm(obs))
        mu = self.mu(h)
        log_std = self.log_std_head(h) if self.state_dependent_std else self.log_std
        log_std = torch.clamp(log_std, LOG_STD_MIN, LOG_STD_MAX).expand_as(mu)
        return mu, log_std.exp()

    def distribution(self, obs: torch.Tensor) -> Normal:
        """Return the per-dimension Normal of pi(.|obs) for a batch of observations."""
        return Normal(*self.mean_std(obs))

    def log_prob(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """Return ``log pi(act|obs)``, summed over action dimensions (shape ``(B,)``)."""
        return self.distribution(obs).log_prob(act).sum(-1)

    def entropy(self, obs: torch.Tensor) -> torch.Tensor:
        """Return the entropy of pi(.|obs), summed over action dimensions."""
        return self.distribution(obs).entropy().sum(-1)

    @torch.no_grad()
    def sample(self, obs: torch.Tensor, generator: torch.Generator = None
               ) -> Tuple[torch.Tensor, torch.Tensor]:
        """
        Draw ``u ~ pi(.|obs)``; return ``(act, logp)``.

        With a ``generator`` the draw is reproducible (lock-step training uses one seeded
        generator per actor).
        """
        mu, std = self.mean_std(obs)
        eps = torch.randn(mu.shape, generator=generator, dtype=mu.dtype)
        act = mu + std * eps
        # Normal(mu, std).log_prob(act), the same operations in the same order (so the same
        # bits), without building and validating a distribution object at every step: the
        # actor samples once per control step, and this halves the cost for 64 arms
        logp = -((act - mu) ** 2) / (2 * std ** 2) - std.log() - LOG_SQRT_2PI
        return act, logp.sum(-1)

    @torch.no_grad()
    def mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        """Return the deterministic action mu(obs), used for evaluation."""
        return self.mean_std(obs)[0]

    @torch.no_grad()
    def act_numpy(self, obs: np.ndarray, deterministic: bool = False,
                  generator: torch.Generator = None) -> Tuple[np.ndarray, np.ndarray]:
        """Numpy in, numpy out: ``(act, logp)`` for a batch of observations."""
        o = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        if deterministic:
            a = self.mean_action(o)
            return a.numpy().astype(np.float64), np.zeros(len(o))
        a, logp = self.sample(o, generator)
        return a.numpy().astype(np.float64), logp.numpy().astype(np.float64)


def flat_params(module: nn.Module) -> np.ndarray:
    """Return all parameters of ``module`` as one float64 vector."""
    return torch.cat([p.detach().reshape(-1) for p in module.parameters()]).double().numpy()


def segment_score_sq(policy: GaussianPolicy, obs: torch.Tensor, act: torch.Tensor,
                     seg: np.ndarray) -> np.ndarray:
    """
    Squared norm of each trajectory's score ``||sum_t grad log pi(u_t|s_t)||^2``.

    The optimal baseline (section 4.4) weighs trajectories by it. ``obs`` and ``act`` are
    flattened ``(B, ...)``; ``seg`` gives each row's segment id. Returns one value per row
    (its segment's), so it can be stored as ``Rollout.score_sq``.
    """
    seg = np.asarray(seg).reshape(-1)
    n_seg = int(seg.max()) + 1
    params = [p for p in policy.parameters() if p.requires_grad]
    logp = policy.log_prob(obs, act)
    seg_t = torch.as_tensor(seg)
    seg_logp = torch.zeros(n_seg, dtype=logp.dtype).index_add(0, seg_t, logp)
    sq = np.zeros(n_seg)
    for i in range(n_seg):
        grads = torch.autograd.grad(seg_logp[i], params, retain_graph=i < n_seg - 1,
                                    allow_unused=True)
        sq[i] = sum(float(g.pow(2).sum()) for g in grads if g is not None)
    return sq[seg]
