"""
``python -m pg_node monitor``: a live terminal view of a running training (rich).

It subscribes to every ``/pg_node/metrics/<name>`` topic (``std_msgs/Float64``, looked for on
the graph every half second, so metrics that appear later are picked up), to
``/pg_node/episode`` (the per-episode summaries) and to ``/diagnostics``, and shows:

* **training**: each metric's latest value, a sparkline of its recent values and how long
  ago it came (the usual ones first: ``episode_return``, losses, entropy, steps per second,
  policy version, environment steps);
* **episodes**: how many summaries arrived, the mean return of the recent ones with its
  sparkline, how many were cut short;
* **nodes**: each diagnostic status (name, level, message, age); a status not refreshed for
  ``--stale`` seconds is shown as STALE.

``--duration S`` quits after S seconds; ``--once`` listens for ``--duration`` seconds
(default 3) and prints the view once, without the live screen, for scripts and tests.
Without a terminal (output to a file or a pipe) the live view cannot redraw: the monitor
prints one plain line every ``--every`` seconds instead. When it has heard no run and no
node after ``--wait`` seconds (``--once``: after listening), it says so, naming the
``ROS_DOMAIN_ID`` it listened on, and exits with code 1.
Works as well on a bag replayed with ``python -m pg_node replay``.

Runs (:mod:`pg_node.common.run`): a run's topics are ``/<run_id>/pg_node/...``. ``--run
NAME`` watches that run; without it the monitor watches the one run it finds on the graph
and, when it finds several, names them and asks for ``--run`` (with ``--once``: exit code
2). The nodes table shows the watched run's statuses (their ``run_id`` value) and those of
nodes of no run (``policy_node``).
"""
import argparse
from collections import deque
import math
import os
import sys
import threading
import time
from typing import Deque, Dict, Tuple

from pg_node.common.run import run_label, run_of_topic, run_topic
from pg_node.tools.args import positive_float, run_id_arg

ORDER = ('episode_return', 'episode_length', 'eval_return', 'policy_loss', 'value_loss',
         'entropy', 'explained_variance', 'approx_kl', 'grad_norm', 'steps_per_second',
         'policy_version', 'env_steps')
BARS = '▁▂▃▄▅▆▇█'
#: seconds of discovery before the monitor takes the only run it found as the one to watch
SETTLE = 1.5
LEVELS = {0: ('OK', 'green'), 1: ('WARN', 'yellow'), 2: ('ERROR', 'red'), 3: ('STALE', 'dim')}


