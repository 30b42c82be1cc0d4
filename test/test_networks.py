"""The Gaussian policy, the value network, observation normalisation, losses and updates."""
import io
import math

import numpy as np
from pg_node.rl import losses
from pg_node.rl.a2c import make_optimizer, PolicyBatch, ValueUpdate
from pg_node.rl.normalization import RunningNorm
from pg_node.rl.policy import GaussianPolicy, segment_score_sq
from pg_node.rl.updaters import UPDATERS
from pg_node.rl.value import ValueFunction
import pytest
import torch


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


@pytest.mark.parametrize('state_dependent_std', [False, True])
def test_log_prob_is_the_diagonal_gaussian_density(state_dependent_std):
    pol = GaussianPolicy(5, 3, log_std_init=-0.5, state_dependent_std=state_dependent_std)
    obs = torch.randn(7, 5)
    act = torch.randn(7, 3)
    dist = pol.distribution(obs)
    mu, std = dist.mean, dist.stddev
    want = (-0.5 * ((act - mu) / std) ** 2 - torch.log(std) - 0.5 * math.log(2 * math.pi)).sum(-1)
    torch.testing.assert_close(pol.log_prob(obs, act), want)
    assert pol.log_prob(obs, act).shape == (7,)


@pytest.mark.parametrize('state_dependent_std', [False, True])
def test_entropy_matches_mean_negative_log_prob(state_dependent_std):
    """For a Gaussian, E[-log pi(u|s)] = H(pi(.|s)); checked within 4 standard errors."""
    pol = GaussianPolicy(4, 2, log_std_init=0.3, state_dependent_std=state_dependent_std)
    obs = torch.randn(1, 4).expand(200_000, 4)
    act, logp = pol.sample(obs, torch.Generator().manual_seed(1))
    neg = -logp.double()
    se = neg.std() / math.sqrt(len(neg))
    ent = pol.entropy(obs[:1]).detach().double()[0]
    assert abs(float(neg.mean() - ent)) < 4 * float(se)


def test_sampling_is_reproducible_and_mean_action_is_deterministic():
    pol = GaussianPolicy(3, 2)
    obs = torch.randn(10, 3)
    a1, l1 = pol.sample(obs, torch.Generator().manual_seed(5))
    a2, l2 = pol.sample(obs, torch.Generator().manual_seed(5))
    a3, _ = pol.sample(obs, torch.Generator().manual_seed(6))
    assert torch.equal(a1, a2) and torch.equal(l1, l2) and not torch.equal(a1, a3)
    torch.testing.assert_close(pol.mean_action(obs), pol.distribution(obs).mean)
    act, logp = pol.act_numpy(obs.numpy(), deterministic=True)
    np.testing.assert_allclose(act, pol.mean_action(obs).numpy(), rtol=1e-6)


@pytest.mark.parametrize('state_dependent_std', [False, True])
def test_sample_log_prob_is_bit_for_bit_the_distribution_log_prob(state_dependent_std):
    """sample() computes log pi without a Normal object: the same bits as log_prob()."""
    pol = GaussianPolicy(5, 3, log_std_init=-0.4, state_dependent_std=state_dependent_std)
    obs = torch.randn(64, 5)
    act, logp = pol.sample(obs, torch.Generator().manual_seed(2))
    with torch.no_grad():
        assert torch.equal(logp, pol.log_prob(obs, act))
        mu, std = pol.mean_std(obs)
        eps = torch.randn(mu.shape, generator=torch.Generator().manual_seed(2))
        assert torch.equal(act, mu + std * eps)


