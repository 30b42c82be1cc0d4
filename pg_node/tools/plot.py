"""
``python -m pg_node plot RUN [RUN ...] [-o FILE.png]``: the learning curves of runs.

Reads the topics :mod:`pg_node.bag.recorder` writes. Panels: the return against
environment steps and against wall time, steps per second, and the policy loss, value loss
and entropy against environment steps (wall time when ``env_steps`` was not recorded).

The return is ``/pg_node/metrics/episode_return`` (the mean over recent episodes the
learner reports) against ``/pg_node/metrics/env_steps`` logged at the same time; a bag
without those metrics is plotted from its ``/pg_node/episode`` summaries instead (each
episode's return against the steps of all episodes summarised so far, with a moving
average). A run directory holds ``bag/`` (and ``bag_1/``, ... after a resume or a learner
restart, read as one, each curve broken between them: no line across the pause) and may
hold ``summary.json``, whose ``eval_return`` is drawn as a horizontal line.
Wall time is the bag's log time, in minutes from its first message. Drawn with
matplotlib's Agg backend (no display needed).

Several runs (seeds, settings) are drawn over each other, one colour each, with a legend of
the run names; one run's name is the title. For the shipped ``reacher2`` model the return
panels also show what random torques (uniform in the control range) and zero torques score,
measured by this project (2000 episodes each, evaluation seeds): the floor a policy must
leave and the "stand still" level it must beat. Without ``-o`` one run directory's figure
is written into it, as ``learning_curve.png``.
"""
import argparse
from pathlib import Path
import sys
from typing import Dict, Optional

import numpy as np
from pg_node.common.run_dir import RunDir
from pg_node.tools.args import positive_int

PANELS = ('policy_loss', 'value_loss', 'entropy')
#: (return, label) of reference policies on the shipped reacher2 model, measured here
REACHER2_REFERENCES = ((-42.8, 'random torques'), (-11.7, 'zero torques'))


class RunData:
    """Metric series and episode summaries of one bag, with its run's summary if any."""

    def __init__(self, path):
        """Read ``path``: a bag directory, an ``.mcap`` file or a run directory."""
        from pg_node.bag.reader import BagReader
        from pg_node.bag.recorder import EPISODE_TOPIC, METRICS_PREFIX, parse_episode
        path = Path(path)
        self.path = path
        self.summary: Optional[Dict] = None
        self.model: Optional[str] = None
        bags = [path]
        run = RunDir(path)
        if run.has_bag():
            self.summary = run.read_summary()
            # a restarted learner, or a resumed run, goes on in bag_1, bag_2, ... beside bag/
            bags = run.bags()
        self.bag = bags[0]
        self.bags = bags
        self.metrics: Dict[str, tuple] = {}
        self.episodes = []
        self.problems = []
        series = {}
        self.t0 = None
        #: the first log time of each bag after the first: where a session starts again
        self.breaks = []
        for bag in bags:
            reader = BagReader(bag, warn=False)
            first = None
            wanted = [t for t in reader.topics
                      if t.startswith(METRICS_PREFIX) or t == EPISODE_TOPIC]
            for m in reader.messages(topics=wanted, deserialize=True):
                if self.t0 is None or m.log_time_ns < self.t0:
                    self.t0 = m.log_time_ns
                if first is None:
                    first = m.log_time_ns
                    if bag != bags[0]:
                        self.breaks.append(first)
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
            if self.model is None:
                self.model = _recorded_model(reader)
        if self.summary and self.summary.get('config'):
            self.model = self.summary['config'].get('/**', {}).get('model', self.model)
        self.episodes.sort(key=lambda e: e['log_time_ns'])
        self.metrics = {}
        for k, (t, v) in series.items():
            order = np.argsort(np.array(t, dtype=np.int64), kind='stable')
            self.metrics[k] = (np.array(t, dtype=np.int64)[order], np.array(v)[order])

    @property
    def name(self) -> str:
        """Return the run's name: its directory (that of the bag for a bag or file)."""
        path = self.path.resolve()
        if path.is_file():
            path = path.parent
        if path.name.startswith('bag') and RunDir(path.parent).progress.exists():
            path = path.parent
        return path.name

    def is_reacher2(self) -> bool:
        """
        Return whether the run used the shipped reacher2 model.

        By name, or by a path to ``reacher2.xml`` that holds the shipped file or no longer
        exists (a bag recorded in another checkout names that checkout's file).
        """
        if not self.model:
            return False
        if self.model == 'reacher2':
            return True
        from pg_node.common.paths import models_dir
        path, shipped = Path(self.model), models_dir() / 'reacher2.xml'
        if path.name != 'reacher2.xml':
            return False
        return not path.is_file() or path.read_bytes() == shipped.read_bytes()

    def broken(self, t_ns, *columns):
        """
        Return ``columns`` (matched to the log times ``t_ns``) with NaN where a session ends.

        A run resumed (or a learner restarted) goes on in a new bag, after a pause of wall
        time, from its last checkpoint's steps: a NaN row between the sessions keeps a line
        from being drawn across the pause.
        """
        t = np.asarray(t_ns)
        cut = np.searchsorted(t, self.breaks, side='left')
        cut = [int(k) for k in np.unique(cut) if 0 < k < len(t)]
        return tuple(np.insert(np.asarray(c, dtype=float), cut, np.nan) for c in columns)

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
        curve = self.timed_returns()
        return None if curve is None else curve[:4]

    def timed_returns(self):
        """Return :meth:`returns` with a fifth item, each point's log time (ns), or None."""
        curve = self.against_steps('episode_return')
        if curve is not None:
            t, _ = self.metrics['episode_return']
            t = t[np.searchsorted(self.metrics['env_steps'][0], t, side='right') >= 1]
            return (curve[0], self.minutes(t), curve[1], "training episodes' mean return", t)
        eps = [e for e in self.episodes if not e.get('cut_short')]
        if not eps:
            return None
        steps = np.cumsum([e.get('length', 0) for e in eps])
        t = np.array([e['log_time_ns'] for e in eps], dtype=np.int64)
        return (steps, self.minutes(t), np.array([e['return'] for e in eps]),
                'episode return (summaries)', t)


