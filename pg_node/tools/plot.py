"""
``python -m pg_node plot <bag or run dir> -o FILE.png``: the learning curves of a run.

Reads the topics :mod:`pg_node.bag.recorder` writes. Panels: the return against
environment steps and against wall time, steps per second, and the policy loss, value loss
and entropy against environment steps (wall time when ``env_steps`` was not recorded).

The return is ``/pg_node/metrics/episode_return`` (the mean over recent episodes the
learner reports) against ``/pg_node/metrics/env_steps`` logged at the same time; a bag
without those metrics is plotted from its ``/pg_node/episode`` summaries instead (each
episode's return against the steps of all episodes summarised so far, with a moving
average). A run directory holds ``bag/`` (and ``bag_1/``, ... after learner restarts, read
as one) and may hold ``summary.json``, whose ``eval_return`` is drawn as a horizontal line.
Wall time is the bag's log time, in minutes from its first message. Drawn with
matplotlib's Agg backend (no display needed).
"""
import argparse
import json
from pathlib import Path
import sys
from typing import Dict, Optional

import numpy as np

PANELS = ('policy_loss', 'value_loss', 'entropy')


class RunData:
    """Metric series and episode summaries of one bag, with its run's summary if any."""

    def __init__(self, path):
        """Read ``path``: a bag directory, an ``.mcap`` file or a run directory."""
        from pg_node.bag.reader import BagReader
        from pg_node.bag.recorder import EPISODE_TOPIC, METRICS_PREFIX, parse_episode
        path = Path(path)
        self.summary: Optional[Dict] = None
        bags = [path]
        if (path / 'bag').exists():
            if (path / 'summary.json').is_file():
                self.summary = json.loads((path / 'summary.json').read_text())
            # a restarted learner goes on in bag_1, bag_2, ... beside bag/
            extra = sorted((p for p in path.glob('bag_*') if p.name[4:].isdigit()),
                           key=lambda p: int(p.name[4:]))
            bags = [path / 'bag'] + extra
        self.bag = bags[0]
        self.metrics: Dict[str, tuple] = {}
        self.episodes = []
        self.problems = []
        series = {}
        self.t0 = None
        for bag in bags:
            reader = BagReader(bag, warn=False)
            wanted = [t for t in reader.topics
                      if t.startswith(METRICS_PREFIX) or t == EPISODE_TOPIC]
            for m in reader.messages(topics=wanted, deserialize=True):
                if self.t0 is None or m.log_time_ns < self.t0:
                    self.t0 = m.log_time_ns
                if m.msg is None:
                    continue
                if m.topic == EPISODE_TOPIC:
                    ep = parse_episode(m.msg)
                    ep['log_time_ns'] = m.log_time_ns
                    self.episodes.append(ep)
                elif hasattr(m.msg, 'data'):
                    name = m.topic[len(METRICS_PREFIX):]
                    series.setdefault(name, ([], []))
                    series[name][0].append(m.log_time_ns)
                    series[name][1].append(float(m.msg.data))
            self.problems += reader.problems
        self.episodes.sort(key=lambda e: e['log_time_ns'])
        self.metrics = {}
        for k, (t, v) in series.items():
            order = np.argsort(np.array(t, dtype=np.int64), kind='stable')
            self.metrics[k] = (np.array(t, dtype=np.int64)[order], np.array(v)[order])

    def minutes(self, t_ns):
        """Return log times as minutes from the first message."""
        return (np.asarray(t_ns) - (self.t0 or 0)) / 60e9

    def against_steps(self, name):
        """Return ``(env_steps, values)`` of a metric, matched by log time, or None."""
        if name not in self.metrics or 'env_steps' not in self.metrics:
            return None
        t, v = self.metrics[name]
        ts, steps = self.metrics['env_steps']
        k = np.searchsorted(ts, t, side='right') - 1
        ok = k >= 0
        return steps[k[ok]], v[ok]

    def returns(self):
        """
        Return ``(steps, wall minutes, returns, label)`` of the return curve, or None.

        From the ``episode_return`` metric when it was recorded, else from the episode
        summaries (not cut short).
        """
        curve = self.against_steps('episode_return')
        if curve is not None:
            t, _ = self.metrics['episode_return']
            k = np.searchsorted(self.metrics['env_steps'][0], t, side='right') - 1
            return curve[0], self.minutes(t[k >= 0]), curve[1], 'episode_return (metric)'
        eps = [e for e in self.episodes if not e.get('cut_short')]
        if not eps:
            return None
        steps = np.cumsum([e.get('length', 0) for e in eps])
        return (steps, self.minutes([e['log_time_ns'] for e in eps]),
                np.array([e['return'] for e in eps]), 'episode return (summaries)')


