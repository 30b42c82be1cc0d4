"""Hand-computed returns and advantages, as SB3's test_gae does, plus the special cases."""
import numpy as np
from pg_node.rl import estimators
from pg_node.rl.gae import gae, td_lambda_return, td_residual
from pg_node.rl.returns import discount_cumsum, reward_to_go, total_return
from pg_node.rl.rollout import episode_steps, Rollout, segment_ids
import pytest


def brute_force_gae(rew, val, next_val, term, trunc, gamma, lam):
    """GAE straight from its definition: sum_l (gamma lam)^l delta_{t+l} inside the segment."""
    T, N = rew.shape
    delta = rew + gamma * np.where(term, 0.0, next_val) - val
    adv = np.zeros((T, N))
    for n in range(N):
        for t in range(T):
            total, k = 0.0, t
            while True:
                total += (gamma * lam) ** (k - t) * delta[k, n]
                if term[k, n] or trunc[k, n] or k == T - 1:
                    break
                k += 1
            adv[t, n] = total
    return adv


def brute_force_rtg(rew, next_val, term, trunc, gamma):
    """Reward-to-go from its definition, bootstrapped where the data stops without termination."""
    T, N = rew.shape
    ret = np.zeros((T, N))
    for n in range(N):
        for t in range(T):
            total, k = 0.0, t
            while True:
                total += gamma ** (k - t) * rew[k, n]
                if term[k, n]:
                    break
                if trunc[k, n] or k == T - 1:
                    total += gamma ** (k - t + 1) * next_val[k, n]
                    break
                k += 1
            ret[t, n] = total
    return ret


# Episode boundary patterns over T = 6 steps and N = 3 arms: none, a termination, a truncation
# and both, at different places in different columns.
BOUNDARIES = {
    'none': ([], []),
    'terminated': ([(2, 0), (4, 1)], []),
    'truncated': ([], [(1, 0), (3, 2)]),
    'both': ([(1, 1), (5, 0)], [(3, 1), (2, 2)]),
}


def make_batch(kind, seed=0, constant_v=None):
    rng = np.random.default_rng(seed)
    T, N = 6, 3
    term = np.zeros((T, N), bool)
    trunc = np.zeros((T, N), bool)
    for t, n in BOUNDARIES[kind][0]:
        term[t, n] = True
    for t, n in BOUNDARIES[kind][1]:
        trunc[t, n] = True
    rew = rng.normal(size=(T, N))
    if constant_v is None:
        val, next_val = rng.normal(size=(T, N)), rng.normal(size=(T, N))
        # Inside an episode the next state is the state of the next step: same value.
        cont = ~(term | trunc)
        next_val[:-1] = np.where(cont[:-1], val[1:], next_val[:-1])
    else:
        val = np.full((T, N), constant_v)
        next_val = np.full((T, N), constant_v)
    return Rollout(rew=rew, terminated=term, truncated=trunc, val=val, next_val=next_val)


