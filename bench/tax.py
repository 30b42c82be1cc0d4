"""
The ``tax`` section of ``python -m bench``: what the ROS graph costs against one process.

Three tables, from one invocation:

* **graph vs in-process**: the default A2C (64 arms, 8-step rollouts, lock-step, sync)
  trained in-process (:func:`pg_node.rl.train_inprocess.train_inprocess`), through the
  four nodes as ``python -m pg_node train`` starts them (the simulator and the actor in one
  process, the critic and the learner in another) and with every node a process of its own
  (``train --separate``), in turn, ``tax_repeats`` times each; the median of each and the
  ratios. All clocks start at the first update.
* **per node**: each node's peak resident memory and CPU seconds per 100k training steps
  (``summary.json``'s ``nodes``, read from ``/proc`` by the supervisor) in those graph runs;
* **scaling**: graph and in-process for 16, 64 and 256 arms per simulator and 1 and 2
  simulator/actor pairs. Two pairs of N arms are compared with one process of 2N arms (the
  in-process reference has one actor): the same work per update, not the same computation;
* **round trip**: sim_node's lock-step round trip for 64 arms, inside the training graph
  (the ratio's graph runs log every one, sim_node's ``round_trip_log``: within a rollout the
  actor answers at once; at a rollout's end the answer waits for the critic, the learner and
  the new weights) and with a client that answers at once
  (:func:`bench.runs.lock_step_latency`), with no training running and while
  a training graph runs in another DDS domain on the same two cores.
"""
import argparse
import json
import os
from pathlib import Path
import statistics
import sys
import tempfile
import threading
import time
import traceback
from typing import Callable, Dict, List, Sequence, Tuple

import numpy as np
from pg_node.tools.train import PAIR_PROCESSES, TRAINING_PROCESSES

#: budgets: full run, and --quick
BUDGETS = {'tax_steps': (200_000, 4_096), 'tax_repeats': (5, 1),
           'tax_scaling_steps': (150_000, 4_096), 'tax_latency_steps': (5_000, 300),
           # scaling rows: (arms per simulator, simulator/actor pairs); --quick runs the one
           # row that starts two pairs
           'tax_scaling': (((16, 1), (16, 2), (64, 1), (64, 2), (256, 1), (256, 2)),
                           ((16, 2),))}
#: the graphs' processes as train names them: every node apart, then the default's
NODES = tuple(name for compose in (False, True)
              for table in (PAIR_PROCESSES, TRAINING_PROCESSES)
              for name, _ in table[compose])
#: the processes that hold torch (the learning side)
TORCH_NODES = tuple(name for compose in (False, True)
                    for name, _ in TRAINING_PROCESSES[compose])
#: seconds the training round trip waits for the background graph's first update
LEARNING_DEADLINE = 180.0
LATENCY_LABELS = {'idle': 'no training running', 'training': 'a training graph runs'}
TRAINING_LABELS = {'rollout': 'within a rollout',
                   'boundary': "at a rollout's end (hand-over)",
                   'separate_rollout': 'within a rollout, every node its own process',
                   'separate_boundary': "at a rollout's end, every node its own process"}


class LoadWatch:
    """
    The machine's load (``os.getloadavg``) before and during a block, sampled each second.

    ``with LoadWatch() as load: ...``; then ``load.result()``: the 1/5/15-minute averages
    just before the block (``before``) and the 1-minute average's mean and largest value
    while it ran (``during_mean``, ``during_max``; the 1-minute average lags: a run of a few
    seconds shows mostly the load before it).
    """

    def __init__(self, period: float = 1.0):
        self.period = period
        self.before = None
        self.samples: List[float] = []
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self):
        while not self._done.wait(self.period):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self):
        self.before = [round(x, 2) for x in os.getloadavg()]
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.samples.append(os.getloadavg()[0])
        self._done.set()
        self._thread.join()
        return False

    def result(self) -> Dict:
        """Return ``before``, ``during_mean`` and ``during_max`` (1-minute averages)."""
        return {'before': self.before,
                'during_mean': round(statistics.fmean(self.samples), 2),
                'during_max': round(max(self.samples), 2)}


