"""
The TD residual and generalized advantage estimation, GAE(gamma, lambda).

With a critic V, the advantage of the action at step t can be estimated by the one-step TD
residual ``delta_t = r_t + gamma V(s_{t+1}) - V(s_t)`` (the notes' list of phi choices after
eq. 28), or by an exponentially weighted sum of future residuals, GAE (the notes'
reference [11]): ``A_t = sum_l (gamma lambda)^l delta_{t+l}``. lambda = 0 gives the TD
residual (low variance, biased unless V is exact); lambda = 1 gives the discounted
reward-to-go minus V(s_t), the A2C advantage of eq. 64 (unbiased for any V, higher
variance). GAE plus V(s_t) is the TD(lambda) return, a value target.
"""
import numpy as np

from pg_node.rl.rollout import Rollout


def td_residual(batch: Rollout, gamma: float) -> np.ndarray:
    """
    One-step TD residual ``delta_t = r_t + gamma (1 - term_t) V(s_{t+1}) - V(s_t)``.

    After a termination the next state's value is zero; after a truncation it is
    ``V`` of the true last state (``batch.next_val``), the bootstrap the time limit asks for.

    >>> b = Rollout(rew=[1.0, 1.0], terminated=[0, 1], truncated=[0, 0],
    ...             val=[2.0, 1.0], next_val=[1.0, 5.0])
    >>> td_residual(b, gamma=0.5).ravel().tolist()
    [-0.5, 0.0]
    """
    return batch.rew + gamma * np.where(batch.terminated, 0.0, batch.next_val) - batch.val


def gae(batch: Rollout, gamma: float, gae_lambda: float) -> np.ndarray:
    """
    Generalized advantage estimate ``A_t = delta_t + gamma lambda A_{t+1}`` within a segment.

    The recursion stops at every episode end (the residual there already holds the right
    bootstrap) and at the edge of the batch (where ``next_val`` bootstraps).

    >>> b = Rollout(rew=[1.0, 1.0, 1.0], terminated=[0, 0, 1], truncated=[0, 0, 0])
    >>> gae(b, gamma=1.0, gae_lambda=0.5).ravel().tolist()
    [1.75, 1.5, 1.0]
    """
    delta = td_residual(batch, gamma)
    cont = ~batch.done
    adv = np.zeros_like(delta)
    last = np.zeros(delta.shape[1])
    for t in range(delta.shape[0] - 1, -1, -1):
        # the next line implements GAE-lambda: A_t = delta_t + gamma*lambda*A_{t+1}
        last = delta[t] + gamma * gae_lambda * np.where(cont[t], last, 0.0)
        adv[t] = last
    return adv


def td_lambda_return(batch: Rollout, gamma: float, gae_lambda: float) -> np.ndarray:
    """TD(lambda) value target ``GAE(gamma, lambda) + V(s_t)``, bootstrapped as GAE is."""
    return gae(batch, gamma, gae_lambda) + batch.val
