"""
``python -m bench`` end to end on a tiny budget, and its report logic on fixed numbers.

Benchmarks are scripts: nothing here asserts a speed, only that every section runs, writes
its table with the expected rows, and that the numbers in it are finite.
"""
import json
import math
import os
from pathlib import Path
import re
import subprocess
import sys

from bench import suite
from bench.runs import graph_available
import pytest

REPO = Path(__file__).resolve().parent.parent


def fake_results():
    curve = [{'env_steps': s, 'wall_seconds': s / 1000, 'episode_return': -40 + s / 100}
             for s in range(512, 4097, 512)]
    run = {'evals': {1024: -11.0, 2048: -9.0, 4096: -5.5}, 'curve': curve,
           'wall_seconds': 4.1, 'total_steps': 4096, 'steps_per_second': 1000.0}
    return {
        'date': '2026-01-01 00:00', 'quick': True, 'elapsed_seconds': 60.0,
        'machine': suite.machine_facts(), 'load_start': '1', 'load_end': '1', 'errors': [],
        'throughput': {'load': '1', 'rows': [
            {'key': 'mujoco', 'name': 'raw', 'steps_per_second': 40000.0, 'note': ''},
            {'key': 'graph', 'name': 'graph', 'steps_per_second': 9000.0, 'note': ''},
            {'key': 'sb3_a2c', 'name': 'sb3', 'steps_per_second': 4000.0, 'note': ''}]},
        'latency': {'load': '1', 'samples_ms': {}, 'rows': [
            {'num_envs': 64, 'label': '64 arms', 'round_trips': 10, 'median_ms': 0.5,
             'p99_ms': 3.0,
             'max_ms': 4.0, 'mean_ms': 0.6, 'steps_per_second': 100.0}]},
        'learning': {'load': '1', 'steps': 4096, 'seeds': [0], 'points': [1024, 2048, 4096],
                     'eval_episodes': 10,
                     'runs': {'pg_node_graph': [dict(run, seed=0)],
                              'sb3_a2c': [dict(run, seed=0, evals={4096: -6.0})]}},
    }


def test_targets_from_fixed_numbers():
    rows = {t['target']: t for t in suite.targets(fake_results())}
    assert rows['graph >= 2x SB3 A2C env steps/s']['met'] is True
    assert rows['lock-step p99 < 2 ms (64 arms)']['met'] is False
    ret = [t for name, t in rows.items() if name.startswith('pg_node eval return')]
    assert ret[0]['met'] is True and '-5.50 vs -6.00' in ret[0]['value']
    # both curves are the same: time to -6 ties, which meets "no longer than"
    assert rows['pg_node time to -6 <= that of SB3 A2C (training return)']['met'] is True
    by_eval = rows['pg_node time to -6 <= that of SB3 A2C (deterministic eval at the fixed '
                   'points)']
    assert by_eval['met'] is True and 'pg_node by 4 s' in by_eval['value']


def test_time_to_threshold_and_value_at():
    from bench.runs import first_time_at, value_at
    curve = fake_results()['learning']['runs']['pg_node_graph'][0]['curve']
    assert first_time_at(curve, -10.0) == pytest.approx(3.072)
    assert first_time_at(curve, 100.0) is None
    assert value_at(curve, 2100) == pytest.approx(-40 + 2048 / 100)


def test_markdown_marks_missing_graph():
    res = fake_results()
    res['learning']['runs']['pg_node_graph'] = suite.NOT_AVAILABLE
    text = suite.render_markdown(res, 'python -m bench --quick', {})
    assert suite.NOT_AVAILABLE in text
    assert '| SB3 A2C |' in text


def test_partial_report_while_a_learner_has_no_finished_run():
    # the graph's runs went first and reached -6; SB3 A2C's runs had not finished (a
    # partial report written between runs: an invocation died on this, 7e0c30c)
    res = fake_results()
    res['learning']['runs']['sb3_a2c'] = []
    text = suite.render_markdown(res, 'python -m bench', {})
    assert '| pg_node A2C, ROS graph |' in text and '| SB3 A2C |' not in text


def test_results_are_saved_before_the_report_is_rendered(tmp_path, monkeypatch):
    def broken(*args):
        raise RuntimeError('a bug in the report')

    monkeypatch.setattr(suite, 'render_markdown', broken)
    with pytest.raises(RuntimeError, match='a bug in the report'):
        suite.main(['--quick', '--only', 'variance', '--variance-batches', '2',
                    '--out', str(tmp_path)])
    saved = json.loads((tmp_path / 'bench_results.json').read_text())
    assert len(saved['variance']['rows']) == 11


