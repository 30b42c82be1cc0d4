"""
Discounted returns: the total return R(tau) and the reward-to-go.

These are the two baseline-free choices of phi in the notes: the whole trajectory's return,
which multiplies every score term of that trajectory (eq. 18), and the return that follows
each action only (eq. 63), which drops the past rewards an action cannot affect.
"""
import numpy as np

from pg_node.rl.rollout import Rollout, segment_ids


def discount_cumsum(x, gamma: float) -> np.ndarray:
    """
    Return the discounted cumulative sum along the first axis, the tail folded back.

    ``[x0, x1, x2] -> [x0 + g*x1 + g^2*x2, x1 + g*x2, x2]``:

    >>> discount_cumsum([1.0, 2.0, 4.0], 0.5).tolist()
    [3.0, 4.0, 4.0]
    """
    x = np.asarray(x, dtype=np.float64)
    out = np.zeros_like(x)
    acc = np.zeros_like(x[0]) if x.ndim > 1 else 0.0
    for t in range(len(x) - 1, -1, -1):
        acc = x[t] + gamma * acc
        out[t] = acc
    return out


def reward_to_go(batch: Rollout, gamma: float, bootstrap: bool = True) -> np.ndarray:
    """
    Discounted reward-to-go ``G_t = sum_{k>=t} gamma^(k-t) r_k`` within each segment.

    This is eq. 63's inner sum with discounting. Where a segment stops without the task
    having terminated (time-limit truncation, or the edge of the batch) the future beyond it
    is not zero, so with ``bootstrap`` the sum is completed by ``gamma * V(s_end)`` from
    ``batch.next_val``; after a termination nothing is added.

    >>> b = Rollout(rew=[1.0, 1.0, 1.0, 1.0], terminated=[0, 1, 0, 0], truncated=[0, 0, 0, 0],
    ...             next_val=[0.0, 0.0, 0.0, 10.0])
    >>> reward_to_go(b, gamma=0.5)[:, 0].tolist()
    [1.5, 1.0, 4.0, 6.0]
    """
    rew, term = batch.rew, batch.terminated
    cut = batch.done.copy()
    cut[-1] = True
    boot = np.where(term, 0.0, batch.next_val if bootstrap else 0.0)
    ret = np.zeros_like(rew)
    future = np.zeros(rew.shape[1])
    for t in range(rew.shape[0] - 1, -1, -1):
        # the next two lines are G_t = r_t + gamma * (G_{t+1}, or V(s_{t+1}) where cut)
        tail = np.where(cut[t], boot[t], future)
        future = rew[t] + gamma * tail
        ret[t] = future
    return ret


def total_return(batch: Rollout, gamma: float, bootstrap: bool = True) -> np.ndarray:
    """
    Return each step's whole-segment return ``R(tau)``, repeated along the segment.

    Eq. 18 weighs each score term ``grad log pi(u_t|s_t)`` with the return of the entire
    trajectory, rewards before t included. Over a batch that cuts episodes, R(tau) is the
    (bootstrapped) discounted return from the segment's first step.

    >>> b = Rollout(rew=[1.0, 2.0, 4.0], terminated=[0, 1, 0], truncated=[0, 0, 0])
    >>> total_return(b, gamma=1.0, bootstrap=False)[:, 0].tolist()
    [3.0, 3.0, 4.0]
    """
    ret = reward_to_go(batch, gamma, bootstrap)
    seg = segment_ids(batch.done)
    return per_segment_first(ret, seg)[seg]


def per_segment_first(values: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Return, for each segment id, the value at that segment's first step."""
    first = np.zeros(seg.max() + 1)
    # Iterate time backwards so that the earliest step of a segment is written last.
    for t in range(values.shape[0] - 1, -1, -1):
        first[seg[t]] = values[t]
    return first
