"""
A batch of experience laid out time-major, as ``(T, N)`` arrays for N parallel arms.

Every estimator of phi in pg_node reads this one layout. Column ``n`` is arm ``n``'s stream of
control steps; an episode may end inside the batch by *termination* (the task is over: the
value of what follows is zero) or by *truncation* (the time limit cut it: what follows still
has value, so estimators bootstrap with ``V`` of the true last state). A stretch of one column
between two ends, or between an end and the edge of the batch, is a *segment*: a trajectory
tau in the notes' sense, complete or cut by the rollout.
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np


@dataclass
class Rollout:
    """
    Rewards, episode ends and value estimates of a ``(T, N)`` batch.

    - ``rew``: ``r_t``, reward received for the action at step t.
    - ``terminated``: True where the episode ended for good after step t.
    - ``truncated``: True where a time limit cut the episode after step t.
    - ``val``: ``V(s_t)``, the critic's value of the state acted in (zeros if none).
    - ``next_val``: ``V(s_{t+1})`` of the true next state, also where the episode ended and
      the arm was reset (the final observation, not the reset one); used to bootstrap.
    - ``ep_step``: the step's index inside its episode (0 at a reset), for the time-dependent
      baseline; derived from the ends if not given (the batch then starts episodes).
    - ``score_sq``: per step, the squared norm of its segment's score
      ``||sum_t grad log pi(u_t|s_t)||^2``; only the optimal baseline needs it.
    """

    rew: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    val: Optional[np.ndarray] = None
    next_val: Optional[np.ndarray] = None
    ep_step: Optional[np.ndarray] = None
    score_sq: Optional[np.ndarray] = None

    def __post_init__(self):
        self.rew = np.asarray(self.rew, dtype=np.float64)
        if self.rew.ndim == 1:
            self.rew = self.rew[:, None]
        if self.rew.ndim != 2:
            raise ValueError(f'rew must be (T, N) or (T,), got shape {self.rew.shape}')
        shape = self.rew.shape
        self.terminated = _as(self.terminated, shape, bool, 'terminated')
        self.truncated = _as(self.truncated, shape, bool, 'truncated')
        self.val = np.zeros(shape) if self.val is None else _as(self.val, shape, float, 'val')
        self.next_val = (np.zeros(shape) if self.next_val is None
                         else _as(self.next_val, shape, float, 'next_val'))
        self.ep_step = (episode_steps(self.terminated | self.truncated) if self.ep_step is None
                        else _as(self.ep_step, shape, np.int64, 'ep_step'))
        if self.score_sq is not None:
            self.score_sq = _as(self.score_sq, shape, float, 'score_sq')

    @property
    def done(self) -> np.ndarray:
        """Return where an episode ended after step t, by termination or truncation."""
        return self.terminated | self.truncated

    @property
    def shape(self):
        """Return ``(T, N)``."""
        return self.rew.shape


def _as(x, shape, dtype, name):
    arr = np.asarray(x, dtype=dtype)
    if arr.ndim == 1 and len(shape) == 2 and shape[1] == 1:
        arr = arr[:, None]
    if arr.shape != shape:
        raise ValueError(f'{name} has shape {arr.shape}, expected {shape} like rew')
    return arr


def episode_steps(done: np.ndarray) -> np.ndarray:
    """
    Return the index of each step inside its episode, counting from 0 after every end.

    >>> episode_steps(np.array([[False], [True], [False]]))[:, 0].tolist()
    [0, 1, 0]
    """
    done = np.asarray(done, dtype=bool)
    steps = np.zeros(done.shape, dtype=np.int64)
    for t in range(1, done.shape[0]):
        steps[t] = np.where(done[t - 1], 0, steps[t - 1] + 1)
    return steps


def segment_ids(done: np.ndarray) -> np.ndarray:
    """
    Return segment numbers of a ``(T, N)`` batch: 0, 1, ... column by column.

    A new segment starts at t = 0 and after every end.

    >>> segment_ids(np.array([[False, False], [True, False], [False, False]])).tolist()
    [[0, 2], [0, 2], [1, 2]]
    """
    done = np.asarray(done, dtype=bool)
    starts = np.zeros(done.shape, dtype=bool)
    starts[0] = True
    starts[1:] = done[:-1]
    # Column-major numbering so that one arm's segments are consecutive.
    flat = starts.T.reshape(-1)
    return (np.cumsum(flat) - 1).reshape(done.shape[::-1]).T
