"""
The numpy sampler is the torch policy's step path: same layout, same distribution.

The actor node and the in-process reference sample with :class:`NumpySampler`; the learner
differentiates the torch :class:`GaussianPolicy`. These tests hold the two to the same
function, and check that the nodes that only act run with torch made unimportable.
"""
import subprocess
import sys

import numpy as np
from pg_node.rl.policy import GaussianPolicy
from pg_node.rl.sampler import make_rng, NumpySampler, policy_layout
from pg_node.rl.weights import flatten_state, layout_of
import pytest
import torch

CASES = [((64, 64), 'tanh', False, True), ((32,), 'relu', True, True),
         ((16, 8, 4), 'elu', False, False), ((), 'tanh', True, True)]


def _pair(hidden, act, sds, norm, obs_dim=10, act_dim=3, seed=0):
    """Return a torch policy with non-trivial weights and statistics and its loaded sampler."""
    torch.manual_seed(seed)
    policy = GaussianPolicy(obs_dim, act_dim, hidden, act, -0.5, sds, norm)
    with torch.no_grad():
        for p in policy.parameters():           # the initial mean head is nearly zero
            p.add_(0.3 * torch.randn(p.shape))
    rng = np.random.default_rng(seed)
    policy.obs_norm.update(rng.normal(2.0, 3.0, size=(500, obs_dim)))
    sampler = NumpySampler(obs_dim, act_dim, hidden, act, sds, norm)
    sampler.load(*flatten_state(policy))
    return policy, sampler, rng


@pytest.mark.parametrize('hidden,act,sds,norm', CASES)
def test_layout_is_the_torch_policys(hidden, act, sds, norm):
    policy = GaussianPolicy(7, 2, hidden, act, 0.0, sds, norm)
    assert policy_layout(7, 2, hidden, sds) == layout_of(policy)


@pytest.mark.parametrize('hidden,act,sds,norm', CASES)
def test_mean_and_std_equal_the_torch_policys(hidden, act, sds, norm):
    policy, sampler, rng = _pair(hidden, act, sds, norm)
    obs = rng.normal(2.0, 3.0, size=(64, 10))
    mu, std = sampler.mean_std(obs)
    with torch.no_grad():
        mu_t, std_t = policy.mean_std(torch.as_tensor(obs, dtype=torch.float32))
    assert mu.dtype == np.float32 and mu.shape == (64, 3) and std.shape == (64, 3)
    # float32 arithmetic in another library: equal to a few units in the last place
    np.testing.assert_allclose(mu, mu_t.numpy(), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(std, std_t.numpy(), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(sampler.mean_action(obs), mu_t.numpy(), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize('hidden,act,sds,norm', CASES[:2])
def test_logp_is_the_torch_log_prob_of_the_draw(hidden, act, sds, norm):
    policy, sampler, rng = _pair(hidden, act, sds, norm)
    obs = rng.normal(2.0, 3.0, size=(256, 10))
    u, logp = sampler.sample(obs, make_rng(1))
    assert u.dtype == np.float64 and logp.shape == (256,)
    with torch.no_grad():
        ref = policy.log_prob(torch.as_tensor(obs, dtype=torch.float32),
                              torch.as_tensor(u, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(logp, ref, rtol=1e-5, atol=1e-5)


def test_draws_follow_the_gaussian():
    """Standardised draws have mean 0 and variance 1, within 5 standard errors."""
    _, sampler, rng = _pair((64, 64), 'tanh', False, True)
    obs = rng.normal(2.0, 3.0, size=(64, 10))
    mu, std = sampler.mean_std(obs)
    gen = make_rng(3)
    z = np.stack([(sampler.sample(obs, gen)[0] - mu) / std for _ in range(200)])
    n = z.size                                   # 38,400 independent standard normals
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert abs(z.var() - 1) < 5 * np.sqrt(2 / n)


def test_same_seed_same_draws_other_seed_other_draws():
    _, sampler, rng = _pair((64, 64), 'tanh', False, True)
    obs = rng.normal(size=(8, 10))
    a = sampler.sample(obs, make_rng(5))
    b = sampler.sample(obs, make_rng(5))
    c = sampler.sample(obs, make_rng(6))
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


def test_bad_weights_are_refused_in_one_clear_line():
    policy, sampler, _ = _pair((64, 64), 'tanh', False, True)
    layout, vec = flatten_state(policy)
    with pytest.raises(ValueError, match='layout does not match.*trunk.0.weight'):
        NumpySampler(10, 3, (32, 64)).load(layout, vec)
    with pytest.raises(ValueError, match='values, layout needs'):
        sampler.load(layout, vec[:-1])
    bad = vec.copy()
    bad[5] = np.nan
    with pytest.raises(ValueError, match='non-finite'):
        sampler.load(layout, bad)
    with pytest.raises(ValueError, match='unknown activation'):
        NumpySampler(10, 3, act='swish')
    with pytest.raises(RuntimeError, match='no weights yet'):
        NumpySampler(10, 3).mean_std(np.zeros((1, 10)))


TORCH_BLOCKER = """
import importlib, importlib.abc, sys

class NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] == 'torch':
            raise ImportError(f'{name} is not importable in this test')

sys.meta_path.insert(0, NoTorch())
for name in sys.argv[1:]:
    importlib.import_module(name)
    print(name)
"""

LIGHT_NODES = ['pg_node.ros.sim_node', 'pg_node.ros.actor_node', 'pg_node.ros.replay_node',
               'pg_node.ros.policy_node', 'pg_node.rl.sampler']


def test_nodes_that_do_not_train_import_without_torch():
    res = subprocess.run([sys.executable, '-c', TORCH_BLOCKER, *LIGHT_NODES],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.split() == LIGHT_NODES


def test_the_torch_blocker_blocks():
    res = subprocess.run([sys.executable, '-c', TORCH_BLOCKER, 'pg_node.rl.policy'],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode != 0 and 'not importable in this test' in res.stderr
