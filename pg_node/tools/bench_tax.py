"""
The ``tax`` section of ``python -m pg_node bench``: what the ROS graph costs against one process.

Three tables, from one invocation:

* **graph vs in-process**: the default A2C (64 arms, 8-step rollouts, lock-step, sync)
  trained in-process (:func:`pg_node.rl.train_inprocess.train_inprocess`) and through the
  four nodes (``python -m pg_node train``), alternately, ``tax_repeats`` times each; the
  median of each and their ratio. Both clocks start at the first update.
* **per node**: each node's peak resident memory and CPU seconds per 100k training steps
  (``summary.json``'s ``nodes``, read from ``/proc`` by the supervisor) in those graph runs;
* **scaling**: graph and in-process for 16, 64 and 256 arms per simulator and 1 and 2
  simulator/actor pairs. Two pairs of N arms are compared with one process of 2N arms (the
  in-process reference has one actor): the same work per update, not the same computation;
* **round trip under load**: sim_node's lock-step round trip for 64 arms
  (:func:`pg_node.tools.bench_runs.lock_step_latency`) measured with no training running
  and again while a training graph runs in another DDS domain on the same two cores.
"""
from pathlib import Path
import statistics
import tempfile
import threading
import traceback
from typing import Callable, Dict, List, Sequence

#: budgets: full run, and --quick
BUDGETS = {'tax_steps': (200_000, 4_096), 'tax_repeats': (5, 1),
           'tax_scaling_steps': (150_000, 4_096), 'tax_scaling_rows': (6, 2),
           'tax_latency_steps': (5_000, 300)}
#: scaling rows: (arms per simulator, simulator/actor pairs)
SCALING = ((16, 1), (16, 2), (64, 1), (64, 2), (256, 1), (256, 2))
NODES = ('sim_node', 'actor_node', 'critic_node', 'learner_node')
LATENCY_LABELS = {'idle': 'no training running', 'training': 'a training graph runs'}


def inprocess_rate(steps: int, overrides: Sequence[str] = ()) -> float:
    """Return env steps/s of in-process training (clock from the first update, as the graph)."""
    from pg_node.common.params import load_config
    from pg_node.rl.train_inprocess import train_inprocess
    first = []

    def note(point):
        if not first:
            first.append((point['env_steps'], point['wall_seconds']))
        note.last = (point['env_steps'], point['wall_seconds'])

    train_inprocess(load_config(None, list(overrides)), steps, callback=note, eval_episodes=1)
    (s0, t0), (s1, t1) = first[0], note.last
    return (s1 - s0) / (t1 - t0)


def graph_run(steps: int, overrides: Sequence[str] = ()) -> Dict:
    """Train through the graph; return ``summary.json`` (steps/s and per-node usage)."""
    from pg_node.tools import bench_runs as br
    with tempfile.TemporaryDirectory() as tmp:
        return br.run_graph(Path(tmp) / 'run', steps, 0,
                            [*overrides, '--eval-episodes', '1'])


def run_tax(b: Dict, log: Callable[[str], None]) -> Dict:
    """Measure the three tables; return every number."""
    from pg_node.tools import bench_runs as br
    out = {'steps': b['tax_steps'], 'pairs': [], 'nodes': {}, 'scaling': [], 'latency': {}}
    steps = b['tax_steps']
    for k in range(b['tax_repeats']):
        log(f'tax: in-process and graph, 64 arms, {steps:,} steps ({k + 1}/{b["tax_repeats"]})')
        ip = inprocess_rate(steps)
        summary = graph_run(steps)
        out['pairs'].append({'inprocess': ip, 'graph': summary['steps_per_second']})
        trained = summary['session_steps']
        for name, usage in summary.get('nodes', {}).items():
            out['nodes'].setdefault(name, []).append({
                'peak_rss_mb': usage['peak_rss_mb'],
                'cpu_per_100k': usage['cpu_seconds_training'] / trained * 1e5})
    for arms, pairs in SCALING[:b['tax_scaling_rows']]:
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
    done = threading.Event()
    background = threading.Thread(target=_train_until, args=(done,), daemon=True)
    background.start()
    try:
        out['latency']['training'] = _latency(br, n, wait=15.0)
    finally:
        done.set()
        background.join()
    return out


def _latency(br, steps: int, wait: float = 0.0) -> Dict:
    import time
    time.sleep(wait)             # let the background graph come up and start learning
    res = br.lock_step_latency(64, steps)
    res.pop('samples_ms')
    return res


