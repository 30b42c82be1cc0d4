"""
The ``curves`` section of ``python -m bench``: every estimator's learning curve.

Each choice of phi of the critic (``estimator``: total return, reward-to-go, constant,
optimal and time baselines, value baseline, TD residual, GAE) is trained in-process
(:func:`pg_node.rl.train_inprocess.train_inprocess`, the graph's computation) with otherwise
the default settings (A2C, ``config/a2c.yaml``), over the same seeds; the deterministic policy is
evaluated at every tenth of the budget (full: 100k, 200k, ..., 1M environment steps, 100
episodes, 3 seeds), so that the curves show where one row overtakes another; the table
shows 30%, 50% and all of it, and the times to each return come from every point.
The algorithm rows go in the same table: A2C (the ``gae`` runs above: the defaults),
plain REINFORCE (total return, no advantage normalisation), PPO (the ``config/ppo.yaml``
preset), the design's A2C (the defaults before issue 48: gamma 0.9, V fitted once per
batch), NPG and TRPO (the
``config/npg.yaml`` and ``config/trpo.yaml`` presets);
SB3 A2C and PPO come from the ``learning`` section of the same invocation (not run twice),
and Tianshou's published numbers are quoted with their source (:data:`TIANSHOU`).

The report's text says only what the numbers compute: each estimator's rank by variance
(the ``variance`` section, same invocation) and by final evaluation, and Spearman's rank
correlation between the two.
"""
import time
from typing import Callable, Dict, List, Optional, Sequence

from bench.pool import JOBS_NOTE, run_all
import numpy as np

ESTIMATORS = ('total_return', 'reward_to_go', 'constant_baseline', 'optimal_baseline',
              'time_baseline', 'value_baseline', 'td_residual', 'gae')
#: algorithm rows: key -> (name, preset or None for the defaults, overrides)
ALGORITHMS = {
    'reinforce': ('plain REINFORCE (total return, no baseline, advantages not normalised)',
                  None, ('estimator=total_return', 'normalize_advantage=false')),
    'a2c_design': ("the design's A2C (gamma 0.9, vf_epochs 1: the defaults before issue 48)",
                   None, ('gamma=0.9', 'vf_epochs=1')),
    'ppo': ('PPO (config/ppo.yaml)', 'ppo', ()),
    'npg': ('NPG (config/npg.yaml)', 'npg', ()),
    'trpo': ('TRPO (config/trpo.yaml)', 'trpo', ()),
}
#: rows that are the runs of another row (same configuration): key -> (name, that row's key)
SAME_RUNS = {'a2c': ('A2C (the defaults, config/a2c.yaml)', 'gae')}
#: SB3 rows of the ``learning`` section shown in this table
SB3_ROWS = {'sb3_a2c': 'SB3 A2C (defaults, 8 envs; learning section)',
            'sb3_ppo': 'SB3 PPO (defaults, 8 envs; learning section)'}
TIANSHOU_SOURCE = ('https://github.com/thu-ml/tianshou/blob/master/examples/mujoco/README.md '
                   '(Tianshou MuJoCo benchmark, Reacher-v2, 1M steps, 10 seeds: max average '
                   'return during training, each seed averaged over 10 test episodes, '
                   '+/- one std over seeds)')
#: Tianshou's published Reacher returns at 1M steps: name -> (mean, std)
TIANSHOU = {'PPO': (-4.1, 0.3), 'NPG': (-4.5, 0.5), 'TRPO': (-5.1, 0.8), 'A2C': (-6.7, 2.3)}
#: Gymnasium's return at which Reacher counts as solved
SOLVED = -3.75
#: evaluation returns whose wall-clock time the table gives (issue 15: -5 and -4.5; 32: -4)
TIME_THRESHOLDS = (-5.0, -4.5, -4.0)

#: budgets: full run, and --quick
BUDGETS = {'curve_steps': (1_000_000, 1_024), 'curve_seeds': (3, 1),
           'curve_eval_episodes': (100, 4)}


