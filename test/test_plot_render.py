"""
plot and render from the sample bag: images of the expected size that are not blank.

``render`` runs as its own process: it selects MuJoCo's OSMesa backend before importing
MuJoCo, which must not happen in a process that also loads torch's triton (both bring an
LLVM; the process crashes).
"""
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
from pg_node.bag.reader import BagReader
from pg_node.bag.recorder import parse_episode
from pg_node.bag.writer import BagWriter
from pg_node.tools.plot import main as plot_main, RunData
from pg_node.tools.render import recorded_episodes
from PIL import Image
import pytest
from std_msgs.msg import String

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / 'bags' / 'sample'


def not_blank(image: np.ndarray):
    """Assert an image is not uniform: many distinct colours, spread pixel values."""
    flat = image.reshape(-1, image.shape[-1])
    assert flat.std(axis=0).max() > 10.0
    assert len(np.unique(flat, axis=0)) > 20


def test_plot_sample_bag(tmp_path):
    out = tmp_path / 'curve.png'
    assert plot_main([str(SAMPLE), '-o', str(out)]) == 0
    image = np.asarray(Image.open(out).convert('RGB'))
    assert image.shape == (800, 1500, 3)
    not_blank(image)


def test_plot_run_dir_with_summary_and_custom_size(tmp_path):
    run = tmp_path / 'run'
    shutil.copytree(SAMPLE, run / 'bag')
    (run / 'summary.json').write_text(json.dumps({'eval_return': -6.5, 'total_steps': 1}))
    out = tmp_path / 'sub' / 'run.png'
    assert plot_main([str(run), '-o', str(out), '--width', '900', '--height', '600']) == 0
    assert Image.open(out).size == (900, 600)
    not_blank(np.asarray(Image.open(out).convert('RGB')))
    data = RunData(run)
    assert data.summary['eval_return'] == -6.5
    # a restarted learner's second bag is read with the first
    (run / 'bag_1').mkdir()
    first_half = len(data.metrics['env_steps'][0]) // 2
    t_cut = int(data.metrics['env_steps'][0][first_half])
    shutil.rmtree(run / 'bag')
    metric_topics = [t for t in BagReader(SAMPLE).topics if t.startswith('/pg_node/metrics/')]
    for target, keep in ((run / 'bag', lambda t: t < t_cut),
                         (run / 'bag_1', lambda t: t >= t_cut)):
        shutil.rmtree(target, ignore_errors=True)
        with BagWriter(target) as writer:
            for topic in metric_topics:
                writer.add_topic(topic, 'std_msgs/msg/Float64')
            for m in BagReader(SAMPLE, warn=False).messages(topics=metric_topics):
                if keep(m.log_time_ns):
                    writer.write(m.topic, m.data, m.log_time_ns)
    split = RunData(run)
    for name, (t, v) in data.metrics.items():
        np.testing.assert_array_equal(split.metrics[name][0], t)
        np.testing.assert_array_equal(split.metrics[name][1], v)
    steps, minutes, returns, label = data.returns()
    assert label == "training episodes' mean return"
    assert steps[-1] == 600064 and np.all(np.diff(steps) > 0)
    assert returns[-1] > returns[0] + 10  # the sample run learned


def test_plot_from_episode_summaries_only(tmp_path):
    bag = tmp_path / 'episodes'
    with BagWriter(bag) as writer:
        for m in BagReader(SAMPLE, warn=False).messages(topics=['/pg_node/episode'],
                                                        deserialize=True):
            writer.write(m.topic, m.msg, m.log_time_ns)
    data = RunData(bag)
    steps, _, returns, label = data.returns()
    assert label.startswith('episode return') and len(returns) == 12
    assert steps[-1] == 12 * 50
    out = tmp_path / 'eps.png'
    assert plot_main([str(bag), '-o', str(out)]) == 0
    not_blank(np.asarray(Image.open(out).convert('RGB')))


