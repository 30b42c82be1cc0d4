"""
``scripts/lan_hosts.py``: hosts made by hand as network namespaces, used, and removed.

Root only, as CI runs (``bench/lan.py``); a prefix of this test process's own keeps it
apart from another test's LAN and from one a person left up.
"""
import os
from pathlib import Path
import subprocess
import sys
import time

from bench.lan import Lan, unavailable
import pytest

REPO = Path(__file__).resolve().parent.parent
SCRIPT = REPO / 'scripts' / 'lan_hosts.py'
PREFIX = f'pgt{os.getpid() % 100000}'


def lan_hosts(*args, timeout=60):
    return subprocess.run([sys.executable, str(SCRIPT), '--prefix', PREFIX, '--subnet', '252',
                           *args], cwd=REPO, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def root():
    why = unavailable()
    if why is not None:
        pytest.fail(f'scripts/lan_hosts.py needs network namespaces: {why}')
    yield
    Lan.existing(PREFIX, 252).remove()      # whatever a failed test left


def test_up_run_status_down_leaves_nothing(root):
    done = lan_hosts('up', '--hosts', '2')
    assert done.returncode == 0, done.stderr
    assert f'host 1: namespace {PREFIX}h1, address 10.213.252.2' in done.stdout
    # a command runs in the host named: its address, the test's DDS settings
    done = lan_hosts('run', '1', '--', 'sh', '-c', 'ip -o -4 addr show; '
                     'echo "$FASTDDS_BUILTIN_TRANSPORTS $ROS_AUTOMATIC_DISCOVERY_RANGE"')
    assert done.returncode == 0, done.stderr
    assert 'inet 10.213.252.2/24' in done.stdout and '10.213.252.1/' not in done.stdout
    assert done.stdout.splitlines()[-1] == 'UDPv4 SUBNET'
    done = lan_hosts('run', '0', '--static-peers', '--', 'sh', '-c',
                     'echo "$ROS_STATIC_PEERS $ROS_AUTOMATIC_DISCOVERY_RANGE"')
    assert done.stdout.splitlines() == ['10.213.252.2 LOCALHOST'], done.stdout + done.stderr
    # a process left running in a host: status shows it, down stops it
    sleeper = subprocess.Popen([sys.executable, str(SCRIPT), '--prefix', PREFIX, '--subnet',
                                '252', 'run', '0', '--', 'sleep', '120'],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    try:
        end = time.monotonic() + 10
        while str(sleeper.pid) not in lan_hosts('status').stdout:
            assert time.monotonic() < end, 'the process did not show in host 0'
            time.sleep(0.2)
        done = lan_hosts('down')
        assert done.returncode == 0, done.stderr
        assert f'{PREFIX}h0: stopping {sleeper.pid}' in done.stdout
        assert sleeper.wait(10) is not None
    finally:
        if sleeper.poll() is None:
            sleeper.kill()
    assert Lan.existing(PREFIX, 252).leftovers() == [] and not Lan.existing(PREFIX, 252).hosts
    assert 'no hosts of prefix' in lan_hosts('status').stdout


def test_bad_host_and_bad_prefix_are_one_line(root):
    assert lan_hosts('up', '--hosts', '1').returncode == 0
    done = lan_hosts('run', '3', '--', 'true')
    assert done.returncode == 1
    assert done.stderr.strip() == f"lan_hosts: no host '3'; hosts: 0 ({PREFIX}h0)"
    assert lan_hosts('down').returncode == 0
    done = subprocess.run([sys.executable, str(SCRIPT), '--prefix', 'much-too-long', 'status'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and 'at most 8 letters and digits' in done.stderr
