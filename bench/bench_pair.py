"""
Alternating pairs: in-process training, then the same through the graph, setting by setting.

What BENCHMARKS.md ("Lock-step groups") and PROFILE.md measured with ``/tmp/pair.py``, kept
here so that the figures can be made again. Each pair trains ``steps`` steps in-process
(``bench_tax.inprocess_rate``) and then through the graph (``bench_tax.graph_run``), with
one setting; the settings alternate, ``--repeat`` times. On a shared machine the in-process
rate moves from pair to pair: the graph / in-process ratio within a pair is the figure to
read. The CPU seconds per 100k steps are each node process's, in training.

    .venv/bin/python bench/bench_pair.py 200000 2 '' lock_step_groups=2
"""
import argparse
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench.tax import graph_run, inprocess_rate  # noqa: E402


def one_pair(steps: int, overrides) -> dict:
    """Train in-process, then through the graph; return the rates and CPU per 100k steps."""
    inproc = inprocess_rate(steps, overrides)
    summary = graph_run(steps, overrides)
    per_100k = {name: node['cpu_seconds_training'] * 100_000 / summary['session_steps']
                for name, node in summary['nodes'].items()}
    return {'inprocess': inproc, 'graph': summary['steps_per_second'], 'cpu': per_100k}


def main(argv=None) -> int:
    """Run the pairs; print one markdown row per pair."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('steps', type=int, help='environment steps per training')
    parser.add_argument('repeat', type=int, help='how many times each setting runs')
    parser.add_argument('settings', nargs='+',
                        help="each setting: space-separated key=value overrides ('' = defaults)")
    args = parser.parse_args(argv)
    print('| setting | in-process steps/s | graph steps/s | graph / in-process | '
          'CPU s per 100k steps, by process |')
    print('|---|---|---|---|---|')
    for _ in range(args.repeat):
        for setting in args.settings:
            res = one_pair(args.steps, setting.split())
            cpu = ', '.join(f'{name} {sec:.2f}' for name, sec in sorted(res['cpu'].items()))
            print(f"| {setting or '(defaults)'} | {res['inprocess']:,.0f} | "
                  f"{res['graph']:,.0f} | {res['graph'] / res['inprocess']:.3f} | {cpu} |",
                  flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
