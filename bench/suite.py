"""
``python -m bench``: throughput, latency, learning and estimator-variance benchmarks.

Runs every selected section in this one invocation (so that ratios between rows hold on a
noisy machine) and writes, under ``--out`` (default: ``docs/results/`` of this checkout):

* ``BENCHMARKS.md``: the tables, the exact command, the machine, the load average, and
  whether each performance target of issue 6 is met; into the page's block between
  :mod:`bench.report`'s markers when it has them (the summary and the sections that sessions
  wrote stay; the block replaced goes to ``LOG.md``), else the whole file;
* ``bench_plots/*.png``: throughput ladder, latency histogram, learning curves, variance;
* ``bench_results.json``: every number, saved after each section.

Sections (``--only``, comma-separated; default all):

* ``throughput``: env steps/s (one arm advanced by one control step) of raw ``mj_step``,
  ``ArmTask`` with 1/16/64 arms, sim_node lock-step with a minimal client, pg_node A2C
  in-process, the training graph (``python -m pg_node train``) and SB3 A2C (8 envs, its
  defaults) training on ``pg_node/Reacher2-v0``; each as a ratio to SB3 A2C and to raw MuJoCo;
* ``latency``: sim_node's lock-step round trip (transition published to its command
  received), measured inside sim_node (:mod:`bench.latency_probe`), for 1 and 64 arms;
* ``tax``: the graph against the same computation in one process, each node's memory and
  CPU, scaling with arms and simulator/actor pairs, the round trip while training runs
  (:mod:`bench.tax`);
* ``learning``: pg_node A2C through the graph and in-process, SB3 A2C and SB3 PPO on
  ``pg_node/Reacher2-v0``, and SB3 A2C/PPO on Gymnasium's ``Reacher-v5``, over seeds:
  deterministic evaluation return at fixed step counts, wall-clock time to -10 and -6;
* ``variance``: the gradient-estimator lab on the arm (:mod:`pg_node.lab.arm`);
* ``curves``: every estimator's (and algorithm's) learning curve, beside the variance table
  (:mod:`bench.curves`; SB3 rows from ``learning``);
* ``profile`` (only when asked for): the training graph with every node under cProfile, and
  where each node's time goes (``--only profile --report PROFILE.md`` keeps it apart).

``--quick`` shrinks every budget to a smoke run (seconds, not a measurement) and leaves out
the rows that only repeat another with other settings (the lean graph). The numbers
of the measurement functions come from :mod:`bench.runs`.
"""
import argparse
from datetime import datetime, timezone
import json
import math
import os
from pathlib import Path
import platform
import sys
import tempfile
import time
import traceback
from typing import Dict, List, Sequence

from bench import curves, report, tax
from bench.curves import eval_time_at, reached
from bench.pool import JOBS_NOTE, run_all
import numpy as np
from pg_node.tools.processes import terminate_as_interrupt

SECTIONS = ('throughput', 'latency', 'tax', 'variance', 'curves', 'learning', 'profile')
DEFAULT_SECTIONS = ('throughput', 'latency', 'tax', 'variance', 'curves', 'learning')
LEARNERS = ('pg_node_graph', 'pg_node_inprocess', 'sb3_a2c', 'sb3_ppo', 'sb3_a2c_v5',
            'sb3_ppo_v5')
LEARNER_NAMES = {
    'pg_node_graph': 'pg_node A2C, ROS graph',
    'pg_node_inprocess': 'pg_node A2C, in-process (reference)',
    'sb3_a2c': 'SB3 A2C',
    'sb3_ppo': 'SB3 PPO',
    'sb3_a2c_v5': 'SB3 A2C on Reacher-v5',
    'sb3_ppo_v5': 'SB3 PPO on Reacher-v5',
}
THRESHOLDS = (-10.0, -6.0)
#: where the committed reports and plots live: the default of ``--out``
RESULTS = Path(__file__).resolve().parent.parent / 'docs' / 'results'
#: overrides that take the sim's MarkerArray and the bag's per-step records off the graph
LEAN_GRAPH = ('sim_node.marker_rate=0.0', 'learner_node.record_arms=0')
#: latency rows: (arms, extra sim_node parameters)
LATENCY_ROWS = ((1, ()), (64, ()), (64, ('-p', 'marker_rate:=0.0')))
NOT_AVAILABLE = 'not run: training graph not available'

#: budgets: full run, and --quick
BUDGETS = {
    'seconds': (3.0, 0.3),
    'sb3_steps': (50_000, 2_000),
    'inprocess_steps': (200_000, 4_096),
    'graph_steps': (200_000, 4_096),
    # the lean graph's row: the same run with two overrides, 11 s of a quick run's 120
    'graph_lean': (True, False),
    'repeats': (3, 1),
    'latency_steps': (10_000, 300),
    'learning_steps': (1_000_000, 4_096),
    'seeds': (3, 1),
    'eval_episodes': (100, 10),
    'var_batches': (200, 4),
    'var_batch_size': (32, 4),
    'var_train_steps': (100_000, 4_096),
    'var_true_episodes': (32_768, 256),
    'var_value_episodes': (4_096, 128),
    'profile_steps': (100_000, 4_096),
    **curves.BUDGETS,
    **tax.BUDGETS,
}


# --- machine -------------------------------------------------------------------------------

def _version(dist: str) -> str:
    from importlib import metadata
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return 'not installed'


