"""
Every test leaves no pg_node process running behind it, and DDS stays on this machine.

A node that outlives the process that started it keeps talking on its ROS domain, and a
later test on that domain hears it: on 2026-12-02 a test that failed left a training graph
running, and the soak test after it counted that graph's dropped messages as its own. After
each test, a pg_node process of this machine started since pytest began that is not a
descendant of pytest (its supervisor died without stopping it) gets some seconds to stop on
its own, as a node does whose supervisor died (``stop_with_supervisor``); then it is killed,
and the test errors, naming it.
"""
import os
import signal
import sys
import time

from pg_node.tools.processes import proc_stat
import pytest

GRACE = 30.0        # seconds: a node that lost its supervisor closes its bag and checkpoint

# Localhost by default (Jazzy's discovery range): no test's nodes, nor the test process's own,
# send discovery traffic out of this machine's network interfaces. A user's own setting wins;
# the tests that build network namespaces set what they test (test/netns.py).
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')


def _processes():
    """Return ``{pid: (ppid, start ticks, argv)}`` of every process, from ``/proc``."""
    found = {}
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        fields = proc_stat(int(entry))
        try:
            with open(f'/proc/{entry}/cmdline', 'rb') as f:
                argv = f.read().decode(errors='replace').split('\0')[:-1]
        except OSError:
            continue
        if fields is not None:
            found[int(entry)] = (int(fields[1]), int(fields[19]), argv)
    return found


def stray_processes():
    """Return ``{pid: command line}`` of pg_node processes that escaped this pytest."""
    me = os.getpid()
    procs = _processes()
    if me not in procs:
        return {}
    started = procs[me][1]

    def ours(pid):
        seen = set()
        while pid > 1 and pid not in seen:
            if pid == me:
                return True
            seen.add(pid)
            pid = procs.get(pid, (0,))[0]
        return False

    return {pid: ' '.join(argv) for pid, (_, start, argv) in procs.items()
            if pid != me and start >= started and argv and argv[0] == sys.executable
            and any(a.startswith('pg_node') for a in argv[1:]) and not ours(pid)}


@pytest.fixture(autouse=True)
def no_process_left_behind():
    """Fail the test whose run left a pg_node process running without its supervisor."""
    yield
    if not sys.platform.startswith('linux'):
        return
    stray = stray_processes()
    end = time.monotonic() + GRACE
    while stray and time.monotonic() < end:
        time.sleep(0.5)
        stray = {pid: cmd for pid, cmd in stray_processes().items() if pid in stray}
    for pid in stray:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert not stray, ('left running after the test (killed now): '
                       + '; '.join(f'{pid} {cmd[:200]}' for pid, cmd in stray.items()))
