"""
The simulated arm as a problem for the gradient-estimator lab.

The policy is a fixed, partly trained :class:`~pg_node.rl.policy.GaussianPolicy` on the default
arm (``reacher2``), trained in-process with a fixed seed. A *trajectory* is one full episode
of ``horizon`` control steps from a fresh start, the notes' finite-horizon setting without
discounting (gamma = 1): the last step is marked terminated, so ``U(theta)`` is the expected
sum of the episode's rewards and nothing is bootstrapped past it.

Estimates are over all of the policy's parameters (trunk, mean head, log-std). For one batch,
each row's estimate ``g = (1/m) grad_theta sum_{i,t} log pi(u_t|s_t) phi_t`` (eq. 20) is one
vector-Jacobian product of the batch's log-probabilities with phi as the weights; all rows
are taken in one batched backward pass, so no per-step score is ever stored. The optimal
baseline's weights (the squared norm of each trajectory's score) come from the same kind of
batched product with one row per trajectory.

Value functions, both fitted on separate data drawn before the lab starts:

- ``value_baseline``, ``td_residual``, ``gae``: a value network ``V(s, t/H)`` fitted by
  regression on the Monte-Carlo reward-to-go (the step index is an input because, with a
  finite horizon, the value depends on the steps left);
- the ``[approx V]`` rows: the mean reward-to-go at each step index, a state-blind V.

Neither is the true V^pi, so the TD residual and GAE rows are biased to the extent the fitted
network is wrong, and the lab reports how much. The true gradient is the ``value_baseline``
estimate (unbiased for any V) over a very large batch, with its standard error.
"""
from typing import Dict, Optional, Tuple

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.lab.variance import LAB_ROWS
from pg_node.rl.estimators import compute_phi
from pg_node.rl.returns import reward_to_go
from pg_node.rl.rollout import Rollout
from pg_node.rl.value import ValueFunction
from pg_node.sim.arm_task import ArmTask
import torch


def z_threshold(n_params: int, family_error: float = 1e-3) -> float:
    """Return the |z| that a max over ``n_params`` unbiased components exceeds w.p. ~error."""
    from statistics import NormalDist
    return max(4.0, NormalDist().inv_cdf(1 - family_error / (2 * n_params)))


