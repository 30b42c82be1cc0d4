"""
Benchmark: the graph / in-process ratio of two versions of the code, run alternately.

A cut to the ROS tax is worth a few percent; this machine drifts by more than that from
one minute to the next. So the two versions run in turns (A B, B A, A B, ...), each run an
in-process training and then the same training through the graph (``bench.tax``'s
``inprocess_rate`` and ``graph_run``, default settings), and the ratio is read within each
run (both versions from issue 43 on, where the bench is the ``bench`` package). Give each
version its own git worktree::

    git worktree add /tmp/before <commit>
    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/ab_trees.py /tmp/before . --repeats 6

Prints one line per run (in-process and graph steps/s, their ratio, each node's CPU seconds
per 100k steps) and the medians. ``--override key=value`` passes a setting to both graphs.
Not a test: nothing is asserted. Run nothing else meanwhile.
"""
import argparse
import json
import os
from pathlib import Path
import statistics
import subprocess
import sys


def one_run(steps: int, overrides) -> dict:
    """Train in-process, then through the graph, with the code on ``sys.path``."""
    from bench import tax
    inprocess = tax.inprocess_rate(steps)
    summary = tax.graph_run(steps, overrides)
    trained = summary['session_steps']
    return {'inprocess': inprocess, 'graph': summary['steps_per_second'],
            'ratio': summary['steps_per_second'] / inprocess,
            'cpu_per_100k': {name: round(u['cpu_seconds_training'] / trained * 1e5, 2)
                             for name, u in summary.get('nodes', {}).items()}}


def main(argv=None) -> int:
    """Alternate the trees, print each run and the medians."""
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('trees', nargs='*', help='two (or more) checkouts of pg_node')
    ap.add_argument('--steps', type=int, default=200_000)
    ap.add_argument('--repeats', type=int, default=6)
    ap.add_argument('--override', action='append', default=[], metavar='KEY=VALUE')
    ap.add_argument('--one', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:                       # a child, in one tree: one pair, as JSON
        print(json.dumps(one_run(args.steps, args.override)), flush=True)
        return 0
    if len(args.trees) < 2:
        ap.error('give two checkouts to compare')
    trees = [str(Path(t).resolve()) for t in args.trees]
    missing = [t for t in trees if not (Path(t) / 'pg_node').is_dir()]
    if missing:
        ap.error(f'not a pg_node checkout: {", ".join(missing)}')
    ratios = {t: [] for t in trees}
    for k in range(args.repeats):
        for tree in trees if k % 2 == 0 else trees[::-1]:
            env = dict(os.environ, PYTHONPATH=tree)
            cmd = [sys.executable, str(Path(__file__).resolve()), '--one',
                   '--steps', str(args.steps)] + [f'--override={o}' for o in args.override]
            out = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
            lines = [ln for ln in out.stdout.splitlines() if ln.startswith('{')]
            if out.returncode or not lines:
                print(f'{tree}: run failed (exit {out.returncode}): '
                      f'{out.stderr.strip().splitlines()[-1:] or ""}', flush=True)
                continue
            r = json.loads(lines[-1])
            ratios[tree].append(r['ratio'])
            print(f'{tree}: in-process {r["inprocess"]:,.0f} graph {r["graph"]:,.0f} '
                  f'ratio {r["ratio"]:.3f} CPU s per 100k {r["cpu_per_100k"]}', flush=True)
    for tree, rs in ratios.items():
        med = f'{statistics.median(rs):.3f}' if rs else '-'
        print(f'{tree}: median ratio {med} of {[round(r, 3) for r in rs]}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