def inprocess_rate(steps: int, overrides: Sequence[str] = ()) -> float:
    """Return env steps/s of in-process training (clock from the first update, as the graph)."""
    from pg_node.common.config_files import load_config
    from pg_node.rl.train_inprocess import train_inprocess
    first = []

    def note(point):
        if not first:
            first.append((point['env_steps'], point['wall_seconds']))
        note.last = (point['env_steps'], point['wall_seconds'])

    train_inprocess(load_config(None, list(overrides)), steps, callback=note, eval_episodes=1)
    (s0, t0), (s1, t1) = first[0], note.last
    return (s1 - s0) / (t1 - t0)


def graph_run(steps: int, overrides: Sequence[str] = (), round_trips: bool = False) -> Dict:
    """
    Train through the graph; return ``summary.json`` (steps/s and per-node usage).

    With ``round_trips``, sim_node logs its lock-step round trips (``round_trip_log``) and
    the summary gets them as ``round_trips_ns``.
    """
    from bench import runs as br
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / 'round_trips.npy'
        extra = [f'sim_node.round_trip_log={log}'] if round_trips else []
        summary = br.run_graph(Path(tmp) / 'run', steps, 0,
                               [*overrides, *extra, '--eval-episodes', '1'])
        if round_trips:
            summary['round_trips_ns'] = np.load(log)
        return summary


def split_round_trips(trips_ns: np.ndarray, n_steps: int, skip_rollouts: int = 2
                      ) -> Tuple[np.ndarray, np.ndarray]:
    """
    Return a training's lock-step round trips in ms: ``(within rollouts, at rollout ends)``.

    One actor answers every transition at once except after the last step of a rollout,
    when it waits for the next weights: every ``n_steps``-th round trip is that wait. Which
    phase it is follows from the data (the phase whose median is largest), as the sim does
    not know where the actor's rollouts start. The first ``skip_rollouts`` rollouts (start-up)
    are left out.

    >>> trips = np.array([1, 1, 9, 1, 1, 9, 1, 1, 9, 2, 1, 8]) * 1_000_000
    >>> inside, ends = split_round_trips(trips, 3, skip_rollouts=1)
    >>> inside.tolist(), ends.tolist()
    ([1.0, 1.0, 1.0, 1.0, 2.0, 1.0], [9.0, 9.0, 8.0])
    """
    ms = np.asarray(trips_ns, dtype=np.float64)[skip_rollouts * n_steps:] / 1e6
    phase = np.arange(ms.size) % n_steps
    end = max(range(min(n_steps, ms.size)), key=lambda k: np.median(ms[phase == k]))
    return ms[phase != end], ms[phase == end]


def trip_stats(ms: np.ndarray) -> Dict:
    """Return count, median, p99 and max of round trips in ms (``None`` for none)."""
    if ms.size == 0:
        return {'round_trips': 0, 'median_ms': None, 'p99_ms': None, 'max_ms': None}
    return {'round_trips': int(ms.size), 'median_ms': float(np.median(ms)),
            'p99_ms': float(np.percentile(ms, 99)), 'max_ms': float(ms.max())}


