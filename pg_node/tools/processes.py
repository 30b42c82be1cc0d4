"""
Starting and stopping pg_node's node processes from Python (bring-up, tests, benchmarks).

A node started from a non-interactive shell or a script must run in its own session
(``start_new_session=True``): a child started with ``&`` ignores SIGINT, and a session of its
own keeps a Ctrl-C meant for the parent from reaching it twice. It is stopped the way
``ros2 launch`` stops nodes: SIGINT, then SIGTERM, then SIGKILL, waiting between.
"""
import contextlib
import os
import signal
import subprocess
import threading
from typing import Dict, Iterator, List, Optional

from pg_node.common.paths import SOURCE_ROOT, SUPERVISOR_ENV

REPO = SOURCE_ROOT
STOP_WAITS = ((signal.SIGINT, 10.0), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0))
#: the exit code of a command a Ctrl-C (or SIGTERM) stopped before it was done: a shell's
#: 128 + SIGINT, as troubleshooting.md's table of exit codes says
EXIT_INTERRUPTED = 128 + signal.SIGINT


def child_env(domain_id: Optional[int] = None) -> Dict[str, str]:
    """
    Return the environment of a node process: this one, pg_node importable, unbuffered.

    With ``domain_id`` the child joins that ``ROS_DOMAIN_ID`` (tests use one per process so
    that parallel runs do not hear each other). Called from the main thread, it names this
    process as the node's supervisor: the node then stops when this process dies, even by
    SIGKILL (:func:`pg_node.ros.runtime.stop_with_supervisor`). Not from another thread:
    the kernel ties that to the thread that started the child, which may end first.
    """
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    env.pop(SUPERVISOR_ENV, None)
    if threading.current_thread() is threading.main_thread():
        env[SUPERVISOR_ENV] = str(os.getpid())
    path = env.get('PYTHONPATH')
    env['PYTHONPATH'] = f'{REPO}{os.pathsep}{path}' if path else str(REPO)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(domain_id)
    return env


@contextlib.contextmanager
def signals_handled(signals, handler) -> Iterator[None]:
    """Handle ``signals`` with ``handler`` inside the block (main thread only), then restore."""
    old = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


def _interrupt(signum, frame):
    raise KeyboardInterrupt(f'signal {signal.Signals(signum).name}')


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """
    Turn SIGINT, SIGTERM and SIGHUP into KeyboardInterrupt inside the block.

    A supervisor (``train``, ``soak``, ``bench``, ``play``) starts its nodes in sessions of
    their own, so a signal sent to the supervisor alone (``timeout``, ``kill``, a closed
    terminal) does not reach them: without this it dies at once and leaves them running.
    With it the signal takes the Ctrl-C path, which stops the nodes.

    SIGINT gets Python's own Ctrl-C handler even when the supervisor inherited it ignored
    (started with ``&`` by a non-interactive shell, which Python leaves as it is): a
    ``kill -INT`` then stops it as it stops the nodes, which take SIGINT in any case (rclpy
    installs its handler), and as ``ros2 launch`` expects of what it starts.
    """
    with signals_handled((signal.SIGINT,), signal.default_int_handler), \
            signals_handled((signal.SIGTERM, signal.SIGHUP), _interrupt):
        yield


