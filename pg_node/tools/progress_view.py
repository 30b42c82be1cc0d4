"""
``train``'s view of a run while it learns: a progress bar, or plain lines, from ``progress.csv``.

:class:`ProgressView` reads the learner's newest row of this session (the run directory's
progress readers, :mod:`pg_node.common.run_dir`) and shows the steps, the speed since this
session's first update, the time left, the training return and the policy version;
:func:`supervise` runs the :class:`~pg_node.tools.supervisor.Supervisor` and the view
together until the run is done or failed.
"""
from pathlib import Path
import time
from typing import Optional

from pg_node.common.run_dir import last_progress, read_progress
from pg_node.tools.stall import idle_processes, last_complaint, stall_cause, StallWatch
from pg_node.tools.supervisor import Supervisor

#: seconds without a new learned step before the progress line says so, and why
STALL_NOTICE = 30.0


def format_return(value: float) -> str:
    """Return a mean return as the console shows it (NaN: no episode finished yet)."""
    return 'n/a (no episode finished yet)' if value != value else f'{value:.2f}'


def format_rate(value: float) -> str:
    """Return a rate (or a memory size) as the console shows it, n/a for NaN."""
    # NaN: one update so far (a rate), or a node that ended before it was sampled (memory)
    return 'n/a' if value != value else f'{value:,.0f}'


class ProgressView:
    """
    The progress display of ``train``: one bar on a terminal, plain lines otherwise.

    Until the learner's first ``progress.csv`` row of this session it says
    ``starting nodes...``. Then it shows the environment steps, one speed (steps learned
    per second between this session's first update and its newest, by the learner's clock
    in ``progress.csv``: the figure the summary reports too, free of the bring-up), the
    mean return of the recent *training* episodes
    (stochastic policy) and the policy version. Without a terminal (tqdm disables itself)
    it prints a line when learning starts and then every ``every`` seconds.
    """

    def __init__(self, progress: Path, total: int, start: Optional[dict], bar: bool = True,
                 every: float = 30.0):
        self.progress = progress
        self.total = total
        self.start_steps = start['env_steps'] if start else 0
        # rows written before this session are not its progress
        self.offset = progress.stat().st_size if progress.exists() else 0
        self.t0 = time.monotonic()
        self.every = every
        self.bringup_seconds = None
        self.first = None
        self.last = None
        self._next_line = 0.0
        self._quiet = None          # what the line says while nothing is learned
        self._next_quiet = 0.0
        self.bar = None
        if bar:
            from tqdm import tqdm
            # disable=None: no bar when stderr is not a terminal (CI logs stay readable);
            # no tqdm rate: it would count the bring-up and resumed steps as speed
            self.bar = tqdm(total=total, initial=min(self.start_steps, total), unit='step',
                            unit_scale=True, dynamic_ncols=True, disable=None, mininterval=1.0,
                            bar_format='{desc}{percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} '
                                       '[{elapsed}{postfix}]')
            if self.bar.disable:
                self.bar = None
        self.text = bar and self.bar is None
        if self.bar is not None:
            self.bar.set_description_str('starting nodes... ')
        elif self.text:
            print('starting nodes...', flush=True)

    def steps_per_second(self, row) -> float:
        """Return the speed from this session's first update to ``row`` (NaN: one update)."""
        seconds = row['wall_seconds'] - self.first['wall_seconds']
        steps = row['env_steps'] - self.first['env_steps']
        return steps / seconds if seconds > 0 else float('nan')

    def eta(self, row) -> str:
        """
        Return the time left at this session's speed, as tqdm writes times (n/a: unknown).

        The speed is the one shown (since the first update): the bring-up and the steps of
        an earlier session do not make it look faster or slower than it is.
        """
        from tqdm import tqdm
        rate = self.steps_per_second(row)
        if not rate > 0:
            return 'n/a'
        return tqdm.format_interval(max(self.total - row['env_steps'], 0) / rate)

    def describe(self, row) -> str:
        """Return the labelled fields of one progress row."""
        return (f'{format_rate(self.steps_per_second(row))} steps/s (since the first update), '
                f'ETA {self.eta(row)}, '
                f"training episodes' mean return {format_return(row['episode_return'])}, "
                f"policy version {int(row['policy_version'])}")

    def describe_short(self, row) -> str:
        """Return :meth:`describe` in words that leave the bar room."""
        ret = row['episode_return']
        return (f'ETA {self.eta(row)}, {format_rate(self.steps_per_second(row))} steps/s '
                f"since 1st update, training return {'n/a' if ret != ret else f'{ret:.2f}'}, "
                f"policy v{int(row['policy_version'])}")

    def quiet(self, text: Optional[str]):
        """
        Say that nothing is being learned, and why (None: learning again).

        On the bar its description; in plain lines one line every ``every`` s.
        """
        if text == self._quiet:
            return
        shown, self._quiet = self._quiet, text
        if self.bar is not None:
            self.bar.set_description_str(f'{text} ' if text else '')
        elif self.text and text is not None:
            now = time.monotonic()
            if shown is None or now >= self._next_quiet:
                self._next_quiet = now + self.every
                print(text, flush=True)

    def stopping(self):
        """Say that the nodes are being stopped (the bar's clock goes on meanwhile)."""
        if self.bar is not None:
            self.bar.set_description_str('stopping nodes... ')

    def _session_row(self):
        if self.last is not None:
            return last_progress(self.progress)
        rows = read_progress(self.progress, since=self.offset)
        if rows:
            self.first = rows[0]
        return rows[-1] if rows else None

    def poll(self):
        """Read the newest row of this session and show it."""
        row = self._session_row()
        if row is None:
            return
        now = time.monotonic()
        first = self.last is None
        self.last = row
        if first:
            self.bringup_seconds = now - self.t0
            if self.bar is not None:
                self.bar.set_description_str('')  # the bar itself shows it is learning
            elif self.text:
                print(f'nodes up after {self.bringup_seconds:.1f} s; learning', flush=True)
        if self.bar is not None:
            self.bar.n = min(int(row['env_steps']), self.total)
            self.bar.set_postfix_str(self.describe_short(row), refresh=False)
            self.bar.refresh()
        elif self.text and now >= self._next_line:
            self._next_line = now + self.every
            print(f"step {int(row['env_steps'])}/{self.total}: {self.describe(row)}",
                  flush=True)

    def close(self):
        """Close the bar."""
        if self.bar is not None:
            self.bar.close()