def run_tax(b: Dict, log: Callable[[str], None]) -> Dict:
    """Measure the three tables; return every number."""
    from pg_node.common.params import defaults
    from bench import runs as br
    out = {'steps': b['tax_steps'], 'pairs': [], 'pair_loads': [], 'nodes': {}, 'scaling': [],
           'latency': {}}
    steps = b['tax_steps']
    trips = {'rollout': [], 'boundary': [], 'separate_rollout': [], 'separate_boundary': []}
    n_steps = defaults('actor_node')['n_steps']    # the runs' rollouts: a hand-over per n_steps
    for k in range(b['tax_repeats']):
        log(f'tax: in-process, graph and graph of separate processes, 64 arms, {steps:,} '
            f'steps ({k + 1}/{b["tax_repeats"]})')
        loads = {}
        with LoadWatch() as load:
            ip = inprocess_rate(steps)
        loads['inprocess'] = load.result()
        with LoadWatch() as load:
            summary = graph_run(steps, round_trips=True)
        loads['graph'] = load.result()
        with LoadWatch() as load:
            separate = graph_run(steps, ['--separate'], round_trips=True)
        loads['separate'] = load.result()
        out['pairs'].append({'inprocess': ip, 'graph': summary['steps_per_second'],
                             'separate': separate['steps_per_second']})
        out['pair_loads'].append(loads)
        for prefix, run in (('', summary), ('separate_', separate)):
            part = split_round_trips(run['round_trips_ns'], n_steps)
            trips[f'{prefix}rollout'].append(part[0])
            trips[f'{prefix}boundary'].append(part[1])
            trained = run['session_steps']
            for name, usage in run.get('nodes', {}).items():
                # a process name says which graph it ran in: sim_node ... learner_node in
                # the separate one, sim_and_actor and critic_and_learner in the default
                out['nodes'].setdefault(name, []).append({
                    'peak_rss_mb': usage['peak_rss_mb'],
                    'cpu_per_100k': usage['cpu_seconds_training'] / trained * 1e5})
    for key, parts in trips.items():
        out['latency'][key] = trip_stats(np.concatenate(parts))
    for arms, pairs in b['tax_scaling']:
        log(f'tax: scaling, {pairs} x {arms} arms')
        row = {'arms': arms, 'pairs': pairs}
        try:
            row['graph'] = graph_run(b['tax_scaling_steps'], [
                f'num_envs={arms}', f'num_actors={pairs}'])['steps_per_second']
            row['inprocess'] = inprocess_rate(b['tax_scaling_steps'],
                                              [f'num_envs={arms * pairs}'])
        except Exception as exc:  # noqa: B902 - a failed row is reported, not fatal
            row['error'] = str(exc).splitlines()[0]
            log(traceback.format_exc())
        out['scaling'].append(row)
    n = b['tax_latency_steps']
    log(f'tax: lock-step round trip, 64 arms, {n:,} steps, no training running')
    out['latency']['idle'] = _latency(br, n)
    log('tax: lock-step round trip, 64 arms, while a training graph runs')
    done, learning = threading.Event(), threading.Event()
    background = threading.Thread(target=_train_until, args=(done, learning), daemon=True)
    background.start()
    try:
        # measure from the background graph's first update on (it used to be a fixed 15 s
        # for its bring-up: in --quick mode half of this section's time)
        deadline = time.monotonic() + LEARNING_DEADLINE
        while not learning.wait(0.5):
            if not background.is_alive() or time.monotonic() > deadline:
                raise RuntimeError('the background training graph ended or did not start '
                                   f'learning within {LEARNING_DEADLINE:.0f} s')
        out['latency']['training'] = _latency(br, n)
    finally:
        done.set()
        background.join()
    return out


def _latency(br, steps: int) -> Dict:
    res = br.lock_step_latency(64, steps)
    res.pop('samples_ms')
    return res


def _train_until(done: threading.Event, learning: threading.Event):
    """
    Run a training graph in its own domain until ``done`` is set.

    ``learning`` is set once the graph has written its first progress row (its first
    update); if the graph ends before ``done``, so does this thread.
    """
    import subprocess
    import sys
    from bench import runs as br
    from pg_node.tools.processes import child_env, REPO, stop
    from pg_node.common.run_dir import RunDir
    with tempfile.TemporaryDirectory() as tmp:
        run = RunDir(Path(tmp) / 'run')
        proc = subprocess.Popen(
            [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run.path),
             '--total-steps', '100000000', '--no-progress', '--eval-episodes', '1'],
            cwd=REPO, env=child_env(br.domain_id(background=True)),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            while not done.is_set() and proc.poll() is None:
                if not learning.is_set() and run.last_progress():
                    learning.set()
                done.wait(0.2)
        finally:
            stop(proc)


def tax_ratio(pairs: Sequence[Dict], key: str = 'graph') -> float:
    """
    Return the median over runs of graph (``key``) / in-process steps/s, each run's own ratio.

    Not the ratio of the two medians: a run's in-process and graph trainings come a minute
    apart, so their ratio is free of the drift between runs that moves both medians.

    >>> tax_ratio([{'inprocess': 10, 'graph': 5}, {'inprocess': 20, 'graph': 16},
    ...            {'inprocess': 30, 'graph': 18}])
    0.6
    """
    return statistics.median(p[key] / p['inprocess'] for p in pairs)


