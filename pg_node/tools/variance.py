"""``python -m pg_node variance``: the estimator lab's table (see :mod:`pg_node.lab`)."""
import argparse
import json

from pg_node.lab.arm import make_arm_lab
from pg_node.lab.linear_gaussian import LinearGaussianProblem
from pg_node.lab.variance import format_table, run_lab

#: the lab's column names -> two-line headers that keep the table within 80 columns
SHORT_HEADERS = {'bias_z': 'bias\nz', 'bias_z_along_grad': 'bias z\nalong g',
                 'variance': 'vari-\nance', 'relative_variance': 'relative\nvariance',
                 'unbiased?': 'un-\nbiased?'}


def compact(table):
    """
    Return the lab's rich table restyled to fit 80 columns without cutting a cell.

    No vertical rules, two-line headers (:data:`SHORT_HEADERS`); the same rows and numbers.
    """
    from rich import box
    table.box = box.SIMPLE_HEAD
    table.pad_edge = False
    for column in table.columns:
        column.header = SHORT_HEADERS.get(str(column.header), column.header)
    return table


def main(argv=None) -> int:
    """Run ``python -m pg_node variance``."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node variance',
        description='Bias and variance of every policy-gradient estimator against the true '
                    'gradient: of a linear-Gaussian control problem (exact), or of a partly '
                    'trained policy on the simulated arm (from a very large batch).')
    parser.add_argument('--problem', choices=('linear', 'arm'), default='linear',
                        help='linear: linear-Gaussian problem; arm: the default arm with a '
                             'partly trained policy (default: %(default)s)')
    parser.add_argument('--batches', type=int, default=None,
                        help='number of independent batches (default: 2000 linear, 200 arm)')
    parser.add_argument('--batch-size', type=int, default=None,
                        help='trajectories per batch (default: 64 linear, 32 arm)')
    parser.add_argument('--horizon', type=int, default=None,
                        help='steps per trajectory (default: 10 linear, 50 arm)')
    parser.add_argument('--gae-lambda', type=float, default=0.9,
                        help='lambda of the GAE rows (default: %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default: %(default)s)')
    parser.add_argument('--train-steps', type=int, default=100_000,
                        help='arm: in-process A2C steps that train the fixed policy '
                             '(default: %(default)s)')
    parser.add_argument('--true-episodes', type=int, default=32768,
                        help='arm: episodes of the large batch for the true gradient '
                             '(default: %(default)s)')
    parser.add_argument('--value-episodes', type=int, default=4096,
                        help='arm: separate episodes the value network is fitted on '
                             '(default: %(default)s)')
    parser.add_argument('--json', action='store_true', help='print JSON instead of a table')
    args = parser.parse_args(argv)
    arm = args.problem == 'arm'
    batches = args.batches if args.batches is not None else (200 if arm else 2000)
    batch_size = args.batch_size if args.batch_size is not None else (32 if arm else 64)
    horizon = args.horizon if args.horizon is not None else (50 if arm else 10)
    if batches < 2:
        parser.error(f'--batches must be >= 2 (a variance needs two), got {batches}')
    if batch_size < 2:
        parser.error(f'--batch-size must be >= 2 (the baselines of a trajectory are '
                     f'estimated from the others of its batch), got {batch_size}')
    if horizon < 1:
        parser.error(f'--horizon must be >= 1, got {horizon}')
    if not 0.0 <= args.gae_lambda <= 1.0:
        parser.error(f'--gae-lambda must be in [0, 1], got {args.gae_lambda}')
    if arm:
        if args.horizon not in (None, 50):
            parser.error('--horizon of the arm is its episode length, 50')
        problem = make_arm_lab(args.train_steps, args.seed, true_episodes=args.true_episodes,
                               value_episodes=args.value_episodes)
    else:
        problem = LinearGaussianProblem(horizon=horizon)
    result = run_lab(problem, batches, batch_size, args.gae_lambda, args.seed)
    if args.json:
        print(json.dumps(result.rows, indent=2))
    else:
        from rich.console import Console
        Console().print(compact(format_table(result, batches, batch_size)))
        if arm:
            Console().print(f'policy: {problem.info}; value network explained variance '
                            f'{problem.value_explained_variance:.3f}')
    return 0