def _moving_average(y, n):
    if len(y) < n or n < 2:
        return y
    c = np.cumsum(np.insert(np.asarray(y, dtype=float), 0, 0.0))
    out = (c[n:] - c[:-n]) / n
    return np.concatenate([np.full(n - 1, np.nan), out])


def _no_data(ax, what):
    ax.text(0.5, 0.5, f'no {what} recorded', ha='center', va='center',
            transform=ax.transAxes, color='0.4')


def plot_run(data: RunData, output, width=1500, height=800, dpi=100, title=None):
    """Draw the panels of ``data`` into the PNG ``output`` (``width`` x ``height`` px)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 3, figsize=(width / dpi, height / dpi), dpi=dpi)
    ret = data.returns()
    eval_return = None
    if data.summary and 'eval_return' in data.summary:
        eval_return = float(data.summary['eval_return'])
    elif 'eval_return' in data.metrics:
        eval_return = float(data.metrics['eval_return'][1][-1])
    for ax, xi, xlabel in ((axes[0, 0], 0, 'environment steps'),
                           (axes[0, 1], 1, 'wall time (min)')):
        ax.set_xlabel(xlabel)
        ax.set_ylabel('return')
        if ret is None:
            _no_data(ax, 'return')
            continue
        x, y = ret[xi], ret[2]
        if ret[3].startswith('episode return'):
            ax.plot(x, y, '.', ms=3, alpha=0.4, label=ret[3])
            ax.plot(x, _moving_average(y, max(1, len(y) // 20)), label='moving average')
        else:
            ax.plot(x, y, label=ret[3])
        if eval_return is not None:
            ax.axhline(eval_return, color='C3', ls='--',
                       label=f'evaluation {eval_return:.2f}')
        ax.grid(alpha=0.3)
        ax.legend(loc='lower right', fontsize=8)
    ax = axes[0, 2]
    ax.set_title('steps per second', fontsize=10)
    if 'steps_per_second' in data.metrics:
        t, v = data.metrics['steps_per_second']
        ax.plot(data.minutes(t), v)
        ax.set_xlabel('wall time (min)')
        ax.grid(alpha=0.3)
    else:
        _no_data(ax, 'steps_per_second')
    for ax, name in zip(axes[1], PANELS):
        ax.set_title(name, fontsize=10)
        curve = data.against_steps(name)
        if curve is not None:
            ax.plot(curve[0], curve[1], lw=0.8)
            ax.set_xlabel('environment steps')
        elif name in data.metrics:
            t, v = data.metrics[name]
            ax.plot(data.minutes(t), v, lw=0.8)
            ax.set_xlabel('wall time (min)')
        else:
            _no_data(ax, name)
            continue
        ax.grid(alpha=0.3)
    fig.suptitle(title or str(data.bag))
    fig.tight_layout()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=dpi)
    plt.close(fig)
    return output


def main(argv=None) -> int:
    """Plot a bag or run directory; return the exit status."""
    parser = argparse.ArgumentParser(prog='python -m pg_node plot',
                                     description='Learning-curve PNG of a bag or run directory.')
    parser.add_argument('path', help='bag directory, .mcap file, or run directory with bag/')
    parser.add_argument('-o', '--output', type=Path, default=Path('learning_curve.png'))
    parser.add_argument('--width', type=int, default=1500, help='pixels')
    parser.add_argument('--height', type=int, default=800, help='pixels')
    parser.add_argument('--title')
    args = parser.parse_args(argv)
    try:
        data = RunData(args.path)
    except FileNotFoundError as exc:
        print(f'plot: {exc}', file=sys.stderr)
        return 1
    if data.returns() is None and not data.metrics:
        print(f'plot: {args.path} holds no pg_node metrics or episode summaries',
              file=sys.stderr)
        return 1
    plot_run(data, args.output, args.width, args.height, title=args.title)
    for problem in data.problems:
        print(f'plot: warning: {problem}', file=sys.stderr)
    print(f'wrote {args.output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
