"""
Presets through the training graph: final evaluation over seeds, training time, and the KL.

Each preset trains ``--steps`` environment steps per seed with ``python -m pg_node train
--config PRESET --seed S`` (the four nodes, lock-step), one run at a time; the table gives the
deterministic evaluation over 100 episodes (mean ± std over seeds, and each seed's), the
training seconds and steps/s, and the largest per-update KL the learner logged
(``approx_kl`` in ``progress.csv``: for NPG and TRPO the measured mean KL of each step).

    .venv/bin/python bench/bench_presets.py --presets npg,trpo --seeds 0,1,2
"""
import argparse
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench.runs import run_graph  # noqa: E402
import numpy as np  # noqa: E402
from pg_node.common.config_files import load_config  # noqa: E402
from pg_node.common.paths import config_file  # noqa: E402
from pg_node.common.run_dir import RunDir  # noqa: E402


def one_preset(preset: str, seeds, steps: int, root: Path) -> dict:
    """Train ``preset`` once per seed through the graph; return its row's values."""
    runs = []
    for seed in seeds:
        run_dir = root / f'{preset}_s{seed}'
        summary = run_graph(run_dir, steps, seed, ['--config', preset])
        kls = [r['approx_kl'] for r in RunDir(run_dir).read_progress()
               if np.isfinite(r['approx_kl'])]
        runs.append({'eval': summary['eval_return'],
                     'seconds': summary['session_training_seconds'],
                     'rate': summary['steps_per_second'],
                     'max_kl': max(kls) if kls else float('nan')})
        print(f'{preset} seed {seed}: {runs[-1]}', file=sys.stderr, flush=True)
    evals = [r['eval'] for r in runs]
    return {'preset': preset, 'evals': evals, 'mean': statistics.mean(evals),
            'std': statistics.pstdev(evals), 'runs': runs,
            'max_kl_bound': load_config(config_file(preset))['learner_node']['max_kl']}


def table(rows, steps: int) -> str:
    """Return the rows as a markdown table."""
    lines = [f'| preset | eval @{steps:,} (mean ± std) | seeds | training s | steps/s | '
             'largest update KL (bound) |', '|---|---|---|---|---|---|']
    for row in rows:
        runs = row['runs']

        def each(key, fmt):
            return ', '.join(format(r[key], fmt) for r in runs)
        largest = max(r['max_kl'] for r in runs)
        lines.append(f"| `{row['preset']}` | **{row['mean']:.2f} ± {row['std']:.2f}** | "
                     f"{each('eval', '.2f')} | {each('seconds', '.0f')} | "
                     f"{each('rate', ',.0f')} | {largest:.4f} ({row['max_kl_bound']}) |")
    return '\n'.join(lines)


def main(argv=None) -> int:
    """Run the presets; print the table with its command and commit."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--presets', default='npg,trpo', help='comma-separated preset names')
    parser.add_argument('--seeds', default='0,1,2', help='comma-separated seeds')
    parser.add_argument('--steps', type=int, default=1_000_000)
    parser.add_argument('--out', type=Path, help='keep the run dirs here (default: temporary)')
    args = parser.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(',')]
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], capture_output=True,
                            text=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        rows = [one_preset(p, seeds, args.steps, root) for p in args.presets.split(',')]
    print(f'`{" ".join(["bench/bench_presets.py", *sys.argv[1:]])}` at {commit}, '
          f'{args.steps:,} steps per run, deterministic evaluation over 100 episodes\n')
    print(table(rows, args.steps))
    return 0


if __name__ == '__main__':
    sys.exit(main())
