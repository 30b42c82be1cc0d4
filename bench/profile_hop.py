"""
Benchmark: where each process of the training graph spends its time per control step.

The training graph (``python -m pg_node train``) runs under cProfile once with sim_node's
``in_process_hop`` (the default) and once without (``sim_node.in_process_hop=false``), in
turn (:func:`bench.runs.profile_graph`); for each process, each group of functions (waiting
in the executor, publish, take, message objects, torch, physics, start-up and the rest) in
ms per control step (one step of all arms), and the pg_node functions with the most
cumulative time. cProfile slows Python two- to threefold and sees each
process's main thread only (the simulator's stepping threads show as the main thread's
waits on them): compare the two columns, not the figures with an unprofiled run::

    python bench/profile_hop.py 100000

Not a test: nothing is asserted.
"""
import os
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench import runs as br  # noqa: E402

SETTINGS = {'hop': [], 'over DDS': ['sim_node.in_process_hop=false']}


def main(argv=None) -> int:
    """Profile both settings; print one table per process."""
    argv = sys.argv[1:] if argv is None else argv
    steps = int(argv[0]) if argv else 100_000
    control_steps = steps / 64
    runs = {}
    for name, overrides in SETTINGS.items():
        load = ' / '.join(f'{x:.2f}' for x in os.getloadavg())
        runs[name] = br.profile_graph(steps, overrides=overrides)
        print(f'{name}: {runs[name]["steps_per_second"]:,.0f} steps/s under cProfile; load '
              f'average at its start {load}', file=sys.stderr)
    for process in ('sim_and_actor', 'critic_and_learner'):
        key = f'ros.{process}'
        rows = {}
        for name, res in runs.items():
            node = res['nodes'].get(key)
            if node is None:
                continue
            for group, seconds in node['groups'].items():
                rows.setdefault(group, {})[name] = seconds / control_steps * 1e3
            rows.setdefault('total', {})[name] = node['total_seconds'] / control_steps * 1e3
        print(f'\n**{process}**, ms per control step ({control_steps:,.0f} steps of 64 arms)\n')
        print('| group | ' + ' | '.join(runs) + ' |')
        print('|---|' + '---|' * len(runs))
        for group, by in rows.items():
            print(f'| {group} | ' + ' | '.join(f'{by.get(n, 0):.3f}' for n in runs) + ' |')
        for name, res in runs.items():
            node = res['nodes'].get(key)
            if node:
                print(f'\n{name}: ' + '; '.join(
                    f'`{t["function"]}` {t["cumulative_seconds"]:.2f} s / {t["calls"]:,}'
                    for t in node['top']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
