"""
A problem with a known policy gradient: linear dynamics, Gaussian noise, quadratic cost.

``s_{t+1} = A s_t + B u_t + w_t`` with ``w_t ~ N(0, W)``, ``s_0 ~ N(mu0, S0)``, reward
``r_t = -(s_t' Q s_t + u_t' R u_t)`` over a finite horizon H, and a linear Gaussian policy
``u_t ~ N(K s_t + k, diag(exp(2 log_std)))`` with parameters ``theta = (K, k, log_std)``.

Every state is Gaussian, so ``U(theta) = E[sum_t r_t]`` (the notes' objective before eq. 2)
is a closed-form function of theta (propagate the state mean and covariance) and torch's
autograd differentiates it exactly. The true value function ``V_t(s)`` is quadratic in s and
follows from a backward recursion. Both let the variance lab check each estimator of
``grad U`` against the truth.
"""
from dataclasses import dataclass, field

import numpy as np
import torch


def _t(x):
    return torch.as_tensor(np.asarray(x, dtype=np.float64))


@dataclass
class LinearGaussianProblem:
    """System, cost, horizon and the policy parameters at which the gradient is wanted."""

    A: np.ndarray = field(default_factory=lambda: np.array([[1.0, 0.2], [-0.1, 0.9]]))
    B: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.1], [0.2, 0.0]]))
    Q: np.ndarray = field(default_factory=lambda: np.diag([1.0, 0.5]))
    R: np.ndarray = field(default_factory=lambda: np.diag([0.1, 0.1]))
    W: np.ndarray = field(default_factory=lambda: 0.01 * np.eye(2))
    mu0: np.ndarray = field(default_factory=lambda: np.array([1.0, -0.5]))
    S0: np.ndarray = field(default_factory=lambda: 0.1 * np.eye(2))
    horizon: int = 10
    K: np.ndarray = field(default_factory=lambda: np.array([[-0.3, 0.1], [0.0, -0.2]]))
    k: np.ndarray = field(default_factory=lambda: np.array([0.1, 0.0]))
    log_std: np.ndarray = field(default_factory=lambda: np.log(np.array([0.3, 0.3])))

    @property
    def obs_dim(self) -> int:
        """Return the state dimension n."""
        return self.A.shape[0]

    @property
    def act_dim(self) -> int:
        """Return the action dimension d."""
        return self.B.shape[1]

    @property
    def theta(self) -> np.ndarray:
        """Return the flat parameter vector ``(K row-major, k, log_std)``."""
        return np.concatenate([self.K.ravel(), self.k, self.log_std])

    @property
    def n_params(self) -> int:
        """Return the number of policy parameters."""
        return self.theta.size

    def _unpack(self, theta: torch.Tensor):
        n, d = self.obs_dim, self.act_dim
        return theta[:d * n].reshape(d, n), theta[d * n:d * n + d], theta[d * n + d:]

    def expected_return(self, theta: torch.Tensor) -> torch.Tensor:
        """Return ``U(theta)`` in closed form (differentiable in theta)."""
        K, k, log_std = self._unpack(theta)
        A, B, Q, R, W = map(_t, (self.A, self.B, self.Q, self.R, self.W))
        var_u = torch.diag(torch.exp(2 * log_std))
        m, S = _t(self.mu0), _t(self.S0)
        total = torch.zeros((), dtype=torch.float64)
        for _ in range(self.horizon):
            mu_u = K @ m + k
            S_u = K @ S @ K.T + var_u
            # E[s'Qs] = tr(QS) + m'Qm and E[u'Ru] likewise, u's moments from s's.
            total = total - (torch.trace(Q @ S) + m @ Q @ m
                             + torch.trace(R @ S_u) + mu_u @ R @ mu_u)
            M = A + B @ K
            m = M @ m + B @ k
            S = M @ S @ M.T + B @ var_u @ B.T + W
        return total

    def true_gradient(self) -> np.ndarray:
        """Return ``grad_theta U(theta)`` at the problem's theta, exact up to float64."""
        theta = _t(self.theta).requires_grad_(True)
        (grad,) = torch.autograd.grad(self.expected_return(theta), theta)
        return grad.numpy()

    def value_coefficients(self):
        """
        Return ``[(P_t, p_t, c_t)]`` for t = 0..H with ``V_t(s) = -(s'P_t s + p_t's + c_t)``.

        Backward recursion from ``V_H = 0``: ``V_t(s) = E[r_t + V_{t+1}(s_{t+1})]`` with
        ``u = K s + k + noise`` and ``s_{t+1} = M s + B k + B noise + w``, ``M = A + B K``.
        """
        A, B, Q, R, W, K, k = self.A, self.B, self.Q, self.R, self.W, self.K, self.k
        var_u = np.diag(np.exp(2 * self.log_std))
        M = A + B @ K
        Bk = B @ k
        C = B @ var_u @ B.T + W
        n = self.obs_dim
        coeffs = [(np.zeros((n, n)), np.zeros(n), 0.0)]
        for _ in range(self.horizon):
            P, p, c = coeffs[0]
            coeffs.insert(0, (
                Q + K.T @ R @ K + M.T @ P @ M,
                2 * K.T @ R @ k + 2 * M.T @ P @ Bk + M.T @ p,
                k @ R @ k + np.trace(R @ var_u) + Bk @ P @ Bk + np.trace(P @ C) + p @ Bk + c,
            ))
        return coeffs

    def sample(self, m: int, rng: np.random.Generator):
        """
        Roll out m trajectories; return a dict of ``(H, m, ...)`` arrays.

        Keys: ``obs``, ``act``, ``rew``, ``score`` (``grad_theta log pi(u_t|s_t)`` per step, in
        closed form for the Gaussian), ``val`` (true ``V_t(s_t)``) and ``next_val`` (true
        ``V_{t+1}(s_{t+1})``, zero after the last step).
        """
        H, n, d = self.horizon, self.obs_dim, self.act_dim
        std = np.exp(self.log_std)
        obs = np.zeros((H + 1, m, n))
        act = np.zeros((H, m, d))
        rew = np.zeros((H, m))
        score = np.zeros((H, m, self.n_params))
        obs[0] = rng.multivariate_normal(self.mu0, self.S0, size=m)
        w_chol = np.linalg.cholesky(self.W)
        for t in range(H):
            s = obs[t]
            eps = rng.standard_normal((m, d))
            u = s @ self.K.T + self.k + std * eps
            act[t] = u
            rew[t] = -(np.einsum('mi,ij,mj->m', s, self.Q, s)
                       + np.einsum('mi,ij,mj->m', u, self.R, u))
            # Score of the Gaussian: d/dmu = (u - mu)/var, d/dlog_std = (u - mu)^2/var - 1.
            z = eps / std
            score[t, :, :d * n] = (z[:, :, None] * s[:, None, :]).reshape(m, d * n)
            score[t, :, d * n:d * n + d] = z
            score[t, :, d * n + d:] = eps ** 2 - 1.0
            obs[t + 1] = s @ self.A.T + u @ self.B.T + rng.standard_normal((m, n)) @ w_chol.T
        coeffs = self.value_coefficients()
        vals = np.stack([-(np.einsum('mi,ij,mj->m', obs[t], P, obs[t]) + obs[t] @ p + c)
                         for t, (P, p, c) in enumerate(coeffs)])
        return {'obs': obs[:H], 'act': act, 'rew': rew, 'score': score,
                'val': vals[:H], 'next_val': vals[1:]}
