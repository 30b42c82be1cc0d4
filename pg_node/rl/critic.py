"""
The critic's job, without ROS: annotate a rollout with phi and fit V_w on it.

It evaluates ``V(s_t)`` and ``V(s_{t+1})`` (the latter on the observation each action really
reached, so truncated episodes bootstrap from their true last state), computes the chosen
phi (:mod:`pg_node.rl.estimators`) and the value targets, then takes its regression step on V
(section 4.5). phi is computed *before* V is updated, with the V the rollout is judged by.
"""
from typing import Dict, Optional, Tuple

import numpy as np
from pg_node.rl.a2c import ValueUpdate
from pg_node.rl.estimators import compute_phi, value_targets
from pg_node.rl.losses import explained_variance
from pg_node.rl.policy import segment_score_sq
from pg_node.rl.rollout import Rollout, segment_ids
from pg_node.rl.rollout_buffer import RolloutArrays
from pg_node.rl.value import ValueFunction
import torch


class Critic:
    """A value network, its optimiser, and the estimator settings."""

    #: settings that may change between batches: config key -> attribute of V's update
    UPDATE_SETTINGS = {'vf_learning_rate': 'learning_rate', 'vf_coef': 'vf_coef',
                       'vf_max_grad_norm': 'max_grad_norm', 'vf_epochs': 'n_epochs',
                       'vf_batch_size': 'batch_size'}

    def __init__(self, obs_dim: int, cfg: Dict):
        torch.manual_seed(cfg['seed'] + 1)
        self.cfg = cfg
        self.value_fn = ValueFunction(obs_dim, cfg['hidden_sizes'], cfg['activation'],
                                      cfg['normalize_obs'])
        self.update = ValueUpdate(
            self.value_fn, learning_rate=cfg['vf_learning_rate'], vf_coef=cfg['vf_coef'],
            max_grad_norm=cfg['vf_max_grad_norm'], optimizer=cfg['vf_optimizer'],
            n_epochs=cfg['vf_epochs'], batch_size=cfg['vf_batch_size'] or None,
            seed=cfg['seed'])

    def annotate(self, ro: RolloutArrays, policy=None
                 ) -> Tuple[np.ndarray, np.ndarray, Dict[str, float]]:
        """
        Return ``(adv, ret, metrics)`` for a rollout and fit V on it: :meth:`judge`, :meth:`fit`.

        ``policy`` is needed only by the optimal baseline, which weighs trajectories by the
        squared norm of their score.
        """
        adv, ret, _ = self.judge(ro, policy)
        return adv, ret, self.fit(ro.obs, ret)

    def judge(self, ro: RolloutArrays, policy=None
              ) -> Tuple[np.ndarray, np.ndarray, Dict[str, float]]:
        """
        Return ``(adv, ret, metrics)`` with V as it is, before it learns from this rollout.

        ``metrics`` are V's ``value_loss`` (mean squared error against ``ret``) and
        ``explained_variance`` on the rollout, measured before :meth:`fit` (for A2C's one
        full-batch step, the loss that step starts from). critic_node sends the batch after
        this and fits V afterwards, off the path the next rollout waits on.
        """
        cfg = self.cfg
        self.value_fn.obs_norm.update(ro.obs.reshape(-1, ro.obs.shape[-1]))
        val = self.value_fn.value_numpy(ro.obs)
        next_val = self.value_fn.value_numpy(ro.final_obs)
        score_sq = None
        if cfg['estimator'] == 'optimal_baseline':
            score_sq = self._score_sq(ro, policy)
        batch = Rollout(rew=ro.rew, terminated=ro.terminated, truncated=ro.truncated,
                        val=val, next_val=next_val, ep_step=ro.ep_step, score_sq=score_sq)
        adv = compute_phi(cfg['estimator'], batch, cfg['gamma'], cfg['gae_lambda'])
        ret = value_targets(batch, cfg['gamma'], cfg['gae_lambda'], cfg['value_target'])
        metrics = {'value_loss': float(np.mean(np.square(ret - val))),
                   'explained_variance': explained_variance(val.ravel(), ret.ravel())}
        return adv, ret, metrics

    def fit(self, obs: np.ndarray, ret: np.ndarray) -> Dict[str, float]:
        """Take V's regression step(s) towards ``ret`` (section 4.5); return its metrics."""
        return self.update.update(obs, ret)

    @staticmethod
    def _score_sq(ro: RolloutArrays, policy) -> np.ndarray:
        if policy is None:
            raise ValueError('the optimal baseline needs the sampling policy')
        seg = segment_ids(ro.terminated | ro.truncated)
        obs = torch.as_tensor(ro.obs.reshape(-1, ro.obs.shape[-1]), dtype=torch.float32)
        act = torch.as_tensor(ro.act.reshape(-1, ro.act.shape[-1]), dtype=torch.float32)
        # rows are time-major (t, n); segment ids are per (t, n) as well
        return segment_score_sq(policy, obs, act, seg.reshape(-1)).reshape(seg.shape)

    def configure(self, name: str, value) -> None:
        """Change one setting between batches (``ros2 param set``); the next batch uses it."""
        self.cfg[name] = value
        if name in self.UPDATE_SETTINGS:
            if name == 'vf_batch_size':
                value = value or None                   # 0: the whole batch
            setattr(self.update, self.UPDATE_SETTINGS[name], value)

    def state(self) -> Dict:
        """Return what a checkpoint keeps of the critic."""
        return {'value_fn': self.value_fn.state_dict(), 'vf_opt': self.update.opt.state_dict()}

    def load(self, state: Optional[Dict]) -> None:
        """Restore from :meth:`state`'s output."""
        self.value_fn.load_state_dict(state['value_fn'])
        self.update.opt.load_state_dict(state['vf_opt'])
        self.update.learning_rate = self.cfg['vf_learning_rate']   # the run's setting decides