def fake_curves(order):
    """Curves results in which the estimators' final evaluations follow ``order`` (best first)."""
    from bench import curves as bc
    points = bc.points_of(4096)
    runs = {}
    for key in bc.configurations():
        best = order.index(key) if key in order else len(order)
        runs[key] = [{'seed': s, 'evals': {p: -5.0 - best - s * 0.5 + p / 4096 for p in points},
                      'wall_seconds': 10.0 + s, 'steps_per_second': 400.0,
                      'total_steps': 4096} for s in (0, 1)]
    runs['npg'][1] = {'seed': 1, 'error': 'boom\nmore'}
    return {'steps': 4096, 'seeds': [0, 1], 'points': points, 'eval_episodes': 10,
            'runs': runs, 'load': '1'}


def test_curves_table_ranks_and_quotes_from_fixed_numbers():
    from bench import curves as bc
    by_variance = list(bc.ESTIMATORS)   # variance rows in this order, lowest first
    variance = {'rows': [{'estimator': e, 'relative_variance': 10.0 ** -i}
                         for i, e in enumerate(reversed(by_variance))]}
    res = fake_results()
    res['variance'] = variance
    for order, rho in ((by_variance, 1.0), (by_variance[::-1], -1.0)):
        res['curves'] = fake_curves(order)
        rows = {r['key']: r for r in bc.summarize(res['curves'], res['learning'], variance)}
        final = res['curves']['points'][-1]
        assert rows['gae']['evals'][final][0] == pytest.approx(
            -5.0 - order.index('gae') - 0.25 + 1.0)
        assert rows['a2c']['evals'] == rows['gae']['evals']   # the same runs
        assert rows['npg']['seeds'] == 1 and 'failed: boom' in rows['npg']['note']
        rk = bc.ranks(list(rows.values()), final)
        assert rk['n'] == 8 and rk['spearman'] == pytest.approx(rho)
        assert rk['rows'][order[0]]['eval'] == 1
    # SB3 from the learning section, at the points it evaluated (2 of the curves' 10)
    assert res['curves']['points'][:2] == [409, 819]
    assert rows['sb3_a2c']['evals'][4096][0] == pytest.approx(-6.0)
    assert rows['sb3_a2c']['evals'][409] is None and rows['sb3_a2c']['wall_seconds'][0] == 4.1
    assert 'evaluated at 1,024, 2,048, 4,096 only' in rows['sb3_a2c']['note']
    res['learning']['points'] = [4096]
    rows = {r['key']: r for r in bc.summarize(res['curves'], res['learning'], variance)}
    assert 'evaluated at 4,096 only' in rows['sb3_a2c']['note']
    text = '\n'.join(bc.render(res, {'curves': 'bench_plots/curves.png'}))
    assert "## 5. Every estimator's learning curve" in text
    assert 'github.com/thu-ml/tianshou/blob/master/examples/mujoco/README.md' in text
    assert '| Tianshou PPO (published) |' in text and '-4.1 ± 0.3' in text
    assert 'over 8 estimators: -1.00' in text
    assert bc.render({}, {}) == []


def test_curves_time_to_a_return_is_the_first_point_that_reached_it():
    """Per seed, the training seconds of the first evaluation at or above the return."""
    from bench import curves as bc
    points = [1024, 2048, 4096]
    runs = [{'seed': 0, 'evals': {1024: -6.0, 2048: -4.8, 4096: -4.4},
             'wall_at': {1024: 10.0, 2048: 20.0, 4096: 40.0}, 'wall_seconds': 40.0,
             'steps_per_second': 100.0, 'total_steps': 4096},
            {'seed': 1, 'evals': {1024: -5.5, 2048: -5.2, 4096: -4.9},
             'wall_at': {'1024': 12.0, '2048': 24.0, '4096': 48.0}, 'wall_seconds': 48.0,
             'steps_per_second': 90.0, 'total_steps': 4096}]       # keys as from JSON
    curves = {'steps': 4096, 'seeds': [0, 1], 'points': points, 'eval_episodes': 10,
              'runs': {'gae': runs}}
    row = bc.summarize(curves)[0]
    assert row['time_to'][-5.0] == {'mean': pytest.approx(34.0), 'reached': 2, 'of': 2}
    assert row['time_to'][-4.5] == {'mean': pytest.approx(40.0), 'reached': 1, 'of': 2}
    # a learning run has no wall_at: its training curve gives the time of the point
    learning = fake_results()['learning']
    sb3 = learning['runs']['pg_node_graph'][0]
    assert bc.eval_time_at(sb3, learning['points'], -9.5) == pytest.approx(2.048)
    assert bc.eval_time_at(sb3, learning['points'], -5.5) == pytest.approx(4.1)
    assert bc.eval_time_at(sb3, learning['points'], -5.0) is None
    text = '\n'.join(bc.render({'curves': curves}, {}))
    assert '| time to -5 | time to -4.5 |' in text
    assert '| <= 34 s (2/2) | <= 40 s (1/2) |' in text
    runs[0]['evals'][4096] = -4.6
    assert 'not reached (0/2)' in '\n'.join(bc.render({'curves': curves}, {}))