@pytest.mark.parametrize('kind', list(BOUNDARIES))
@pytest.mark.parametrize('gamma', [0.0, 0.5, 0.99, 1.0])
@pytest.mark.parametrize('lam', [0.0, 0.3, 0.95, 1.0])
def test_gae_matches_definition(kind, gamma, lam):
    b = make_batch(kind)
    want = brute_force_gae(b.rew, b.val, b.next_val, b.terminated, b.truncated, gamma, lam)
    np.testing.assert_allclose(gae(b, gamma, lam), want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('kind', list(BOUNDARIES))
@pytest.mark.parametrize('gamma', [0.0, 0.5, 0.99, 1.0])
def test_reward_to_go_matches_definition(kind, gamma):
    b = make_batch(kind)
    want = brute_force_rtg(b.rew, b.next_val, b.terminated, b.truncated, gamma)
    np.testing.assert_allclose(reward_to_go(b, gamma), want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('kind', list(BOUNDARIES))
@pytest.mark.parametrize('gamma', [0.5, 0.99])
def test_lambda_one_is_reward_to_go_minus_v(kind, gamma):
    b = make_batch(kind)
    np.testing.assert_allclose(gae(b, gamma, 1.0), reward_to_go(b, gamma) - b.val, atol=1e-12)
    np.testing.assert_allclose(estimators.value_baseline(b, gamma),
                               estimators.gae(b, gamma, gae_lambda=1.0), atol=1e-12)


@pytest.mark.parametrize('kind', list(BOUNDARIES))
def test_lambda_zero_is_td_residual(kind):
    b = make_batch(kind)
    np.testing.assert_allclose(gae(b, 0.9, 0.0), td_residual(b, 0.9), atol=1e-12)


def test_constant_v_by_hand():
    """SB3-style: V fixed to a constant, advantages worked out on paper."""
    # One arm, 4 steps, termination after step 1, truncation after step 3; V = 1 everywhere.
    b = Rollout(rew=[1.0, 2.0, 3.0, 4.0], terminated=[0, 1, 0, 0], truncated=[0, 0, 0, 1],
                val=[1.0] * 4, next_val=[1.0] * 4)
    g, lam = 0.5, 0.5
    # delta: r + g*V' - V, with V' = 0 after the termination.
    delta = [1 + 0.5 - 1, 2 + 0 - 1, 3 + 0.5 - 1, 4 + 0.5 - 1]
    assert td_residual(b, g).ravel().tolist() == delta
    want = [delta[0] + g * lam * delta[1], delta[1], delta[2] + g * lam * delta[3], delta[3]]
    np.testing.assert_allclose(gae(b, g, lam).ravel(), want)
    np.testing.assert_allclose(td_lambda_return(b, g, lam).ravel(), np.array(want) + 1.0)
    # Reward-to-go: termination adds nothing, truncation bootstraps with V' = 1.
    np.testing.assert_allclose(reward_to_go(b, g).ravel(),
                               [1 + 0.5 * 2, 2, 3 + 0.5 * (4 + 0.5 * 1), 4 + 0.5 * 1])
    # R(tau) of each segment, repeated along it.
    np.testing.assert_allclose(total_return(b, g).ravel(), [2, 2, 5.25, 5.25])


def test_truncation_bootstraps_but_termination_does_not():
    base = {'rew': [1.0, 1.0], 'val': [0.0, 0.0], 'next_val': [0.0, 7.0]}
    term = Rollout(terminated=[0, 1], truncated=[0, 0], **base)
    trunc = Rollout(terminated=[0, 0], truncated=[0, 1], **base)
    assert reward_to_go(term, 1.0)[1, 0] == 1.0
    assert reward_to_go(trunc, 1.0)[1, 0] == 8.0
    assert gae(term, 1.0, 0.9)[1, 0] == 1.0
    assert gae(trunc, 1.0, 0.9)[1, 0] == 8.0


@pytest.mark.parametrize('gamma', [0.9, 0.99])
def test_endless_constant_reward_tends_to_r_over_one_minus_gamma(gamma):
    r, T = 2.0, 3000
    b = Rollout(rew=np.full(T, r), terminated=np.zeros(T), truncated=np.zeros(T))
    ret = reward_to_go(b, gamma, bootstrap=False)
    want = r / (1 - gamma)
    # The finite sum is want * (1 - gamma^T); the tail is below 1e-12 here.
    np.testing.assert_allclose(ret[0, 0], want, rtol=1e-9)
    # r / (1 - gamma) is the fixed point of bootstrapping: with V = want everywhere,
    # every TD residual is zero, also across truncations.
    trunc = np.zeros(T, bool)
    trunc[::50] = True
    b = Rollout(rew=np.full(T, r), terminated=np.zeros(T), truncated=trunc,
                val=np.full(T, want), next_val=np.full(T, want))
    np.testing.assert_allclose(td_residual(b, gamma), 0.0, atol=1e-9)
    np.testing.assert_allclose(reward_to_go(b, gamma), want, rtol=1e-12)


def test_discount_cumsum_example():
    x = np.array([1.0, 10.0, 100.0])
    g = 0.9
    np.testing.assert_allclose(discount_cumsum(x, g),
                               [1 + g * 10 + g * g * 100, 10 + g * 100, 100])


def test_segments_and_episode_steps():
    done = np.array([[0, 1], [1, 0], [0, 0], [0, 1]], bool)
    assert episode_steps(done).tolist() == [[0, 0], [1, 0], [0, 1], [1, 2]]
    assert segment_ids(done).tolist() == [[0, 2], [0, 3], [1, 3], [1, 3]]


def test_rollout_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match='terminated has shape'):
        Rollout(rew=np.zeros((4, 2)), terminated=np.zeros((3, 2)), truncated=np.zeros((4, 2)))


def test_unknown_estimator_is_named():
    with pytest.raises(ValueError, match="unknown estimator 'gea'.*gae"):
        estimators.compute_phi('gea', make_batch('none'), 0.9)
    with pytest.raises(ValueError, match='score_sq'):
        estimators.compute_phi('optimal_baseline', make_batch('none'), 0.9)


@pytest.mark.parametrize('name', list(estimators.ESTIMATORS))
def test_every_estimator_returns_batch_shape(name):
    b = make_batch('both')
    b.score_sq = np.ones(b.shape)
    phi = estimators.compute_phi(name, b, 0.9, 0.9)
    assert phi.shape == b.shape and np.all(np.isfinite(phi))


def test_value_targets():
    b = make_batch('both')
    np.testing.assert_allclose(estimators.value_targets(b, 0.9, kind='mc'), reward_to_go(b, 0.9))
    np.testing.assert_allclose(estimators.value_targets(b, 0.9, 0.7, kind='td_lambda'),
                               gae(b, 0.9, 0.7) + b.val)
    with pytest.raises(ValueError, match='unknown value target'):
        estimators.value_targets(b, 0.9, kind='q')