def _fmt(x, spec=',.0f'):
    return '—' if x is None else format(x, spec)


def _spread(values, spec):
    return f'{format(min(values), spec)}-{format(max(values), spec)}'


def load_text(loads, keys) -> str:
    """
    Return one run's loads as ``1.02, 1.80 (2.10); ...``: per side, before, during (max).

    >>> load_text({'inprocess': {'before': [1.02, 0.9, 0.8], 'during_mean': 1.5,
    ...                          'during_max': 1.8}}, ['inprocess', 'graph'])
    '1.02, 1.50 (1.80)'
    """
    if not loads:
        return '—'
    return '; '.join(f"{loads[k]['before'][0]:.2f}, {loads[k]['during_mean']:.2f} "
                     f"({loads[k]['during_max']:.2f})" for k in keys if k in loads)


def render_tax(res: Dict, table: Callable[[List[str], List[List[str]]], str]) -> List[str]:
    """Return the section's markdown lines."""
    pairs = res['pairs']
    keys = ['graph', 'separate'] if all('separate' in p for p in pairs) else ['graph']
    ratio_head = ['run', 'in-process steps/s', 'graph steps/s', 'graph / in-process',
                  'graph, separate, steps/s', 'separate / in-process'][:2 + 2 * len(keys)]
    loads = res.get('pair_loads') or [None] * len(pairs)
    ratio_head.append('load: 1-min average before, during (max) each run')
    ratio_rows = [[str(k + 1), _fmt(p['inprocess'])]
                  + [x for key in keys
                     for x in (_fmt(p[key]), _fmt(p[key] / p['inprocess'], '.3f'))]
                  + [load_text(loads[k], ['inprocess', *keys])]
                  for k, p in enumerate(pairs)]
    ratio_rows.append(
        ['**median**', f"**{_fmt(statistics.median(p['inprocess'] for p in pairs))}**"]
        + [f'**{x}**' for key in keys for x in (_fmt(statistics.median(p[key] for p in pairs)),
                                                _fmt(tax_ratio(pairs, key), '.3f'))] + [''])
    ratio_rows.append(['min-max', _spread([p['inprocess'] for p in pairs], ',.0f')]
                      + [x for key in keys
                         for x in (_spread([p[key] for p in pairs], ',.0f'),
                                   _spread([p[key] / p['inprocess'] for p in pairs], '.3f'))]
                      + [''])
    out = ['## The ROS tax: the graph against the same computation in one process', '',
           f'Default settings (64 arms, 8-step rollouts, A2C, lock-step, sync), '
           f'{res["steps"]:,} steps per run, in-process and graph in turn, '
           f'{len(pairs)} times; steps/s from the first update to the last (all). The '
           'ratio is read within each run (its trainings are a minute apart; the machine '
           'drifts more than that between runs), and its median is the figure. '
           + ('"Graph" is `python -m pg_node train`: the simulator and the actor in one '
              'process (`sim_and_actor`), the critic and the learner in another '
              '(`critic_and_learner`); '
              '"separate" the same graph with every node a process of its own '
              '(`train --separate`). ' if 'separate' in keys else '')
           + f'Load average {res.get("load", "?")}.', '',
           table(ratio_head, ratio_rows), '',
           "Each process in those graph runs: peak resident memory (the kernel's high-water "
           'mark) and CPU seconds per 100k training steps (median over the runs; a node '
           "by its own name: its process in the separate runs; two nodes' names: the "
           "default graph's processes).", '',
           table(['node', 'imports torch', 'peak memory MB', 'CPU s per 100k steps'],
                 [[name, 'yes' if name in TORCH_NODES else 'no',
                   _fmt(statistics.median(u['peak_rss_mb'] for u in res['nodes'][name])),
                   _fmt(statistics.median(u['cpu_per_100k'] for u in res['nodes'][name]),
                        '.2f')]
                  for name in NODES if name in res['nodes']]), '',
           'How cost grows with work: arms per simulator and simulator/actor pairs (each pair '
           'a process of a simulator and an actor, as `train` starts them; one critic and one '
           'learner). In-process has one actor, so two pairs of N arms are set beside one '
           'process of 2N arms.', '',
           table(['arms per simulator', 'pairs', 'graph steps/s', 'in-process steps/s '
                  '(pairs x arms in one process)', 'graph / in-process'],
                 [[str(r['arms']), str(r['pairs']), _fmt(r.get('graph')),
                   _fmt(r.get('inprocess')),
                   _fmt(r['graph'] / r['inprocess'], '.3f') if r.get('graph')
                   and r.get('inprocess') else r.get('error', '—')]
                  for r in res['scaling']]), '']
    lat = res['latency']

    def rows(labels):
        return [[label, _fmt(lat[key].get('round_trips')),
                 _fmt(lat[key].get('median_ms'), '.3f'), _fmt(lat[key].get('p99_ms'), '.3f'),
                 _fmt(lat[key].get('max_ms'), '.2f')]
                for key, label in labels.items() if key in lat]
    head = ['', 'round trips', 'median ms', 'p99 ms', 'max ms']
    if 'rollout' in lat:
        out += ["Lock-step round trip inside the training: sim_node's own, in the graph runs "
                'of the first table (a transition published to the command answering it '
                'received; every round trip of the runs after their first two rollouts, '
                'pooled). Within a rollout the actor answers at once; after the last step of '
                'a rollout the answer waits for the critic, the learner and the new weights '
                '(the hand-over). "Every node its own process": the separate runs.', '',
                table(['in the training graph', *head[1:]], rows(TRAINING_LABELS)), '']
    out += ['Lock-step round trip of sim_node with 64 arms and a client that answers at once '
            '(no actor, no learning), with no training running and while a training graph '
            'runs in another DDS domain on the same two cores.', '',
            table(['while', *head[1:]], rows(LATENCY_LABELS)), '']
    return out


