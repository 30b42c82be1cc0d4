"""
Benchmark probe: graph runs of N arms x P simulator/actor pairs, and each process's CPU.

Behind BENCHMARKS.md's finding on two pairs (the tax section's scaling table). Each
argument is ``ARMS:PAIRS[:OVERRIDE...]``; the overrides go to ``train`` as
``node.param=value``. For each it trains ``--steps`` environment steps through the graph
(``python -m pg_node train``) and prints one row: steps/s from the first update to the
last, the training's wall seconds, the CPU seconds of every process over them, and their
sum as cores kept busy (at most 2 on this machine)::

    .venv/bin/python bench/cpu_by_process.py 16:2 256:2 256:2:critic_node.nice=0

Run the arguments in alternation and compare neighbours: the machine drifts. Nothing is
asserted.
"""
import argparse
from pathlib import Path
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench.runs import run_graph  # noqa: E402


def main():
    """Train once per argument and print a row of throughput and CPU per process."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[1])
    parser.add_argument('runs', nargs='+', metavar='ARMS:PAIRS[:OVERRIDE...]')
    parser.add_argument('--steps', type=int, default=150_000)
    args = parser.parse_args()
    print('| arms x pairs | overrides | graph steps/s | wall s | cores busy | CPU s by process |')
    print('|---|---|---|---|---|---|')
    for spec in args.runs:
        arms, pairs, *extra = spec.split(':')
        with tempfile.TemporaryDirectory() as tmp:
            summary = run_graph(
                Path(tmp) / 'run', args.steps, 0,
                [f'num_envs={arms}', f'num_actors={pairs}', *extra, '--eval-episodes', '1'])
        wall = summary['session_training_seconds']
        cpu = {name: u['cpu_seconds_training'] for name, u in summary['nodes'].items()}
        print(f'| {arms} x {pairs} | {" ".join(extra) or "-"} | '
              f'{summary["steps_per_second"]:,.0f} | {wall:.1f} | '
              f'{sum(cpu.values()) / wall:.2f} | '
              + ', '.join(f'{name} {s:.1f}' for name, s in sorted(cpu.items())) + ' |',
              flush=True)


if __name__ == '__main__':
    main()