def _recorded_model(reader) -> Optional[str]:
    meta = reader.metadata or {}
    custom = (meta.get('rosbag2_bagfile_information', meta) or {}).get('custom_data') or {}
    return custom.get('pg_node.model')


def _moving_average(y, n):
    if len(y) < n or n < 2:
        return y
    c = np.cumsum(np.insert(np.asarray(y, dtype=float), 0, 0.0))
    out = (c[n:] - c[:-n]) / n
    return np.concatenate([np.full(n - 1, np.nan), out])


def _no_data(ax, what):
    ax.text(0.5, 0.5, f'no {what} recorded', ha='center', va='center',
            transform=ax.transAxes, color='0.4')


def _eval_return(data: RunData):
    if data.summary and 'eval_return' in data.summary:
        return float(data.summary['eval_return'])
    if 'eval_return' in data.metrics:
        return float(data.metrics['eval_return'][1][-1])
    return None


def plot_run(data: RunData, output, width=1500, height=800, dpi=100, title=None):
    """Draw the panels of ``data`` into the PNG ``output`` (``width`` x ``height`` px)."""
    return plot_runs([data], output, width, height, dpi, title)


def plot_runs(runs, output, width=1500, height=800, dpi=100, title=None):
    """Draw :func:`draw_runs`' figure into the PNG ``output`` (``width`` x ``height`` px)."""
    import matplotlib.pyplot as plt
    fig = draw_runs(runs, width, height, dpi, title)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=dpi)
    plt.close(fig)
    return output


def _steps_axis(ax) -> None:
    """Label ``ax``'s x axis as environment steps, ticks as 50k, 1.5M (no run-together digits)."""
    from matplotlib.ticker import EngFormatter
    ax.set_xlabel('environment steps')
    ax.xaxis.set_major_formatter(EngFormatter(sep=''))


