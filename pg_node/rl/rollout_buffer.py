"""
The actor's rollout buffer: ``n_steps`` control steps of ``num_envs`` arms, time-major.

A row holds what the critic and learner need of one (arm, step): the observation acted on,
the action, its log-probability under the sampling policy, and what the simulator answered
(reward, termination, truncation, the observation reached, the episode's id and step),
and the sequence number of the simulator's transition message it answered.
"""
from dataclasses import dataclass, fields

import numpy as np


@dataclass
class RolloutArrays:
    """A finished rollout, each array ``(T, N, ...)``; see :class:`RolloutBuffer`."""

    obs: np.ndarray
    act: np.ndarray
    logp: np.ndarray
    rew: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    final_obs: np.ndarray
    ep_step: np.ndarray
    episode_id: np.ndarray
    seq: np.ndarray

    @property
    def n_steps(self) -> int:
        """Return T."""
        return self.rew.shape[0]

    @property
    def num_envs(self) -> int:
        """Return N."""
        return self.rew.shape[1]

    def as_dict(self):
        """Return the arrays by field name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def concat_arms(parts) -> RolloutArrays:
    """Join rollouts of consecutive groups of arms (same steps) into one, arm after arm."""
    if len(parts) == 1:
        return parts[0]
    return RolloutArrays(**{f.name: np.concatenate([getattr(p, f.name) for p in parts], axis=1)
                            for f in fields(RolloutArrays)})


class RolloutBuffer:
    """
    Collect ``n_steps`` x ``num_envs`` transitions.

    The actor calls :meth:`add_action` when it sends a command for observation ``obs`` and
    :meth:`add_outcome` when the simulator reports what that command led to; the buffer is
    full after ``n_steps`` outcomes.
    """

    def __init__(self, n_steps: int, num_envs: int, obs_dim: int, act_dim: int):
        if n_steps < 1 or num_envs < 1:
            raise ValueError('n_steps and num_envs must be >= 1')
        self.n_steps, self.num_envs = int(n_steps), int(num_envs)
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)
        self.reset()

    def reset(self):
        """Empty the buffer (allocating fresh arrays: a finished rollout is handed away)."""
        T, N = self.n_steps, self.num_envs
        self.obs = np.zeros((T, N, self.obs_dim))
        self.act = np.zeros((T, N, self.act_dim))
        self.logp = np.zeros((T, N))
        self.rew = np.zeros((T, N))
        self.terminated = np.zeros((T, N), dtype=bool)
        self.truncated = np.zeros((T, N), dtype=bool)
        self.final_obs = np.zeros((T, N, self.obs_dim))
        self.ep_step = np.zeros((T, N), dtype=np.int64)
        self.episode_id = np.zeros((T, N), dtype=np.int64)
        self.seq = np.zeros((T, N), dtype=np.int64)
        self.pos = 0
        self.pending = False

    @property
    def full(self) -> bool:
        """Return True when all ``n_steps`` outcomes are in."""
        return self.pos >= self.n_steps

    def add_action(self, obs, act, logp, ep_step, episode_id, seq=0):
        """Record the command sent for ``obs`` (transition number ``seq``) at this step."""
        if self.full:
            raise RuntimeError('rollout buffer is full; take it with finish()')
        if self.pending:
            raise RuntimeError('a command is already pending its outcome')
        t = self.pos
        self.obs[t], self.act[t], self.logp[t] = obs, act, logp
        self.ep_step[t], self.episode_id[t], self.seq[t] = ep_step, episode_id, seq
        self.pending = True

    def add_outcome(self, rew, terminated, truncated, final_obs):
        """Record what the pending command led to and advance one step."""
        if not self.pending:
            raise RuntimeError('no command is pending an outcome')
        t = self.pos
        self.rew[t], self.terminated[t], self.truncated[t] = rew, terminated, truncated
        self.final_obs[t] = final_obs
        self.pos += 1
        self.pending = False

    def finish(self) -> RolloutArrays:
        """Return the full rollout and start an empty one."""
        if not self.full:
            raise RuntimeError(f'rollout has {self.pos} of {self.n_steps} steps')
        out = RolloutArrays(self.obs, self.act, self.logp, self.rew, self.terminated,
                            self.truncated, self.final_obs, self.ep_step, self.episode_id,
                            self.seq)
        self.reset()
        return out
