"""
Losses whose gradients are the policy-gradient estimates of the notes.

Minimising ``-(1/B) sum logp * phi`` with phi held fixed gives exactly the estimator
``(1/B) sum grad log pi(u|s) phi`` of eq. 20 (eq. 64 for the A2C advantage). The entropy
bonus pushes toward exploration (section 4.4, end); PPO's clipped surrogate is the "better
estimator" the notes point to in section 4 (ref. [12]).
"""
from typing import Dict, Tuple

import torch
import torch.nn.functional as F


def normalize_advantage(adv: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Scale phi to zero mean and unit standard deviation over the batch (SB3's option)."""
    if adv.numel() < 2:
        return adv
    return (adv - adv.mean()) / (adv.std() + eps)


def policy_gradient_loss(logp: torch.Tensor, adv: torch.Tensor) -> torch.Tensor:
    """Return ``-mean(logp * phi)``: its gradient is minus the estimate of eq. 20."""
    return -(logp * adv.detach()).mean()


def ppo_clip_loss(logp: torch.Tensor, old_logp: torch.Tensor, adv: torch.Tensor,
                  clip_range: float) -> Tuple[torch.Tensor, Dict[str, float]]:
    """
    Return PPO's clipped surrogate ``-mean(min(rho A, clip(rho, 1-eps, 1+eps) A))``.

    ``rho = pi_new(u|s) / pi_old(u|s)``. At ``rho = 1`` (the first step on fresh data) its
    gradient equals the A2C policy gradient; away from it, the clip removes the incentive to
    move the policy further than ``clip_range`` on this data. Also returns ``approx_kl``
    (the low-variance ``E[(rho - 1) - log rho]`` estimator) and ``clip_fraction``.
    """
    log_ratio = logp - old_logp.detach()
    ratio = log_ratio.exp()
    adv = adv.detach()
    unclipped = ratio * adv
    clipped = torch.clamp(ratio, 1.0 - clip_range, 1.0 + clip_range) * adv
    loss = -torch.min(unclipped, clipped).mean()
    with torch.no_grad():
        approx_kl = float(((ratio - 1.0) - log_ratio).mean())
        clip_fraction = float(((ratio - 1.0).abs() > clip_range).float().mean())
    return loss, {'approx_kl': approx_kl, 'clip_fraction': clip_fraction}


def entropy_loss(entropy: torch.Tensor) -> torch.Tensor:
    """Return ``-mean(entropy)``; adding ``ent_coef`` times it rewards exploration."""
    return -entropy.mean()


def value_loss(val_pred: torch.Tensor, ret: torch.Tensor) -> torch.Tensor:
    """Mean squared error of V against its targets (section 4.5: a regression problem)."""
    return F.mse_loss(val_pred, ret.detach())


def explained_variance(val_pred, ret) -> float:
    """Return ``1 - Var[ret - V] / Var[ret]``: 1 for a perfect critic, 0 for a constant."""
    ret = torch.as_tensor(ret, dtype=torch.float64)
    val_pred = torch.as_tensor(val_pred, dtype=torch.float64)
    var = ret.var(unbiased=False)
    if not torch.isfinite(var) or var == 0:
        return float('nan')
    return float(1.0 - (ret - val_pred).var(unbiased=False) / var)