def test_plot_refuses_a_bag_without_metrics(tmp_path):
    with BagWriter(tmp_path / 'chat') as writer:
        writer.write('/chatter', String(data='hi'), 1)
    assert plot_main([str(tmp_path / 'chat'), '-o', str(tmp_path / 'x.png')]) == 1
    assert not (tmp_path / 'x.png').exists()


def test_recorded_episodes_match_the_episode_summaries():
    episodes = recorded_episodes(SAMPLE)
    assert len(episodes) == 12 and all(len(ep.stamps) == 50 for ep in episodes)
    summaries = [parse_episode(m.msg) for m in BagReader(SAMPLE, warn=False).messages(
        topics=['/pg_node/episode'], deserialize=True)]
    by_arm = {}
    for s in summaries:
        by_arm.setdefault(int(s['arm']), []).append(s['return'])
    for arm, returns in by_arm.items():
        mine = [ep.ret for ep in episodes if ep.arm == arm]
        np.testing.assert_allclose(mine, returns, rtol=0, atol=1e-9)


def run_render(tmp_path, *args):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    env.pop('MUJOCO_GL', None)
    return subprocess.run([sys.executable, '-m', 'pg_node', 'render', *map(str, args)],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=120)


@pytest.mark.e2e
def test_render_sample_episode(tmp_path):
    out = tmp_path / 'ep.gif'
    done = run_render(tmp_path, SAMPLE, '--episode', 1, '-o', out, '--width', 320,
                      '--height', 240)
    assert done.returncode == 0, done.stderr
    gif = Image.open(out)
    assert gif.size == (320, 240) and gif.n_frames == 50
    frames = []
    for k in (0, 25, 49):
        gif.seek(k)
        frames.append(np.asarray(gif.convert('RGB')).astype(int))
    for f in frames:
        not_blank(f)
        # the caption strip at the bottom is black with white text
        strip = f[-40:]
        assert (strip.sum(axis=2) == 0).mean() > 0.8 and strip.max() > 200
        # the target: red pixels (the arena's walls are pink, the arm blue-green)
        red = (f[..., 0] > 80) & (f[..., 0] > 2 * f[..., 1]) & (f[..., 0] > 2 * f[..., 2])
        assert red.sum() > 30
    assert np.abs(frames[0] - frames[2])[:-40].sum() > 0  # the arm moved


@pytest.mark.e2e
def test_render_rejects_missing_episode(tmp_path):
    done = run_render(tmp_path, SAMPLE, '--episode', 99, '-o', tmp_path / 'x.gif')
    assert done.returncode == 1 and 'out of range' in done.stderr


@pytest.mark.e2e
def test_render_refuses_mp4_without_its_codec_and_a_zero_width(tmp_path):
    import importlib.util
    if importlib.util.find_spec('imageio_ffmpeg') is None:
        done = run_render(tmp_path, SAMPLE, '-o', tmp_path / 'e.mp4')
        assert done.returncode == 2 and 'Traceback' not in done.stderr, done.stderr
        assert 'pip install imageio-ffmpeg' in done.stderr and '.gif' in done.stderr
        assert not (tmp_path / 'e.mp4').exists()
    done = run_render(tmp_path, SAMPLE, '--width', 0, '-o', tmp_path / 'x.gif')
    assert done.returncode == 2 and 'argument --width: must be >= 1' in done.stderr
    assert 'Traceback' not in done.stderr