def test_bench_runs_join_the_domain_ros_domain_id_sets(monkeypatch):
    """
    Keep a bench inside an isolated run (ROS_DOMAIN_ID set).

    Its background graph takes the id after it; unset, ids come from the pid and differ run
    by run.
    """
    from bench.runs import domain_id
    monkeypatch.setenv('ROS_DOMAIN_ID', '42')
    assert [domain_id(), domain_id(), domain_id(background=True)] == [42, 42, 43]
    monkeypatch.delenv('ROS_DOMAIN_ID')
    ids = [domain_id() for _ in range(3)]
    assert all(1 <= i <= 99 for i in ids) and len(set(ids)) == 3


def test_tax_alternates_and_reports_each_runs_load_median_and_spread(monkeypatch):
    """``python -m bench tax``: the order turns round every other run; fixed rates in."""
    from bench import tax
    calls = []

    def rate(steps, overrides=()):
        calls.append(('inprocess', tuple(overrides)))
        return 10_000.0 * len(calls)

    def graph(steps, overrides=(), round_trips=False):
        calls.append(('graph', tuple(overrides)))
        return {'steps_per_second': 1_000.0 * len(calls)}

    monkeypatch.setattr(tax, 'inprocess_rate', rate)
    monkeypatch.setattr(tax, 'graph_run', graph)
    res = tax.ratio_runs(100, 3, {'a': [], 'b': ['x=1']}, lambda text: None)
    assert calls == [('inprocess', ()), ('graph', ()), ('graph', ('x=1',)),
                     ('graph', ('x=1',)), ('graph', ()), ('inprocess', ()),
                     ('inprocess', ()), ('graph', ()), ('graph', ('x=1',))]
    assert [p['inprocess'] for p in res['pairs']] == [10_000, 60_000, 70_000]
    assert res['pairs'][1] == {'b': 4_000, 'a': 5_000, 'inprocess': 60_000}
    loads = res['pair_loads'][0]['a']
    assert len(loads['before']) == 3 and loads['during_max'] >= 0
    text = '\n'.join(tax.render_ratio(res, 'python -m bench tax'))
    # ratios a: 0.2, 0.0833, 0.1143 -> median 0.114, spread 0.083-0.200
    assert '| **median** | **60,000** | **5,000** | **0.114** |' in text, text
    assert '| min-max | 10,000-70,000 | 2,000-8,000 | 0.083-0.200 |' in text, text
    assert 'b: `train x=1`' in text and 'Load average (1/5/15 min)' in text
    # --set: both sides take the common settings, the graph's own after them
    calls.clear()
    res = tax.ratio_runs(100, 3, {'b': ['x=1']}, lambda text: None, ['gamma=0.9'])
    assert calls[:2] == [('inprocess', ('gamma=0.9',)), ('graph', ('gamma=0.9', 'x=1'))]
    assert 'default settings but gamma=0.9' in '\n'.join(tax.render_ratio(res, 'tax'))


def test_rejects_unknown_section():
    res = subprocess.run([sys.executable, '-m', 'bench', '--only', 'nope'],
                         capture_output=True, text=True, cwd=REPO)
    assert res.returncode == 2 and '--only takes' in res.stderr


def numbers(line):
    return [float(x.replace(',', '')) for x in re.findall(r'-?[\d,]*\.?\d+(?:e[+-]?\d+)?',
                                                          line)]