def sparkline(values, width: int = 32) -> str:
    """
    Return the last ``width`` finite values as a line of block characters.

    >>> sparkline([0, 1, 2, 3, 4, 5, 6, 7])
    '▁▂▃▄▅▆▇█'
    >>> sparkline([3, 3, 3])
    '▄▄▄'
    """
    vals = [v for v in list(values)[-width:] if v is not None and math.isfinite(v)]
    if not vals:
        return ''
    lo, hi = min(vals), max(vals)
    if hi - lo < 1e-12:
        return BARS[len(BARS) // 2 - 1] * len(vals)
    scale = (len(BARS) - 1) / (hi - lo)
    return ''.join(BARS[int(round((v - lo) * scale))] for v in vals)


def _fmt(v: float) -> str:
    if not math.isfinite(v):
        return str(v)
    if v == int(v) and abs(v) < 1e12:
        return f'{int(v):d}'
    return f'{v:.4g}'


class MonitorState:
    """What the monitor has heard, and its rendering; no ROS here."""

    def __init__(self, history: int = 64, stale: float = 5.0):
        """Keep ``history`` values per metric; diagnostics older than ``stale`` s are STALE."""
        self.history = history
        self.stale = stale
        self.metrics: Dict[str, Deque[Tuple[float, float]]] = {}
        self.episode_returns: Deque[float] = deque(maxlen=history)
        self.episodes = 0
        self.cut_short = 0
        self.statuses: Dict[str, tuple] = {}
        self.lock = threading.Lock()
        self.started = time.monotonic()
        self.run = None             # the run watched (None: not chosen yet)
        self.runs = set()           # the runs seen on the graph
        self.asked = False          # the user named the run (--run)

    def on_metric(self, name: str, value: float, now: float = None):
        """Record one metric value."""
        with self.lock:
            self.metrics.setdefault(name, deque(maxlen=self.history)).append(
                (now if now is not None else time.monotonic(), float(value)))

    def on_episode(self, status, now: float = None):
        """Record one ``/pg_node/episode`` summary (a DiagnosticStatus)."""
        values = {kv.key: kv.value for kv in status.values}
        with self.lock:
            self.episodes += 1
            if values.get('cut_short') == 'true':
                self.cut_short += 1
                return
            try:
                self.episode_returns.append(float(values['return']))
            except (KeyError, ValueError):
                pass

    def on_diagnostics(self, array, now: float = None):
        """Record the statuses of a ``/diagnostics`` DiagnosticArray."""
        now = now if now is not None else time.monotonic()
        with self.lock:
            for s in array.status:
                run = next((kv.value for kv in s.values if kv.key == 'run_id'), None)
                if run is not None and run != self.run:
                    continue            # a node of another run (or of none chosen yet)
                level = s.level[0] if isinstance(s.level, bytes) else int(s.level)
                self.statuses[s.name] = (level, s.message, s.hardware_id, now)

    def choice(self) -> str:
        """Return what the monitor says about runs: the one watched, or the ones to pick."""
        several = self.several()
        if self.run is not None:
            watched = f'run {run_label(self.run)}: {run_topic(self.run, "...")}'
            # picked as the only run, and another one showed up later
            return watched if self.asked or len(self.runs) < 2 else f'{watched}; {several}'
        if len(self.runs) > 1:
            return several
        return 'no pg_node run heard yet'

    def several(self) -> str:
        """Return the line that names the runs heard and asks for one."""
        return (f'several runs on this ROS domain: '
                f'{", ".join(map(run_label, sorted(self.runs)))}; choose one with --run NAME')

    def ambiguous(self) -> bool:
        """Whether several runs were heard and the user did not name one."""
        return not self.asked and len(self.runs) > 1

    def choose(self, run: str):
        """Watch ``run``: the statuses heard so far may be of another run."""
        with self.lock:
            self.run = run
            self.statuses.clear()

    def heard_nothing(self) -> bool:
        """Whether no run's topic and no node's diagnostics were heard."""
        with self.lock:
            return not self.runs and not self.statuses

    def line(self, now: float = None) -> str:
        """
        Return the view as one plain line, for output that is not a terminal.

        >>> state = MonitorState()
        >>> state.runs, state.run = {'exp1'}, 'exp1'
        >>> state.on_metric('env_steps', 4096, now=0.0)
        >>> state.on_metric('episode_return', -12.25, now=0.0)
        >>> print(*state.line(now=1.0).split('; '), sep=';' + chr(10))
        run exp1: /exp1/pg_node/...: episode_return -12.25, env_steps 4096;
        0 episodes;
        no node statuses
        """
        now = now if now is not None else time.monotonic()
        with self.lock:
            metrics = {k: v[-1][1] for k, v in self.metrics.items() if v}
            returns = list(self.episode_returns)
            episodes, cut = self.episodes, self.cut_short
            statuses = dict(self.statuses)
        names = [n for n in ORDER if n in metrics] + sorted(set(metrics) - set(ORDER))
        text = self.choice()
        if names:
            text += ': ' + ', '.join(f'{n} {_fmt(metrics[n])}' for n in names)
        text += f'; {episodes} episodes'
        if returns:
            text += f' (mean return {sum(returns) / len(returns):.3f} of the recent ones'
            text += f', {cut} cut short)' if cut else ')'
        levels = {}
        for level, _, _, t in statuses.values():
            name = LEVELS.get(3 if now - t > self.stale else level, (str(level),))[0]
            levels[name] = levels.get(name, 0) + 1
        text += '; nodes ' + ', '.join(f'{n} {name}' for name, n in levels.items()) if (
            levels) else '; no node statuses'
        return text

    def render(self, now: float = None):
        """Return the view as a rich renderable."""
        from rich.console import Group
        from rich.table import Table
        now = now if now is not None else time.monotonic()
        with self.lock:
            metrics = {k: list(v) for k, v in self.metrics.items()}
            returns = list(self.episode_returns)
            episodes, cut = self.episodes, self.cut_short
            statuses = dict(self.statuses)
        train = Table(title=f'training ({self.choice()})', title_justify='left', expand=False)
        for col, justify in (('metric', 'left'), ('value', 'right'), ('recent', 'left'),
                             ('age (s)', 'right')):
            train.add_column(col, justify=justify)
        names = [n for n in ORDER if n in metrics] + sorted(set(metrics) - set(ORDER))
        for name in names:
            series = metrics[name]
            train.add_row(name, _fmt(series[-1][1]), sparkline([v for _, v in series]),
                          f'{now - series[-1][0]:.1f}')
        if not names:
            train.add_row('(no metrics heard yet)', '', '', '')
        eps = Table(title='episodes', title_justify='left')
        for col in ('summaries', 'mean return (recent)', 'recent returns', 'cut short'):
            eps.add_column(col)
        mean = f'{sum(returns) / len(returns):.3f}' if returns else '-'
        eps.add_row(str(episodes), mean, sparkline(returns), str(cut))
        nodes = Table(title='nodes (/diagnostics)', title_justify='left')
        for col in ('name', 'level', 'message', 'age (s)'):
            nodes.add_column(col)
        for name, (level, message, hw, t) in sorted(statuses.items()):
            if now - t > self.stale:
                level = 3
            text, style = LEVELS.get(level, (str(level), ''))
            nodes.add_row(name, f'[{style}]{text}[/]', message, f'{now - t:.1f}')
        if not statuses:
            nodes.add_row('(no /diagnostics heard yet)', '', '', '')
        return Group(train, eps, nodes)


class MonitorNode:
    """The ROS side: subscriptions feeding a :class:`MonitorState`."""

    def __init__(self, state: MonitorState, context=None, run=None):
        """Create the node; the run's topics are subscribed once the run is known."""
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        self.state = state
        self.node = rclpy.create_node('pg_node_monitor', context=context,
                                      start_parameter_services=False)
        self.qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      state.on_diagnostics, self.qos)
        self.subscribed = set()
        self.started = time.monotonic()
        if run is not None:
            state.asked = True
            self.watch(run)
        self.discover()
        self.node.create_timer(0.5, self.discover)

    def watch(self, run: str):
        """Watch ``run``: subscribe its episode summaries; its metrics come in discover."""
        from diagnostic_msgs.msg import DiagnosticStatus
        self.state.choose(run)
        self.node.create_subscription(DiagnosticStatus, run_topic(run, 'episode'),
                                      self.state.on_episode, self.qos)

    def discover(self):
        """Note the runs on the graph, pick the only one if none was chosen, find metrics."""
        from std_msgs.msg import Float64
        topics = self.node.get_topic_names_and_types()
        self.state.runs |= {run for name, _ in topics
                            for run in [run_of_topic(name, 'episode')] if run is not None}
        # the only run, once discovery had time to show the others too
        if (self.state.run is None and len(self.state.runs) == 1
                and time.monotonic() - self.started >= SETTLE):
            self.watch(next(iter(self.state.runs)))
        if self.state.run is None:
            return
        prefix = run_topic(self.state.run, 'metrics/')
        for name, types in topics:
            if (name.startswith(prefix) and name not in self.subscribed
                    and 'std_msgs/msg/Float64' in types):
                metric = name[len(prefix):]
                self.node.create_subscription(
                    Float64, name, lambda msg, m=metric: self.state.on_metric(m, msg.data),
                    self.qos)
                self.subscribed.add(name)


