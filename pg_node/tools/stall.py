"""
A run that learns nothing says so, and why, and stops: ``train``'s stall watch.

:class:`StallWatch` counts the seconds since the learner last wrote a new step (or since the
nodes started, before the first): past ``notice`` s the progress line says so with the
cause :func:`stall_cause` finds, and past ``stop`` s the run stops with that cause in one
line. The cause is looked for where a person would look: a node waiting to be restarted, a
node that used no CPU since the last step (stopped, or blocked), the newest warning or error
a node logged since then (a simulator whose physics blew up, an actor dropping transitions,
a resend loop), else that the nodes run and say nothing.
"""
from pathlib import Path
import re
from typing import Dict, Iterable, Optional

#: the level of a line rclpy's logging writes: ``[WARN] [1796665690.78] [name]: text``
LOG_LINE = re.compile(r'^\[(WARN|ERROR|FATAL)\] \[[\d.]+\] \[([^\]]+)\]: (.*)$')
#: how much of a log's end is read for its newest complaint
TAIL_BYTES = 16384


class StallWatch:
    """
    Seconds since the newest learned step; whether to say so, whether to stop.

    >>> w = StallWatch(notice=30.0, stop=120.0, now=0.0)
    >>> w.update(10.0, None), w.update(40.0, None)             # no step yet: quiet 40 s
    ('ok', 'notice')
    >>> w.update(41.0, 512), w.update(60.0, 512), w.update(100.0, 512), w.update(161.0, 512)
    ('ok', 'ok', 'notice', 'stop')
    """

    def __init__(self, notice: float, stop: float, now: float):
        """``stop``: 0 never stops; times in the caller's clock (monotonic s)."""
        self.notice, self.stop = notice, stop
        self.since = now                  # when the newest step was learned (or the start)
        self.steps: Optional[int] = None

    def quiet(self, now: float) -> float:
        """Return the seconds since the newest learned step (or since the start)."""
        return now - self.since

    def update(self, now: float, steps: Optional[int]) -> str:
        """Take the steps learned so far (None: none yet); return 'ok', 'notice' or 'stop'."""
        if steps is not None and steps != self.steps:
            self.steps, self.since = steps, now
            return 'ok'
        quiet = self.quiet(now)
        if self.stop and quiet >= self.stop:
            return 'stop'
        return 'notice' if quiet >= self.notice else 'ok'


def last_complaint(logs: Dict[str, Path], since_size: Dict[str, int]) -> Optional[str]:
    """
    Return the newest WARN, ERROR or FATAL line any log got past ``since_size``, named.

    ``logs``: process name -> log file; ``since_size``: the size each had at the newest
    learned step (what came before is not this stall's). The newest is the last line of the
    log written last: ``'sim_and_actor.log: [sim_node] the physics of arm 3 blew up ...'``.
    """
    found = []
    for name, path in logs.items():
        try:
            size = path.stat().st_size
            start = max(since_size.get(name, 0), size - TAIL_BYTES)
            if size <= start:
                continue
            with open(path, 'rb') as f:
                f.seek(start)
                text = f.read().decode('utf-8', 'replace')
        except OSError:
            continue
        lines = [m for m in map(LOG_LINE.match, text.splitlines()) if m]
        if lines:
            node, said = lines[-1].group(2), lines[-1].group(3)
            found.append((path.stat().st_mtime, f'{path.name}: [{node}] {said.strip()}'))
    return max(found)[1] if found else None


def idle_processes(cpu_now: Dict[str, float], cpu_then: Dict[str, float],
                   running: Iterable[str]) -> list:
    """Return the running processes that used no CPU since ``cpu_then`` was sampled."""
    return [name for name in running
            if name in cpu_then and cpu_now.get(name, 0.0) - cpu_then[name] < 0.01]


def stall_cause(restarting: Iterable[str], idle: Iterable[str],
                complaint: Optional[str]) -> str:
    """
    Return the words that say why nothing is learned, the most telling first.

    >>> stall_cause([], ['sim_and_actor'], None)
    'sim_and_actor used no CPU since then (stopped, or blocked?)'
    >>> stall_cause([], [], 'sim_and_actor.log: [actor_node] dropped a transition')
    'the newest warning: sim_and_actor.log: [actor_node] dropped a transition'
    """
    restarting, idle = list(restarting), list(idle)
    if restarting:
        return f'{", ".join(restarting)} waiting to be restarted'
    parts = []
    if idle:
        parts.append(f'{", ".join(idle)} used no CPU since then (stopped, or blocked?)')
    if complaint:
        parts.append(f'the newest warning: {complaint}')
    return '; '.join(parts) or 'the nodes run, and their logs say nothing new'
