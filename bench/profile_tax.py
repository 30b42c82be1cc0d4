r"""
Benchmark: where each side of the ROS tax spends its time per control step (issue 49).

The same training (the default job, or ``key=value`` overrides) runs under cProfile in
turn:

- **graph**: ``python -m pg_node train`` (:func:`bench.runs.profile_graph`), each node
  process profiled: ``sim_and_actor`` (the simulator and the actor, with sim_node's
  ``in_process_hop``, the default) and ``critic_and_learner``;
- **in-process**: ``pg_node.rl.train_inprocess`` in this process
  (:func:`bench.runs.profile_inprocess`), the graph's lock-step reference;
- with ``--dds``, the graph again with ``sim_node.in_process_hop=false`` (both messages of
  every control step over DDS).

Each process is profiled from the first update past ``--warmup`` steps on (the graph's
nodes from a SIGUSR1 the bench sends them once ``progress.csv`` shows it), so that the
start-up (imports, torch's first optimizer, DDS discovery) is left out. For each process,
each group of functions (waiting in the executor, publish, take, message objects, torch,
physics, start-up, the rest) in ms per control step,
then the time inside the policy's forward pass and sampling (``NumpySampler.sample``) and
the physics step (``ArmTask.step``), cumulative, and the pg_node functions with the most
cumulative time. cProfile slows Python two- to threefold and sees each process's main
thread only (the simulator's second stepping thread shows as the main thread's waits on
it): compare the columns with each other, not with an unprofiled run::

    python bench/profile_tax.py 300000 [--warmup 50000] [--dds] [key=value ...]

Not a test: nothing is asserted. Run nothing else meanwhile; the load average at each run's
start and end is printed.
"""
import argparse
import os
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root

from bench import runs as br  # noqa: E402

#: cumulative time of these pg_node functions, per control step, below the groups
INSIDE = (('policy forward + sampling (NumpySampler.sample)', 'sampler.py:sample'),
          ('physics step (ArmTask.step)', 'arm_task.py:step'))


def load() -> str:
    """Return the 1-minute load average."""
    return f'{os.getloadavg()[0]:.2f}'


def main(argv=None) -> int:
    """Profile both sides; print one table of ms per control step."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('steps', type=int, nargs='?', default=100_000)
    parser.add_argument('overrides', nargs='*', help='key=value, as train takes them')
    parser.add_argument('--warmup', type=int, default=50_000,
                        help='steps before the profile starts')
    parser.add_argument('--dds', action='store_true',
                        help='also the graph with sim_node.in_process_hop=false')
    args = parser.parse_args(argv)
    settings = [('graph', br.profile_graph, [])]
    if args.dds:
        settings.append(('graph over DDS', br.profile_graph, ['sim_node.in_process_hop=false']))
    settings.append(('in-process', br.profile_inprocess, []))
    columns, rates = {}, {}
    from pg_node.common.config_files import load_config
    arms = load_config(None, args.overrides)['sim_node']['num_envs']
    per_step = {}
    for name, profile, extra in settings:
        start = load()
        res = profile(args.steps, overrides=[*args.overrides, *extra], warmup=args.warmup)
        rates[name] = res['steps_per_second']
        print(f'{name}: {res["steps_per_second"]:,.0f} steps/s under cProfile, profiled from '
              f'step {res["profiled_from_steps"]:,}; load average {start} at its start, '
              f'{load()} at its end', file=sys.stderr)
        for process, node in res['nodes'].items():
            label = name if process == 'in-process' else f'{name}: {process[4:]}'
            columns[label] = node
            per_step[label] = (args.steps - res['profiled_from_steps']) / arms
    groups = list(next(iter(columns.values()))['groups'])

    def row(values):
        return ' | '.join(f'{v / n * 1e3:.3f}' for v, n in zip(values, per_step.values()))

    print(f'\nms per control step (of {arms} arms) from step {args.warmup:,} on, each process '
          'its main thread under cProfile\n')
    print('| | ' + ' | '.join(columns) + ' |')
    print('|---|' + '---:|' * len(columns))
    for group in groups:
        print(f'| {group} | ' + row(c['groups'][group] for c in columns.values()) + ' |')
    print('| **total** | ' + row(c['total_seconds'] for c in columns.values()) + ' |')
    for label, function in INSIDE:
        print(f'| of which inside {label} | '
              + row(c['inside'].get(function, 0.0) for c in columns.values()) + ' |')
    print('\nsteps/s under cProfile: ' + ', '.join(f'{n} {r:,.0f}' for n, r in rates.items()))
    for name, node in columns.items():
        print(f'\n{name}: ' + '; '.join(
            f'`{t["function"]}` {t["cumulative_seconds"]:.2f} s / {t["calls"]:,}'
            for t in node['top']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
