"""
Baselines b subtracted from phi: constant, variance-optimal and time-dependent.

Subtracting anything that does not depend on the action leaves the gradient estimate
unbiased, because the score has zero mean (eqs. 21-28 and 49-59); a good choice lowers its
variance (the control-variate argument, eqs. 39-47). The state-dependent baseline V(s_t) is
the critic's output and lives with the value function (see ``estimators.value_baseline``).

Each baseline here is estimated from the batch itself. Estimating b from the same
trajectories it is then subtracted from correlates the two and biases the estimate by
O(1/m). pg_node uses the *leave-one-out* form instead: trajectory i's baseline is computed
from the other m-1 trajectories only, so it is independent of trajectory i and the estimator
stays exactly unbiased for any batch size m >= 2 (with m = 1 the baseline is 0).
"""
import numpy as np


def _leave_one_out(total: np.ndarray, count: np.ndarray, own: np.ndarray,
                   own_count=1.0) -> np.ndarray:
    """Mean of a group without one member: ``(total - own) / (count - own_count)``."""
    rest = count - own_count
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(rest > 0, (total - own) / np.where(rest > 0, rest, 1.0), 0.0)


def constant_baseline(seg_return: np.ndarray) -> np.ndarray:
    """
    Mean-return baseline ``b = (1/m) sum_i R(tau_i)``, one value per trajectory.

    The notes' first choice in section 4.4, the one Williams' REINFORCE uses. ``seg_return``
    holds R(tau_i) for each of the m trajectories; the result holds trajectory i's b,
    the mean over the other trajectories (leave-one-out, see the module docstring).

    >>> constant_baseline(np.array([1.0, 2.0, 6.0])).tolist()
    [4.0, 3.5, 1.5]
    """
    seg_return = np.asarray(seg_return, dtype=np.float64)
    return _leave_one_out(seg_return.sum(), float(len(seg_return)), seg_return)


def optimal_baseline(seg_return: np.ndarray, score_sq: np.ndarray) -> np.ndarray:
    """
    Variance-optimal constant baseline ``b* = E[|g|^2 R] / E[|g|^2]``, g the score.

    The notes' section 4.4 gives ``b = sum_i (grad log P(tau_i))^2 R(tau_i) / sum_i
    (grad log P(tau_i))^2``; reading the square as the squared norm of the whole score
    vector makes b the single constant that minimises the trace of the estimator's
    covariance: ``Var = E[|g|^2 (R - b)^2] - |grad U|^2`` is a parabola in b with its
    minimum there (the same calculus as eqs. 41-46). Trajectories with large scores weigh
    more. Leave-one-out as in the module docstring.

    >>> optimal_baseline(np.array([1.0, 2.0, 6.0]), np.array([1.0, 1.0, 2.0])).tolist()
    [4.666666666666667, 4.333333333333333, 1.5]
    """
    seg_return = np.asarray(seg_return, dtype=np.float64)
    w = np.asarray(score_sq, dtype=np.float64)
    num = _leave_one_out((w * seg_return).sum(), 1.0, w * seg_return, 0.0)
    den = _leave_one_out(w.sum(), 1.0, w, 0.0)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def time_baseline(ret: np.ndarray, ep_step: np.ndarray) -> np.ndarray:
    """
    Time-dependent baseline ``b_t = (1/m) sum_i G_t^(i)``, the mean reward-to-go at step t.

    Section 4.4's third choice: one baseline per time index, so that early steps (with much
    reward still ahead) and late steps (with little) are centred separately. ``ret`` holds
    the reward-to-go G_t of every step and ``ep_step`` its index in the episode; steps of
    other trajectories with the same index are averaged (leave-one-out: a trajectory has one
    step per index, so leaving the step out leaves its trajectory out).

    >>> time_baseline(np.array([[3.0, 5.0], [1.0, 3.0]]), np.array([[0, 0], [1, 1]])).tolist()
    [[5.0, 3.0], [3.0, 1.0]]
    """
    ret = np.asarray(ret, dtype=np.float64)
    ep_step = np.asarray(ep_step, dtype=np.int64)
    total = np.bincount(ep_step.ravel(), weights=ret.ravel())
    count = np.bincount(ep_step.ravel()).astype(np.float64)
    return _leave_one_out(total[ep_step], count[ep_step], ret)