def points_of(steps: int) -> List[int]:
    """
    Return the evaluation points of a budget: every tenth of it.

    >>> points_of(1_000_000)[:3], points_of(1_000_000)[-1]
    ([100000, 200000, 300000], 1000000)
    """
    return sorted({steps * k // 10 for k in range(1, 11)})


def table_points(points: Sequence[int]) -> List[int]:
    """
    Return the points the table shows: 30%, 50% and all of a budget of ten points.

    >>> table_points(points_of(1_000_000)), table_points([1024, 2048, 4096])
    ([300000, 500000, 1000000], [1024, 2048, 4096])
    """
    points = sorted(points)
    return [points[2], points[4], points[9]] if len(points) == 10 else list(points)


def configurations() -> Dict[str, Dict]:
    """Return every trained row: key -> name, preset, overrides."""
    rows = {e: {'name': f'phi = {e}', 'preset': None, 'overrides': (f'estimator={e}',),
                'kind': 'estimator'} for e in ESTIMATORS}
    for key, (name, preset, overrides) in ALGORITHMS.items():
        rows[key] = {'name': name, 'preset': preset, 'overrides': overrides,
                     'kind': 'algorithm'}
    return rows


def curve_run(preset: Optional[str], overrides: Sequence[str], steps: int, seed: int,
              points: Sequence[int], eval_episodes: int) -> Dict:
    """
    Train one configuration in-process; deterministic evaluations at ``points``.

    Returns the evaluations, the training seconds (evaluations excluded) and steps/s.
    """
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import config_file
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(config_file(preset) if preset else None,
                      [*overrides, f'seed={seed}'])
    todo = sorted({int(p) for p in points})
    rec = {'evals': {}, 'eval_time': 0.0, 'at': {}}

    def callback(stats):
        while todo and stats['env_steps'] >= todo[0]:
            t = time.perf_counter()
            res = evaluate_policy(stats['learner'].policy, cfg['/**']['model'], eval_episodes,
                                  seed)
            rec['eval_time'] += time.perf_counter() - t
            point = todo.pop(0)
            rec['evals'][point] = res['eval_return']
            rec['at'][point] = stats['wall_seconds'] - rec['eval_time']

    summary = train_inprocess(cfg, steps, callback, eval_episodes=eval_episodes)
    for p in todo:   # the budget ended before a point (whole batches)
        rec['evals'][p] = summary['eval_return']
    wall = summary['wall_seconds'] - rec['eval_time']
    return {'evals': rec['evals'], 'wall_at': rec['at'], 'wall_seconds': wall,
            'total_steps': int(summary['total_steps']),
            'steps_per_second': summary['total_steps'] / wall}


def run_curves(b: Dict, log: Callable[[str], None],
               progress: Optional[Callable[[Dict], None]] = None,
               progress_every: float = 30.0, jobs: int = 1) -> Dict:
    """
    Train every row over the seeds; ``progress(partial)`` after a run, ``progress_every`` s apart.

    ``b`` holds :data:`BUDGETS`' keys (one value each). A failed run is kept as its error.
    ``jobs`` > 1 trains that many runs at a time, each in a process of its own
    (:mod:`bench.pool`); the evaluations are the same, the clocks then count a
    neighbour. Interrupted, it hands the runs that finished to ``progress`` and re-raises.
    """
    steps, seeds = b['curve_steps'], list(range(b['curve_seeds']))
    points = points_of(steps)
    out = {'steps': steps, 'seeds': seeds, 'points': points, 'jobs': int(jobs),
           'eval_episodes': b['curve_eval_episodes'],
           'runs': {key: [] for key in configurations()}}
    specs = [(key, spec, seed) for key, spec in configurations().items() for seed in seeds]
    tasks = [(curve_run, (spec['preset'], spec['overrides'], steps, seed, points,
                          b['curve_eval_episodes'])) for _, spec, seed in specs]
    last = [time.monotonic()]

    def so_far():
        # the rows that have a finished run, in the table's order
        return dict(out, runs={k: v for k, v in out['runs'].items() if v})

    if jobs > 1:
        log(f'curves: {len(tasks)} runs of {steps:,} steps, {jobs} at a time')

    def before(i):
        log(f'curves: {specs[i][1]["name"]}, seed {specs[i][2]}, {steps:,} steps')

    def done(i, res):
        key, spec, seed = specs[i]
        res['seed'] = seed
        runs = out['runs'][key]
        runs.append(res)
        runs.sort(key=lambda r: r['seed'])
        if jobs > 1:
            finished = sum(len(r) for r in out['runs'].values())
            what = res.get('error') or f'{res["evals"][points[-1]]:.2f} at {points[-1]:,}'
            log(f'curves: {spec["name"]}, seed {seed}: {what} ({finished}/{len(tasks)})')
        if progress is not None and time.monotonic() - last[0] >= progress_every:
            progress(dict(so_far(), partial=True))   # a report of the runs so far
            last[0] = time.monotonic()

    try:
        run_all(tasks, jobs, done, before)
    except KeyboardInterrupt:
        if progress is not None:
            progress(dict(so_far(), partial=True))
        raise
    return so_far()


# --- summary -------------------------------------------------------------------------------

def _evals_of(run: Dict, point: int):
    evals = run.get('evals', {})
    return evals.get(point, evals.get(str(point)))


def eval_time_at(run: Dict, points: Sequence[int], threshold: float) -> Optional[float]:
    """
    Return the training seconds at the first point whose deterministic evaluation >= threshold.

    An upper bound on the time to the threshold (the policy may have got there between
    points); None if no evaluated point reached it. A curve run keeps the time of each point
    (``wall_at``); a learning run its training curve, whose first entry at or past the point
    is taken (its whole time if the point is its end).
    """
    for p in points:
        ret = _evals_of(run, p)
        if ret is None or ret < threshold:
            continue
        at = run.get('wall_at', {})
        if at.get(p, at.get(str(p))) is not None:
            return float(at.get(p, at.get(str(p))))
        if p >= run['total_steps'] or not run.get('curve'):
            return float(run['wall_seconds'])
        later = [c['wall_seconds'] for c in run['curve'] if c['env_steps'] >= p]
        return float(later[0]) if later else float(run['wall_seconds'])
    return None


def reached(times: Sequence[Optional[float]]) -> Dict:
    """Return the mean time of the seeds that reached a return (None marks one that did not)."""
    got = [t for t in times if t is not None]
    return {'mean': float(np.mean(got)) if got else None, 'reached': len(got),
            'of': len(times)}


def _mean_std(values):
    vals = [float(v) for v in values if v is not None and np.isfinite(v)]
    if not vals:
        return None
    return float(np.mean(vals)), float(np.std(vals)), len(vals)


def summarize(curves: Dict, learning: Optional[Dict] = None,
              variance: Optional[Dict] = None) -> List[Dict]:
    """
    Return the table's rows: mean/std over seeds at each point, wall seconds, steps/s.

    Estimator rows also carry their variance relative to REINFORCE (the lab's row of the same
    name, its exact V) when the ``variance`` section ran. SB3 rows are read from ``learning``
    at the same points when it evaluated there.
    """
    points = curves['points']
    configs = configurations()
    var = {}
    if variance and variance.get('rows'):
        var = {r['estimator']: r['relative_variance'] for r in variance['rows']}
    rows = []

    def add(key, name, kind, runs, note='', at=points):
        ok = [r for r in runs if 'error' not in r]
        errors = [r['error'] for r in runs if 'error' in r]
        if errors:
            note = (note + '; ' if note else '') + f'{len(errors)} seed(s) failed: {errors[0]}'
        rows.append({'key': key, 'name': name, 'kind': kind, 'seeds': len(ok),
                     'evals': {p: _mean_std([_evals_of(r, p) for r in ok]) for p in points},
                     'wall_seconds': _mean_std([r.get('wall_seconds') for r in ok]),
                     'steps_per_second': _mean_std([r.get('steps_per_second') for r in ok]),
                     'relative_variance': var.get(key) if kind == 'estimator' else None,
                     'time_to': {th: reached([eval_time_at(r, at, th) for r in ok])
                                 for th in TIME_THRESHOLDS},
                     'note': note})

    for key, runs in curves['runs'].items():
        spec = configs.get(key, {'name': key, 'kind': 'algorithm'})
        add(key, spec['name'], spec['kind'], runs)
        for same, (name, of) in SAME_RUNS.items():
            if of == key:
                add(same, name, 'algorithm', runs, f'the runs of phi = {of}')
    learned = (learning or {}).get('runs', {})
    for key, name in SB3_ROWS.items():
        runs = learned.get(key)
        if not isinstance(runs, list):
            continue
        at = [p for p in points if p in learning.get('points', [])]
        note = ('' if len(at) == len(points) else
                f'learning section ran {learning.get("steps", 0):,} steps: evaluated at '
                f'{", ".join(f"{p:,}" for p in learning.get("points", []))} only')
        note = '; '.join(x for x in (note, f'{learning.get("eval_episodes", "?")} episodes, '
                                           'SB3 evaluate_policy') if x)
        add(key, name, 'sb3', runs, note, learning.get('points', []))
    return rows


def ranks(rows: List[Dict], final: int) -> Dict[str, Dict]:
    """
    Rank the estimator rows by variance (1: lowest) and by final evaluation (1: highest).

    Only estimators with both numbers are ranked; returns ``{key: {'variance': r, 'eval': r}}``
    and, under ``'spearman'``, the rank correlation of the two orders (None below 3 rows).
    """
    est = [r for r in rows if r['kind'] == 'estimator' and r['relative_variance'] is not None
           and r['evals'].get(final) is not None]
    by_var = sorted(est, key=lambda r: r['relative_variance'])
    by_eval = sorted(est, key=lambda r: -r['evals'][final][0])
    out = {r['key']: {'variance': by_var.index(r) + 1, 'eval': by_eval.index(r) + 1}
           for r in est}
    n = len(est)
    rho = None
    if n >= 3:
        d2 = sum((v['variance'] - v['eval']) ** 2 for v in out.values())
        rho = 1 - 6 * d2 / (n * (n * n - 1))
    return {'rows': out, 'spearman': rho, 'n': n}


# --- report --------------------------------------------------------------------------------

def _fmt(ms) -> str:
    if ms is None:
        return '—'
    mean, std, n = ms
    return f'{mean:.2f} ± {std:.2f}' if n > 1 else f'{mean:.2f}'


def _fmt_time(t: Dict) -> str:
    if not t['reached']:
        return f'not reached (0/{t["of"]})'
    return f'<= {t["mean"]:.0f} s ({t["reached"]}/{t["of"]})'


def render(results: Dict, plots: Dict[str, str]) -> List[str]:
    """Return the lines of the section (nothing when it did not run)."""
    curves = results.get('curves')
    if not curves:
        return []
    points, final = table_points(curves['points']), curves['points'][-1]
    rows = summarize(curves, results.get('learning'), results.get('variance'))
    rk = ranks(rows, final)
    out = ["## 5. Every estimator's learning curve", '',
           f"Each phi of the critic trained in-process (`train_inprocess`, the graph's "
           f'computation) for {curves["steps"]:,} environment steps with otherwise the default '
           f'settings (the design\'s A2C), seeds {", ".join(map(str, curves["seeds"]))}; '
           f'deterministic evaluation over {curves["eval_episodes"]} episodes at each of '
           f'{len(curves["points"])} points (the plot has them all), '
           'mean ± std over seeds. Wall seconds: training only, evaluations excluded; '
           'time to a return: the training seconds at the first point whose evaluation '
           'reached it (an upper bound), mean over the seeds that did (k/n). '
           "Variance / REINFORCE: the estimator lab's row of the same name (section 4, exact "
           'V, gamma = 1); ranks: 1 = lowest variance, 1 = best final evaluation. '
           f'Load average {curves.get("load", "?")}.'
           + (JOBS_NOTE.format(jobs=curves['jobs'], runs='runs')
              if curves.get('jobs', 1) > 1 else ''), '']
    header = (['row'] + [f'eval @ {p:,}' for p in points]
              + [f'time to {th:g}' for th in TIME_THRESHOLDS]
              + ['wall s', 'env steps/s', 'variance / REINFORCE', 'variance rank',
                 'eval rank', 'note'])
    table = []
    for r in rows:
        rank = rk['rows'].get(r['key'], {})
        table.append([r['name']] + [_fmt(r['evals'][p]) for p in points]
                     + [_fmt_time(r['time_to'][th]) for th in TIME_THRESHOLDS]
                     + [f'{r["wall_seconds"][0]:.1f}' if r['wall_seconds'] else '—',
                        f'{r["steps_per_second"][0]:,.0f}' if r['steps_per_second'] else '—',
                        (f'{r["relative_variance"]:.4f}' if r['relative_variance'] is not None
                         else ''),
                        str(rank.get('variance', '')), str(rank.get('eval', '')), r['note']])
    for name, (mean, std) in TIANSHOU.items():
        table.append([f'Tianshou {name} (published)'] + ['—'] * (len(points) - 1)
                     + [f'{mean:.1f} ± {std:.1f}'] + ['—'] * (len(TIME_THRESHOLDS) + 2)
                     + ['', '', '',
                        'at 1M, 10 seeds, max over training; see source below'])
    out += ['| ' + ' | '.join(header) + ' |', '|' + '|'.join('---' for _ in header) + '|']
    out += ['| ' + ' | '.join(row) + ' |' for row in table]
    out += ['', f'Tianshou: {TIANSHOU_SOURCE}. Their metric is the best evaluation during '
                "training, ours the evaluation at the point; their Reacher is Gym's "
                'Reacher-v2.', '']
    if rk['spearman'] is not None:
        out += [f'Spearman rank correlation between variance (lower first) and final '
                f'evaluation at {final:,} steps (best first) over {rk["n"]} estimators: '
                f'{rk["spearman"]:+.2f} (+1: the variance order is the learning order).', '']
    solved = [r['name'] for r in rows if r['evals'][final] is not None
              and r['evals'][final][0] >= SOLVED]
    out += [f'Rows whose mean final evaluation reaches {SOLVED} (Gymnasium\'s "solved"): '
            + (', '.join(solved) if solved else 'none') + '.', '']
    if 'curves' in plots:
        out += [f'![curves]({plots["curves"]})', '']
    return out


def make_plot(results: Dict, plot_dir) -> Dict[str, str]:
    """
    Write ``curves.png``: algorithms in one panel, estimators in the other.

    Each line is the mean over seeds at every evaluation point, its band one std either
    side; Tianshou's published results stand beside the algorithms' panel.
    """
    curves = results.get('curves')
    if not curves:
        return {}
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    rows = summarize(curves, results.get('learning'), results.get('variance'))
    points = curves['points']
    fig, (alg, est) = plt.subplots(1, 2, figsize=(15, 7), sharey=True)
    colors = plt.get_cmap('tab10').colors
    panels = {alg: [r for r in rows if r['kind'] != 'estimator'],
              est: [r for r in rows if r['kind'] == 'estimator']}
    for ax, drawn in panels.items():
        for i, r in enumerate(r for r in drawn if any(r['evals'][p] for p in points)):
            xs = [p for p in points if r['evals'][p] is not None]
            mean = np.array([r['evals'][p][0] for p in xs])
            std = np.array([r['evals'][p][1] for p in xs])
            color = colors[i % len(colors)]
            ax.plot(xs, mean, ':' if r['kind'] == 'sb3' else '-', marker='o', ms=2.5, lw=1.4,
                    color=color, label=r['key'] if r['kind'] == 'estimator' else r['name'])
            ax.fill_between(xs, mean - std, mean + std, color=color, alpha=0.15, lw=0)
        ax.axhline(SOLVED, color='k', ls=':', lw=0.7)
        ax.set_xlabel('environment steps')
        ax.grid(alpha=0.3)
    for i, (name, (mean, std)) in enumerate(TIANSHOU.items()):
        x = points[-1] * (1.02 + 0.025 * i)
        alg.errorbar([x], [mean], yerr=[std], fmt='x', color='k', ms=5, lw=0.7,
                     label='Tianshou (published, 1M; max over training)' if i == 0 else None)
        alg.annotate(name, (x, mean), xytext=(3, 0), textcoords='offset points', fontsize=6,
                     va='center')
    alg.set_ylabel(f'deterministic evaluation return ({curves["eval_episodes"]} episodes)')
    alg.set_title('Algorithms (mean over seeds, band: ± std)')
    est.set_title('Estimators phi, the default A2C otherwise (mean over seeds, band: ± std)')
    for ax in (alg, est):          # below each panel: the curves keep the whole plot
        ax.legend(fontsize=7, loc='upper center', bbox_to_anchor=(0.5, -0.1), ncol=2)
    fig.tight_layout()
    fig.savefig(plot_dir / 'curves.png', dpi=100)
    plt.close(fig)
    return {'curves': f'{plot_dir.name}/curves.png'}