@pytest.mark.slow
@pytest.mark.e2e
def test_quick_bench_writes_every_table(tmp_path):
    scratch = tmp_path / 'tmpdir'     # the bench's TMPDIR: SB3 must leave nothing there
    scratch.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO), TMPDIR=str(scratch))
    cmd = [sys.executable, '-m', 'bench', '--quick', '--out', str(tmp_path),
           '--seconds', '0.2', '--latency-steps', '100', '--graph-steps', '2048',
           '--learning-steps', '2048', '--learners', 'pg_node_graph,pg_node_inprocess,sb3_a2c']
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO, env=env, timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    assert [p.name for p in scratch.glob('SB3-*')] == []
    text = (tmp_path / 'BENCHMARKS.md').read_text()
    data = json.loads((tmp_path / 'bench_results.json').read_text())
    for heading in ('## Machine', '## Targets', '## 1. Throughput ladder',
                    '## 2. Lock-step latency', '## 3. Learning',
                    '## 4. Estimator variance on the arm'):
        assert heading in text
    assert 'python -m bench --quick' in text
    graph = graph_available()
    for key in ('mujoco', 'task1', 'task16', 'task64', 'sim_node1', 'sim_node64', 'inprocess',
                'sb3_a2c') + (('graph',) if graph else ()):
        row = [r for r in data['throughput']['rows'] if r['key'] == key]
        assert row and row[0]['steps_per_second'] > 0, (key, row)
        assert f'| {row[0]["name"]} | ' in text
    if not graph:
        assert suite.NOT_AVAILABLE in text
    for row in data['latency']['rows']:
        assert row['round_trips'] >= 100
        assert all(math.isfinite(row[k]) for k in ('median_ms', 'p99_ms', 'max_ms'))
    sb3 = [line for line in text.splitlines() if line.startswith('| SB3 A2C |')]
    assert len(sb3) == 2 and all(math.isfinite(x) for x in numbers(sb3[0]))
    var = data['variance']['rows']
    assert [r['estimator'] for r in var][0] == 'total_return' and len(var) == 11
    assert all(math.isfinite(r['variance']) and r['variance'] > 0 for r in var)
    from bench.curves import configurations
    assert "## 5. Every estimator's learning curve" in text
    curves = data['curves']
    assert set(curves['runs']) == set(configurations())
    for key, runs in curves['runs'].items():
        assert len(runs) == 1 and 'error' not in runs[0], (key, runs)
        assert all(math.isfinite(v) for v in runs[0]['evals'].values()), key
    assert '| SB3 A2C (defaults, 8 envs; learning section) |' in text
    assert '## The ROS tax: the graph against the same computation in one process' in text
    tax = data['tax']
    assert len(tax['pairs']) == 1 and all(v > 0 for v in tax['pairs'][0].values())
    assert set(tax['pairs'][0]) == {'inprocess', 'graph', 'separate'}
    assert set(tax['nodes']) == {'sim_node', 'actor_node', 'critic_node', 'learner_node',
                                 'sim_and_actor', 'critic_and_learner'}
    assert [(r['arms'], r['pairs']) for r in tax['scaling']] == [(16, 2)]
    assert all(r['graph'] > 0 and r['inprocess'] > 0 for r in tax['scaling']), tax['scaling']
    for key in ('idle', 'training'):
        assert tax['latency'][key]['round_trips'] >= 100, tax['latency']
    # the graph run's own round trips: 64 control steps (and the start of the rollout the
    # stop cut), the first 16 left out, every 8th the wait for new weights (far longer than
    # an answer within a rollout)
    for prefix in ('', 'separate_'):
        inside, ends = tax['latency'][f'{prefix}rollout'], tax['latency'][f'{prefix}boundary']
        assert ends['round_trips'] >= 6 and inside['round_trips'] >= 42, tax['latency']
        assert abs(inside['round_trips'] - 7 * ends['round_trips']) < 8, tax['latency']
        assert ends['median_ms'] > 2 * inside['median_ms'], tax['latency']
    assert '| critic_and_learner | yes |' in text and '| sim_and_actor | no |' in text
    assert '| separate / in-process |' in text
    assert 'in the training graph' in text and "at a rollout's end (hand-over)" in text
    for name in ('throughput', 'latency', 'learning', 'variance', 'curves'):
        assert (tmp_path / 'bench_plots' / f'{name}.png').stat().st_size > 1000


