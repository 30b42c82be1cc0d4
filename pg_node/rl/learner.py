"""
The learner's job, without ROS: the policy, its update, versions and checkpoints.

Each applied update increases the policy ``version`` by one. A batch is tagged with the
version of the policy that sampled it; in synchronous mode only a batch of the current
version is exact on-policy A2C, so the node's gate
(:class:`pg_node.rl.learner_gate.LearnerGate`) lets no other reach :meth:`Learner.learn`. The
observation statistics are merged *after* the gradient step, so that the step is taken at
exactly the policy the actor sampled from.
"""
from typing import Dict, Optional

import numpy as np
from pg_node.rl.a2c import PolicyBatch
from pg_node.rl.checkpoint import load_latest, save_checkpoint
from pg_node.rl.policy import GaussianPolicy
from pg_node.rl.update_settings import check_algo_setting
from pg_node.rl.updaters import make_updater
from pg_node.rl.weights import flatten_state
import torch


def make_policy(obs_dim: int, act_dim: int, cfg: Dict) -> GaussianPolicy:
    """Build the policy network the configuration describes (same in actor and learner)."""
    torch.manual_seed(cfg['seed'])
    return GaussianPolicy(obs_dim, act_dim, cfg['hidden_sizes'], cfg['activation'],
                          cfg['log_std_init'], cfg['state_dependent_std'],
                          cfg['normalize_obs'])


def policy_from_checkpoint(state: Dict) -> GaussianPolicy:
    """Return the policy a checkpoint's ``state`` holds: built as configured, weights loaded."""
    policy = make_policy(int(state['obs_dim']), int(state['act_dim']), state['config'])
    policy.load_state_dict(state['policy'])
    return policy


class Learner:
    """The policy, its update (:mod:`pg_node.rl.updaters`) and its version."""

    def __init__(self, obs_dim: int, act_dim: int, cfg: Dict):
        self.cfg = cfg
        self.policy = make_policy(obs_dim, act_dim, cfg)
        self.update = make_updater(self.policy, cfg)
        self.version = 0
        self.env_steps = 0

    def learn(self, obs, act, logp, adv) -> Dict[str, float]:
        """
        Apply one update from a batch; return its metrics.

        The version advances with every batch learned from, also when the gradient step was
        skipped for a non-finite loss or gradient (weights kept): the actors wait for the
        next version in sync mode, and must get one to go on sampling.
        """
        stats = self.update.update(PolicyBatch.from_numpy(obs, act, logp, adv))
        if stats['skipped_updates'] == 0 or self.update.merge_obs_after_skip:
            self.policy.obs_norm.update(np.asarray(obs).reshape(-1, self.policy.obs_dim))
        self.version += 1
        self.env_steps += int(np.asarray(adv).size)
        stats['policy_version'] = float(self.version)
        return stats

    def configure(self, name: str, value) -> None:
        """
        Change one setting between updates (``ros2 param set``); the next update uses it.

        Raises :class:`~pg_node.common.param_schema.ConfigError` for a setting the update does not
        have, unless ``value`` is its default (then nothing changes).
        """
        check_algo_setting(name, self.cfg['algo'], name, value)
        self.cfg[name] = value
        if name in self.update.settings:
            setattr(self.update, name, value)

    def weights(self):
        """Return ``(layout, vector)`` of the current policy, for the actors."""
        return flatten_state(self.policy)

    def state(self) -> Dict:
        """Return what a checkpoint keeps of the learner."""
        return {'policy': self.policy.state_dict(), 'opt': self.update.optimizer_state(),
                'env_steps': self.env_steps, 'obs_dim': self.policy.obs_dim,
                'act_dim': self.policy.act_dim, 'config': dict(self.cfg)}

    def save(self, directory, extra: Optional[Dict] = None):
        """Write an atomic checkpoint of the current version."""
        return save_checkpoint(directory, self.version, {**self.state(), **(extra or {})})

    def resume(self, directory):
        """Load the newest valid checkpoint; return ``(state or None, problems)``."""
        state, problems = load_latest(directory)
        if state is not None:
            self.policy.load_state_dict(state['policy'])
            if state.get('opt') is not None:
                self.update.load_optimizer_state(state['opt'])
            self.version = int(state['version'])
            self.env_steps = int(state.get('env_steps', 0))
        return state, problems


class EpisodeStats:
    """
    Running returns of the episodes a stream of batches holds, and the recent finished ones.

    Episodes span several batches, so each arm's return is summed across them, keyed by
    (actor, arm column, episode id); an arm that shows a new episode id without the old one
    having ended (a reset, a restarted simulator) drops the old, cut-short sum.
    """

    def __init__(self, window: int = 100):
        self.window = int(window)
        self.open = {}
        self.returns = []
        self.lengths = []
        self.finished = 0

    def update(self, rew, terminated, truncated, episode_id, actor) -> int:
        """Add a batch's ``(T, N)`` arrays; return how many episodes finished in it."""
        rew = np.asarray(rew, dtype=np.float64)
        episode_id = np.asarray(episode_id)
        done = np.asarray(terminated) | np.asarray(truncated)
        T, N = rew.shape
        # a column that continues its open episode to the batch's end (most of them) adds
        # its rewards in one cumulative sum, in the same order as one at a time
        through = ~done.any(axis=0) & (episode_id == episode_id[0]).all(axis=0)
        ended = []  # (t, n, return, length)
        cols, opened = [], []
        ids, actors = episode_id[0].tolist(), np.asarray(actor)[0].tolist()
        for n in range(N):
            key = (int(actors[n]), n)
            cur = self.open.get(key)
            if through[n] and cur is not None and cur[0] == ids[n]:
                cols.append(n)
                opened.append(cur)
                continue
            for t in range(T):
                ep = int(episode_id[t, n])
                cur = self.open.get(key)
                if cur is None or cur[0] != ep:
                    cur = self.open[key] = [ep, 0.0, 0]
                cur[1] += float(rew[t, n])
                cur[2] += 1
                if done[t, n]:
                    ended.append((t, n, cur[1], cur[2]))
                    del self.open[key]
        if cols:
            sums = np.cumsum(np.vstack([[cur[1] for cur in opened], rew[:, cols]]), axis=0)[-1]
            for cur, total in zip(opened, sums.tolist()):
                cur[1] = total
                cur[2] += T
        ended.sort(key=lambda e: (e[0], e[1]))
        self.returns.extend(e[2] for e in ended)
        self.lengths.extend(e[3] for e in ended)
        self.returns = self.returns[-self.window:]
        self.lengths = self.lengths[-self.window:]
        self.finished += len(ended)
        return len(ended)

    def forget_actor(self, actor: int) -> int:
        """Drop the open sums of ``actor``'s arms (its simulator restarted); return how many."""
        keys = [k for k in self.open if k[0] == int(actor)]
        for k in keys:
            del self.open[k]
        return len(keys)

    def mean_return(self) -> float:
        """Return the mean return of the last ``window`` finished episodes (NaN if none)."""
        return float(np.mean(self.returns)) if self.returns else float('nan')

    def mean_length(self) -> float:
        """Return the mean length of the last ``window`` finished episodes (NaN if none)."""
        return float(np.mean(self.lengths)) if self.lengths else float('nan')
