"""
How every pg_node node stops: SIGINT and SIGTERM end ``runtime.run``'s loop between callbacks.

A node is checked while it is always busy in a callback (a 1 ms timer whose callback computes
for 20 ms), which is where a signal lands in a training node: rclpy's default handlers raised
KeyboardInterrupt inside the callback there (logged as ``[FATAL] ... Exception in 'timers'
callback`` with the stack, issue 16's note) or shut the context down under it. Now the callback
finishes, the loop stops, the cleanup runs, and the exit code is 0. A second signal during a
cleanup that hangs ends the process, as ``ros2 launch``'s escalation expects. SIGHUP (a
closed terminal, a supervisor's death) only ever asks, however often it comes.
"""
import os
import signal
import subprocess
import sys
import textwrap
import time

from domains import ros_domain
from pg_node.tools import processes
import pytest

DOMAIN_ID = ros_domain(base=160, spread=60)

BUSY_NODE = textwrap.dedent("""
    import sys, time
    import rclpy
    from rclpy.node import Node
    from pg_node.ros import runtime

    HANG = sys.argv[1] == 'hang'

    class Busy(Node):
        def __init__(self):
            super().__init__('busy_node')
            self.ticks = 0
            self.create_timer(0.001, self.on_tick)

        def on_tick(self):
            self.ticks += 1
            if self.ticks == 20:
                print('busy', flush=True)
            end = time.monotonic() + 0.02
            while time.monotonic() < end:      # Python bytecode: where a signal handler runs
                pass

    def cleanup(node):
        print(f'cleanup after {node.ticks} ticks', flush=True)
        if HANG:
            time.sleep(60)
        if sys.argv[1] == 'slow':
            time.sleep(1.0)
        print('cleaned up', flush=True)

    sys.exit(runtime.run(Busy, cleanup=cleanup))
""")


def start_busy(mode: str, ignore_sigint: bool = False) -> subprocess.Popen:
    """Start the busy node in a session of its own; return once its timer has run 20 times."""
    preexec = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore_sigint else None
    proc = subprocess.Popen([sys.executable, '-c', BUSY_NODE, mode],
                            env=processes.child_env(DOMAIN_ID), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=preexec)
    line = proc.stdout.readline()
    assert line == 'busy\n', line + proc.stdout.read()
    return proc


def finish(proc: subprocess.Popen, timeout: float = 30) -> str:
    """Wait for ``proc``; return its output (killed and failed if it does not end)."""
    try:
        return proc.communicate(timeout=timeout)[0]
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail('the node did not stop: ' + proc.communicate()[0][-2000:])


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
@pytest.mark.parametrize('ignore_sigint', [False, True], ids=['', 'started-with-amp'])
def test_a_signal_inside_a_callback_stops_the_node_cleanly(sig, ignore_sigint):
    """
    Three signals during busy callbacks, each to a fresh node: exit 0, cleanup, no stack.

    ``started-with-amp``: the node inherits SIGINT ignored, as ``node &`` in a script gives
    it, and still stops on SIGINT (rclpy's handler took it too).
    """
    for _ in range(3):
        proc = start_busy('clean', ignore_sigint)
        sent = time.monotonic()
        proc.send_signal(sig)
        out = finish(proc)
        took = time.monotonic() - sent
        assert proc.returncode == 0, out[-3000:]
        assert 'cleaned up' in out, out[-3000:]
        for bad in ('Traceback', 'Exception in', 'KeyboardInterrupt', 'FATAL'):
            assert bad not in out, out[-3000:]
        # one callback (20 ms) and the cleanup; generous for a loaded 2-core machine
        assert took < 10, took


def signal_twice(mode: str, first, second):
    """Send ``first``, then ``second`` once the cleanup has begun; return exit code, output."""
    proc = start_busy(mode)
    proc.send_signal(first)
    line = proc.stdout.readline()
    assert line.startswith('cleanup after'), line
    proc.send_signal(second)
    out = finish(proc)
    return proc.returncode, out


def test_a_second_signal_ends_a_cleanup_that_hangs():
    """SIGINT starts the stop; SIGTERM during a cleanup that hangs ends the process."""
    code, out = signal_twice('hang', signal.SIGINT, signal.SIGTERM)
    assert code == -signal.SIGTERM, out[-3000:]
    assert 'cleaned up' not in out


def test_every_sighup_only_asks():
    """
    SIGHUP twice, the second during the cleanup: the node still saves and exits 0.

    The kernel may send the parent-death signal twice within microseconds
    (``stop_with_supervisor``); with SIGTERM the second killed half the nodes mid-save.
    """
    code, out = signal_twice('slow', signal.SIGHUP, signal.SIGHUP)
    assert code == 0 and 'cleaned up' in out, out[-3000:]


SUPERVISOR = textwrap.dedent("""
    import subprocess, sys, time
    from pg_node.tools import processes
    log = open(sys.argv[2], 'w')
    node = subprocess.Popen([sys.executable, '-c', sys.argv[1], 'slow'], stdout=log,
                            stderr=subprocess.STDOUT, env=processes.child_env(int(sys.argv[3])),
                            start_new_session=True)
    print(node.pid, flush=True)
    time.sleep(600)
""")


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie that init has not reaped yet has exited)."""
    fields = processes.proc_stat(pid)
    return fields is not None and fields[0] != 'Z'


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='prctl(PR_SET_PDEATHSIG)')
def test_a_node_stops_cleanly_when_its_supervisor_is_killed(tmp_path):
    """A supervisor killed by SIGKILL: its node (own session) saves and exits by itself."""
    log = tmp_path / 'node.log'
    sup = subprocess.Popen([sys.executable, '-c', SUPERVISOR, BUSY_NODE, str(log),
                            str(DOMAIN_ID)], env=processes.child_env(DOMAIN_ID),
                           stdout=subprocess.PIPE, text=True, start_new_session=True)
    node = int(sup.stdout.readline())
    try:
        end = time.monotonic() + 60
        while 'busy' not in log.read_text() and time.monotonic() < end:
            time.sleep(0.1)
        sup.kill()
        sup.wait()
        while time.monotonic() < end and alive(node):
            time.sleep(0.1)
        if alive(node):
            pytest.fail('the node did not stop: ' + log.read_text()[-2000:])
    finally:
        if sup.poll() is None:
            sup.kill()
        try:
            os.kill(node, signal.SIGKILL)
        except ProcessLookupError:
            pass
    out = log.read_text()
    assert 'cleaned up' in out and 'Traceback' not in out, out[-3000:]
