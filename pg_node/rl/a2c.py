"""
One learner step and one critic step: the A2C and PPO updates on a finished batch.

In pg_node the actor and the critic are separate networks living in separate processes
(the learner and critic nodes), so SB3's single loss ``pg + vf_coef * vl - ent_coef * H`` is
split in two: :class:`A2CUpdate` (and :class:`PPOUpdate`) minimises ``pg - ent_coef * H``
for the policy and :class:`ValueUpdate` minimises ``vf_coef * vl`` for V. With no shared
parameters this is the same gradient step SB3 takes.

A step whose loss or gradient is not finite is skipped: the weights stay as they were and
the step is reported (``skipped``), so one bad batch cannot poison the policy.
"""
from dataclasses import dataclass
from typing import Dict, List, Optional

import numpy as np
from pg_node.rl import losses
from pg_node.rl.update_settings import SETTINGS
import torch
from torch import nn

OPTIMIZERS = ('rmsprop', 'adam')


def make_optimizer(name: str, params, learning_rate: float) -> torch.optim.Optimizer:
    """Build SB3's A2C optimiser (RMSprop, alpha 0.99, eps 1e-5) or Adam (eps 1e-5)."""
    if name == 'rmsprop':
        return torch.optim.RMSprop(params, lr=learning_rate, alpha=0.99, eps=1e-5)
    if name == 'adam':
        return torch.optim.Adam(params, lr=learning_rate, eps=1e-5)
    raise ValueError(f'unknown optimizer {name!r}; choose one of: {", ".join(OPTIMIZERS)}')


def _step(module: nn.Module, opt: torch.optim.Optimizer, loss: torch.Tensor,
          max_grad_norm: Optional[float]) -> Optional[float]:
    """Back-propagate and step; return the gradient norm, or None if the step was skipped."""
    opt.zero_grad(set_to_none=True)
    if not torch.isfinite(loss):
        return None
    loss.backward()
    params = [p for p in module.parameters() if p.grad is not None]
    norm = torch.nn.utils.clip_grad_norm_(
        params, max_grad_norm if max_grad_norm and max_grad_norm > 0 else float('inf'))
    if not torch.isfinite(norm):
        opt.zero_grad(set_to_none=True)
        return None
    opt.step()
    return float(norm)


@dataclass
class PolicyBatch:
    """What the learner needs of a batch: flattened observations, actions, old log-probs, phi."""

    obs: torch.Tensor
    act: torch.Tensor
    logp: torch.Tensor
    adv: torch.Tensor

    @classmethod
    def from_numpy(cls, obs, act, logp, adv) -> 'PolicyBatch':
        """Build from arrays of any leading shape (flattened to one batch axis)."""
        obs = np.asarray(obs)
        act = np.asarray(act)
        return cls(torch.as_tensor(obs.reshape(-1, obs.shape[-1]), dtype=torch.float32),
                   torch.as_tensor(act.reshape(-1, act.shape[-1]), dtype=torch.float32),
                   torch.as_tensor(np.asarray(logp).reshape(-1), dtype=torch.float32),
                   torch.as_tensor(np.asarray(adv).reshape(-1), dtype=torch.float32))


class _Optimized:
    """An update that steps an optimiser ``self.opt``: its learning rate as a setting."""

    @property
    def learning_rate(self) -> float:
        """Return the optimiser's learning rate; setting it sets every parameter group's."""
        return self.opt.param_groups[0]['lr']

    @learning_rate.setter
    def learning_rate(self, value: float):
        for group in self.opt.param_groups:
            group['lr'] = value

    def optimizer_state(self) -> Dict:
        """Return the optimiser's state, for a checkpoint."""
        return self.opt.state_dict()

    def load_optimizer_state(self, state: Dict) -> None:
        """Load a checkpoint's optimiser state, keeping the configured learning rate."""
        learning_rate = self.learning_rate
        self.opt.load_state_dict(state)
        self.learning_rate = learning_rate       # the run's configuration decides, not the file