def test_throughput_plot_ticks_read_apart(tmp_path, monkeypatch):
    """The ladder's log axis: labels 2k, 5k, 10k ... at major ticks only, none run together."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figures = []
    monkeypatch.setattr(plt, 'close', figures.append)
    res = fake_results()
    res['throughput']['rows'].append(
        {'key': 'sim_node1', 'name': 'one arm', 'steps_per_second': 1900.0, 'note': ''})
    suite.make_plots({'throughput': res['throughput']}, tmp_path)
    (fig,) = figures
    ax = fig.axes[0]
    fig.canvas.draw()
    axis = ax.xaxis
    low, high = ax.get_xlim()
    shown = [t.get_text() for t in axis.get_ticklabels() if t.get_text()]
    assert [t.get_text() for t in axis.get_ticklabels(minor=True) if t.get_text()] == []
    assert shown and set(shown) <= {'1k', '2k', '5k', '10k', '20k', '50k', '100k'}, shown
    assert low < 2000 and high > 40000 and {'2k', '10k'} <= set(shown), (low, high, shown)
    monkeypatch.undo()                        # plt.close is matplotlib's again
    plt.close(fig)


def test_bench_bag_keeps_only_the_rows_asked_for():
    """``bench/bench_bag.py --rows`` (BENCHMARKS.md's zstd repeats) runs, with just those rows."""
    env = dict(os.environ, PYTHONPATH=str(REPO),
               AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))
    done = subprocess.run([sys.executable, 'bench/bench_bag.py', '--rows', 'bytes in',
                           '--messages', '300', '--repeat', '1'], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = [line.split('|')[1].strip() for line in done.stdout.splitlines()
            if line.startswith('| ') and 'configuration' not in line]
    assert rows == ['bytes in, none', 'bytes in, zstd', 'bytes in, lz4'], done.stdout


def test_bench_presets_table_from_fixed_numbers():
    from bench.bench_presets import table
    runs = [{'eval': e, 'seconds': 100.0 + i, 'rate': 9000.0, 'max_kl': 0.01 + i / 1000}
            for i, e in enumerate((-4.0, -3.5, -4.5))]
    text = table([{'preset': 'trpo', 'evals': [-4.0, -3.5, -4.5], 'mean': -4.0, 'std': 0.408,
                   'runs': runs, 'max_kl_bound': 0.02}], 1_000_000)
    row = text.splitlines()[-1]
    assert row.startswith('| `trpo` | **-4.00 ± 0.41** | -4.00, -3.50, -4.50 | 100, 101, 102 |')
    assert row.endswith('| 9,000, 9,000, 9,000 | 0.0120 (0.02) |'), row


def test_bench_reach_row_reads_a_runs_summary_in_cm_and_percent():
    """bench_reach's row: metres to cm, the reached fraction to %, CPU summed over nodes."""
    import argparse
    from bench.bench_reach import parse_config, row_of, table
    summary = {'eval_return': -3.79, 'eval_final_distance': 0.0072, 'eval_reached': 0.96,
               'session_training_seconds': 88.4, 'wall_seconds_total': 96.0,
               'nodes': {'sim_and_actor': {'cpu_seconds_training': 58.7},
                         'critic_and_learner': {'cpu_seconds_training': 73.5}}}
    row = row_of('default', 0, summary)
    assert row['distance_cm'] == pytest.approx(0.72) and row['within_2cm'] == pytest.approx(96)
    assert row['cpu_s'] == pytest.approx(132.2)
    assert table([row]).splitlines()[-1] == '| default | 0 | -3.79 | 0.72 | 96% | 88 | 132 | 96 |'
    assert parse_config('old=gamma=0.9 vf_epochs=1') == ('old', ['gamma=0.9', 'vf_epochs=1'])
    with pytest.raises(argparse.ArgumentTypeError, match='LABEL=OVERRIDES'):
        parse_config('gamma')


def test_curves_plot_two_panels_with_a_band_per_row(tmp_path, monkeypatch):
    """Algorithms and estimators in two panels; each drawn row a mean line and a std band."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib.axes import Axes
    from PIL import Image
    from bench import curves as bc
    bands = []
    real = Axes.fill_between
    monkeypatch.setattr(Axes, 'fill_between',
                        lambda ax, *a, **k: bands.append(ax) or real(ax, *a, **k))
    res = fake_results()
    res['curves'] = fake_curves(list(bc.ESTIMATORS))
    assert bc.make_plot(res, tmp_path) == {'curves': f'{tmp_path.name}/curves.png'}
    panels = {id(ax): ax for ax in bands}
    assert len(panels) == 2
    by_panel = sorted(sum(1 for b in bands if b is ax) for ax in panels.values())
    # a2c, reinforce, a2c_design, ppo, npg, trpo and the SB3 A2C row; 8 estimators
    assert by_panel == [7, 8]
    with Image.open(tmp_path / 'curves.png') as img:
        assert img.size == (1500, 700)
