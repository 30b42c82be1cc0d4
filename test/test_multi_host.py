"""
One run on many machines, for real: hosts are network namespaces on a bridge (``lan.py``).

A learner host runs ``train --part learner``, each worker host ``train --part workers
--actors i``, with the same configuration and run id; Fast DDS's shared memory is off, so
every rollout and every weights message crosses the virtual network over UDP, and discovery
is multicast (``SUBNET``) or, with multicast off, ``ROS_STATIC_PEERS``. In lock-step sync the
run equals the same ``num_actors=2`` run on one host, bit for bit; a worker host whose link
goes down for 10 s, and one whose node process is killed, do not change what is learned.
"""
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from bench.lan import dds_env, Lan, unavailable
from domains import ros_domains
from pg_node.common.run_dir import read_progress
from pg_node.tools.processes import proc_stat
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID, PROBE_DOMAIN = ros_domains(2, base=170, spread=30)
CONFIG = ['num_actors=2', 'num_envs=16']
STEPS = 20_480                  # 80 updates of 2 x 16 arms x 8 steps


def env():
    return dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONPATH=str(REPO),
                PYTHONUNBUFFERED='1',
                AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))


def train_args(run_dir, *args, steps=STEPS):
    return [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir), '--no-progress',
            '--eval-episodes', '20', '--total-steps', str(steps), *CONFIG, *args]


@pytest.fixture(scope='module')
def lan():
    why = unavailable()
    if why is not None:
        pytest.fail(f'multi-host tests need network namespaces: {why}')
    with Lan(3) as built:
        yield built
    assert built.leftovers() == []          # every namespace and link was removed


