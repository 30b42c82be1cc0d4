"""
Every choice of phi in ``grad U ~ mean sum_t grad log pi(u_t|s_t) phi_t`` (eq. 20).

The notes reduce the policy gradient to the score of each action times a weight phi_t, and
then lower the variance step by step by choosing phi better. Each function here computes one
phi over a :class:`~pg_node.rl.rollout.Rollout` and returns an array of the batch's ``(T, N)``
shape. All are *functions of the batch only*: the policy's scores are applied by the caller
(``losses.policy_gradient_loss`` multiplies phi with log-probabilities).

=====================  =========================================  ===========================
name                   phi_t                                      notes
=====================  =========================================  ===========================
``total_return``       R(tau), the trajectory's whole return      eq. 18, REINFORCE
``reward_to_go``       G_t, the return after step t               eq. 63 with b = 0
``constant_baseline``  R(tau) - mean return                       eq. 49 / 60, section 4.4
``optimal_baseline``   R(tau) - b*, b* score-weighted             section 4.4
``time_baseline``      G_t - b_t, b_t mean G at that step index   section 4.4
``value_baseline``     G_t - V(s_t)                               eq. 64, A2C
``td_residual``        r_t + gamma V(s_{t+1}) - V(s_t)            TD residual
``gae``                sum_l (gamma lambda)^l delta_{t+l}          GAE, ref. [11]
=====================  =========================================  ===========================

The first six are unbiased whatever the baseline's quality, since no baseline depends on the
action (eq. 21). The last two use ``V(s_{t+1})``, which depends on the action through the
next state: they are unbiased only if V is the true value function, and otherwise trade bias
for lower variance; the variance lab measures and reports that bias instead of hiding it.
"""
from typing import Callable, Dict, Tuple

import numpy as np

from pg_node.rl import baselines
from pg_node.rl.gae import gae as _gae
from pg_node.rl.gae import td_lambda_return, td_residual as _td_residual
from pg_node.rl.returns import per_segment_first, reward_to_go as _rtg
from pg_node.rl.returns import total_return as _total_return
from pg_node.rl.rollout import Rollout, segment_ids


def total_return(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = R(tau): every step weighted by its whole trajectory's return (eq. 18)."""
    return _total_return(batch, gamma)


def reward_to_go(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = G_t: only the rewards from step t on (eq. 63, past rewards dropped)."""
    return _rtg(batch, gamma)


def _segment_returns(batch: Rollout, gamma: float):
    seg = segment_ids(batch.done)
    return seg, per_segment_first(_rtg(batch, gamma), seg)


def constant_baseline(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = R(tau) - b with b the mean return of the batch's other trajectories (eq. 49)."""
    seg, seg_ret = _segment_returns(batch, gamma)
    return (seg_ret - baselines.constant_baseline(seg_ret))[seg]


def optimal_baseline(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = R(tau) - b*, the variance-optimal constant (section 4.4); needs ``score_sq``."""
    if batch.score_sq is None:
        raise ValueError('optimal_baseline needs the squared score norm of each trajectory '
                         '(Rollout.score_sq); compute it with policy.segment_score_sq')
    seg, seg_ret = _segment_returns(batch, gamma)
    seg_score_sq = per_segment_first(batch.score_sq, seg)
    return (seg_ret - baselines.optimal_baseline(seg_ret, seg_score_sq))[seg]


def time_baseline(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = G_t - b_t, b_t the batch's mean reward-to-go at the same step index (4.4)."""
    ret = _rtg(batch, gamma)
    return ret - baselines.time_baseline(ret, batch.ep_step)


def value_baseline(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = G_t - V(s_t), the A2C advantage (eq. 64); equal to GAE with lambda = 1."""
    return _rtg(batch, gamma) - batch.val


def td_residual(batch: Rollout, gamma: float, **_) -> np.ndarray:
    """Phi = delta_t = r_t + gamma V(s_{t+1}) - V(s_t); equal to GAE with lambda = 0."""
    return _td_residual(batch, gamma)


def gae(batch: Rollout, gamma: float, gae_lambda: float = 0.95, **_) -> np.ndarray:
    """Phi = GAE(gamma, lambda), the exponentially weighted sum of TD residuals."""
    return _gae(batch, gamma, gae_lambda)


ESTIMATORS: Dict[str, Callable[..., np.ndarray]] = {
    'total_return': total_return,
    'reward_to_go': reward_to_go,
    'constant_baseline': constant_baseline,
    'optimal_baseline': optimal_baseline,
    'time_baseline': time_baseline,
    'value_baseline': value_baseline,
    'td_residual': td_residual,
    'gae': gae,
}

#: Estimators whose phi can depend on the action through V(s_{t+1}) (biased unless V = V^pi).
ACTION_DEPENDENT = frozenset({'td_residual', 'gae'})

VALUE_TARGETS = ('td_lambda', 'mc')


def compute_phi(name: str, batch: Rollout, gamma: float, gae_lambda: float = 0.95) -> np.ndarray:
    """Compute the phi called ``name`` (a key of :data:`ESTIMATORS`) over ``batch``."""
    try:
        fn = ESTIMATORS[name]
    except KeyError:
        raise ValueError(f'unknown estimator {name!r}; choose one of: '
                         f'{", ".join(ESTIMATORS)}') from None
    return fn(batch, gamma=gamma, gae_lambda=gae_lambda)


def value_targets(batch: Rollout, gamma: float, gae_lambda: float = 0.95,
                  kind: str = 'td_lambda') -> np.ndarray:
    """
    Targets for fitting V (section 4.5).

    ``mc`` regresses V on the empirical discounted return (section 4.5.1), bootstrapped only
    where the data stops without a termination; ``td_lambda`` on the TD(lambda) return
    ``GAE + V(s_t)``, which bootstraps through the critic's own estimates.
    """
    if kind == 'mc':
        return _rtg(batch, gamma)
    if kind == 'td_lambda':
        return td_lambda_return(batch, gamma, gae_lambda)
    raise ValueError(f'unknown value target {kind!r}; choose one of: {", ".join(VALUE_TARGETS)}')


def advantages_and_targets(name: str, batch: Rollout, gamma: float, gae_lambda: float = 0.95,
                           value_target: str = 'td_lambda') -> Tuple[np.ndarray, np.ndarray]:
    """Return ``(phi, value_target)`` for one batch: what the critic hands the learner."""
    return (compute_phi(name, batch, gamma, gae_lambda),
            value_targets(batch, gamma, gae_lambda, value_target))