class Interrupts:
    """
    Ctrl-C (SIGINT), SIGTERM and SIGHUP, counted, for a command that winds down in steps.

    Inside :meth:`handled` each of them is counted (:attr:`count`); inside :meth:`raising`
    it also raises KeyboardInterrupt (``signal SIGTERM`` for the others), as Ctrl-C does.
    ``train`` and ``play`` run their nodes inside :meth:`raising`: the first Ctrl-C stops
    them. Stopping the nodes runs outside it, so a second one cannot leave a node behind; the
    slow step after it (``train``'s evaluation, ``play``'s GIF) runs inside it again, only
    when fewer than two came: the second Ctrl-C skips it. SIGINT is taken even when it was
    inherited ignored (see :func:`terminate_as_interrupt`).
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self):
        """Count none yet."""
        self.count = 0
        self._raise = False

    def _handle(self, signum, frame):
        self.count += 1
        if self._raise:
            self._raise = False         # one KeyboardInterrupt per raising block
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            raise KeyboardInterrupt(f'signal {signal.Signals(signum).name}')

    def handled(self):
        """Count the signals inside the block (main thread only), then restore."""
        return signals_handled(self.SIGNALS, self._handle)

    @contextlib.contextmanager
    def raising(self) -> Iterator[None]:
        """Inside :meth:`handled`: a signal in this block raises KeyboardInterrupt."""
        self._raise = True
        try:
            yield
        finally:
            self._raise = False


def shutting_down():
    """Ignore SIGINT, SIGTERM and SIGHUP inside the block: the nodes are being stopped."""
    return signals_handled((signal.SIGINT, signal.SIGTERM, signal.SIGHUP), signal.SIG_IGN)


def signal_process(proc: subprocess.Popen, sig) -> None:
    """
    Send ``sig`` to ``proc``, and to its whole process group when it leads one.

    A process started with ``start_new_session=True`` leads its own group, so a bring-up's
    node children get the signal too.
    """
    try:
        if os.getpgid(proc.pid) == proc.pid:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
    except ProcessLookupError:
        pass


def stop(proc: subprocess.Popen, waits=STOP_WAITS) -> Optional[int]:
    """Stop ``proc``: each signal of ``waits`` in turn until it exits; return its exit code."""
    for sig, wait in waits:
        if proc.poll() is not None:
            break
        signal_process(proc, sig)
        try:
            proc.wait(wait)
        except subprocess.TimeoutExpired:
            pass
    return proc.poll()


def start_logged(args, log_path, env=None, cwd=REPO) -> subprocess.Popen:
    """
    Start ``args`` in its own session, its output going to ``log_path``.

    The log stays open as ``proc.log`` so that :func:`stop_logged` can read it back.
    """
    log = open(log_path, 'w+')
    proc = subprocess.Popen(list(map(str, args)), env=env, cwd=cwd, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    proc.log = log
    return proc


def stop_logged(proc: subprocess.Popen):
    """Stop a process of :func:`start_logged`; return ``(exit code, its whole log)``."""
    stop(proc)
    proc.log.seek(0)
    text = proc.log.read()
    proc.log.close()
    return proc.returncode, text


_TICK = os.sysconf('SC_CLK_TCK') if hasattr(os, 'sysconf') else 100


def proc_stat(pid: int) -> Optional[List[str]]:
    """
    Return the fields of ``/proc/<pid>/stat`` after the command name (Linux); None if gone.

    The command name (field 2) may hold spaces and parentheses, so the fields are counted
    after its last ``)``: index 0 is the state (field 3), 1 the parent pid, 11 and 12 the
    user and system CPU ticks, 19 the start time in ticks since boot.
    """
    try:
        with open(f'/proc/{pid}/stat') as f:
            return f.read().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return None


def process_usage(pid: int) -> Optional[Dict[str, float]]:
    """
    Return a live process's CPU seconds (user + system), resident and peak resident MB.

    Read from ``/proc/<pid>/stat`` and ``/proc/<pid>/status`` (Linux); None when the process
    is gone or ``/proc`` cannot tell. The peak (``VmHWM``) is the kernel's high-water mark,
    exact however seldom it is read.
    """
    fields = proc_stat(pid)
    if fields is None:
        return None
    try:
        with open(f'/proc/{pid}/status') as f:
            status = dict(line.split(':', 1) for line in f if ':' in line)
        return {'cpu_seconds': (int(fields[11]) + int(fields[12])) / _TICK,
                'rss_mb': int(status['VmRSS'].split()[0]) / 1024,
                'peak_rss_mb': int(status['VmHWM'].split()[0]) / 1024}
    except (OSError, IndexError, KeyError, ValueError):
        return None
