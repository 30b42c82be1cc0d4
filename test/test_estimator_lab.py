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
from pg_node import baselines
from pg_node.linear_gaussian import LinearGaussianProblem
from pg_node.variance_lab import LAB_ROWS, run_lab
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