def legend_of(ax):
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_plot_overlays_runs_with_their_names_and_reacher2_references(tmp_path):
    import matplotlib.pyplot as plt
    from pg_node.tools.plot import draw_runs
    for name, ret in (('seed0', -6.5), ('seed1', -7.25)):
        shutil.copytree(SAMPLE, tmp_path / name / 'bag')
        (tmp_path / name / 'summary.json').write_text(json.dumps({'eval_return': ret}))
    runs = [RunData(tmp_path / 'seed0'), RunData(tmp_path / 'seed1')]
    assert [r.name for r in runs] == ['seed0', 'seed1'] and runs[0].is_reacher2()
    fig = draw_runs(runs)
    legend = legend_of(fig.axes[0])
    assert legend == ['seed0', 'seed0 deterministic evaluation -6.50',
                      'seed1', 'seed1 deterministic evaluation -7.25',
                      'random torques -42.8', 'zero torques -11.7']
    assert fig._suptitle.get_text() == 'seed0, seed1'
    # environment steps read 150k, 2M: not 150000175000200000 run together under a panel
    steps_axes = [ax for ax in fig.axes if ax.get_xlabel() == 'environment steps']
    assert fig.axes[0] in steps_axes and len(steps_axes) >= 2
    for ax in steps_axes:
        fmt = ax.xaxis.get_major_formatter()
        assert (fmt(150_000, 0), fmt(2_000_000, 1)) == ('150k', '2M')
    plt.close(fig)
    # one run: its name is the title; another model: no reacher2 references
    one = RunData(tmp_path / 'seed0')
    one.model = 'arm5_3d'
    fig = draw_runs([one])
    assert fig._suptitle.get_text() == 'seed0'
    assert not any('torques' in t for t in legend_of(fig.axes[0]))
    plt.close(fig)
    out = tmp_path / 'both.png'
    assert plot_main([str(tmp_path / 'seed0'), str(tmp_path / 'seed1'), '-o', str(out)]) == 0
    not_blank(np.asarray(Image.open(out).convert('RGB')))


def test_plot_without_output_writes_into_the_run_dir(tmp_path, monkeypatch):
    shutil.copytree(SAMPLE, tmp_path / 'run' / 'bag')
    monkeypatch.chdir(tmp_path)
    assert plot_main([str(tmp_path / 'run')]) == 0
    assert (tmp_path / 'run' / 'learning_curve.png').is_file()
    assert not (tmp_path / 'learning_curve.png').exists()


def test_a_resumed_run_is_drawn_without_a_line_across_the_pause(tmp_path):
    """bag/ then, ten minutes later, bag_1/: each curve breaks (NaN) between the two."""
    import matplotlib.pyplot as plt
    from pg_node.tools.plot import draw_runs
    run = tmp_path / 'run'
    metric_topics = [t for t in BagReader(SAMPLE).topics if t.startswith('/pg_node/metrics/')]
    steps_t = RunData(SAMPLE).metrics['env_steps'][0]
    t_cut = int(steps_t[len(steps_t) // 2])
    pause = 600 * 10**9
    for target, keep, shift in ((run / 'bag', lambda t: t < t_cut, 0),
                                (run / 'bag_1', lambda t: t >= t_cut, pause)):
        with BagWriter(target) as writer:
            for topic in metric_topics:
                writer.add_topic(topic, 'std_msgs/msg/Float64')
            for m in BagReader(SAMPLE, warn=False).messages(topics=metric_topics):
                if keep(m.log_time_ns):
                    writer.write(m.topic, m.data, m.log_time_ns + shift)
    data = RunData(run)
    assert [b.name for b in data.bags] == ['bag', 'bag_1'] and len(data.breaks) == 1
    t_returns = data.metrics['episode_return'][0]
    first_session = int(np.sum(t_returns < t_cut))
    assert 0 < first_session < len(t_returns)
    fig = draw_runs([data])
    for ax in fig.axes[:2]:     # the return against steps, and against wall time
        (line,) = [ln for ln in ax.get_lines() if ln.get_label().startswith('training')]
        x, y = (np.asarray(a, dtype=float) for a in line.get_data())
        assert np.flatnonzero(np.isnan(y)).tolist() == [first_session], ax.get_xlabel()
    minutes = fig.axes[1].get_lines()[0].get_xdata()
    assert minutes[first_session + 1] - minutes[first_session - 1] > 9.9  # the pause
    for ax in fig.axes[2:]:     # speed, losses, entropy: one break each
        (line,) = ax.get_lines()
        assert np.isnan(np.asarray(line.get_ydata(), dtype=float)).sum() == 1, ax.get_title()
    plt.close(fig)