def machine_facts() -> Dict[str, str]:
    """Return CPU model, cores, RAM, OS and package versions of this machine."""
    cpu = platform.processor() or 'unknown'
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    ram = 'unknown'
    try:
        for line in Path('/proc/meminfo').read_text().splitlines():
            if line.startswith('MemTotal'):
                ram = f'{int(line.split()[1]) / 2 ** 20:.1f} GiB'
    except OSError:
        pass
    return {
        'cpu': cpu, 'cores': str(os.cpu_count()), 'ram': ram,
        'os': f'{platform.system()} {platform.release()}',
        'python': platform.python_version(), 'torch': _version('torch'),
        'mujoco': _version('mujoco'), 'rclpy': _version('ros-jazzy-rclpy'),
        'stable-baselines3': _version('stable-baselines3'),
        'gymnasium': _version('gymnasium'), 'numpy': _version('numpy'),
        'pg_node commit': _commit(),
    }


def _commit() -> str:
    """Return the checkout's commit, ``+ local changes`` when code or config differ from it."""
    from pg_node.tools.processes import REPO as repo
    import subprocess
    try:
        head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=repo, text=True,
                              capture_output=True, timeout=10).stdout.strip()
        # the reports this command writes are not changes to what it measures
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no', '--',
                                '.', ':!*.md', ':!docs/results'],
                               cwd=repo, text=True, capture_output=True,
                               timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return 'unknown'
    return (head or 'unknown') + (' + local changes' if dirty else '')


def b_repeats(results) -> int:
    """Return how many times the repeated throughput rows ran (1 in older results)."""
    return int(results.get('budgets', {}).get('repeats', 1))


def load_average() -> str:
    """Return the 1/5/15-minute load averages as text."""
    try:
        return ' / '.join(f'{x:.2f}' for x in os.getloadavg())
    except OSError:
        return 'unknown'


# --- sections ------------------------------------------------------------------------------

def run_throughput(b: Dict, log) -> Dict:
    """Measure the throughput ladder; return ``{'rows': [...]}`` in env steps/s."""
    from bench import runs as br
    rows = []

    def add(key, name, fn, note='', repeats=1):
        """Measure a row ``repeats`` times and keep the median (each run in the note)."""
        log(f'throughput: {name}' + (f' (x{repeats})' if repeats > 1 else ''))
        try:
            values = [float(fn()) for _ in range(repeats)]
            if repeats > 1:
                note = (f'{note}; ' if note else '') + 'median of ' + ', '.join(
                    f'{v:,.0f}' for v in values)
            rows.append({'key': key, 'name': name, 'steps_per_second': float(np.median(values)),
                         'runs': values, 'note': note})
        except Exception as exc:  # noqa: B902 - a failed row is reported, not fatal
            rows.append({'key': key, 'name': name, 'steps_per_second': None,
                         'note': f'failed: {exc}'.splitlines()[0]})
            log(traceback.format_exc())

    s = b['seconds']
    add('mujoco', 'raw mj_step (1 MjData, 2 substeps = 1 control step)',
        lambda: br.raw_mujoco(s))
    for n in (1, 16, 64):
        add(f'task{n}', f'ArmTask in-process, {n} arm{"s" if n > 1 else ""}',
            lambda n=n: br.task_in_process(n, s))
    for n in (1, 64):
        add(f'sim_node{n}', f'sim_node lock-step + minimal client, {n} arm{"s" if n > 1 else ""}',
            lambda n=n: br.sim_node_lock_step(n, max(s, 1.0)))
    add('inprocess', 'pg_node A2C training, in-process (64 arms)',
        lambda: br.a2c_in_process(b['inprocess_steps'])['steps_per_second'],
        f'{b["inprocess_steps"]:,} steps')
    if br.graph_available():
        def graph(overrides=()):
            with tempfile.TemporaryDirectory() as tmp:
                return br.run_graph(Path(tmp) / 'run', b['graph_steps'], 0,
                                    overrides)['steps_per_second']
        add('graph', 'pg_node A2C training, whole ROS graph (64 arms)', graph,
            f'{b["graph_steps"]:,} steps, summary.json steps_per_second', b['repeats'])
        if b['graph_lean']:
            add('graph_lean', 'the same, sim markers and per-step bag recording off',
                lambda: graph(LEAN_GRAPH), f'overrides: {" ".join(LEAN_GRAPH)}', b['repeats'])
    else:
        rows.append({'key': 'graph', 'name': 'pg_node A2C training, whole ROS graph',
                     'steps_per_second': None, 'note': NOT_AVAILABLE})
    add('sb3_a2c', 'SB3 A2C training (8 envs, defaults)',
        lambda: br.sb3_throughput(b['sb3_steps'])['steps_per_second'],
        f'{b["sb3_steps"]:,} steps', b['repeats'])
    return {'rows': rows}


def run_latency(b: Dict, log) -> Dict:
    """Measure lock-step round trips for 1 and 64 arms."""
    from bench import runs as br
    out = {'rows': [], 'samples_ms': {}}
    for n, extra in LATENCY_ROWS:
        label = f'{n} arm{"s" if n > 1 else ""}' + (', markers off' if extra else '')
        log(f'latency: {label}, {b["latency_steps"]:,} steps')
        try:
            res = br.lock_step_latency(n, b['latency_steps'], ros_args=extra)
            out['samples_ms'][label] = res.pop('samples_ms').tolist()
            res['label'] = label
            out['rows'].append(res)
        except Exception as exc:  # noqa: B902 - reported in the table
            out['rows'].append({'num_envs': n, 'label': label,
                                'error': str(exc).splitlines()[0]})
            log(traceback.format_exc())
    return out


