"""The guard of conftest.py finds the pg_node processes that escaped pytest, only those."""
import os
import signal
import subprocess
import sys
import time

from conftest import stray_processes
import pytest


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
def test_a_process_whose_parent_died_is_stray_a_child_is_not():
    sleeper = [sys.executable, '-c', 'import time; time.sleep(60)']
    child = subprocess.Popen(sleeper + ['pg_node_child'])
    # a shell starts it in the background and exits at once: its parent is gone, as the
    # nodes' are when train is killed with SIGKILL
    subprocess.run(['sh', '-c', ' '.join(f"'{a}'" for a in sleeper) + ' pg_node_escaped &'],
                   check=True)
    try:
        deadline = time.monotonic() + 10
        found = {}
        while time.monotonic() < deadline:
            found = {pid: cmd for pid, cmd in stray_processes().items()
                     if 'pg_node_escaped' in cmd}
            if found:
                break
            time.sleep(0.1)
        assert len(found) == 1, stray_processes()
        assert child.pid not in stray_processes()
    finally:
        child.kill()
        child.wait()
        for pid in found:
            os.kill(pid, signal.SIGKILL)
    time.sleep(0.5)
    assert not any('pg_node_escaped' in cmd for cmd in stray_processes().values())


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='reads /proc')
def test_an_escaped_process_of_another_pytest_is_not_ours():
    """Another pytest's escaped node (a worker beside this one) is left to that pytest."""
    from conftest import OWNER, OWNER_ENV
    sleeper = [sys.executable, '-c', 'import time; time.sleep(60)']
    found = {}
    for owner, tag in ((str(int(OWNER) + 1), 'pg_node_theirs'), (OWNER, 'pg_node_mine')):
        env = dict(os.environ, **{OWNER_ENV: owner})
        subprocess.run(['sh', '-c', ' '.join(f"'{a}'" for a in sleeper) + f' {tag} &'],
                       check=True, env=env)
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not found.get('pg_node_mine'):
            found = {tag: pid for pid, cmd in stray_processes().items()
                     for tag in ('pg_node_theirs', 'pg_node_mine') if tag in cmd}
            time.sleep(0.1)
        assert 'pg_node_mine' in found and 'pg_node_theirs' not in found, found
    finally:
        out = subprocess.run(['pgrep', '-f', 'pg_node_theirs|pg_node_mine'],
                             capture_output=True, text=True).stdout.split()
        for pid in out:
            os.kill(int(pid), signal.SIGKILL)


def test_each_xdist_worker_takes_a_block_of_domains_of_its_own():
    from conftest import DOMAINS_PER_WORKER, worker_domain
    assert worker_domain('42', 'gw0', 'ab') == '42'
    assert worker_domain('42', 'gw1', 'ab') == str(42 + DOMAINS_PER_WORKER)
    first = {worker_domain('', f'gw{k}', 'c0ffee12') for k in range(2)}
    assert len(first) == 2 and all(20 <= int(d) <= 232 - DOMAINS_PER_WORKER for d in first)
