"""
Unbiasedness and variance of every estimator against the exact gradient (the lab).

All claims use one fixed seed and tolerances from the sampling error: a bias z-score is the
mean's distance from the true gradient in standard errors, and a variance difference is
compared with its own standard error from the paired per-batch deviations.
"""
import json
import subprocess
import sys

import numpy as np
from pg_node.lab.linear_gaussian import LinearGaussianProblem
from pg_node.lab.variance import LAB_ROWS, run_lab
from pg_node.rl import baselines
import pytest
import torch


@pytest.fixture(scope='module')
def lab():
    return run_lab(n_batches=2000, batch_size=64, seed=0)


def rows(lab):
    return {r['estimator']: r for r in lab.rows}


def test_closed_form_return_matches_monte_carlo():
    prob = LinearGaussianProblem()
    data = prob.sample(100_000, np.random.default_rng(3))
    ret = data['rew'].sum(0)
    u = float(prob.expected_return(torch.as_tensor(prob.theta)))
    assert abs(ret.mean() - u) < 4 * ret.std() / np.sqrt(len(ret))
    # the true V_0, averaged over start states, is U as well
    v0 = data['val'][0]
    assert abs(v0.mean() - u) < 4 * v0.std() / np.sqrt(len(v0))
    # and V_t(s_t) = E[r_t + V_{t+1}(s_{t+1}) | s_t]: residuals average to zero
    resid = (data['rew'] + data['next_val'] - data['val']).ravel()
    assert abs(resid.mean()) < 4 * resid.std() / np.sqrt(resid.size)


def test_true_gradient_matches_finite_differences():
    prob = LinearGaussianProblem()
    g = prob.true_gradient()
    theta = torch.as_tensor(prob.theta)
    h = 1e-6
    for i in range(len(theta)):
        e = torch.zeros_like(theta)
        e[i] = h
        fd = (prob.expected_return(theta + e) - prob.expected_return(theta - e)) / (2 * h)
        assert float(fd) == pytest.approx(g[i], rel=1e-5, abs=1e-7)


def test_state_independent_estimators_are_unbiased(lab):
    for name, est, which in LAB_ROWS:
        row = rows(lab)[name]
        if not row['action_dependent']:
            assert abs(row['bias_z']) < 4, (name, row)


def test_td_with_a_poor_value_function_is_reported_biased(lab):
    """An action-dependent phi (V(s_{t+1}) from a wrong V) is shown biased, not hidden."""
    r = rows(lab)
    assert r['td_residual[approx V]']['action_dependent']
    assert abs(r['td_residual[approx V]']['bias_z']) > 4
    assert abs(r['gae[approx V]']['bias_z']) > 4
    # the same poor V used only as a baseline stays unbiased
    assert abs(r['value_baseline[approx V]']['bias_z']) < 4


@pytest.mark.parametrize('lower,higher', [
    ('reward_to_go', 'total_return'),
    ('constant_baseline', 'total_return'),
    ('optimal_baseline', 'total_return'),
    ('time_baseline', 'reward_to_go'),
    ('value_baseline', 'reward_to_go'),
    ('value_baseline[approx V]', 'reward_to_go'),
    ('value_baseline', 'time_baseline'),
    ('gae', 'value_baseline'),
])
def test_variance_ordering_is_measured(lab, lower, higher):
    diff, se = lab.variance_difference(lower, higher)
    assert diff < -3 * se, (lower, higher, diff, se)


def test_optimal_baseline_at_or_below_mean_return_baseline(lab):
    diff, se = lab.variance_difference('optimal_baseline', 'constant_baseline')
    assert diff < 3 * se, (diff, se)


def test_leave_one_out_baselines_by_hand():
    r = np.array([1.0, 2.0, 6.0])
    np.testing.assert_allclose(baselines.constant_baseline(r), [4.0, 3.5, 1.5])
    w = np.array([1.0, 1.0, 2.0])
    np.testing.assert_allclose(baselines.optimal_baseline(r, w), [14 / 3, 13 / 3, 1.5])
    # with equal weights the optimal baseline is the mean baseline
    np.testing.assert_allclose(baselines.optimal_baseline(r, np.ones(3)),
                               baselines.constant_baseline(r))
    # a single trajectory has no other to learn from: b = 0
    assert baselines.constant_baseline(np.array([5.0])).tolist() == [0.0]


def test_cli_json_has_one_object_per_estimator():
    out = subprocess.run([sys.executable, '-m', 'pg_node', 'variance', '--batches', '50',
                          '--batch-size', '8', '--json'], capture_output=True, text=True,
                         check=True).stdout
    data = json.loads(out)
    assert [d['estimator'] for d in data] == [name for name, _, _ in LAB_ROWS]
    for d in data:
        assert {'estimator', 'bias_z', 'variance', 'relative_variance'} <= set(d)
        assert np.isfinite(d['variance']) and d['variance'] > 0
    assert data[0]['relative_variance'] == 1.0


