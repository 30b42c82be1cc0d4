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