# --- python -m bench tax: the ratio alone, in alternating runs ------------------------------

#: the graphs ``python -m bench tax`` sets beside in-process by default: ``train``'s default,
#: and the same with the simulator and the actor exchanging over DDS (``in_process_hop`` off)
GRAPHS = {'graph': [], 'graph_over_dds': ['sim_node.in_process_hop=false']}


def ratio_runs(steps: int, runs: int, graphs: Dict[str, List[str]],
               log: Callable[[str], None], common: Sequence[str] = ()) -> Dict:
    """
    Train in-process and through each of ``graphs`` in turn, ``runs`` times; every load.

    The order turns round every other run (in-process first, then last), so that a load
    that drifts through a run weighs on both sides alike. ``graphs``: a name for each graph
    and its ``train`` overrides; ``common``: overrides of both sides (``gamma=0.9``).
    """
    out = {'steps': steps, 'graphs': graphs, 'common': list(common), 'pairs': [],
           'pair_loads': [],
           'load_start': [round(x, 2) for x in os.getloadavg()]}
    for k in range(runs):
        order = ['inprocess', *graphs]
        if k % 2:
            order.reverse()
        rates, loads = {}, {}
        for side in order:
            log(f'tax: run {k + 1}/{runs}, {side}, {steps:,} steps')
            with LoadWatch() as load:
                rates[side] = (inprocess_rate(steps, common) if side == 'inprocess' else
                               graph_run(steps, [*common, *graphs[side]])['steps_per_second'])
            loads[side] = load.result()
            log(f'tax: {side} {rates[side]:,.0f} steps/s, load {load_text(loads, [side])}')
        out['pairs'].append(rates)
        out['pair_loads'].append(loads)
    out['load_end'] = [round(x, 2) for x in os.getloadavg()]
    return out