def draw_runs(runs, width=1500, height=800, dpi=100, title=None):
    """
    Return a figure of the panels of one or more runs, drawn over each other.

    One run keeps the look of a single learning curve (title: its name); several get one
    colour each and a legend of their names. Reacher2's reference returns are drawn when
    every run used that model.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 3, figsize=(width / dpi, height / dpi), dpi=dpi)
    many = len(runs) > 1
    names = [r.name for r in runs]
    if len(set(names)) < len(names):
        names = [str(r.path) for r in runs]
    colours = [f'C{i % 10}' for i in range(len(runs))]
    references = REACHER2_REFERENCES if all(r.is_reacher2() for r in runs) else ()
    for ax, xi, xlabel in ((axes[0, 0], 0, 'environment steps'),
                           (axes[0, 1], 1, 'wall time (min)')):
        ax.set_xlabel(xlabel)
        if xi == 0:
            _steps_axis(ax)
        ax.set_ylabel('return')
        drawn = False
        for data, name, colour in zip(runs, names, colours):
            ret = data.timed_returns()
            if ret is None:
                continue
            drawn = True
            x, y = data.broken(ret[4], ret[xi], ret[2])
            label = name if many else ret[3]
            if ret[3].startswith('episode return'):
                ax.plot(x, y, '.', ms=3, alpha=0.4, color=colour,
                        label=None if many else label)
                n = max(1, len(ret[2]) // 20)
                (average,) = data.broken(ret[4], _moving_average(ret[2], n))
                ax.plot(x, average, color=colour, label=label if many else 'moving average')
            else:
                ax.plot(x, y, color=colour, label=label)
            eval_return = _eval_return(data)
            if eval_return is not None:
                ax.axhline(eval_return, color=colour if many else 'C3', ls='--', lw=1,
                           label=f'{name + " " if many else ""}deterministic evaluation '
                                 f'{eval_return:.2f}')
        if not drawn:
            _no_data(ax, 'return')
            continue
        for (value, text), style in zip(references, (':', '-.')):
            ax.axhline(value, color='0.4', ls=style, lw=1.2, label=f'{text} {value:g}')
        ax.grid(alpha=0.3)
        ax.legend(loc='best', fontsize=8)
    ax = axes[0, 2]
    ax.set_title('steps per second', fontsize=10)
    drawn = False
    for data, colour in zip(runs, colours):
        if 'steps_per_second' in data.metrics:
            t, v = data.metrics['steps_per_second']
            ax.plot(*data.broken(t, data.minutes(t), v), color=colour)
            drawn = True
    if drawn:
        ax.set_xlabel('wall time (min)')
        ax.grid(alpha=0.3)
    else:
        _no_data(ax, 'steps_per_second')
    for ax, name in zip(axes[1], PANELS):
        ax.set_title(name, fontsize=10)
        drawn = False
        for data, colour in zip(runs, colours):
            curve = data.against_steps(name)
            if curve is not None:
                t = data.metrics[name][0]
                t = t[np.searchsorted(data.metrics['env_steps'][0], t, side='right') >= 1]
                ax.plot(*data.broken(t, *curve), lw=0.8, color=colour)
                _steps_axis(ax)
            elif name in data.metrics:
                t, v = data.metrics[name]
                ax.plot(*data.broken(t, data.minutes(t), v), lw=0.8, color=colour)
                ax.set_xlabel('wall time (min)')
            else:
                continue
            drawn = True
        if not drawn:
            _no_data(ax, name)
            continue
        ax.grid(alpha=0.3)
    fig.suptitle(title or (', '.join(names) if many else names[0]))
    fig.tight_layout()
    return fig


def main(argv=None) -> int:
    """Plot bags or run directories; return the exit status."""
    parser = argparse.ArgumentParser(
        prog='python -m pg_node plot',
        description='Learning-curve PNG of one or more bags or run directories (drawn over '
                    'each other, with a legend of their names).')
    parser.add_argument('paths', nargs='+', metavar='RUN',
                        help='bag directory, .mcap file, or run directory with bag/')
    parser.add_argument('-o', '--output', type=Path,
                        help='PNG to write (default: learning_curve.png in the run directory '
                             'when one run directory is given, else in the current one)')
    parser.add_argument('--width', type=positive_int, default=1500, help='pixels')
    parser.add_argument('--height', type=positive_int, default=800, help='pixels')
    parser.add_argument('--title', help='default: the run name (one run), else the names')
    args = parser.parse_args(argv)
    runs = []
    for path in args.paths:
        try:
            data = RunData(path)
        except (ValueError, OSError) as exc:
            print(f'plot: {exc}', file=sys.stderr)
            return 1
        if data.returns() is None and not data.metrics:
            print(f'plot: {path} holds no pg_node metrics or episode summaries',
                  file=sys.stderr)
            return 1
        runs.append(data)
    output = args.output
    if output is None:
        run = RunDir(args.paths[0])     # one run directory's figure goes into it
        output = run.curve if len(runs) == 1 and run.has_bag() else RunDir('.').curve
    plot_runs(runs, output, args.width, args.height, title=args.title)
    for data in runs:
        for problem in data.problems:
            print(f'plot: warning: {problem}', file=sys.stderr)
    print(f'wrote {output}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