def _train_until(done: threading.Event):
    """Run training graphs one after another in their own domain until ``done`` is set."""
    import subprocess
    import sys
    from pg_node.tools import bench_runs as br
    from pg_node.tools.processes import child_env, REPO, stop
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.Popen(
            [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(Path(tmp) / 'run'),
             '--total-steps', '100000000', '--no-progress', '--eval-episodes', '1'],
            cwd=REPO, env=child_env(br.domain_id(background=True)),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL, start_new_session=True)
        done.wait()
        stop(proc)


def tax_ratio(pairs: Sequence[Dict]) -> float:
    """
    Return the median over runs of graph / in-process steps/s, each run's own ratio.

    Not the ratio of the two medians: a run's in-process and graph trainings come a minute
    apart, so their ratio is free of the drift between runs that moves both medians.

    >>> tax_ratio([{'inprocess': 10, 'graph': 5}, {'inprocess': 20, 'graph': 16},
    ...            {'inprocess': 30, 'graph': 18}])
    0.6
    """
    return statistics.median(p['graph'] / p['inprocess'] for p in pairs)


def _fmt(x, spec=',.0f'):
    return '—' if x is None else format(x, spec)


def render_tax(res: Dict, table: Callable[[List[str], List[List[str]]], str]) -> List[str]:
    """Return the section's markdown lines."""
    pairs = res['pairs']
    ip = statistics.median(p['inprocess'] for p in pairs)
    gr = statistics.median(p['graph'] for p in pairs)
    ratio = tax_ratio(pairs)
    out = ['## The ROS tax: the graph against the same computation in one process', '',
           f'Default settings (64 arms, 8-step rollouts, A2C, lock-step, sync), '
           f'{res["steps"]:,} steps per run, in-process and graph alternately, '
           f'{len(pairs)} times; steps/s from the first update to the last (both). The '
           'ratio is read within each run (its two trainings are a minute apart; the machine '
           'drifts more than that between runs), and its median is the figure. '
           f'Load average {res.get("load", "?")}.', '',
           table(['run', 'in-process steps/s', 'graph steps/s', 'graph / in-process'],
                 [[str(k + 1), _fmt(p['inprocess']), _fmt(p['graph']),
                   _fmt(p['graph'] / p['inprocess'], '.3f')] for k, p in enumerate(pairs)]
                 + [['**median**', f'**{_fmt(ip)}**', f'**{_fmt(gr)}**',
                     f'**{_fmt(ratio, ".3f")}**']]), '',
           "Each node in those graph runs: peak resident memory (the kernel's high-water "
           'mark) and CPU seconds per 100k training steps (median over the runs).', '',
           table(['node', 'imports torch', 'peak memory MB', 'CPU s per 100k steps'],
                 [[name, 'yes' if name in ('critic_node', 'learner_node') else 'no',
                   _fmt(statistics.median(u['peak_rss_mb'] for u in res['nodes'][name])),
                   _fmt(statistics.median(u['cpu_per_100k'] for u in res['nodes'][name]),
                        '.2f')]
                  for name in NODES if name in res['nodes']]), '',
           'How cost grows with work: arms per simulator and simulator/actor pairs (each pair '
           'a simulator and an actor process; one critic and one learner). In-process has one '
           'actor, so two pairs of N arms are set beside one process of 2N arms.', '',
           table(['arms per simulator', 'pairs', 'graph steps/s', 'in-process steps/s '
                  '(pairs x arms in one process)', 'graph / in-process'],
                 [[str(r['arms']), str(r['pairs']), _fmt(r.get('graph')),
                   _fmt(r.get('inprocess')),
                   _fmt(r['graph'] / r['inprocess'], '.3f') if r.get('graph')
                   and r.get('inprocess') else r.get('error', '—')]
                  for r in res['scaling']]), '']
    lat = res['latency']
    out += ['Lock-step round trip of sim_node with 64 arms (transition published to its '
            'answer received; the client answers at once), with no training running and while a '
            'training graph runs in another DDS domain on the same cores.', '',
            table(['while', 'round trips', 'median ms', 'p99 ms', 'max ms'],
                  [[label, _fmt(lat[key].get('round_trips')),
                    _fmt(lat[key].get('median_ms'), '.3f'), _fmt(lat[key].get('p99_ms'), '.3f'),
                    _fmt(lat[key].get('max_ms'), '.2f')]
                   for key, label in LATENCY_LABELS.items() if key in lat]), '']
    return out