class A2CUpdate(_Optimized):
    """A2C: one gradient step of ``pg - ent_coef * H`` on the whole batch."""

    name = 'a2c'
    #: the learner parameters it is built from (pg_node.rl.updaters checks configurations here)
    settings = SETTINGS['a2c']
    #: a skipped step left the policy as it was: its batch's observations are not merged
    merge_obs_after_skip = False
    #: stop a batch's epochs once the approximate KL exceeds 1.5 of this (0: never; PPO's)
    target_kl = 0.0

    def __init__(self, policy: nn.Module, learning_rate: float = 7e-4, ent_coef: float = 0.0,
                 max_grad_norm: float = 0.5, normalize_advantage: bool = False,
                 optimizer: str = 'rmsprop'):
        self.policy = policy
        self.optimizer = optimizer
        self.opt = make_optimizer(optimizer, policy.parameters(), learning_rate)
        self.ent_coef = ent_coef
        self.max_grad_norm = max_grad_norm
        self.normalize_advantage = normalize_advantage
        self.skipped = 0

    @classmethod
    def from_config(cls, policy: nn.Module, cfg: Dict) -> 'A2CUpdate':
        """Build the update from the learner's configuration: its own settings."""
        return cls(policy, **{k: cfg[k] for k in cls.settings})

    def _plan(self, n: int) -> List[List[torch.Tensor]]:
        """Return the minibatches of each epoch: A2C takes one step on all ``n`` samples."""
        return [[torch.arange(n)]]

    def _policy_loss(self, logp, old_logp, adv):
        """Return the policy-gradient loss and its statistics (A2C: -mean(logp * phi))."""
        pg = losses.policy_gradient_loss(logp, adv)
        with torch.no_grad():
            log_ratio = logp - old_logp
            stats = {'approx_kl': float(((log_ratio.exp() - 1) - log_ratio).mean()),
                     'clip_fraction': 0.0}
        return pg, stats

    def _loss(self, b: PolicyBatch, idx):
        obs, act, old_logp, adv = b.obs[idx], b.act[idx], b.logp[idx], b.adv[idx]
        if self.normalize_advantage:
            adv = losses.normalize_advantage(adv)
        dist = self.policy.distribution(obs)
        logp = dist.log_prob(act).sum(-1)
        entropy = dist.entropy().sum(-1)
        pg, stats = self._policy_loss(logp, old_logp, adv)
        loss = pg + self.ent_coef * losses.entropy_loss(entropy)
        stats.update(policy_loss=float(pg.detach()), entropy=float(entropy.detach().mean()))
        return loss, stats

    def update(self, batch: PolicyBatch) -> Dict[str, float]:
        """Update the policy on one batch; return the metrics SB3/CleanRL users know."""
        logs, norms, skipped = [], [], 0
        for epoch in self._plan(batch.obs.shape[0]):
            for idx in epoch:
                loss, stats = self._loss(batch, idx)
                norm = _step(self.policy, self.opt, loss, self.max_grad_norm)
                if norm is None:
                    skipped += 1
                else:
                    norms.append(norm)
                logs.append(stats)
            kl = logs[-1]['approx_kl'] if logs else 0.0
            if self.target_kl and kl > 1.5 * self.target_kl:
                break
        self.skipped += skipped
        out = {k: float(np.mean([s[k] for s in logs])) for k in logs[0]}
        out['grad_norm'] = float(np.mean(norms)) if norms else float('nan')
        out['skipped_updates'] = float(skipped)
        return out


class PPOUpdate(A2CUpdate):
    """PPO: ``n_epochs`` passes of shuffled minibatches on the clipped surrogate."""

    name = 'ppo'
    settings = SETTINGS['ppo']
    #: ``skipped`` counts minibatches: the others moved the policy, so the batch is merged
    merge_obs_after_skip = True

    def __init__(self, policy: nn.Module, learning_rate: float = 7e-4, ent_coef: float = 0.0,
                 max_grad_norm: float = 0.5, normalize_advantage: bool = False,
                 optimizer: str = 'rmsprop', clip_range: float = 0.2, n_epochs: int = 10,
                 batch_size: int = 64, target_kl: float = 0.0, seed: int = 0):
        super().__init__(policy, learning_rate, ent_coef, max_grad_norm, normalize_advantage,
                         optimizer)
        self.clip_range = clip_range
        self.n_epochs = n_epochs
        self.batch_size = batch_size
        self.target_kl = target_kl
        self.gen = torch.Generator().manual_seed(seed)

    @classmethod
    def from_config(cls, policy: nn.Module, cfg: Dict) -> 'PPOUpdate':
        """Build the update from its settings and the run's ``seed`` (the minibatch order)."""
        return cls(policy, seed=cfg['seed'], **{k: cfg[k] for k in cls.settings})

    def _plan(self, n: int) -> List[List[torch.Tensor]]:
        """Return ``n_epochs`` shuffles of the ``n`` samples, split into minibatches."""
        size = min(self.batch_size, n)
        return [list(torch.randperm(n, generator=self.gen).split(size))
                for _ in range(self.n_epochs)]

    def _policy_loss(self, logp, old_logp, adv):
        """Return PPO's clipped surrogate loss and its statistics."""
        return losses.ppo_clip_loss(logp, old_logp, adv, self.clip_range)


class ValueUpdate(_Optimized):
    """Fits V_w to its targets: ``n_epochs`` passes of ``vf_coef * MSE`` (1 pass for A2C)."""

    def __init__(self, value_fn: nn.Module, learning_rate: float = 7e-4, vf_coef: float = 0.5,
                 max_grad_norm: float = 0.5, optimizer: str = 'rmsprop', n_epochs: int = 1,
                 batch_size: Optional[int] = None, seed: int = 0):
        self.value_fn = value_fn
        self.opt = make_optimizer(optimizer, value_fn.parameters(), learning_rate)
        self.vf_coef = vf_coef
        self.max_grad_norm = max_grad_norm
        self.n_epochs = n_epochs
        self.batch_size = batch_size
        self.gen = torch.Generator().manual_seed(seed)
        self.skipped = 0

    def update(self, obs, ret) -> Dict[str, float]:
        """Regress V(obs) on ``ret``; return ``value_loss`` and ``explained_variance``."""
        obs = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        obs = obs.reshape(-1, obs.shape[-1])
        ret = torch.as_tensor(np.asarray(ret).reshape(-1), dtype=torch.float32)
        with torch.no_grad():
            ev = losses.explained_variance(self.value_fn(obs), ret)
        n = obs.shape[0]
        size = min(self.batch_size or n, n)
        vls, skipped = [], 0
        for _ in range(self.n_epochs):
            order = torch.randperm(n, generator=self.gen) if size < n else torch.arange(n)
            for idx in order.split(size):
                vl = losses.value_loss(self.value_fn(obs[idx]), ret[idx])
                if _step(self.value_fn, self.opt, self.vf_coef * vl, self.max_grad_norm) is None:
                    skipped += 1
                vls.append(float(vl.detach()))
        self.skipped += skipped
        return {'value_loss': float(np.mean(vls)), 'explained_variance': ev,
                'skipped_updates': float(skipped)}