@pytest.fixture(scope='module')
def one_host(tmp_path_factory):
    """Train the same run in one piece, on this machine: the reference."""
    run_dir = tmp_path_factory.mktemp('one_host') / 'run'
    done = subprocess.run(train_args(run_dir), env=env(), cwd=REPO, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads((run_dir / 'summary.json').read_text())


# ``python -c CHATTER pub|sub TAG``: publish "TAG i" at 20 Hz, or print each message heard
CHATTER = """
import sys, rclpy
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import String
mode, tag = sys.argv[1:3]
rclpy.init()
node = rclpy.create_node(f'{mode}_{tag}')
if mode == 'pub':
    pub = node.create_publisher(String, 'chatter', 10)
    node.create_timer(0.05, lambda: pub.publish(String(data=tag)))
else:
    node.create_subscription(String, 'chatter', lambda m: print('got', m.data, flush=True), 10)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


def chatter(host, mode, tag, tmp_path, host_env):
    """Start a CHATTER publisher or subscriber in ``host``."""
    return host.popen([sys.executable, '-c', CHATTER, mode, tag], tmp_path / f'{mode}_{tag}.out',
                      host_env)


def heard(proc, tag):
    """Return how many messages of ``tag`` a CHATTER subscriber printed so far."""
    proc.log.seek(0)
    return proc.log.read().count(f'got {tag}')


def start_hosts(lan, tmp_path, run_id, steps=STEPS, static_peers=False):
    """Start the learner host and two worker hosts; return their processes."""
    peers = [h.address for h in lan.hosts] if static_peers else ()
    host_env = dds_env(env(), discovery='LOCALHOST' if static_peers else 'SUBNET',
                       static_peers=peers)
    learner = lan.hosts[0].popen(
        train_args(tmp_path / 'learner', '--part', 'learner', '--run-id', run_id, steps=steps),
        tmp_path / 'learner.out', host_env)
    workers = [host.popen(train_args(tmp_path / f'worker{i}', '--part', 'workers', '--actors',
                                     str(i), '--run-id', run_id, steps=steps),
                          tmp_path / f'worker{i}.out', host_env)
               for i, host in enumerate(lan.hosts[1:])]
    return learner, workers


def finish(proc, timeout):
    """Wait for a host's train to end by itself; return ``(exit code, its output)``."""
    try:
        proc.wait(timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(60)
    proc.log.seek(0)
    return proc.returncode, proc.log.read()


def wait_for_steps(run_dir, steps, procs, timeout=300):
    end = time.monotonic() + timeout
    while True:
        rows = read_progress(Path(run_dir) / 'progress.csv')
        if rows and rows[-1]['env_steps'] >= steps:
            return
        assert time.monotonic() < end, f'no progress past {steps} steps'
        assert all(p.poll() is None for p in procs), 'a host ended early'
        time.sleep(0.2)


def test_localhost_keeps_each_host_to_itself(lan, tmp_path):
    """LOCALHOST (train's default) reaches no other host: a worker finds no learner there."""
    local = dds_env(env(), discovery='LOCALHOST')
    learner = lan.hosts[0].popen(train_args(tmp_path / 'learner', '--part', 'learner',
                                            '--run-id', 'mh_local'), tmp_path / 'l.out', local)
    worker = lan.hosts[1].popen(train_args(tmp_path / 'worker', '--part', 'workers',
                                           '--run-id', 'mh_local', '--wait-learner', '8'),
                                tmp_path / 'w.out', local)
    try:
        code, out = finish(worker, 120)
    finally:
        os.killpg(learner.pid, signal.SIGINT)
        lcode, lout = finish(learner, 120)
    assert code == 2, out[-2000:]
    assert "no learner host announces run 'mh_local'" in out
    assert lcode == 130, lout[-2000:]           # the learner host interrupted (Ctrl-C)


def test_localhost_is_no_firewall(lan, tmp_path):
    """A LOCALHOST node hears another host that names it in its ROS_STATIC_PEERS."""
    listener = chatter(lan.hosts[0], 'sub', 'B', tmp_path, dds_env(env(), discovery='LOCALHOST'))
    chatter(lan.hosts[1], 'pub', 'B', tmp_path,
            dds_env(env(), discovery='LOCALHOST', static_peers=[lan.hosts[0].address]))
    end = time.monotonic() + 30
    while heard(listener, 'B') < 5:
        assert time.monotonic() < end, 'the named host was not heard in 30 s'
        time.sleep(0.2)


@pytest.mark.parametrize('discovery', ['multicast', 'static_peers'])
def test_learner_and_two_worker_hosts_equal_the_run_on_one_host(
        lan, one_host, tmp_path, discovery):
    """Three hosts over UDP, discovered by multicast or by static peers: the same run."""
    static = discovery == 'static_peers'
    for host in lan.hosts:
        host.multicast(not static)          # static peers need no multicast at all
    # a probe on a domain of its own (static peers' unicast does not reach it): SUBNET
    # nodes in two hosts hear each other by multicast, and only by multicast
    probe = dds_env(dict(env(), ROS_DOMAIN_ID=str(PROBE_DOMAIN)), discovery='SUBNET')
    try:
        listener = chatter(lan.hosts[2], 'sub', 'M', tmp_path, probe)
        chatter(lan.hosts[1], 'pub', 'M', tmp_path, probe)
        learner, workers = start_hosts(lan, tmp_path, f'mh_{discovery}', static_peers=static)
        code, out = finish(learner, 600)
        # the run took some seconds (13 s here): discovery takes well under one
        multicast_heard = heard(listener, 'M')
    finally:
        for host in lan.hosts:
            host.multicast(True)
    assert code == 0, out[-3000:]
    assert (multicast_heard == 0) == static, f'{multicast_heard} probe messages heard'
    # the worker hosts end by themselves once the learner host has announced the end
    for i, w in enumerate(workers):
        wcode, wout = finish(w, 60)
        assert wcode == 0, wout[-3000:]
        assert 'has ended on the learner host (done)' in wout, wout[-2000:]
        assert f'this host ran actors {i}' in wout
    summary = json.loads((tmp_path / 'learner' / 'summary.json').read_text())
    assert summary['policy_version'] == one_host['policy_version']
    assert summary['eval_returns'] == one_host['eval_returns']
    assert 'graph on this machine and its subnet' in out or discovery == 'static_peers'


def _child(pid, name):
    """Return the pid of ``pid``'s child whose command line names ``name``."""
    for entry in os.listdir('/proc'):
        if entry.isdigit() and (proc_stat(int(entry)) or [0, 0])[1] == str(pid):
            with open(f'/proc/{entry}/cmdline', 'rb') as f:
                if name.encode() in f.read():
                    return int(entry)
    return None


def test_a_worker_host_cut_off_for_10_s_and_a_killed_node_change_nothing(lan, tmp_path):
    """Link down 10 s on worker 1, SIGKILL of worker 0's node: the run finishes, whole."""
    steps = 4 * STEPS
    learner, workers = start_hosts(lan, tmp_path, 'mh_faults', steps=steps)
    try:
        wait_for_steps(tmp_path / 'learner', STEPS // 2, [learner, *workers])
        lan.hosts[2].link_down()
        time.sleep(10.0)                   # the fault itself: a pulled cable, for 10 s
        lan.hosts[2].link_up()
        rows = read_progress(tmp_path / 'learner' / 'progress.csv')
        at = rows[-1]['env_steps']
        assert at < steps                  # the run waited for the cut-off host
        wait_for_steps(tmp_path / 'learner', at + STEPS // 2, [learner, *workers])
        node = _child(workers[0].pid, 'sim_and_actor')
        assert node is not None
        os.kill(node, signal.SIGKILL)
    finally:
        code, out = finish(learner, 600)
        outs = [finish(w, 60) for w in workers]
    assert code == 0, out[-3000:]
    for wcode, wout in outs:
        assert wcode == 0, wout[-3000:]
    assert 'sim_and_actor_0 exited with code -9; restarting' in outs[0][1], outs[0][1][-2000:]
    # the learner says what happened: the gap, and the end of it
    log = (tmp_path / 'learner' / 'logs' / 'critic_and_learner.log').read_text()
    assert 'no batch for' in log and 'a batch again after' in log, log[-3000:]
    # every version learned once, in order, none lost: one batch of both actors each
    rows = read_progress(tmp_path / 'learner' / 'progress.csv')
    versions = [int(r['policy_version']) for r in rows]
    assert versions == list(range(1, len(versions) + 1))
    assert [int(r['env_steps']) for r in rows] == [v * 256 for v in versions]
    # the episodes in the bag are whole: every summary a full 50-step episode, except the
    # ones the killed simulator cut short (actor 0), which say so
    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(tmp_path / 'learner' / 'bag') as reader:
        conns = [c for c in reader.connections if c.topic == '/pg_node/episode']
        episodes = [{kv.key: kv.value for kv in store.deserialize_cdr(raw, c.msgtype).values}
                    for c, _, raw in reader.messages(conns)]
    assert episodes
    for ep in episodes:
        if ep['cut_short'] == 'true':
            assert ep['actor'] == '0', ep
        else:
            assert ep['length'] == '50', ep
    assert any(ep['actor'] == '1' for ep in episodes)
