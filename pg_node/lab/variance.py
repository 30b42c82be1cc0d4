"""
The gradient-estimator lab: bias and variance of every phi against a known true gradient.

Draws many independent batches of m trajectories from a problem whose ``grad U`` is known
(:class:`~pg_node.lab.linear_gaussian.LinearGaussianProblem`), forms the estimate
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
from typing import Dict, List, Tuple

import numpy as np

from pg_node.lab.linear_gaussian import LinearGaussianProblem
from pg_node.rl.estimators import ACTION_DEPENDENT, compute_phi
from pg_node.rl.rollout import Rollout

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
    title: str = 'the linear-Gaussian problem'
    bias_threshold: float = 4.0

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


class LinearGaussianLab:
    """
    The linear-Gaussian problem as a lab problem: closed-form scores, the true V^pi.

    ``exact`` rows use the true value function, ``approx`` rows the state-blind
    :func:`approx_values`; the true gradient is exact, so its standard error is zero.
    """

    title = 'the linear-Gaussian problem'
    gamma = 1.0
    bias_threshold = 4.0
    exact_value = True

    def __init__(self, problem: LinearGaussianProblem = None):
        self.problem = problem or LinearGaussianProblem()
        self.n_params = self.problem.n_params
        self.v_hat = approx_values(self.problem)

    def true_gradient(self) -> Tuple[np.ndarray, np.ndarray]:
        """Return ``(grad U, its standard error)``: exact, so the error is zero."""
        return self.problem.true_gradient(), np.zeros(self.n_params)

    def batch_estimates(self, m: int, rng: np.random.Generator,
                        gae_lambda: float) -> Dict[str, np.ndarray]:
        """Sample one batch of m trajectories; return every row's gradient estimate."""
        H = self.problem.horizon
        approx_val = np.broadcast_to(self.v_hat[:H, None], (H, m))
        approx_next = np.broadcast_to(self.v_hat[1:, None], (H, m))
        terminated = np.zeros((H, m), dtype=bool)
        terminated[-1] = True
        data = self.problem.sample(m, rng)
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
        out = {}
        for name, est, which in LAB_ROWS:
            phi = compute_phi(est, batches[which], gamma=self.gamma, gae_lambda=gae_lambda)
            # the next line is eq. 20: the average over trajectories of sum_t score_t * phi_t
            out[name] = np.einsum('tmp,tm->p', score, phi) / m
        return out


def run_lab(problem=None, n_batches: int = 2000, batch_size: int = 64,
            gae_lambda: float = 0.9, seed: int = 0) -> LabResult:
    """
    Estimate the gradient with every row of :data:`LAB_ROWS` on the same batches.

    ``problem`` is a :class:`LinearGaussianProblem` (the default) or any lab problem: an
    object with ``n_params``, ``bias_threshold``, ``true_gradient() -> (grad, se)`` and
    ``batch_estimates(m, rng, gae_lambda) -> {row: estimate}`` that draws one batch of m
    trajectories and returns every row's estimate computed on it (e.g.
    :class:`pg_node.lab.arm.ArmLab`). ``bias_z`` divides by the standard error of the
    batches' mean and of the true gradient combined.
    """
    if problem is None or isinstance(problem, LinearGaussianProblem):
        problem = LinearGaussianLab(problem)
    if n_batches < 2 or batch_size < 1:
        raise ValueError('need n_batches >= 2 and batch_size >= 1')
    rng = np.random.default_rng(seed)
    estimates = {name: np.zeros((n_batches, problem.n_params)) for name, _, _ in LAB_ROWS}
    for b in range(n_batches):
        for name, g in problem.batch_estimates(batch_size, rng, gae_lambda).items():
            estimates[name][b] = g
    true_grad, true_se = problem.true_gradient()
    result = LabResult(true_grad=true_grad, estimates=estimates)
    unit = true_grad / max(np.linalg.norm(true_grad), 1e-300)
    exact_v = getattr(problem, 'exact_value', False)
    base_var = None
    for name, est, which in LAB_ROWS:
        g = estimates[name]
        se = np.sqrt(g.var(0, ddof=1) / n_batches + true_se ** 2)
        z = (g.mean(0) - result.true_grad) / se
        # the same along the true gradient's direction: one number, no multiple comparisons
        proj = g @ unit
        z_dir = (proj.mean() - true_grad @ unit) / np.sqrt(
            proj.var(ddof=1) / n_batches + true_se ** 2 @ unit ** 2)
        var = float(g.var(0, ddof=1).sum())
        base_var = var if base_var is None else base_var
        result.rows.append({
            'estimator': name,
            'bias_z': float(z[np.argmax(np.abs(z))]),
            'bias_z_along_grad': float(z_dir),
            'variance': var,
            'relative_variance': var / base_var,
            'action_dependent': est in ACTION_DEPENDENT and (which == 'approx' or not exact_v),
        })
    result.title = getattr(problem, 'title', 'a lab problem')
    result.bias_threshold = float(getattr(problem, 'bias_threshold', 4.0))
    return result


def format_table(result: LabResult, n_batches: int, batch_size: int):
    """Return a rich Table of the lab's rows."""
    from rich.markup import escape
    from rich.table import Table
    table = Table(title=f'Policy-gradient estimators on {result.title} '
                        f'({n_batches} batches x {batch_size} trajectories)')
    for col in ('estimator', 'bias_z', 'bias_z_along_grad', 'variance', 'relative_variance',
                'unbiased?'):
        table.add_column(col, justify='left' if col == 'estimator' else 'right', no_wrap=True)
    for row in result.rows:
        ok = 'yes' if abs(row['bias_z']) < result.bias_threshold else 'NO (biased)'
        table.add_row(escape(row['estimator']), f"{row['bias_z']:+.2f}",
                      f"{row['bias_z_along_grad']:+.2f}", f"{row['variance']:.4g}",
                      f"{row['relative_variance']:.4f}", ok)
    return table
