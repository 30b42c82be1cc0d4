"""The natural gradient: conjugate gradient, Fisher-vector products, NPG and TRPO steps."""
import json
import os
from pathlib import Path
import subprocess
import sys

from domains import ros_domain
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.run_dir import read_progress
from pg_node.rl.a2c import PolicyBatch
from pg_node.rl.learner import Learner
from pg_node.rl.natural_gradient import (conjugate_gradient, fisher_vector_product, flat,
                                         NPGUpdate, TRPOUpdate)
from pg_node.rl.policy import GaussianPolicy
import pytest
import torch
from torch.distributions import kl_divergence, Normal

REPO = Path(__file__).resolve().parent.parent


def test_conjugate_gradient_solves_a_known_spd_system():
    gen = torch.Generator().manual_seed(0)
    m = torch.randn(30, 30, generator=gen, dtype=torch.float64)
    a = m @ m.T + 30 * torch.eye(30, dtype=torch.float64)     # SPD, condition number ~5
    x_true = torch.randn(30, generator=gen, dtype=torch.float64)
    b = a @ x_true
    x = conjugate_gradient(lambda v: a @ v, b, iters=30)
    assert torch.linalg.norm(a @ x - b) < 1e-8 * torch.linalg.norm(b)
    torch.testing.assert_close(x, x_true, rtol=1e-6, atol=1e-8)   # residual x cond(A)
    # few iterations: an approximation whose residual still fell
    x3 = conjugate_gradient(lambda v: a @ v, b, iters=3)
    assert 0 < torch.linalg.norm(a @ x3 - b) < torch.linalg.norm(b)


