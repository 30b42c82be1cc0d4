"""
Every test leaves no pg_node process running behind it, and DDS stays on this machine.

A node that outlives the process that started it keeps talking on its ROS domain, and a
later test on that domain hears it: on 2026-12-02 a test that failed left a training graph
running, and the soak test after it counted that graph's dropped messages as its own. After
each test, a pg_node process of this machine started since pytest began that is not a
descendant of pytest (its supervisor died without stopping it) gets some seconds to stop on
its own, as a node does whose supervisor died (``stop_with_supervisor``); then it is killed,
and the test errors, naming it.

Several pytest processes may run at once on one machine: the workers of ``pytest -n 3``
(pytest-xdist, as ``make test`` runs), or a developer's run beside a clean clone's. Each
names itself in the environment its children inherit (``PG_NODE_TEST_RUN``), and only its
own escaped processes are its business. Each xdist worker also takes a block of DDS domains
of its own (:func:`worker_domain`), so the workers' graphs never hear each other.
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

OWNER_ENV = 'PG_NODE_TEST_RUN'
#: this pytest process: its children inherit it, and the guard reaps only processes that carry it
OWNER = str(os.getpid())
os.environ[OWNER_ENV] = OWNER
XDIST_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
#: whose escaped processes the guard reaps: its own; alone, also those that carry no name
#: (started with an environment of their own); beside another worker, never those
REAPED_OWNERS = (OWNER,) if XDIST_WORKER else (OWNER, None)
DOMAINS_PER_WORKER = 5      # the most a test file takes (test_faults.py: one per node + one)


def worker_domain(given: str, worker: str, run_uid: str) -> str:
    """
    Return the first DDS domain of an xdist worker (``gw0``, ``gw1``, ...): a block of its own.

    ``ROS_DOMAIN_ID`` given: worker k starts ``k * DOMAINS_PER_WORKER`` after it (so
    ``ROS_DOMAIN_ID=42 make test`` takes 42..56 with its three workers). Not given: a block drawn
    from the run's id (shared by its workers), so that two test runs on one machine rarely
    meet.

    >>> worker_domain('42', 'gw1', 'ab'), worker_domain('', 'gw0', 'ff')
    ('47', '95')
    """
    k = int(worker[2:])
    start = int(given) if given else 20 + (int(run_uid or '0', 16) % 40) * 5
    return str(start + k * DOMAINS_PER_WORKER)


if XDIST_WORKER:
    os.environ['ROS_DOMAIN_ID'] = worker_domain(
        os.environ.get('ROS_DOMAIN_ID', '').strip(), XDIST_WORKER,
        ''.join(c for c in os.environ.get('PYTEST_XDIST_TESTRUNUID', '') if c in
                '0123456789abcdef')[:8])


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


def _owner(pid: int):
    """Return the pytest process a process was started under (its ``PG_NODE_TEST_RUN``)."""
    try:
        with open(f'/proc/{pid}/environ', 'rb') as f:
            env = f.read().split(b'\0')
    except OSError:
        return None
    prefix = f'{OWNER_ENV}='.encode()
    return next((e[len(prefix):].decode() for e in env if e.startswith(prefix)), None)


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
            and any(a.startswith('pg_node') for a in argv[1:]) and not ours(pid)
            and _owner(pid) in REAPED_OWNERS}


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
