"""
The gradient-estimator lab: bias and variance of every phi against a known true gradient.

Draws many independent batches of m trajectories from a problem whose ``grad U`` is known
(:class:`~pg_node.linear_gaussian.LinearGaussianProblem`), forms the estimate
``g = (1/m) sum_i sum_t grad log pi(u_t|s_t) phi_t`` (eq. 20) for every phi on the *same*
batches, and reports for each estimator:

- ``bias_z``: the largest-magnitude component of ``(mean(g) - grad U) / se``, se the
  standard error of the mean over batches; |bias_z| well below 4 means no bias is visible;
- ``variance``: the trace of the covariance of g over batches (total variance);
- ``relative_variance``: that variance over plain REINFORCE's (phi = R(tau), eq. 18).

Estimators that use V come twice: with the true V^pi, and with a poor V that ignores the
state (``[approx V]``, the mean value at each time step). As a baseline (eq. 64) a poor V only
costs variance; inside the TD residual and GAE it biases the estimate, and the lab shows it.
The lab works in the notes' setting: finite horizon, no discounting (gamma = 1).
"""
from dataclasses import dataclass, field
import json
from typing import Dict, List, Tuple

import numpy as np

from pg_node.estimators import ACTION_DEPENDENT, compute_phi
from pg_node.linear_gaussian import LinearGaussianProblem
from pg_node.rollout import Rollout

#: (row name, estimator, which V) in table order.
LAB_ROWS = [
    ('total_return', 'total_return', 'exact'),
    ('reward_to_go', 'reward_to_go', 'exact'),
    ('constant_baseline', 'constant_baseline', 'exact'),
    ('optimal_baseline', 'optimal_baseline', 'exact'),
    ('time_baseline', 'time_baseline', 'exact'),
    ('value_baseline', 'value_baseline', 'exact'),
    ('value_baseline[approx V]', 'value_baseline', 'approx'),
    ('td_residual', 'td_residual', 'exact'),
    ('td_residual[approx V]', 'td_residual', 'approx'),
    ('gae', 'gae', 'exact'),
    ('gae[approx V]', 'gae', 'approx'),
]


def approx_values(problem: LinearGaussianProblem) -> np.ndarray:
    """Return ``E[V_t(s_t)]`` for t = 0..H: a value 'function' that ignores the state."""
    coeffs = problem.value_coefficients()
    M = problem.A + problem.B @ problem.K
    C = problem.B @ np.diag(np.exp(2 * problem.log_std)) @ problem.B.T + problem.W
    m, S = problem.mu0.copy(), problem.S0.copy()
    out = []
    for P, p, c in coeffs:
        out.append(-(np.trace(P @ S) + m @ P @ m + p @ m + c))
        m, S = M @ m + problem.B @ problem.k, M @ S @ M.T + C
    return np.array(out)


@dataclass
class LabResult:
    """Per-batch gradient estimates of every row, the true gradient, and the summary rows."""

    true_grad: np.ndarray
    estimates: Dict[str, np.ndarray]
    rows: List[dict] = field(default_factory=list)

    def variance_difference(self, a: str, b: str) -> Tuple[float, float]:
        """
        Return ``(Var_a - Var_b, standard error)`` from paired per-batch deviations.

        Both rows were computed on the same batches, so the difference of the per-batch
        squared deviations has a small, directly estimable standard error.
        """
        ga, gb = self.estimates[a], self.estimates[b]
        n = len(ga)
        da = ((ga - ga.mean(0)) ** 2).sum(1) * n / (n - 1)
        db = ((gb - gb.mean(0)) ** 2).sum(1) * n / (n - 1)
        d = da - db
        return float(d.mean()), float(d.std(ddof=1) / np.sqrt(n))