def test_fisher_vector_product_of_a_diagonal_gaussian_is_the_analytic_fisher():
    """For N(mu, diag(sigma^2)) in (mu, log sigma): F = diag(1 / sigma^2, 2)."""
    mu = torch.nn.Parameter(torch.tensor([0.3, -1.2, 0.5], dtype=torch.float64))
    log_std = torch.nn.Parameter(torch.tensor([-0.5, 0.2, 0.0], dtype=torch.float64))
    old = Normal(mu.detach().clone(), log_std.detach().exp())

    def kl():
        return kl_divergence(old, Normal(mu, log_std.exp())).sum()

    fisher = torch.diag(torch.cat([torch.exp(-2 * log_std.detach()),
                                   torch.full((3,), 2.0, dtype=torch.float64)]))
    v = torch.tensor([1.0, -2.0, 0.5, 0.3, -0.7, 1.1], dtype=torch.float64)
    torch.testing.assert_close(fisher_vector_product(kl, [mu, log_std], v), fisher @ v,
                               rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(fisher_vector_product(kl, [mu, log_std], v, damping=0.1),
                               fisher @ v + 0.1 * v, rtol=1e-10, atol=1e-12)


def test_fisher_vector_product_of_the_policy_network():
    """With the MLP mean: F = E_s[J^T diag(1/sigma^2) J], and 2 I for log sigma."""
    torch.manual_seed(0)
    policy = GaussianPolicy(4, 2, (8,), log_std_init=-0.3, normalize_obs=False).double()
    named = list(policy.named_parameters())
    assert named[0][0] == 'log_std'                 # the first block of the flat vector
    params = [p for _, p in named]
    mean_params = params[1:]
    obs = torch.randn(16, 4, dtype=torch.float64)
    with torch.no_grad():
        old = Normal(*policy.mean_std(obs))

    def kl():
        return kl_divergence(old, policy.distribution(obs)).sum(-1).mean()

    # the Jacobian of the mean over the batch, one row per (state, action dimension)
    mu = policy.mean_std(obs)[0]
    rows = [flat(torch.autograd.grad(mu[b, a], mean_params, retain_graph=True))
            for b in range(16) for a in range(2)]
    jac = torch.stack(rows).reshape(16, 2, -1)
    inv_var = torch.exp(-2 * policy.log_std.detach())
    f_mean = torch.einsum('bai,a,baj->ij', jac, inv_var, jac) / 16
    n_mean = f_mean.shape[0]
    v = torch.randn(2 + n_mean, dtype=torch.float64)
    expected = torch.cat([2.0 * v[:2], f_mean @ v[2:]])
    torch.testing.assert_close(fisher_vector_product(kl, params, v), expected,
                               rtol=1e-8, atol=1e-10)


def _batch(seed=0, n=512):
    """Return a fresh policy and a batch it sampled, with phi favouring positive actions."""
    torch.manual_seed(seed)
    policy = GaussianPolicy(6, 2, (32,), log_std_init=-0.5)
    obs = torch.randn(n, 6)
    policy.obs_norm.update(obs.numpy())
    with torch.no_grad():
        dist = policy.distribution(obs)
        act = dist.sample()
        logp = dist.log_prob(act).sum(-1)
    adv = act.sum(-1) + 0.3 * torch.randn(n)
    return policy, PolicyBatch(obs, act, logp, adv)


@pytest.mark.parametrize('max_kl', [0.001, 0.01, 0.05])
def test_trpo_step_keeps_the_kl_bound_and_improves_the_surrogate(max_kl):
    policy, batch = _batch()
    update = TRPOUpdate(policy, max_kl=max_kl)
    adv = (batch.adv - batch.adv.mean()) / (batch.adv.std() + 1e-8)
    with torch.no_grad():
        before = float(update.surrogate(batch, adv))
        old = Normal(*policy.mean_std(batch.obs))
    stats = update.update(batch)
    with torch.no_grad():
        after = float(update.surrogate(batch, adv))
        kl = float(update.mean_kl(batch, old))
    assert stats['step_fraction'] > 0 and stats['skipped_updates'] == 0
    assert kl <= max_kl and kl == pytest.approx(stats['approx_kl'])
    assert after > before


def test_npg_step_has_the_kl_it_was_sized_for():
    """The step is sized by the quadratic model of the KL: the measured KL is close to max_kl."""
    policy, batch = _batch(1)
    update = NPGUpdate(policy, max_kl=0.005, cg_iters=20, cg_damping=1e-3)
    stats = update.update(batch)
    assert 0.5 * 0.005 < stats['approx_kl'] < 2.0 * 0.005
    assert stats['step_fraction'] == 1.0


def test_learner_runs_trpo_and_checkpoints_without_an_optimiser(tmp_path):
    cfg = load_config(None, ['algo=trpo', 'max_kl=0.02'])
    c = {**cfg['learner_node'], **cfg['actor_node']}
    learner = Learner(6, 2, c)
    _, batch = _batch(2)
    before = flat(learner.policy.parameters()).detach().clone()
    stats = learner.learn(batch.obs.numpy(), batch.act.numpy(), batch.logp.numpy(),
                          batch.adv.numpy())
    assert stats['approx_kl'] <= 0.02 and learner.version == 1
    assert not torch.equal(before, flat(learner.policy.parameters()))
    learner.configure('max_kl', 0.005)
    assert learner.update.max_kl == 0.005
    learner.save(tmp_path)
    again = Learner(6, 2, c)
    again.resume(tmp_path)
    torch.testing.assert_close(flat(again.policy.parameters()), flat(learner.policy.parameters()))


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.parametrize('preset', ['npg', 'trpo'])
def test_the_graph_trains_with_the_preset(tmp_path, preset):
    """Four nodes, ``--config npg|trpo``: the return rises, every step keeps its KL bound."""
    run_dir = tmp_path / 'run'
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain(base=60, spread=60)),
               PYTHONPATH=str(REPO), PYTHONUNBUFFERED='1')
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir),
                          '--no-progress', '--total-steps', '60000', '--eval-episodes', '20',
                          '--config', preset], env=env, cwd=REPO, capture_output=True,
                         text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['config']['learner_node']['algo'] == preset
    max_kl = summary['config']['learner_node']['max_kl']
    rows = read_progress(run_dir / 'progress.csv')
    returns = [r['episode_return'] for r in rows if np.isfinite(r['episode_return'])]
    # a fresh policy scores about -40 (log_std -0.5 pays for its noisy torques); 30 updates
    # of 2048 transitions reach about -8 (-7.6 for npg, -9.3 for trpo when written)
    assert returns[-1] > returns[0] + 10, (returns[0], returns[-1])
    assert summary['eval_return'] > returns[0] + 10
    kls = [r['approx_kl'] for r in rows]
    assert len(kls) == summary['policy_version'] and all(np.isfinite(kls)), kls
    if preset == 'trpo':        # the line search accepts no step beyond the bound
        assert max(kls) <= max_kl + 1e-9
    else:                       # NPG sizes its step on the KL's quadratic model: close to it
        assert 0.5 * max_kl < np.median(kls) and max(kls) < 1.25 * max_kl, kls