def test_running_norm_merges_batches_exactly():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 2.0, size=(1000, 4))
    norm = RunningNorm(4, eps=1e-12)
    for chunk in np.array_split(x, 7):
        norm.update(chunk)
    np.testing.assert_allclose(norm.mean.numpy(), x.mean(0), rtol=1e-9)
    np.testing.assert_allclose(norm.var.numpy(), x.var(0), rtol=1e-6)
    y = norm(torch.as_tensor(x, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(y.mean(0), 0.0, atol=1e-6)
    np.testing.assert_allclose(y.std(0), 1.0, rtol=1e-4)


def test_normalisation_is_saved_with_the_policy():
    pol = GaussianPolicy(3, 1)
    pol.obs_norm.update(np.random.default_rng(1).normal(5.0, 3.0, size=(500, 3)))
    buf = io.BytesIO()
    torch.save(pol.state_dict(), buf)
    buf.seek(0)
    other = GaussianPolicy(3, 1)
    other.load_state_dict(torch.load(buf))
    obs = torch.randn(4, 3) * 3 + 5
    torch.testing.assert_close(other.mean_action(obs), pol.mean_action(obs))
    torch.testing.assert_close(other.obs_norm.mean, pol.obs_norm.mean)
    # and the statistics do change what the policy sees
    assert not torch.allclose(GaussianPolicy(3, 1).obs_norm.mean, pol.obs_norm.mean)


def test_segment_score_sq_matches_autograd_per_segment():
    pol = GaussianPolicy(3, 2)
    obs = torch.randn(5, 3)
    act = torch.randn(5, 2)
    seg = np.array([0, 0, 1, 1, 1])
    got = segment_score_sq(pol, obs, act, seg)
    for s in (0, 1):
        pol.zero_grad()
        pol.log_prob(obs[seg == s], act[seg == s]).sum().backward()
        want = sum(float(p.grad.pow(2).sum()) for p in pol.parameters() if p.grad is not None)
        assert got[seg == s] == pytest.approx(want, rel=1e-5)


def test_ppo_gradient_equals_a2c_gradient_at_ratio_one():
    pol = GaussianPolicy(3, 2)
    obs, act, adv = torch.randn(16, 3), torch.randn(16, 2), torch.randn(16)
    logp = pol.log_prob(obs, act)
    (g_a2c,) = torch.autograd.grad(losses.policy_gradient_loss(logp, adv), pol.log_std)
    logp = pol.log_prob(obs, act)
    loss, stats = losses.ppo_clip_loss(logp, logp.detach(), adv, 0.2)
    (g_ppo,) = torch.autograd.grad(loss, pol.log_std)
    torch.testing.assert_close(g_ppo, g_a2c)
    assert stats['approx_kl'] == pytest.approx(0.0, abs=1e-7)


def test_ppo_clip_stops_the_gradient_beyond_the_range():
    logp = torch.tensor([0.5, -0.5], requires_grad=True)
    old = torch.zeros(2)
    adv = torch.tensor([1.0, -1.0])
    # ratio e^0.5 > 1.2 with A > 0, ratio e^-0.5 < 0.8 with A < 0: both clipped.
    loss, stats = losses.ppo_clip_loss(logp, old, adv, 0.2)
    (g,) = torch.autograd.grad(loss, logp)
    assert torch.all(g == 0) and stats['clip_fraction'] == 1.0
    # inside the range the gradient is -A * ratio / B
    logp = torch.tensor([0.1, -0.1], requires_grad=True)
    loss, _ = losses.ppo_clip_loss(logp, old, adv, 0.2)
    (g,) = torch.autograd.grad(loss, logp)
    torch.testing.assert_close(g, -adv * torch.exp(torch.tensor([0.1, -0.1])) / 2)


def test_explained_variance():
    y = torch.randn(100)
    assert losses.explained_variance(y, y) == pytest.approx(1.0)
    assert losses.explained_variance(torch.full((100,), float(y.mean())), y) == pytest.approx(0.0)


def test_normalize_advantage():
    adv = losses.normalize_advantage(torch.tensor([1.0, 2.0, 3.0, 10.0]))
    assert float(adv.mean()) == pytest.approx(0.0, abs=1e-6)
    assert float(adv.std()) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize('algo', ['a2c', 'ppo'])
def test_policy_update_climbs_a_gaussian_bandit(algo):
    """Reward -(u - 2)^2 with phi = reward - mean: the policy mean must move to about 2."""
    pol = GaussianPolicy(1, 1, hidden=(), normalize_obs=False, log_std_init=0.0)
    extra = {'n_epochs': 4, 'batch_size': 128} if algo == 'ppo' else {}
    upd = UPDATERS[algo](pol, learning_rate=0.05, optimizer='adam', max_grad_norm=10.0, **extra)
    gen = torch.Generator().manual_seed(0)
    obs = torch.ones(256, 1)
    for _ in range(150):
        act, logp = pol.sample(obs, gen)
        rew = -(act[:, 0] - 2.0) ** 2
        stats = upd.update(PolicyBatch(obs, act, logp, rew - rew.mean()))
    assert float(pol.mean_action(obs[:1])) == pytest.approx(2.0, abs=0.15)
    assert set(stats) >= {'policy_loss', 'entropy', 'approx_kl', 'grad_norm'}


def test_non_finite_batch_is_skipped_and_weights_kept():
    pol = GaussianPolicy(2, 1)
    upd = UPDATERS['a2c'](pol)
    before = [p.detach().clone() for p in pol.parameters()]
    obs, act = torch.randn(8, 2), torch.randn(8, 1)
    adv = torch.ones(8)
    adv[3] = float('nan')
    stats = upd.update(PolicyBatch(obs, act, torch.zeros(8), adv))
    assert stats['skipped_updates'] == 1 and upd.skipped == 1
    assert all(torch.equal(a, b) for a, b in zip(before, pol.parameters()))
    # a good batch afterwards is applied
    upd.update(PolicyBatch(obs, act, torch.zeros(8), torch.ones(8)))
    assert not all(torch.equal(a, b) for a, b in zip(before, pol.parameters()))


def test_value_update_fits_td_targets_of_an_endless_constant_reward():
    """Bootstrapped V of reward 1 every step (episodes cut only by truncation) -> 1/(1-gamma)."""
    gamma = 0.9
    vf = ValueFunction(2, hidden=(16,), normalize_obs=False)
    upd = ValueUpdate(vf, learning_rate=0.01, optimizer='adam', vf_coef=1.0,
                      max_grad_norm=100.0)
    obs = torch.randn(64, 2)
    for _ in range(600):
        # TD(0) target r + gamma V(s') with the next state drawn like the current ones
        with torch.no_grad():
            target = 1.0 + gamma * vf(torch.randn(64, 2))
        stats = upd.update(obs, target)
    v = vf.value_numpy(torch.randn(256, 2).numpy())
    assert v.mean() == pytest.approx(1 / (1 - gamma), rel=0.03)
    assert stats['value_loss'] < 0.1


def test_optimizer_names_are_checked():
    with pytest.raises(ValueError, match="unknown optimizer 'sgd'"):
        make_optimizer('sgd', GaussianPolicy(1, 1).parameters(), 1e-3)
