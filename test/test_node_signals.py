"""
How every pg_node node stops: SIGINT and SIGTERM end ``node_utils.run``'s loop between callbacks.

A node is checked while it is always busy in a callback (a 1 ms timer whose callback computes
for 20 ms), which is where a signal lands in a training node: rclpy's default handlers raised
KeyboardInterrupt inside the callback there (logged as ``[FATAL] ... Exception in 'timers'
callback`` with the stack, issue 16's note) or shut the context down under it. Now the callback
finishes, the loop stops, the cleanup runs, and the exit code is 0. A second signal during a
cleanup that hangs ends the process, as ``ros2 launch``'s escalation expects.
"""
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
    from pg_node.ros import node_utils

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
        print('cleaned up', flush=True)

    sys.exit(node_utils.run(Busy, cleanup=cleanup))
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


def test_a_second_signal_ends_a_cleanup_that_hangs():
    """SIGINT starts the stop; SIGTERM during a cleanup that hangs ends the process."""
    proc = start_busy('hang')
    proc.send_signal(signal.SIGINT)
    line = proc.stdout.readline()
    assert line.startswith('cleanup after'), line
    proc.send_signal(signal.SIGTERM)
    out = finish(proc)
    assert proc.returncode == -signal.SIGTERM, out[-3000:]
    assert 'cleaned up' not in out
