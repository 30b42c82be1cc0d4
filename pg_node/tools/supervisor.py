"""
The supervisor of a run's node processes: starts, watches, restarts and stops them.

Each node process runs in a session of its own (signals reach it alone) and logs to the
run's ``logs/<process>.log``. A node that dies is restarted, at most ``max_restarts`` times
each, after a back-off that doubles at each restart; a restarted simulator gets a new seed.
Twice a second the processes' CPU seconds and memory are sampled from ``/proc`` (exact at a
process's end: the kernel's account of the children waited for). A learner that dies
without closing its bag leaves that bag to :func:`make_bags_whole`. ``train``, its worker
hosts and ``bench/soak.py`` supervise with it.
"""
from pathlib import Path
import resource
import subprocess
import sys
import time
from typing import Optional

from pg_node.common.run_dir import RunDir
from pg_node.tools.processes import child_env, process_usage, signal_process, STOP_WAITS


#: a restarted simulator's seed moves on by this much per restart: it draws new episodes
RESTART_SEED_STRIDE = 1_000_003


def make_bags_whole(bags) -> list:
    """Reindex each bag (what ``ros2 bag reindex`` does); return one line per bag."""
    from pg_node.bag.writer import reindex
    lines = []
    for bag in bags:
        report = reindex(bag)
        damage = '; '.join(f'{name}: {d}' for name, d in report.repaired) or 'nothing damaged'
        kept = f'; damaged originals kept: {", ".join(report.kept)}' if report.kept else ''
        lines.append(f'made {bag} whole: {report.message_count} messages ({damage}){kept}')
        lines += [f'{bag / name}: nothing recoverable ({d.reason}); left as it is'
                  for name, d in report.unrecoverable]
    return lines