def learning_run(key: str, steps: int, seed: int, points: Sequence[int],
                 eval_episodes: int) -> Dict:
    """Train one learner (a key of :data:`LEARNERS`) once; evaluations at ``points``."""
    from bench import runs as br
    if key == 'pg_node_graph':
        with tempfile.TemporaryDirectory() as tmp:  # bag and checkpoints: gone
            return br.graph_learning(Path(tmp) / 'run', steps, seed, points)
    if key == 'pg_node_inprocess':
        return br.inprocess_learning(steps, seed, points, eval_episodes)
    algo = 'a2c' if 'a2c' in key else 'ppo'
    env_id = 'Reacher-v5' if key.endswith('_v5') else 'pg_node/Reacher2-v0'
    return br.sb3_learning(algo, env_id, steps, seed, points, eval_episodes)


def run_learning(b: Dict, learners: List[str], log, progress=None, jobs: int = 1) -> Dict:
    """
    Train every learner over the seeds; evaluations at fixed points and curves.

    ``progress(partial)`` is called after every run with the results so far. With ``jobs``
    > 1 the graph's runs go first, alone, then the in-process ones (pg_node, SB3) that many
    at a time (:mod:`bench.pool`).
    """
    from bench import runs as br
    steps, seeds = b['learning_steps'], list(range(b['seeds']))
    points = sorted({steps // 4, steps // 2, steps})
    runs, specs = {}, []
    for spec in learners:
        key, _, n_seeds = spec.partition(':')
        runs[key] = []
        if key == 'pg_node_graph' and not br.graph_available():
            runs[key] = NOT_AVAILABLE
            continue
        specs += [(key, seed) for seed in (range(int(n_seeds)) if n_seeds else seeds)]

    def report(partial=True):
        return {'steps': steps, 'seeds': seeds, 'points': points,
                'runs': {k: v for k, v in runs.items() if v},     # those that have finished
                'eval_episodes': b['eval_episodes'], 'jobs': int(jobs),
                **({'load': load_average(), 'partial': True} if partial else {})}

    def before(i):
        key, seed = specs[i]
        log(f'learning: {LEARNER_NAMES[key]}, seed {seed}, {steps:,} steps')

    def done(i, res):
        key, seed = specs[i]
        res['seed'] = seed
        runs[key].append(res)
        runs[key].sort(key=lambda r: r['seed'])
        if jobs > 1 and key != 'pg_node_graph':
            log(f'learning: {LEARNER_NAMES[key]}, seed {seed}: '
                + (res.get('error') or f'{res["evals"].get(steps, float("nan")):.2f} at '
                   f'{steps:,}'))
        if progress is not None:
            progress(report())

    alone = [k for k, (key, _) in enumerate(specs) if jobs <= 1 or key == 'pg_node_graph']
    pooled = [k for k in range(len(specs)) if k not in alone]
    task = [(learning_run, (key, steps, seed, points, b['eval_episodes']))
            for key, seed in specs]
    if pooled:
        log(f"learning: {len(pooled)} in-process runs after the graph's, {jobs} at a time")
    run_all([task[k] for k in alone], 1, lambda j, res: done(alone[j], res),
            lambda j: before(alone[j]))
    run_all([task[k] for k in pooled], jobs, lambda j, res: done(pooled[j], res))
    return report(partial=False)


def run_profile(b: Dict, log) -> Dict:
    """Profile every node of the training graph with cProfile."""
    from bench import runs as br
    if not br.graph_available():
        return {'note': NOT_AVAILABLE}
    log(f'profile: training graph under cProfile, {b["profile_steps"]:,} steps')
    return br.profile_graph(b['profile_steps'])


def run_variance(b: Dict, log) -> Dict:
    """Run the estimator lab on the arm."""
    from pg_node.lab.arm import make_arm_lab
    from pg_node.lab.variance import run_lab
    log(f'variance: training the fixed policy ({b["var_train_steps"]:,} steps), fitting V, '
        f'true gradient from {b["var_true_episodes"]:,} episodes')
    chunk = min(1024, max(2, b['var_true_episodes'] // 2))
    lab = make_arm_lab(b['var_train_steps'], seed=0, true_episodes=b['var_true_episodes'],
                       value_episodes=b['var_value_episodes'], chunk=chunk)
    log(f'variance: {b["var_batches"]} batches x {b["var_batch_size"]} episodes')
    start = time.perf_counter()
    result = run_lab(lab, b['var_batches'], b['var_batch_size'], gae_lambda=0.9, seed=0)
    lab.close()
    return {'rows': result.rows, 'title': result.title, 'policy': lab.info,
            'bias_threshold': result.bias_threshold, 'n_params': lab.n_params,
            'value_explained_variance': lab.value_explained_variance,
            'batches': b['var_batches'], 'batch_size': b['var_batch_size'],
            'true_episodes': b['var_true_episodes'], 'gae_lambda': 0.9,
            'true_grad_norm': float(np.linalg.norm(result.true_grad)),
            'seconds': time.perf_counter() - start}


# --- summaries -----------------------------------------------------------------------------

def _mean_std(values):
    vals = [v for v in values if v is not None and np.isfinite(v)]
    if not vals:
        return None, None
    return float(np.mean(vals)), float(np.std(vals))


def learning_summary(learning: Dict) -> Dict[str, Dict]:
    """Per learner: eval return mean/std over seeds at each point, and times to thresholds."""
    from bench.runs import first_time_at, value_at
    out = {}
    for key, runs in learning['runs'].items():
        if isinstance(runs, str):
            out[key] = {'note': runs}
            continue
        if not runs:        # a partial report: this learner's runs have not finished yet
            continue
        ok = [r for r in runs if 'error' not in r]
        row = {'seeds_ok': len(ok), 'seeds': len(runs), 'evals': {}, 'train_return': {}}
        errors = [r['error'] for r in runs if 'error' in r]
        if errors:
            row['note'] = f'{len(errors)} seed(s) failed: {errors[0]}'
        for p in learning['points']:
            row['evals'][p] = _mean_std([r['evals'].get(p, r['evals'].get(str(p)))
                                         for r in ok])
            row['train_return'][p] = _mean_std([value_at(r['curve'], p) for r in ok])
        row['time_to'] = {th: reached([first_time_at(r['curve'], th) for r in ok])
                          for th in THRESHOLDS}
        row['eval_time_to'] = {th: reached([eval_time_at(r, learning['points'], th)
                                            for r in ok]) for th in THRESHOLDS}
        row['wall_seconds'] = _mean_std([r['wall_seconds'] for r in ok])
        row['steps_per_second'] = _mean_std([r['steps_per_second'] for r in ok])
        out[key] = row
    return out


def targets(results: Dict) -> List[Dict]:
    """Return the four performance targets of issue 6, each met / not met / not measured."""
    rows = []
    thr = {r['key']: r['steps_per_second'] for r in results.get('throughput', {}).get('rows', [])}
    g, s = thr.get('graph'), thr.get('sb3_a2c')
    if g and s:
        rows.append(('graph >= 2x SB3 A2C env steps/s', f'{g / s:.2f}x', g >= 2 * s))
    else:
        rows.append(('graph >= 2x SB3 A2C env steps/s', 'not measured'
                     + (f' ({NOT_AVAILABLE})' if 'throughput' in results and not g else ''),
                     None))
    lat = [r for r in results.get('latency', {}).get('rows', []) if 'p99_ms' in r]
    for r in lat:
        rows.append((f'lock-step p99 < 2 ms ({r.get("label", r["num_envs"])})',
                     f'{r["p99_ms"]:.2f} ms', r['p99_ms'] < 2.0))
    if not lat:
        rows.append(('lock-step p99 < 2 ms', 'not measured', None))
    learn = results.get('learning')
    summ = learning_summary(learn) if learn else {}
    pg, a2c = summ.get('pg_node_graph', {}), summ.get('sb3_a2c', {})
    if learn and pg.get('evals') and a2c.get('evals'):
        at = learn['steps']
        label = f'at {at:,} steps' + ('' if at >= 1_000_000 else ' (budget below 1M)')
        mp, ma = pg['evals'][at][0], a2c['evals'][at][0]
        if mp is not None and ma is not None:
            rows.append((f'pg_node eval return >= that of SB3 A2C, {label}',
                         f'{mp:.2f} vs {ma:.2f}', mp >= ma))
        tp, ta = pg['time_to'][-6.0], a2c['time_to'][-6.0]
        ep, ea = pg['eval_time_to'][-6.0], a2c['eval_time_to'][-6.0]
        name = 'pg_node time to -6 <= that of SB3 A2C'
        if tp['reached'] or ta['reached']:
            if tp['mean'] is not None and ta['mean'] is not None:
                rows.append((name + ' (training return)',
                             f'{tp["mean"]:.0f} s vs {ta["mean"]:.0f} s',
                             tp['mean'] <= ta['mean']))
            else:
                rows.append((name + ' (training return)',
                             f'reached by pg_node {tp["reached"]}/{tp["of"]}, SB3 A2C '
                             f'{ta["reached"]}/{ta["of"]} seeds', bool(tp['reached'])))
        if ep['reached'] or ea['reached']:
            text = (f'pg_node by {ep["mean"]:.0f} s ({ep["reached"]}/{ep["of"]} seeds)'
                    if ep['reached'] else f'pg_node never (0/{ep["of"]})')
            text += (f', SB3 A2C by {ea["mean"]:.0f} s ({ea["reached"]}/{ea["of"]})'
                     if ea['reached'] else
                     f', SB3 A2C never in {a2c["wall_seconds"][0]:.0f} s '
                     f'(0/{ea["of"]})')
            if not ep['reached'] or not ea['reached']:
                met = bool(ep['reached'])
            else:  # both are upper bounds: pg_node's being the larger decides nothing
                met = True if ep['mean'] <= ea['mean'] else None
            rows.append((name + ' (deterministic eval at the fixed points)', text, met))
        if not (tp['reached'] or ta['reached'] or ep['reached'] or ea['reached']):
            rows.append((name, 'neither reached -6', None))
    else:
        why = pg.get('note', 'not measured') if learn else 'not measured'
        rows.append(('pg_node eval return at 1M >= that of SB3 A2C', why, None))
        rows.append(('pg_node time to -6 <= that of SB3 A2C', why, None))
    return [{'target': t, 'value': v, 'met': m} for t, v, m in rows]


# --- report --------------------------------------------------------------------------------

def _fmt(x, spec=',.0f', none='—'):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return none
    return format(x, spec)


def _table(header: List[str], rows: List[List[str]]) -> str:
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    lines += ['| ' + ' | '.join(str(c) for c in row) + ' |' for row in rows]
    return '\n'.join(lines)


def render_markdown(results: Dict, command: str, plots: Dict[str, str]) -> str:
    """Return BENCHMARKS.md from the results of this invocation."""
    m = results['machine']
    out = ['# pg_node benchmarks', '',
           'Produced by one invocation of', '', '```', command, '```', '',
           (f'(report rendered again, with no new measurement, by `{results["rendered_by"]}`)'
            '\n\n' if results.get('rendered_by') else '')
           + ('' if results.get('complete') else
              '**Incomplete: written while the run was still going; sections or learning '
              'runs missing below had not finished.**\n\n')
           + f'on {results["date"]} (UTC), {results["elapsed_seconds"] / 60:.1f} min. '
           + ('**Quick smoke run: budgets far too small to measure anything.**'
              if results['quick'] else ''), '',
           '## Machine', '',
           _table(['', ''], [[k, v] for k, v in m.items()]
                  + [['load average (1/5/15 min) at start', results['load_start']],
                     ['load average at end', results['load_end']]]), '',
           'The machine is shared with the test runs of other engineers; the load average of '
           'each section is '
           'given below. Ratios between rows of one section were measured minutes apart in the '
           'same invocation.', '']
    out += ['## Targets', '', _table(['target', 'measured', 'met?'], [
        [t['target'], t['value'], {True: 'met', False: '**not met**', None: '—'}[t['met']]]
        for t in targets(results)]), '']
    if 'throughput' in results:
        thr = results['throughput']
        by = {r['key']: r['steps_per_second'] for r in thr['rows']}
        sb3, raw = by.get('sb3_a2c'), by.get('mujoco')
        out += ['## 1. Throughput ladder', '',
                f'Environment steps per second (one arm advanced one control step), '
                f'load average {thr["load"]}. The training rows ran {b_repeats(results)} '
                'times each, one after another; the table gives the median, the note every '
                'run.', '',
                _table(['way', 'env steps/s', 'x SB3 A2C', 'x raw MuJoCo', 'note'], [
                    [r['name'], _fmt(r['steps_per_second']),
                     _fmt(r['steps_per_second'] / sb3 if r['steps_per_second'] and sb3 else None,
                          '.2f'),
                     _fmt(r['steps_per_second'] / raw if r['steps_per_second'] and raw else None,
                          '.3f'),
                     r['note']] for r in thr['rows']]), '']
        if 'throughput' in plots:
            out += [f'![throughput]({plots["throughput"]})', '']
    if 'latency' in results:
        lat = results['latency']
        out += ['## 2. Lock-step latency', '',
                'Round trip inside sim_node: from just before it publishes a transition to the '
                'arrival of the command that answers it (one process, one clock: '
                '`pg_node/tools/latency_probe.py`), with a client that answers at once. First 200 '
                f'steps are warm-up. Load average {lat["load"]}.', '',
                _table(['sim_node', 'round trips', 'median ms', 'p99 ms', 'max ms', 'mean ms',
                        'env steps/s'], [
                    [r.get('label', r['num_envs']), _fmt(r.get('round_trips')),
                     _fmt(r.get('median_ms'), '.3f'),
                     _fmt(r.get('p99_ms'), '.3f'), _fmt(r.get('max_ms'), '.2f'),
                     _fmt(r.get('mean_ms'), '.3f'),
                     _fmt(r.get('steps_per_second')) if 'error' not in r else r['error']]
                    for r in lat['rows']]), '']
        if 'latency' in plots:
            out += [f'![latency]({plots["latency"]})', '']
    if 'tax' in results:
        out += tax.render_tax(results['tax'], _table)
    if 'learning' in results:
        learn = results['learning']
        summ = learning_summary(learn)
        pts = learn['points']
        out += ['## 3. Learning', '',
                f'{learn["steps"]:,} environment steps per run, seeds 0, 1, ... (how many per '
                'learner: last column); '
                f'load average {learn["load"]}. Evaluation: the deterministic policy (mean '
                f'action) over {learn["eval_episodes"]} episodes, mean and std over seeds of '
                'the per-seed mean. The training graph reports only its final evaluation, so '
                'its earlier columns are empty. SB3 runs use 8 environments and the library '
                'defaults for every hyperparameter; pg_node its `config/` defaults (64 arms).'
                + (JOBS_NOTE.format(jobs=learn['jobs'], runs="runs other than the graph's")
                   if learn.get('jobs', 1) > 1 else ''), '']
        rows = []
        for key, row in summ.items():
            if 'evals' not in row:
                rows.append([LEARNER_NAMES[key]] + ['—'] * len(pts) + [row['note']])
                continue
            cells = []
            for p in pts:
                mean, std = row['evals'][p]
                cells.append('—' if mean is None else f'{mean:.2f} ± {std:.2f}')
            rows.append([LEARNER_NAMES[key]] + cells
                        + [f'{row["seeds_ok"]}/{row["seeds"]} seeds' + (
                            f'; {row["note"]}' if 'note' in row else '')])
        out += ['### Evaluation return at fixed step counts', '',
                _table(['learner'] + [f'{p:,} steps' for p in pts] + ['note'], rows), '']
        rows = []
        for key, row in summ.items():
            if 'time_to' not in row:
                continue
            cells = []
            for th in THRESHOLDS:
                t = row['time_to'][th]
                cells.append(f'{_fmt(t["mean"], ".0f")} s ({t["reached"]}/{t["of"]})'
                             if t['reached'] else f'not reached (0/{t["of"]})')
            for th in THRESHOLDS:
                t = row['eval_time_to'][th]
                cells.append(f'<= {_fmt(t["mean"], ".0f")} s ({t["reached"]}/{t["of"]})'
                             if t['reached'] else f'not reached (0/{t["of"]})')
            train = [row['train_return'][p] for p in pts]
            rows.append([LEARNER_NAMES[key]] + cells
                        + ['—' if mean is None else f'{mean:.2f}' for mean, _ in train]
                        + [_fmt(row['steps_per_second'][0]), _fmt(row['wall_seconds'][0], '.1f')])
        out += ['### Wall-clock time to a return, and training returns', '',
                'Time to X: training wall-clock seconds (evaluations excluded) until the mean '
                'return of the last 100 training episodes (stochastic policy) first reaches X, '
                'mean over the seeds that reached it (count in brackets). The same measure for '
                'every learner: pg_node from its curve, SB3 from its episode buffer. '
                '"eval >= X by": the wall-clock time at the first fixed step count whose '
                'deterministic evaluation reached X, an upper bound (the graph: its final '
                'evaluation only).', '',
                _table(['learner', 'time to -10', 'time to -6', 'eval >= -10 by',
                        'eval >= -6 by']
                       + [f'train return @ {p:,}' for p in pts]
                       + ['env steps/s', 'wall s'], rows), '']
        if 'learning' in plots:
            out += [f'![learning]({plots["learning"]})', '']
    if 'variance' in results:
        var = results['variance']
        pol = var['policy']
        out += ['## 4. Estimator variance on the arm', '',
                f'The gradient-estimator lab (`python -m pg_node variance --problem arm`) on '
                f'{var["title"]}: the policy is pg_node A2C trained in-process for '
                f'{pol["train_steps"]:,} steps (seed {pol["seed"]}; deterministic eval return '
                f'{pol["eval_return"]:.2f}), then fixed. {var["batches"]} batches of '
                f'{var["batch_size"]} full 50-step episodes, gamma = 1, GAE lambda = '
                f'{var["gae_lambda"]}; every estimator is computed on the same batches by one '
                'autograd vector-Jacobian product per batch. True gradient: the value-baseline '
                f'estimate over {var["true_episodes"]:,} separate episodes (norm '
                f'{var["true_grad_norm"]:.3g}), its standard error included in bias_z. V: a '
                f'network V(s, t/H) fitted on separate episodes (explained variance '
                f'{var["value_explained_variance"]:.3f}); [approx V]: the mean reward-to-go '
                f'per step index. bias_z is the largest of {var["n_params"]:,} per-parameter '
                f'z-scores (flagged above {var["bias_threshold"]:.1f}, Bonferroni at 0.1%); '
                f'bias_z along grad projects on the true gradient. Load average '
                f'{var["load"]}.', '',
                _table(['estimator', 'bias_z', 'bias_z along grad', 'variance',
                        'variance / REINFORCE'], [
                    [r['estimator'], f'{r["bias_z"]:+.2f}', f'{r["bias_z_along_grad"]:+.2f}',
                     f'{r["variance"]:.4g}', f'{r["relative_variance"]:.4f}']
                    for r in var['rows']]), '']
        if 'variance' in plots:
            out += [f'![variance]({plots["variance"]})', '']
    out += curves.render(results, plots)
    if 'profile' in results:
        out += render_profile(results['profile'])
    if results.get('errors'):
        out += ['## Errors', ''] + [f'- {e}' for e in results['errors']] + ['']
    return '\n'.join(out)


def render_profile(prof: Dict) -> List[str]:
    """Return the lines of the profile section."""
    from bench.runs import PROFILE_GROUPS
    out = ['## Profile of the training graph', '']
    if 'nodes' not in prof:
        return out + [prof.get('note', 'not run'), '']
    groups = [g for g, _ in PROFILE_GROUPS] + ['other Python']
    out += [f'`python -m pg_node train` for {prof["steps"]:,} steps with every node process '
            'under cProfile (a `sitecustomize` hook; the nodes are unchanged), '
            f'{prof["steps_per_second"]:,.0f} env steps/s under the profiler; load average '
            f'{prof.get("load", "?")}. Seconds of each process by the function that spent '
            'them (tottime), then the pg_node functions with the most cumulative time.', '',
            _table(['process', 'profiled s'] + groups, [
                [name, f'{n["total_seconds"]:.1f}'] + [f'{n["groups"][g]:.2f}' for g in groups]
                for name, n in prof['nodes'].items()]), '']
    for name, n in prof['nodes'].items():
        if name.startswith('train'):
            continue
        out += [f'**{name}**: ' + '; '.join(
            f'`{t["function"]}` {t["cumulative_seconds"]:.2f} s / {t["calls"]:,} calls'
            for t in n['top']), '']
    return out


def _log_axis(axis, set_scale, plain: bool = False) -> None:
    """
    Put ``axis`` on a log scale ticked 2k, 5k, 10k, 20k ...: one label per tick, no minor labels.

    matplotlib's default labels a log axis spanning less than two decades at its minor ticks
    too, and at this size '2x10^3 3x10^3 4x10^3' run together under the throughput ladder.
    ``plain``: 0.2, 0.5, 1, 2 ... (milliseconds) instead of 2k, 5k.
    """
    from matplotlib.ticker import EngFormatter, FuncFormatter, LogLocator, NullFormatter
    set_scale('log')
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}') if plain
                             else EngFormatter(sep=''))
    axis.set_minor_formatter(NullFormatter())


def make_plots(results: Dict, plot_dir: Path) -> Dict[str, str]:
    """Write the PNGs; return section -> path relative to the report."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    plot_dir.mkdir(parents=True, exist_ok=True)
    out = {}
    rel = plot_dir.name
    if 'throughput' in results:
        rows = [r for r in results['throughput']['rows'] if r['steps_per_second']]
        if rows:
            fig, ax = plt.subplots(figsize=(8, 0.45 * len(rows) + 1.2))
            ax.barh([r['name'] for r in rows], [r['steps_per_second'] for r in rows],
                    color=['tab:orange' if r['key'] in ('graph', 'inprocess')
                           else 'tab:gray' if r['key'] == 'sb3_a2c' else 'tab:blue'
                           for r in rows])
            _log_axis(ax.xaxis, ax.set_xscale)
            ax.invert_yaxis()
            ax.set_xlabel('env steps / s (log scale)')
            ax.set_title('Throughput ladder')
            fig.tight_layout()
            fig.savefig(plot_dir / 'throughput.png', dpi=100)
            plt.close(fig)
            out['throughput'] = f'{rel}/throughput.png'
    if results.get('latency', {}).get('samples_ms'):
        fig, ax = plt.subplots(figsize=(7, 3.5))
        for n, ms in results['latency']['samples_ms'].items():
            ms = np.asarray(ms)
            ax.hist(ms, bins=np.logspace(np.log10(max(ms.min(), 1e-3)),
                                         np.log10(ms.max() + 1e-3), 60),
                    histtype='step', label=n)
        ax.axvline(2.0, color='k', ls='--', lw=0.8, label='2 ms target (p99)')
        _log_axis(ax.xaxis, ax.set_xscale, plain=True)
        ax.set_yscale('log')
        ax.set_xlabel('round trip (ms)')
        ax.set_ylabel('steps')
        ax.legend()
        ax.set_title('sim_node lock-step round trip')
        fig.tight_layout()
        fig.savefig(plot_dir / 'latency.png', dpi=100)
        plt.close(fig)
        out['latency'] = f'{rel}/latency.png'
    if 'learning' in results:
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        colors = dict(zip(LEARNERS, plt.rcParams['axes.prop_cycle'].by_key()['color']))
        for key, runs in results['learning']['runs'].items():
            if isinstance(runs, str):
                continue
            for i, r in enumerate(x for x in runs if 'curve' in x):
                curve = r['curve']
                if not curve:
                    continue
                ret = [p['episode_return'] for p in curve]
                label = LEARNER_NAMES[key] if i == 0 else None
                axes[0].plot([p['env_steps'] for p in curve], ret, color=colors[key], lw=0.8,
                             label=label)
                axes[1].plot([p['wall_seconds'] for p in curve], ret, color=colors[key],
                             lw=0.8)
        for ax in axes:
            for th in THRESHOLDS:
                ax.axhline(th, color='k', ls=':', lw=0.7)
        axes[0].set_xlabel('env steps')
        axes[1].set_xlabel('wall-clock s (evaluations excluded)')
        axes[0].set_ylabel('training return (last 100 episodes)')
        axes[0].legend(fontsize=7)
        fig.suptitle('Learning on the default arm (one line per seed)')
        fig.tight_layout()
        fig.savefig(plot_dir / 'learning.png', dpi=100)
        plt.close(fig)
        out['learning'] = f'{rel}/learning.png'
    if 'variance' in results:
        rows = results['variance']['rows']
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.barh([r['estimator'] for r in rows], [r['relative_variance'] for r in rows])
        ax.set_xscale('log')
        ax.invert_yaxis()
        ax.set_xlabel('variance / REINFORCE (log scale)')
        ax.set_title('Gradient-estimator variance on the arm')
        fig.tight_layout()
        fig.savefig(plot_dir / 'variance.png', dpi=100)
        plt.close(fig)
        out['variance'] = f'{rel}/variance.png'
    out.update(curves.make_plot(results, plot_dir))
    return out


# --- command line --------------------------------------------------------------------------

def parse_args(argv):
    """Parse the command line; return ``(args, budgets)``."""
    parser = argparse.ArgumentParser(
        prog='python -m bench',
        description='Throughput, latency, learning and estimator-variance benchmarks; '
                    'writes BENCHMARKS.md and plots.')
    parser.add_argument('--out', default=str(RESULTS), help='directory of BENCHMARKS.md, '
                        'bench_plots/ and bench_results.json (default: %(default)s)')
    parser.add_argument('--only', default=','.join(DEFAULT_SECTIONS),
                        help=f'comma-separated sections of {", ".join(SECTIONS)} '
                             f'(default: {",".join(DEFAULT_SECTIONS)})')
    parser.add_argument('--from-json', metavar='FILE',
                        help='measure nothing: render the report and plots again from the '
                             'results file of an earlier invocation (its numbers, its command)')
    parser.add_argument('--report', default='BENCHMARKS.md',
                        help='file name of the report in --out (default: %(default)s)')
    parser.add_argument('--quick', action='store_true',
                        help='smoke-sized budgets (seconds); numbers mean nothing')
    parser.add_argument('--learning-steps', type=int, help='env steps per learning run '
                        '(default: 1,000,000; quick: 4,096)')
    parser.add_argument('--seeds', type=int, help='seeds per learner (default: 3; quick: 1)')
    parser.add_argument('--learners', default=','.join(LEARNERS),
                        help=f'comma-separated learners of {", ".join(LEARNERS)}; '
                             'learner:N runs that one with N seeds instead of --seeds')
    parser.add_argument('--seconds', type=float,
                        help='seconds per in-process / sim_node throughput row (default: 3)')
    parser.add_argument('--latency-steps', type=int,
                        help='lock-step round trips measured (default: 10,000)')
    parser.add_argument('--graph-steps', type=int,
                        help='env steps of the graph throughput run (default: 200,000)')
    parser.add_argument('--variance-batches', type=int, help='lab batches (default: 200)')
    parser.add_argument('--jobs', type=int, default=1,
                        help='learning runs of the curves and learning sections that train at '
                             "once, each in its own process (default: 1). The graph's runs "
                             "still run alone; pg_node's evaluations are the same, wall-clock "
                             'columns then count a neighbour (the report says so)')
    args = parser.parse_args(argv)
    only = [s.strip() for s in args.only.split(',') if s.strip()]
    bad = [s for s in only if s not in SECTIONS]
    if bad or not only:
        parser.error(f'--only takes {", ".join(SECTIONS)}; got {args.only!r}')
    args.only = only
    if args.jobs < 1:
        parser.error(f'--jobs must be at least 1; got {args.jobs}')
    args.learners = [s.strip() for s in args.learners.split(',') if s.strip()]
    bad = [s for s in args.learners if s.partition(':')[0] not in LEARNERS
           or not (s.partition(':')[2] or '1').isdigit()]
    if bad or not args.learners:
        parser.error(f'--learners takes {", ".join(LEARNERS)}; got {", ".join(bad)}')
    b = {k: v[1 if args.quick else 0] for k, v in BUDGETS.items()}
    for opt, key in (('learning_steps', 'learning_steps'), ('seeds', 'seeds'),
                     ('seconds', 'seconds'), ('latency_steps', 'latency_steps'),
                     ('graph_steps', 'graph_steps'), ('variance_batches', 'var_batches')):
        value = getattr(args, opt)
        if value is not None:
            if value <= 0 or (key == 'var_batches' and value < 2):
                parser.error(f'--{opt.replace("_", "-")} must be positive (batches >= 2)')
            b[key] = value
    return args, b


def main(argv=None) -> int:
    """Run ``python -m bench``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args, budgets = parse_args(argv)
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    command = ' '.join(['python -m bench'] + argv)
    start = time.perf_counter()
    if args.from_json:
        results = json.loads(Path(args.from_json).read_text())
        results['rendered_by'] = command
        plots = make_plots(results, out_dir / 'bench_plots')
        report.write(out_dir / args.report, render_markdown(results, results['command'], plots),
                     results['date'], archived=False)
        print(f'wrote {out_dir / args.report} from {args.from_json}', file=sys.stderr)
        return 0

    def log(text):
        print(f'[bench {time.perf_counter() - start:7.1f} s] {text}', file=sys.stderr,
              flush=True)

    results = {'command': command, 'quick': args.quick, 'budgets': budgets,
               'date': datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M'),
               'machine': machine_facts(), 'load_start': load_average(), 'errors': []}
    json_path = out_dir / ('bench_results.json' if args.report == 'BENCHMARKS.md'
                           else f'{Path(args.report).stem.lower()}_results.json')

    def save():
        json_path.write_text(json.dumps(results, indent=1, default=str))

    archived = [False]      # the block this run replaces goes to the log once

    def write_report():
        results['load_end'] = load_average()
        results['elapsed_seconds'] = time.perf_counter() - start
        save()      # first: the numbers outlive a bug in the plots or the report
        plots = make_plots(results, out_dir / 'bench_plots')
        archived[0] = report.write(out_dir / args.report,
                                   render_markdown(results, command, plots), results['date'],
                                   archived[0])
        return plots

    def learning_progress(partial):
        # an interrupted run still leaves a report of the runs that finished
        results['learning'] = partial
        write_report()

    runners = {
        'throughput': lambda: run_throughput(budgets, log),
        'latency': lambda: run_latency(budgets, log),
        'tax': lambda: tax.run_tax(budgets, log),
        'learning': lambda: run_learning(budgets, args.learners, log, learning_progress,
                                         args.jobs),
        'variance': lambda: run_variance(budgets, log),
        'curves': lambda: curves.run_curves(
            budgets, log, lambda partial: (results.update(curves=partial), write_report()),
            jobs=args.jobs),
        'profile': lambda: run_profile(budgets, log),
    }
    try:
        with terminate_as_interrupt():  # kill/timeout stop the children as Ctrl-C does
            for section in SECTIONS:
                if section not in args.only:
                    continue
                try:
                    res = runners[section]()
                    res['load'] = load_average()
                    results[section] = res
                except Exception as exc:  # noqa: B902 - the report says which section failed
                    log(traceback.format_exc())
                    results['errors'].append(f'{section}: {exc}'.splitlines()[0])
                write_report()
    except KeyboardInterrupt as exc:
        # the runs that finished are in the results already (each section saves as it
        # goes): keep them, say where, and exit as an interrupted program does
        results['interrupted'] = str(exc) or 'SIGINT'
        write_report()
        print(f'bench: interrupted ({results["interrupted"]}); the runs that finished are in '
              f'{out_dir / args.report} and {json_path}', file=sys.stderr)
        return 130
    results['complete'] = True
    plots = write_report()
    log(f'wrote {out_dir / args.report}, {json_path} and {len(plots)} plot(s) in '
        f'{out_dir / "bench_plots"}')
    return 1 if results['errors'] else 0
