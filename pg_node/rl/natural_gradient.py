"""
The natural policy gradient (NPG) and TRPO: steps of bounded KL instead of bounded size.

The notes end with the better estimators that make "small" changes to the policy: TRPO [13],
and the natural gradient that the robotics survey [10] builds on (its section II C). A plain
gradient step of size alpha changes the policy by an amount that depends on how the network
is parametrised; the natural gradient measures the step by what it does to the action
distribution instead, the KL divergence between the old and the new policy, whose second
order expansion around the old parameters is ``0.5 * d^T F d`` with F the Fisher information
of the policy. Maximising the linearised surrogate ``g^T d`` (g the policy gradient of the
notes' eq. 20, here through the importance-weighted surrogate ``mean(ratio * phi)`` whose
gradient at the old parameters is that estimate) under ``0.5 * d^T F d <= max_kl`` gives

    d = sqrt(2 * max_kl / (x^T F x)) * x,    x = F^{-1} g,

with x found by conjugate gradient from Fisher-vector products alone (F is never formed:
``F v`` is the Hessian-vector product of the mean KL at the old parameters). NPG takes that
step. TRPO then searches back along it (halving) and accepts the first fraction that
improves the surrogate and keeps the measured mean KL within ``max_kl``; if none does, the
policy is left as it was.
"""
from typing import Callable, Dict, List, Tuple

import numpy as np
from pg_node.rl import losses
from pg_node.rl.update_settings import SETTINGS
import torch
from torch import nn
from torch.distributions import kl_divergence, Normal


def conjugate_gradient(avp: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor,
                       iters: int = 10, tol: float = 1e-10) -> torch.Tensor:
    """
    Solve ``A x = b`` for a symmetric positive definite A known only through ``avp(v) = A v``.

    >>> A = torch.tensor([[4.0, 1.0], [1.0, 3.0]], dtype=torch.float64)
    >>> x = conjugate_gradient(lambda v: A @ v, torch.tensor([1.0, 2.0], dtype=torch.float64))
    >>> [round(float(v), 6) for v in x]
    [0.090909, 0.636364]
    """
    x = torch.zeros_like(b)
    r = b.clone()
    p = b.clone()
    rr = r @ r
    for _ in range(iters):
        if rr <= tol:
            break
        ap = avp(p)
        alpha = rr / (p @ ap)
        x += alpha * p
        r -= alpha * ap
        rr_new = r @ r
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x


def flat(tensors) -> torch.Tensor:
    """Concatenate tensors (parameters or gradients) into one vector."""
    return torch.cat([t.reshape(-1) for t in tensors])


def assign(params: List[nn.Parameter], vec: torch.Tensor) -> None:
    """Write the vector ``vec`` into ``params`` (the inverse of :func:`flat`)."""
    k = 0
    with torch.no_grad():
        for p in params:
            n = p.numel()
            p.copy_(vec[k:k + n].view_as(p))
            k += n


def fisher_vector_product(kl_fn: Callable[[], torch.Tensor], params: List[nn.Parameter],
                          v: torch.Tensor, damping: float = 0.0) -> torch.Tensor:
    """
    Return ``(F + damping I) v``, F the Hessian of ``kl_fn()`` with respect to ``params``.

    ``kl_fn`` returns the mean KL between the old policy (fixed) and the current one, which
    is zero with zero gradient at the old parameters: there its Hessian is the Fisher
    information matrix, and ``F v`` is the gradient of ``grad(KL) . v``.
    """
    grads = torch.autograd.grad(kl_fn(), params, create_graph=True)
    gv = flat(grads) @ v
    hv = torch.autograd.grad(gv, params)
    return flat(hv) + damping * v