class ArmLab:
    """A fixed policy on the arm, the fitted value functions, and batch estimates."""

    gamma = 1.0
    exact_value = False

    def __init__(self, policy, model: str = 'reacher2', horizon: int = 50, seed: int = 0,
                 value_episodes: int = 4096, true_episodes: int = 32768, chunk: int = 1024,
                 value_epochs: int = 30, info: Optional[Dict] = None):
        self.policy = policy.eval()
        for p in self.policy.parameters():
            p.requires_grad_(True)
        self.params = [p for p in self.policy.parameters() if p.requires_grad]
        self.n_params = int(sum(p.numel() for p in self.params))
        self.model, self.horizon, self.seed = model, int(horizon), int(seed)
        self.chunk = int(chunk)
        self.bias_threshold = z_threshold(self.n_params)
        self.info = dict(info or {})
        self.title = (f'the arm ({model}, {horizon}-step episodes, '
                      f'{self.n_params} policy parameters)')
        self._tasks = {}
        rng = np.random.default_rng(seed + 7919)
        self._fit_values(value_episodes, value_epochs, rng)
        self.true_episodes = int(true_episodes)
        self._true = None

    # --- sampling ---------------------------------------------------------------------------

    def _task(self, m: int, rng: np.random.Generator) -> ArmTask:
        if m not in self._tasks:
            self._tasks[m] = ArmTask(resolve_model(self.model), num_envs=m,
                                     seed=int(rng.integers(2 ** 31)),
                                     max_episode_steps=self.horizon)
            self._tasks[m].reset()
        return self._tasks[m]

    def sample(self, m: int, rng: np.random.Generator) -> Dict[str, np.ndarray]:
        """Run m full episodes of the policy; return ``obs``, ``act``, ``rew`` (time-major)."""
        task = self._task(m, rng)
        gen = torch.Generator().manual_seed(int(rng.integers(2 ** 62)))
        H = self.horizon
        obs = np.zeros((H, m, task.obs_dim))
        act = np.zeros((H, m, task.act_dim))
        rew = np.zeros((H, m))
        o = task.observe()
        lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
        for t in range(H):
            a, _ = self.policy.act_numpy(o, generator=gen)
            obs[t], act[t] = o, a
            o, rew[t], _, _, info = task.step(np.clip(a, lo, hi))
        if not np.all(info['episode_step'] == 0):
            raise RuntimeError('episodes did not end after the horizon')
        return {'obs': obs, 'act': act, 'rew': rew}

    def _episode_batch(self, rew: np.ndarray, val=None, next_val=None, score_sq=None):
        H, m = rew.shape
        terminated = np.zeros((H, m), dtype=bool)
        terminated[-1] = True
        return Rollout(rew=rew, terminated=terminated, truncated=np.zeros((H, m), bool),
                       val=val, next_val=next_val, score_sq=score_sq)

    # --- value functions --------------------------------------------------------------------

    def _features(self, obs: np.ndarray) -> torch.Tensor:
        H = obs.shape[0]
        t = np.broadcast_to((np.arange(H) / H)[:, None, None], obs.shape[:2] + (1,))
        return torch.as_tensor(np.concatenate([obs, t], -1), dtype=torch.float32)

    def _fit_values(self, episodes: int, epochs: int, rng: np.random.Generator):
        """Fit ``V(s, t/H)`` and the per-step mean on ``episodes`` fresh episodes."""
        obs, ret = [], []
        for _ in range(max(1, episodes // self.chunk)):
            data = self.sample(min(self.chunk, episodes), rng)
            obs.append(data['obs'])
            ret.append(reward_to_go(self._episode_batch(data['rew']), self.gamma))
        obs, ret = np.concatenate(obs, 1), np.concatenate(ret, 1)
        self.time_values = np.append(ret.mean(1), 0.0)
        torch.manual_seed(self.seed)
        self.value_fn = ValueFunction(obs.shape[-1] + 1)
        x = self._features(obs).reshape(-1, obs.shape[-1] + 1)
        y = torch.as_tensor(ret.reshape(-1), dtype=torch.float32)
        self.value_fn.obs_norm.update(x.double())
        opt = torch.optim.Adam(self.value_fn.parameters(), lr=1e-3)
        gen = torch.Generator().manual_seed(self.seed)
        for _ in range(epochs):
            for idx in torch.randperm(len(y), generator=gen).split(256):
                loss = (self.value_fn(x[idx]) - y[idx]).pow(2).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
        with torch.no_grad():
            pred = self.value_fn(x)
        self.value_explained_variance = float(1 - (y - pred).var() / y.var())

    def values(self, obs: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Return ``(V(s_t), V(s_{t+1}))`` of the fitted network for ``(H, m, D)`` obs."""
        with torch.no_grad():
            val = self.value_fn(self._features(obs)).double().numpy()
        next_val = np.zeros_like(val)
        next_val[:-1] = val[1:]
        return val, next_val

    # --- gradients --------------------------------------------------------------------------

    def _vjp(self, data: Dict[str, np.ndarray], weights: np.ndarray) -> np.ndarray:
        """Return ``grad_theta sum_b w[k, b] log pi(u_b|s_b)`` for every row k of ``weights``."""
        obs = torch.as_tensor(data['obs'].reshape(-1, data['obs'].shape[-1]),
                              dtype=torch.float32)
        act = torch.as_tensor(data['act'].reshape(-1, data['act'].shape[-1]),
                              dtype=torch.float32)
        logp = self.policy.log_prob(obs, act)
        w = torch.as_tensor(weights, dtype=torch.float32)
        grads = torch.autograd.grad(logp, self.params, grad_outputs=w, is_grads_batched=True)
        return torch.cat([g.reshape(len(weights), -1) for g in grads], 1).double().numpy()

    def _score_sq(self, data: Dict[str, np.ndarray]) -> np.ndarray:
        """Return each trajectory's ``||sum_t grad log pi||^2``, broadcast to ``(H, m)``."""
        H, m = data['rew'].shape
        onehot = np.zeros((m, H, m))
        onehot[np.arange(m), :, np.arange(m)] = 1.0
        scores = self._vjp(data, onehot.reshape(m, H * m))
        return np.broadcast_to((scores ** 2).sum(1), (H, m))

    def batch_estimates(self, m: int, rng: np.random.Generator,
                        gae_lambda: float) -> Dict[str, np.ndarray]:
        """Sample m episodes; return every row of :data:`LAB_ROWS`'s gradient estimate."""
        data = self.sample(m, rng)
        return self._estimates(data, gae_lambda, LAB_ROWS)

    def _estimates(self, data, gae_lambda, rows) -> Dict[str, np.ndarray]:
        rew = data['rew']
        H, m = rew.shape
        val, next_val = self.values(data['obs'])
        need_sq = any(est == 'optimal_baseline' for _, est, _ in rows)
        score_sq = self._score_sq(data) if need_sq else None
        approx = np.broadcast_to(self.time_values[:H, None], (H, m))
        approx_next = np.broadcast_to(self.time_values[1:H + 1, None], (H, m))
        batches = {'exact': self._episode_batch(rew, val, next_val, score_sq),
                   'approx': self._episode_batch(rew, approx, approx_next, score_sq)}
        phis = np.stack([compute_phi(est, batches[which], self.gamma, gae_lambda).ravel()
                         for _, est, which in rows])
        # eq. 20 for every row at once: (1/m) sum_{i,t} score_{t,i} phi_{t,i}
        grads = self._vjp(data, phis / m)
        return {name: grads[k] for k, (name, _, _) in enumerate(rows)}

    def true_gradient(self) -> Tuple[np.ndarray, np.ndarray]:
        """Return the value-baseline estimate over ``true_episodes`` episodes, and its se."""
        if self._true is None:
            rng = np.random.default_rng(self.seed + 104729)
            row = [('value_baseline', 'value_baseline', 'exact')]
            chunks = [self._estimates(self.sample(self.chunk, rng), 0.0, row)['value_baseline']
                      for _ in range(max(2, self.true_episodes // self.chunk))]
            chunks = np.stack(chunks)
            self._true = chunks.mean(0), chunks.std(0, ddof=1) / np.sqrt(len(chunks))
        return self._true

    def close(self):
        """Close the simulators."""
        for task in self._tasks.values():
            task.close()
        self._tasks.clear()


def trained_policy(train_steps: int, seed: int = 0, model: str = 'reacher2'):
    """Train A2C in-process for ``train_steps`` with ``seed``; return ``(policy, summary)``."""
    from pg_node.common.config_files import load_config
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(None, [f'seed={seed}', f'model={model}'])
    summary = train_inprocess(cfg, train_steps, eval_episodes=100)
    policy = summary['learner'].policy
    info = {'train_steps': summary['total_steps'], 'eval_return': summary['eval_return'],
            'eval_return_std': summary['eval_return_std'], 'seed': seed}
    return policy, info


def make_arm_lab(train_steps: int = 100_000, seed: int = 0, model: str = 'reacher2',
                 **kwargs) -> ArmLab:
    """Train a policy briefly with a fixed seed and build the arm lab problem around it."""
    torch.set_num_threads(1)
    policy, info = trained_policy(train_steps, seed, model)
    return ArmLab(policy, model=model, seed=seed, info=info, **kwargs)
