r"""
Does the default job leave a policy that reaches? Return, final distance and share within 2 cm.

Each configuration trains ``--steps`` environment steps per seed through the graph (``python -m
pg_node train --seed S [overrides]``, the four nodes, lock-step), one run at a time; the table
gives, per configuration and seed, the deterministic evaluation over 100 episodes (return, mean
final distance of the fingertip to the target, share of episodes that end within 2 cm) and the
run's training seconds (first update to last), the CPU seconds its nodes spent in training
(all processes; less sensitive to the machine's load than the seconds) and the whole
command's seconds. A configuration is
``LABEL=OVERRIDES``, the overrides as ``train`` takes them, separated by spaces; ``default`` (no
overrides) is what ``make train`` runs.

    .venv/bin/python bench/bench_reach.py --seeds 0,1 \
        --config default= --config 'before issue 48=gamma=0.9 vf_epochs=1'
"""
import argparse
from pathlib import Path
import shlex
import subprocess
import sys
import tempfile
from typing import Dict, List, Sequence, Tuple

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench.runs import run_graph  # noqa: E402

#: the default budget of ``make train`` (learner_node.total_steps)
DEFAULT_STEPS = 2_000_000


def parse_config(text: str) -> Tuple[str, List[str]]:
    """
    Split ``LABEL=OVERRIDES`` into its label and its overrides.

    >>> parse_config('default=')
    ('default', [])
    >>> parse_config('old=gamma=0.9 vf_epochs=1')
    ('old', ['gamma=0.9', 'vf_epochs=1'])
    """
    label, sep, rest = text.partition('=')
    if not sep or not label.strip():
        raise argparse.ArgumentTypeError(f'{text!r} is not LABEL=OVERRIDES (e.g. default=)')
    return label.strip(), rest.split()


def row_of(label: str, seed: int, summary: Dict) -> Dict:
    """Return one table row from a run's ``summary.json``."""
    return {'config': label, 'seed': seed, 'return': summary['eval_return'],
            'distance_cm': 100 * summary['eval_final_distance'],
            'within_2cm': 100 * summary['eval_reached'],
            'training_s': summary['session_training_seconds'],
            'cpu_s': sum(u['cpu_seconds_training'] for u in summary['nodes'].values()),
            'total_s': summary['wall_seconds_total']}


def table(rows: Sequence[Dict]) -> str:
    """
    Return the rows as a markdown table.

    >>> print(table([{'config': 'default', 'seed': 0, 'return': -3.8, 'distance_cm': 0.72,
    ...               'within_2cm': 96.0, 'training_s': 101.4, 'cpu_s': 150.3,
    ...               'total_s': 130.2}]))
    | config | seed | return | final distance cm | within 2 cm | training s | CPU s | command s |
    |---|---|---|---|---|---|---|---|
    | default | 0 | -3.80 | 0.72 | 96% | 101 | 150 | 130 |
    """
    lines = ['| config | seed | return | final distance cm | within 2 cm | training s | CPU s | '
             'command s |', '|---|---|---|---|---|---|---|---|']
    for r in rows:
        lines.append(f"| {r['config']} | {r['seed']} | {r['return']:.2f} | "
                     f"{r['distance_cm']:.2f} | {r['within_2cm']:.0f}% | "
                     f"{r['training_s']:.0f} | {r['cpu_s']:.0f} | {r['total_s']:.0f} |")
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Train each configuration once per seed; print the table with its command and commit."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--config', dest='configs', action='append', type=parse_config,
                        help="LABEL=OVERRIDES, repeatable (default: 'default=', make train)")
    parser.add_argument('--seeds', default='0', help='comma-separated seeds')
    parser.add_argument('--steps', type=int, default=DEFAULT_STEPS)
    parser.add_argument('--out', type=Path, help='keep the run dirs here (default: temporary)')
    args = parser.parse_args(argv)
    configs = args.configs or [('default', [])]
    seeds = [int(s) for s in args.seeds.split(',')]
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                            text=True).stdout.strip()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        for k, (label, overrides) in enumerate(configs):
            for seed in seeds:
                summary = run_graph(root / f'c{k}_s{seed}', args.steps, seed, overrides)
                rows.append(row_of(label, seed, summary))
                print(f'{label} seed {seed}: {rows[-1]}', file=sys.stderr, flush=True)
    print(f'`{shlex.join(["bench/bench_reach.py", *sys.argv[1:]])}` at {commit}, '
          f'{args.steps:,} steps per run, deterministic evaluation over 100 episodes\n')
    print(table(rows))
    return 0


if __name__ == '__main__':
    sys.exit(main())