class Supervisor:
    """Starts, watches, restarts and stops the node processes."""

    def __init__(self, run_dir: Path, commands: dict, max_restarts: int,
                 total_steps: Optional[int] = None, seeds: Optional[dict] = None,
                 learner: str = 'learner_node', env: Optional[dict] = None,
                 restart_delay: float = 1.0):
        self.run = RunDir(run_dir)
        self.run_dir = self.run.path
        self.restart_delay = restart_delay     # s before a first restart, doubling after
        self.learner = learner      # the process the learner runs in
        self.commands = commands
        self.total_steps = total_steps
        self.seeds = dict(seeds or {})
        self.unfinished_bags = []   # bags of learners that died without closing them
        self.max_restarts = max_restarts
        self.procs = {}
        self.started_at = {}        # name -> time.monotonic() of its newest start
        self.restarts = dict.fromkeys(commands, 0)
        self.next_start = {}
        self.failed = None          # why it failed, once check says so
        self.samples = {}           # (name, pid) -> the newest process_usage of that process
        self.cpu_at_first_update = None
        self.run.logs.mkdir(parents=True, exist_ok=True)
        self.env = child_env()
        self.env.setdefault('AMENT_PREFIX_PATH', sys.prefix)
        self.env.update(env or {})

    def start(self, name: str):
        """
        Start one node (own session, so signals reach it alone).

        A simulator started again gets a seed of its own (``seeds[name]`` plus
        :data:`RESTART_SEED_STRIDE` per restart), so that it does not replay the episodes
        it already produced; it logs the seed it uses.
        """
        cmd = list(self.commands[name])
        if name in self.seeds and self.restarts[name] > 0:
            cmd += ['-p', f'seed:={self.seeds[name] + RESTART_SEED_STRIDE * self.restarts[name]}']
        log = open(self.run.log(name), 'a')
        self.procs[name] = subprocess.Popen(cmd, stdout=log,
                                            stderr=subprocess.STDOUT, env=self.env,
                                            start_new_session=True)
        self.started_at[name] = time.monotonic()
        log.close()

    def start_all(self):
        """Start every node."""
        for name in self.commands:
            self.start(name)

    def check(self) -> str:
        """
        Restart nodes that died; return 'done', 'failed' or 'running'.

        The learner exiting with 0 means training is done, if it learned ``total_steps``
        (when given): a learner stopped by SIGTERM or SIGINT also exits with 0, and is
        restarted as any node that stopped early.
        """
        self.sample_usage()
        for name, proc in list(self.procs.items()):
            code = self.poll(name, proc)
            if code is None:
                continue
            if name == self.learner and code == 0 and self._learned_all():
                return 'done'
            if name == self.learner and code != 0 and name not in self.next_start:
                # killed (SIGKILL, OOM...): its bag, the newest, has no summary yet
                bags = self.run.bags()
                if bags and bags[-1] not in self.unfinished_bags:
                    self.unfinished_bags.append(bags[-1])
            if name in self.next_start:
                if time.monotonic() >= self.next_start[name]:
                    del self.next_start[name]
                    self.start(name)
                continue
            if self.restarts[name] >= self.max_restarts:
                self.failed = f'{name} exited with code {code} {self.restarts[name] + 1} times'
                return 'failed'
            self.restarts[name] += 1
            delay = self.restart_delay * 2.0 ** (self.restarts[name] - 1)
            print(f'\n{name} exited with code {code}; restarting in {delay:g} s '
                  f'({self.restarts[name]}/{self.max_restarts}), see '
                  f'{self.run.log(name)}', file=sys.stderr)
            self.next_start[name] = time.monotonic() + delay
        return 'running'

    def poll(self, name: str, proc: subprocess.Popen) -> Optional[int]:
        """
        Return ``proc``'s exit code (None while it runs); at its exit, its exact CPU seconds.

        ``/proc`` is read twice a second, and a node's last moments would be lost; the
        kernel's account of the children waited for (``RUSAGE_CHILDREN``) grows, at the
        wait, by exactly that child's total. Only this thread waits for the nodes.
        """
        if proc.returncode is not None:
            return proc.returncode
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        code = proc.poll()
        if code is not None:
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            sample = self.samples.setdefault((name, proc.pid), {})
            sample['cpu_seconds'] = (after.ru_utime - before.ru_utime
                                     + after.ru_stime - before.ru_stime)
        return code

    def sample_usage(self):
        """Read every live node's CPU seconds and memory from ``/proc``."""
        for name, proc in self.procs.items():
            if self.poll(name, proc) is None:
                sample = process_usage(proc.pid)
                if sample is not None:
                    self.samples[(name, proc.pid)] = sample

    def cpu_seconds(self) -> dict:
        """Return each node's CPU seconds so far, summed over its restarts."""
        total = dict.fromkeys(self.commands, 0.0)
        for (name, _), sample in self.samples.items():
            total[name] += sample['cpu_seconds']
        return total

    def usage(self) -> dict:
        """
        Return each node's peak resident memory (MB) and CPU seconds, whole and in training.

        Sampled from ``/proc`` at every :meth:`check` (twice a second): the peak is exact,
        and so are the CPU seconds of a process that ended (:meth:`poll`); a live one's miss
        at most the last half second. ``cpu_seconds_training`` counts from the first update
        (the first progress row, seen within half a second) to the end, without start-up.
        """
        cpu = self.cpu_seconds()
        start = self.cpu_at_first_update or {}
        return {name: {'peak_rss_mb': round(max((s['peak_rss_mb'] for (n, _), s
                                                 in self.samples.items()
                                                 if n == name and 'peak_rss_mb' in s),
                                                default=float('nan')), 1),
                       'cpu_seconds': round(cpu[name], 2),
                       'cpu_seconds_training': round(cpu[name] - start.get(name, 0.0), 2)}
                for name in self.commands}

    def _learned_all(self) -> bool:
        if self.total_steps is None:
            return True
        row = self.run.last_progress()
        return row is not None and row['env_steps'] >= self.total_steps

    def stop_all(self):
        """Stop every node: SIGINT, then SIGTERM, then SIGKILL, waiting between."""
        self.sample_usage()         # the last reading of each node's CPU and memory
        for sig, wait in STOP_WAITS:
            alive = [(n, p) for n, p in self.procs.items() if self.poll(n, p) is None]
            for _, p in alive:
                signal_process(p, sig)
            deadline = time.monotonic() + wait
            while alive and time.monotonic() < deadline:
                alive = [(n, p) for n, p in alive if self.poll(n, p) is None]
                time.sleep(0.05)
            if not alive:
                return
