"""
The policy's step path without torch: the Gaussian's forward pass and sampling in numpy.

At every control step the actor evaluates mu_theta(s) and sigma_theta(s) for all arms and
draws u = mu + sigma * eps with eps ~ N(0, I); the learner, which differentiates
log pi_theta(u|s) (the score of eqs. 14 and 17 of the notes), keeps the torch
:class:`~pg_node.rl.policy.GaussianPolicy`. For a 64x64 MLP the forward pass is three small
matrix products, for which torch's per-call overhead costs several times the arithmetic,
and importing torch costs a node most of a gigabyte of memory. :class:`NumpySampler` does
the same arithmetic in float32 numpy from the very state the learner publishes (the flat
vector of :mod:`pg_node.rl.weights`, whose names and shapes it checks), so a node that only
acts never imports torch.

Lock-step training through the ROS graph equals the in-process run bit for bit because the
actor node and :func:`pg_node.rl.train_inprocess.train_inprocess` both sample with this
class and the same seeded numpy generator.
"""
import math
from typing import Sequence, Tuple

import numpy as np
from pg_node.rl.weights import Layout, unflatten

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
_ACTIVATIONS = {'tanh': np.tanh, 'relu': lambda x: np.maximum(x, np.float32(0)),
                'elu': lambda x: np.where(x > 0, x, np.expm1(x))}


def policy_layout(obs_dim: int, act_dim: int, hidden: Sequence[int],
                  state_dependent_std: bool) -> Layout:
    """
    Return the ``(name, shape)`` list of the torch policy's ``state_dict``, in its order.

    It is :func:`pg_node.rl.weights.layout_of` of a
    :class:`~pg_node.rl.policy.GaussianPolicy` built with the same arguments, worked out
    without building one (a test keeps the two equal).
    """
    # a module's own parameters come first in its state_dict, then its children in order
    layout = [] if state_dependent_std else [('log_std', (act_dim,))]
    layout += [('obs_norm.mean', (obs_dim,)), ('obs_norm.var', (obs_dim,)),
               ('obs_norm.count', ())]
    sizes = [obs_dim, *hidden]
    for j in range(len(sizes) - 1):
        # nn.Sequential numbers a Linear and its activation 2j and 2j + 1
        layout += [(f'trunk.{2 * j}.weight', (sizes[j + 1], sizes[j])),
                   (f'trunk.{2 * j}.bias', (sizes[j + 1],))]
    width = sizes[-1]
    layout += [('mu.weight', (act_dim, width)), ('mu.bias', (act_dim,))]
    if state_dependent_std:
        layout += [('log_std_head.weight', (act_dim, width)), ('log_std_head.bias', (act_dim,))]
    return layout


class NumpySampler:
    """
    The diagonal Gaussian policy ``N(mu(s), diag(sigma(s)^2))`` for acting, in numpy.

    Built from the configuration keys the torch policy takes (``hidden_sizes``,
    ``activation``, ``normalize_obs``, ``state_dependent_std``); it cannot act until
    :meth:`load` has given it weights.
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden: Sequence[int] = (64, 64),
                 act: str = 'tanh', state_dependent_std: bool = False,
                 normalize_obs: bool = True):
        if act not in _ACTIVATIONS:
            raise ValueError(f'unknown activation {act!r}; choose one of: '
                             f'{", ".join(_ACTIVATIONS)}')
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)
        self.hidden = [int(h) for h in hidden]
        self.activation = _ACTIVATIONS[act]
        self.state_dependent_std = bool(state_dependent_std)
        self.normalize_obs = bool(normalize_obs)
        self.layout = policy_layout(self.obs_dim, self.act_dim, self.hidden,
                                    self.state_dependent_std)
        self.loaded = False

    @classmethod
    def from_config(cls, obs_dim: int, act_dim: int, cfg) -> 'NumpySampler':
        """Build the sampler of the policy :func:`pg_node.rl.learner.make_policy` builds."""
        return cls(obs_dim, act_dim, cfg['hidden_sizes'], cfg['activation'],
                   cfg['state_dependent_std'], cfg['normalize_obs'])

    def load(self, layout, vec) -> None:
        """Take the policy's state as ``(layout, flat float64 vector)``; ValueError if unfit."""
        state = unflatten(layout, vec, self.layout)
        # the torch policy keeps the running moments in float64 and casts mean and
        # sqrt(var + eps) to the input's dtype; its weights are float32
        self.norm_mean = state['obs_norm.mean'].astype(np.float32)
        self.norm_std = np.sqrt(state['obs_norm.var'] + 1e-8).astype(np.float32)
        self.layers = [(state[f'trunk.{2 * j}.weight'].astype(np.float32).T.copy(),
                        state[f'trunk.{2 * j}.bias'].astype(np.float32))
                       for j in range(len(self.hidden))]
        self.mu_w = state['mu.weight'].astype(np.float32).T.copy()
        self.mu_b = state['mu.bias'].astype(np.float32)
        if self.state_dependent_std:
            self.std_w = state['log_std_head.weight'].astype(np.float32).T.copy()
            self.std_b = state['log_std_head.bias'].astype(np.float32)
        else:
            self.log_std = state['log_std'].astype(np.float32)
        self.loaded = True

    def mean_std(self, obs: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Return float32 ``(mu, sigma)``, each ``(B, act_dim)``, for a batch of observations."""
        if not self.loaded:
            raise RuntimeError('the sampler has no weights yet (call load first)')
        x = np.asarray(obs, dtype=np.float32)
        if self.normalize_obs:
            x = np.clip((x - self.norm_mean) / self.norm_std, np.float32(-10.0),
                        np.float32(10.0))
        for w, b in self.layers:
            x = self.activation(x @ w + b)
        mu = x @ self.mu_w + self.mu_b
        log_std = x @ self.std_w + self.std_b if self.state_dependent_std else self.log_std
        log_std = np.clip(log_std, np.float32(LOG_STD_MIN), np.float32(LOG_STD_MAX))
        return mu, np.broadcast_to(np.exp(log_std), mu.shape)

    def sample(self, obs: np.ndarray, rng: np.random.Generator
               ) -> Tuple[np.ndarray, np.ndarray]:
        """
        Draw ``u ~ pi(.|obs)`` with ``rng``; return float64 ``(act, logp)``.

        ``logp`` is ``log pi(u|s)`` summed over the action's dimensions, computed from the
        float32 draw as the torch policy's ``log_prob`` computes it.
        """
        mu, std = self.mean_std(obs)
        eps = rng.standard_normal(mu.shape, dtype=np.float32)
        act = mu + std * eps
        logp = -((act - mu) ** 2) / (2 * std ** 2) - np.log(std) - np.float32(LOG_SQRT_2PI)
        return act.astype(np.float64), logp.sum(-1).astype(np.float64)

    def mean_action(self, obs: np.ndarray) -> np.ndarray:
        """Return the deterministic action mu(obs) as float64."""
        return self.mean_std(obs)[0].astype(np.float64)


def make_rng(seed: int) -> np.random.Generator:
    """Return the seeded generator an actor samples with (PCG64, numpy's default)."""
    return np.random.Generator(np.random.PCG64(int(seed)))