def main(argv=None) -> int:
    """Show the live view (or print it once); return the exit status."""
    parser = argparse.ArgumentParser(prog='python -m pg_node monitor',
                                     description='Live terminal view of a running training.')
    parser.add_argument('--duration', type=positive_float,
                        help='quit after this many seconds (with --once: listen this long)')
    parser.add_argument('--once', action='store_true',
                        help='listen, print the view once and exit (no live screen)')
    parser.add_argument('--stale', type=positive_float, default=5.0,
                        help='seconds after which a diagnostic status is STALE')
    parser.add_argument('--refresh', type=positive_float, default=4.0,
                        help='screen updates per second')
    parser.add_argument('--run', type=run_id_arg,
                        help='the run to watch (default: the only one on the graph)')
    parser.add_argument('--wait', type=positive_float, default=10.0,
                        help='seconds to wait for a run or a node before giving up (exit '
                             'code 1; default 10)')
    parser.add_argument('--every', type=positive_float, default=5.0,
                        help='without a terminal: print one plain line every this many '
                             'seconds (default 5)')
    args = parser.parse_args(argv)
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rich.console import Console
    from rich.live import Live
    context = rclpy.Context()
    rclpy.init(context=context)
    state = MonitorState(stale=args.stale)
    mon = MonitorNode(state, context=context, run=args.run)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(mon.node)
    duration = args.duration if args.duration is not None else (3.0 if args.once else None)
    start = time.monotonic()
    end = None if duration is None else start + duration
    give_up = start + args.wait         # nothing heard by then: wrong domain, or no run
    console = Console()
    silent = False
    try:
        if args.once:
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
            console.print(state.render())
            silent = state.heard_nothing()
        elif not console.is_terminal:
            # a file or a pipe: a live view would print nothing until the end
            next_line = start + args.every
            while end is None or time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)
                now = time.monotonic()
                if now >= give_up and state.heard_nothing():
                    silent = True
                    break
                if now >= next_line:
                    print(f'{now - start:6.1f} s  {state.line(now)}', flush=True)
                    next_line = now + args.every
        else:
            with Live(state.render(), console=console, refresh_per_second=args.refresh,
                      screen=False) as live:
                next_draw = 0.0
                while end is None or time.monotonic() < end:
                    executor.spin_once(timeout_sec=0.05)
                    if time.monotonic() >= give_up and state.heard_nothing():
                        silent = True
                        break
                    if time.monotonic() >= next_draw:
                        live.update(state.render())
                        next_draw = time.monotonic() + 1.0 / max(args.refresh, 0.1)
    except KeyboardInterrupt:
        pass
    finally:
        mon.node.destroy_node()
        rclpy.try_shutdown(context=context)
    if silent:
        waited = time.monotonic() - start
        domain = os.environ.get('ROS_DOMAIN_ID', '').strip() or '0'
        print(f'monitor: no pg_node run and no node heard on ROS domain {domain} '
              f'(ROS_DOMAIN_ID={domain}) in {waited:.0f} s: is a training running, with '
              'the same ROS_DOMAIN_ID (and ROS_AUTOMATIC_DISCOVERY_RANGE) as here?',
              file=sys.stderr)
        return 1
    if state.ambiguous():
        # also when one was picked as the only run and another showed up later: which one
        # the view showed depended on discovery's timing
        print(f'monitor: {state.several()}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