def test_cli_rejects_bad_options():
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'variance', '--gae-lambda', '2'],
                         capture_output=True, text=True)
    assert res.returncode == 2 and '--gae-lambda must be in [0, 1]' in res.stderr


@pytest.fixture(scope='module')
def arm_lab():
    from pg_node.common.config_files import load_config
    from pg_node.lab.arm import ArmLab
    from pg_node.rl.learner import make_policy
    cfg = load_config(None, [])
    torch.set_num_threads(1)
    policy = make_policy(10, 2, {**cfg['learner_node'], **cfg['actor_node']})
    lab = ArmLab(policy, value_episodes=16, true_episodes=32, chunk=16, value_epochs=1)
    yield lab
    lab.close()


def test_arm_lab_batched_gradients_equal_one_backward_per_row(arm_lab):
    """The one batched vector-Jacobian product gives what a backward pass per row gives."""
    from pg_node.rl.estimators import compute_phi
    from pg_node.rl.policy import segment_score_sq
    data = arm_lab.sample(3, np.random.default_rng(0))
    assert data['rew'].shape == (50, 3)
    got = arm_lab._estimates(data, 0.9, LAB_ROWS)
    obs = torch.as_tensor(data['obs'].reshape(-1, 10), dtype=torch.float32)
    act = torch.as_tensor(data['act'].reshape(-1, 2), dtype=torch.float32)
    val, next_val = arm_lab.values(data['obs'])
    seg = np.broadcast_to(np.arange(3), (50, 3))
    score_sq = segment_score_sq(arm_lab.policy, obs, act, seg.reshape(-1)).reshape(50, 3)
    np.testing.assert_allclose(arm_lab._score_sq(data), score_sq, rtol=1e-4)
    approx = np.broadcast_to(arm_lab.time_values[:50, None], (50, 3))
    approx_next = np.broadcast_to(arm_lab.time_values[1:, None], (50, 3))
    batches = {'exact': arm_lab._episode_batch(data['rew'], val, next_val, score_sq),
               'approx': arm_lab._episode_batch(data['rew'], approx, approx_next, score_sq)}
    for name, est, which in LAB_ROWS:
        phi = torch.as_tensor(compute_phi(est, batches[which], 1.0, 0.9).ravel() / 3,
                              dtype=torch.float32)
        logp = arm_lab.policy.log_prob(obs, act)
        grads = torch.autograd.grad((logp * phi).sum(), arm_lab.params)
        want = torch.cat([g.reshape(-1) for g in grads]).double().numpy()
        np.testing.assert_allclose(got[name], want, rtol=1e-3, atol=1e-4 * np.abs(want).max())


def test_arm_lab_runs_every_row(arm_lab):
    res = run_lab(arm_lab, n_batches=3, batch_size=2, seed=1)
    assert [r['estimator'] for r in res.rows] == [name for name, _, _ in LAB_ROWS]
    assert res.rows[0]['relative_variance'] == 1.0
    for r in res.rows:
        assert np.isfinite(r['variance']) and r['variance'] > 0
        assert np.isfinite(r['bias_z']) and np.isfinite(r['bias_z_along_grad'])
    # V comes from a fitted network, so TD and GAE are flagged as possibly biased
    flagged = {r['estimator'] for r in res.rows if r['action_dependent']}
    assert flagged == {'td_residual', 'td_residual[approx V]', 'gae', 'gae[approx V]'}
    assert res.bias_threshold > 4


def test_cli_refuses_a_batch_of_one():
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'variance', '--batch-size', '1'],
                         capture_output=True, text=True)
    assert res.returncode == 2 and '--batch-size must be >= 2' in res.stderr
    assert 'Traceback' not in res.stderr


def test_cli_table_fits_80_columns_without_cutting_a_cell():
    import os
    env = dict(os.environ, COLUMNS='80')
    out = subprocess.run([sys.executable, '-m', 'pg_node', 'variance', '--batches', '50',
                          '--batch-size', '8'], capture_output=True, text=True, check=True,
                         env=env).stdout
    assert max(len(line) for line in out.splitlines()) <= 80, out
    assert '…' not in out, out
    shown = {line.strip().split('  ')[0]: line.strip() for line in out.splitlines()}
    for name, _, _ in LAB_ROWS:
        cells = shown[name][len(name):].replace('NO (biased)', 'NO').split()
        assert len(cells) == 5 and cells[-1] in ('yes', 'NO'), shown[name]  # each cell whole