def render_ratio(res: Dict, command: str) -> List[str]:
    """Return the markdown of :func:`ratio_runs`: one row per run, the median, min-max."""
    pairs, graphs = res['pairs'], list(res['graphs'])
    head = ['run', 'in-process steps/s'] + [x for g in graphs
                                            for x in (f'{g} steps/s', f'{g} / in-process')]
    head.append('load: 1-min average before, during (max), in-process; '
                + '; '.join(graphs))
    rows = [[str(k + 1), _fmt(p['inprocess'])]
            + [x for g in graphs for x in (_fmt(p[g]), _fmt(p[g] / p['inprocess'], '.3f'))]
            + [load_text(res['pair_loads'][k], ['inprocess', *graphs])]
            for k, p in enumerate(pairs)]
    rows.append(['**median**', f"**{_fmt(statistics.median(p['inprocess'] for p in pairs))}**"]
                + [f'**{x}**' for g in graphs
                   for x in (_fmt(statistics.median(p[g] for p in pairs)),
                             _fmt(tax_ratio(pairs, g), '.3f'))] + [''])
    rows.append(['min-max', _spread([p['inprocess'] for p in pairs], ',.0f')]
                + [x for g in graphs
                   for x in (_spread([p[g] for p in pairs], ',.0f'),
                             _spread([p[g] / p['inprocess'] for p in pairs], '.3f'))] + [''])
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    lines += ['| ' + ' | '.join(r) + ' |' for r in rows]
    described = '; '.join(f'{g}: `train {" ".join(o)}`' if o else f'{g}: `train`'
                          for g, o in res['graphs'].items())
    settings = ('default settings' if not res.get('common') else
                f'default settings but {" ".join(res["common"])}')
    return [f'`{command}`: {settings} (64 arms, 8-step rollouts, A2C, lock-step, sync), '
            f'{res["steps"]:,} steps per training, in-process and each graph in turn '
            f'({described}), {len(pairs)} times, the order reversed every other time; steps/s '
            'from the first update to the last. The ratio is read within each run, its median '
            'is the figure. Load average (1/5/15 min) '
            f'{" / ".join(map(str, res["load_start"]))} at the start, '
            f'{" / ".join(map(str, res["load_end"]))} at the end.', '', *lines, '']


def main(argv=None) -> int:
    """``python -m bench tax``: the graph / in-process ratio in alternating runs."""
    from pg_node.tools.processes import REPO
    parser = argparse.ArgumentParser(
        prog='python -m bench tax',
        description='The ROS tax: the default training in-process and through the graph, '
                    'in turn; the ratio of each run, its median and spread, and the load.')
    parser.add_argument('--steps', type=int, default=BUDGETS['tax_steps'][0],
                        help='environment steps per training (default: %(default)s)')
    parser.add_argument('--runs', type=int, default=5,
                        help='runs of each side, alternating (at least 3; default: '
                             '%(default)s)')
    parser.add_argument('--graph', action='append', metavar='NAME[=KEY=VALUE,...]',
                        help='a graph to measure, with its train overrides (repeatable; '
                             'default: graph, and graph_over_dds with '
                             'sim_node.in_process_hop=false)')
    parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                        help='a setting of both sides, in-process and every graph '
                             '(repeatable; e.g. --set gamma=0.9 --set vf_epochs=1)')
    parser.add_argument('--out', metavar='FILE.md',
                        help='also write the table there, and every number to FILE.json')
    args = parser.parse_args(argv)
    if args.runs < 3 or args.steps <= 0:
        parser.error('--runs must be at least 3 and --steps positive')
    graphs = GRAPHS
    if args.graph:
        graphs = {}
        for spec in args.graph:
            name, _, overrides = spec.partition('=')
            if not name or name == 'inprocess' or name in graphs:
                parser.error(f'--graph {spec!r}: a new name (not inprocess) first')
            graphs[name] = [o for o in overrides.split(',') if o]
    command = ' '.join(['python -m bench tax', *(sys.argv[2:] if argv is None else argv)])
    start = time.perf_counter()

    def log(text):
        print(f'[tax {time.perf_counter() - start:7.1f} s] {text}', file=sys.stderr, flush=True)

    log(f'commit {_commit(REPO)}')
    res = ratio_runs(args.steps, args.runs, graphs, log, args.set)
    res['command'], res['commit'] = command, _commit(REPO)
    text = '\n'.join(render_ratio(res, command))
    print(text)
    if args.out:
        out = Path(args.out)
        out.write_text(text)
        out.with_suffix('.json').write_text(json.dumps(res, indent=1))
    return 0


def _commit(repo) -> str:
    import subprocess
    try:
        return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=repo, text=True,
                              capture_output=True, timeout=10).stdout.strip() or '?'
    except OSError:
        return '?'