def run_lab(problem: LinearGaussianProblem = None, n_batches: int = 2000, batch_size: int = 64,
            gae_lambda: float = 0.9, seed: int = 0) -> LabResult:
    """Estimate the gradient with every row of :data:`LAB_ROWS` on the same batches."""
    problem = problem or LinearGaussianProblem()
    if n_batches < 2 or batch_size < 1:
        raise ValueError('need n_batches >= 2 and batch_size >= 1')
    rng = np.random.default_rng(seed)
    H, m = problem.horizon, batch_size
    v_hat = approx_values(problem)
    approx_val = np.broadcast_to(v_hat[:H, None], (H, m))
    approx_next = np.broadcast_to(v_hat[1:, None], (H, m))
    terminated = np.zeros((H, m), dtype=bool)
    terminated[-1] = True
    estimates = {name: np.zeros((n_batches, problem.n_params)) for name, _, _ in LAB_ROWS}
    for b in range(n_batches):
        data = problem.sample(m, rng)
        score = data['score']
        score_sq = np.broadcast_to((score.sum(0) ** 2).sum(-1), (H, m))
        batches = {
            'exact': Rollout(rew=data['rew'], terminated=terminated,
                             truncated=np.zeros((H, m), bool), val=data['val'],
                             next_val=data['next_val'], score_sq=score_sq),
            'approx': Rollout(rew=data['rew'], terminated=terminated,
                              truncated=np.zeros((H, m), bool), val=approx_val,
                              next_val=approx_next, score_sq=score_sq),
        }
        for name, est, which in LAB_ROWS:
            phi = compute_phi(est, batches[which], gamma=1.0, gae_lambda=gae_lambda)
            # the next line is eq. 20: the average over trajectories of sum_t score_t * phi_t
            estimates[name][b] = np.einsum('tmp,tm->p', score, phi) / m
    result = LabResult(true_grad=problem.true_gradient(), estimates=estimates)
    base_var = None
    for name, est, which in LAB_ROWS:
        g = estimates[name]
        se = g.std(0, ddof=1) / np.sqrt(n_batches)
        z = (g.mean(0) - result.true_grad) / se
        var = float(g.var(0, ddof=1).sum())
        base_var = var if base_var is None else base_var
        result.rows.append({
            'estimator': name,
            'bias_z': float(z[np.argmax(np.abs(z))]),
            'variance': var,
            'relative_variance': var / base_var,
            'action_dependent': est in ACTION_DEPENDENT and which == 'approx',
        })
    return result


def format_table(result: LabResult, n_batches: int, batch_size: int):
    """Return a rich Table of the lab's rows."""
    from rich.markup import escape
    from rich.table import Table
    table = Table(title=f'Policy-gradient estimators on the linear-Gaussian problem '
                        f'({n_batches} batches x {batch_size} trajectories)')
    for col in ('estimator', 'bias_z', 'variance', 'relative_variance', 'unbiased?'):
        table.add_column(col, justify='left' if col == 'estimator' else 'right', no_wrap=True)
    for row in result.rows:
        ok = 'yes' if abs(row['bias_z']) < 4 else 'NO (biased)'
        table.add_row(escape(row['estimator']), f"{row['bias_z']:+.2f}", f"{row['variance']:.4g}",
                      f"{row['relative_variance']:.4f}", ok)
    return table


def main(argv=None) -> int:
    """Run ``python -m pg_node variance``."""
    import argparse
    parser = argparse.ArgumentParser(
        prog='python -m pg_node variance',
        description='Bias and variance of every policy-gradient estimator against the exact '
                    'gradient of a linear-Gaussian control problem.')
    parser.add_argument('--batches', type=int, default=2000,
                        help='number of independent batches (default: %(default)s)')
    parser.add_argument('--batch-size', type=int, default=64,
                        help='trajectories per batch (default: %(default)s)')
    parser.add_argument('--horizon', type=int, default=10,
                        help='steps per trajectory (default: %(default)s)')
    parser.add_argument('--gae-lambda', type=float, default=0.9,
                        help='lambda of the GAE rows (default: %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default: %(default)s)')
    parser.add_argument('--json', action='store_true', help='print JSON instead of a table')
    args = parser.parse_args(argv)
    if args.batches < 2 or args.batch_size < 1 or args.horizon < 1:
        parser.error('--batches must be >= 2, --batch-size and --horizon >= 1')
    if not 0.0 <= args.gae_lambda <= 1.0:
        parser.error(f'--gae-lambda must be in [0, 1], got {args.gae_lambda}')
    result = run_lab(LinearGaussianProblem(horizon=args.horizon), args.batches, args.batch_size,
                     args.gae_lambda, args.seed)
    if args.json:
        print(json.dumps(result.rows, indent=2))
    else:
        from rich.console import Console
        Console().print(format_table(result, args.batches, args.batch_size))
    return 0