class NPGUpdate:
    """
    NPG on one batch: the natural gradient step whose quadratic model of the KL is ``max_kl``.

    phi is normalised per batch when ``normalize_advantage`` (as for A2C); an entropy bonus
    ``ent_coef * H`` is part of the surrogate.
    """

    name = 'npg'
    #: the learner parameters it is built from (pg_node.rl.updaters checks configurations here)
    settings = SETTINGS['npg']
    #: no learning rate: the step is sized by ``max_kl``; the logs show 0
    learning_rate = 0.0
    #: a skipped step left the policy as it was: its batch's observations are not merged
    merge_obs_after_skip = False

    def __init__(self, policy: nn.Module, max_kl: float = 0.01, cg_iters: int = 10,
                 cg_damping: float = 0.1, ent_coef: float = 0.0,
                 normalize_advantage: bool = True):
        self.policy = policy
        self.max_kl = max_kl
        self.cg_iters = cg_iters
        self.cg_damping = cg_damping
        self.ent_coef = ent_coef
        self.normalize_advantage = normalize_advantage
        self.skipped = 0

    @classmethod
    def from_config(cls, policy: nn.Module, cfg: Dict) -> 'NPGUpdate':
        """Build the update from the learner's configuration: its own settings."""
        return cls(policy, **{k: cfg[k] for k in cls.settings})

    def optimizer_state(self) -> None:
        """Return None: a natural gradient step keeps no optimiser state."""
        return None

    def load_optimizer_state(self, state: Dict) -> None:
        """Ignore a checkpoint's optimiser state (one of another update): there is none here."""

    def _params(self) -> List[nn.Parameter]:
        return [p for p in self.policy.parameters() if p.requires_grad]

    def surrogate(self, batch, adv: torch.Tensor) -> torch.Tensor:
        """Return ``mean(pi(u|s) / pi_old(u|s) * phi) + ent_coef * H`` (to be maximised)."""
        dist = self.policy.distribution(batch.obs)
        ratio = torch.exp(dist.log_prob(batch.act).sum(-1) - batch.logp)
        return (ratio * adv).mean() + self.ent_coef * dist.entropy().sum(-1).mean()

    def mean_kl(self, batch, old: Normal) -> torch.Tensor:
        """Return the mean over the batch of KL(pi_old(.|s) || pi(.|s))."""
        return kl_divergence(old, self.policy.distribution(batch.obs)).sum(-1).mean()

    def update(self, batch) -> Dict[str, float]:
        """Take one step on ``batch``; return SB3-style metrics and the step's."""
        params = self._params()
        adv = batch.adv
        if self.normalize_advantage:
            adv = losses.normalize_advantage(adv)
        with torch.no_grad():
            mu, std = self.policy.mean_std(batch.obs)
            old = Normal(mu, std)
        theta = flat(params).detach().clone()
        surr = self.surrogate(batch, adv)
        g = flat(torch.autograd.grad(surr, params)).detach()
        stats = {'policy_loss': -float(surr.detach()), 'grad_norm': float(g.norm()),
                 'clip_fraction': 0.0}
        if not (torch.isfinite(g).all() and torch.isfinite(surr)):
            return self._skip(stats, params, theta)

        def fvp(v):
            return fisher_vector_product(lambda: self.mean_kl(batch, old), params, v,
                                         self.cg_damping)

        x = conjugate_gradient(fvp, g, self.cg_iters)
        xfx = float(x @ fvp(x))
        if not np.isfinite(xfx) or xfx <= 0:
            return self._skip(stats, params, theta)
        step = np.sqrt(2.0 * self.max_kl / xfx) * x
        fraction, kl = self._take(batch, adv, old, params, theta, step, float(surr.detach()))
        with torch.no_grad():
            dist = self.policy.distribution(batch.obs)
            stats['entropy'] = float(dist.entropy().sum(-1).mean())
        stats.update(approx_kl=kl, step_fraction=fraction, skipped_updates=0.0)
        return stats

    def _take(self, batch, adv, old, params, theta, step, base) -> Tuple[float, float]:
        """Move the policy to ``theta + step``; return the fraction taken and the mean KL."""
        assign(params, theta + step)
        with torch.no_grad():
            return 1.0, float(self.mean_kl(batch, old))

    def _skip(self, stats, params, theta) -> Dict[str, float]:
        assign(params, theta)
        self.skipped += 1
        with torch.no_grad():
            stats['entropy'] = float('nan')
        stats.update(approx_kl=float('nan'), step_fraction=0.0, skipped_updates=1.0)
        return stats


class TRPOUpdate(NPGUpdate):
    """TRPO on one batch: NPG's step, searched back until the KL bound holds and it improves."""

    name = 'trpo'
    settings = SETTINGS['trpo']

    def __init__(self, policy: nn.Module, max_kl: float = 0.01, cg_iters: int = 10,
                 cg_damping: float = 0.1, line_search_steps: int = 10, ent_coef: float = 0.0,
                 normalize_advantage: bool = True):
        super().__init__(policy, max_kl, cg_iters, cg_damping, ent_coef, normalize_advantage)
        self.line_search_steps = line_search_steps

    def _take(self, batch, adv, old, params, theta, step, base) -> Tuple[float, float]:
        """Halve the step until surrogate ``base`` improves within ``max_kl``; else keep theta."""
        for k in range(self.line_search_steps):
            fraction = 0.5 ** k
            assign(params, theta + fraction * step)
            with torch.no_grad():
                kl = float(self.mean_kl(batch, old))
                gain = float(self.surrogate(batch, adv)) - base
            if np.isfinite(kl) and kl <= self.max_kl and gain > 0:
                return fraction, kl
        assign(params, theta)                           # no acceptable step: keep the policy
        return 0.0, 0.0