def supervise(sup: Supervisor, view: ProgressView, stall_timeout: float = 0.0,
              notice: float = STALL_NOTICE, period: float = 0.5) -> str:
    """
    Start the nodes and watch them until done, failed or stalled; return the final state.

    A run that learns no new step for ``notice`` s says so on the progress line, with the
    cause (:func:`pg_node.tools.stall.stall_cause`); after ``stall_timeout`` s (0: never) it
    is ``'stalled'``, and ``sup.failed`` holds the one line that says why.
    """
    state = 'running'
    sup.start_all()
    watch = StallWatch(notice, stall_timeout, time.monotonic())
    logs = {name: sup.run.log(name) for name in sup.commands}
    mark = _mark(sup, logs)         # the logs' sizes and the CPU at the newest step
    cause, cause_at = '', -1e9
    while state == 'running':
        time.sleep(period)
        state = sup.check()
        view.poll()
        if sup.cpu_at_first_update is None and view.first is not None:
            sup.cpu_at_first_update = sup.cpu_seconds()
        now = time.monotonic()
        verdict = watch.update(now, int(view.last['env_steps']) if view.last else None)
        if verdict == 'ok':
            if watch.since == now:
                mark, cause_at = _mark(sup, logs), -1e9
                view.quiet(None)
            continue
        if now - cause_at >= 5.0 or verdict == 'stop':     # the logs are read now and then
            cause_at = now
            idle = idle_processes(sup.cpu_seconds(), mark[1], sup.procs)
            cause = stall_cause(sup.next_start, idle, last_complaint(logs, mark[0]))
        quiet = watch.quiet(now)
        if verdict == 'stop':
            sup.failed = (f'no step learned for {quiet:.0f} s: {cause} (logs in '
                          f'{sup.run.logs}; --stall-timeout S waits longer, 0 never stops)')
            state = 'stalled'
            break
        view.quiet(f'no step learned for {quiet:.0f} s: {cause}')
    view.poll()
    view.stopping()
    return state


def _mark(sup: Supervisor, logs: dict) -> tuple:
    """Return the logs' sizes and the nodes' CPU seconds now: a stall is what comes after."""
    sizes = {name: path.stat().st_size if path.exists() else 0 for name, path in logs.items()}
    return sizes, sup.cpu_seconds()
