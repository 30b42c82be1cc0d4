"""
Faults and bad input: killed nodes, malformed messages, bad settings, a soak run.

The node processes of the bad-input tests each run in their own DDS domain, so that they do
not form a training graph: the test is the only peer of each and sees exactly what the node
does with what it is sent. The kill test and the soak run the whole graph.
"""
import json
import math
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticArray
from domains import ros_domains
import numpy as np
from pg_node.bag.recorder import EpisodeRecorder, parse_episode
from pg_node.common.params import defaults
from pg_node.common.run_dir import last_progress, read_progress
from pg_node.rl.learner import EpisodeStats, Learner, make_policy
from pg_node.rl.weights import flatten_state
from pg_node.ros import command
from pg_node.ros import messages
from pg_node.ros import table_msg
from pg_node.ros import transition
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
from sample_messages import ACT, make_rollout, N, OBS
from std_msgs.msg import Float64MultiArray

REPO = Path(__file__).resolve().parent.parent
# five DDS domains of this test process: one per node of the bad-input tests, one for runs
SIM, ACTOR, CRITIC, LEARNER, GRAPH = ros_domains(5, base=100, spread=25)
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
# a test publisher with history, so that messages sent 0.1 s apart are all delivered
LATCHED_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL,
                        history=HistoryPolicy.KEEP_LAST)
RELIABLE_10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


def env(domain):
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONPATH=str(REPO),
                PYTHONUNBUFFERED='1',
                AMENT_PREFIX_PATH=os.environ.get('AMENT_PREFIX_PATH', sys.prefix))


def start(module, domain, log_path, *params):
    """Start ``python -m pg_node.ros.<module>`` in its own session, logging to ``log_path``."""
    args = [sys.executable, '-m', f'pg_node.ros.{module}', '--ros-args']
    for p in params:
        args += ['-p', p]
    return processes.start_logged(args, log_path, env(domain))


stop = processes.stop_logged


class Client:
    """The test's side of one node's domain: publishers, subscribers, diagnostics."""

    def __init__(self, domain, proc):
        self.proc = proc
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node('fault_test', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.diag = {}
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)

    def _on_diag(self, msg):
        for s in msg.status:
            self.diag[s.name] = {kv.key: kv.value for kv in s.values}

    def counter(self, status, key):
        return int(float(self.diag.get(status, {}).get(key, -1)))

    def listen(self, topic, qos, convert=lambda m: m):
        got = []
        self.node.create_subscription(Float64MultiArray, topic,
                                      lambda m: got.append(convert(m)), qos)
        return got

    def spin_until(self, cond, timeout=30.0):
        end = time.monotonic() + timeout
        while not cond():
            assert self.proc.poll() is None, 'the node died'
            assert time.monotonic() < end, 'timed out waiting for the node'
            self.ex.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.ex.spin_once(timeout_sec=0.02)

    def total(self, status, keys):
        return sum(max(self.counter(status, k), 0) for k in keys)

    def each(self, pub, msgs, status, keys):
        """Publish the messages one by one, each once the node has counted the last."""
        self.spin_until(lambda: status in self.diag)
        for m in msgs:
            before = self.total(status, keys)
            pub.publish(m)
            self.spin_until(lambda: self.total(status, keys) > before)
            assert self.total(status, keys) == before + 1

    def burst(self, pub, msg, status, keys, n=20):
        """Publish ``msg`` ``n`` times 20 ms apart; return the wall-clock window it took."""
        before = self.total(status, keys)
        t0 = time.time()
        for _ in range(n):
            pub.publish(msg)
            self.spin_for(0.02)
        t1 = time.time()
        # a node that falls behind may lose some of a burst from its queue, never count more
        self.spin_until(lambda: self.total(status, keys) > before)
        self.spin_for(1.5)
        assert before < self.total(status, keys) <= before + n
        return t0, t1

    def close(self):
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def raw(data, offset=0):
    """Return a Float64MultiArray with no layout: garbage for every pg_node receiver."""
    msg = Float64MultiArray()
    msg.layout.data_offset = offset
    msg.data = [float(v) for v in data]
    return msg


def policy_cfg():
    return {**defaults('learner_node'), **defaults('actor_node')}


def make_transition(seq, **change):
    fields = {'seq': seq, 'obs': np.full((N, OBS), 0.1), 'reward': np.zeros(N),
              'terminated': np.zeros(N, bool), 'truncated': np.zeros(N, bool),
              'final_obs': np.full((N, OBS), 0.1), 'episode_id': np.arange(N),
              'episode_step': np.full(N, seq)}
    fields.update(change)
    return transition.to_msg(transition.Transition(**fields))


def make_batch(version, batch_seq=0, obs_dim=OBS, header_version=None, run=0, **change):
    T = 3
    rng = np.random.default_rng(batch_seq)
    zeros = np.zeros((T, N))
    f = {'obs': rng.normal(size=(T, N, obs_dim)), 'act': rng.normal(size=(T, N, ACT)),
         'logp': zeros, 'adv': rng.normal(size=(T, N)), 'ret': zeros, 'rew': zeros,
         'terminated': zeros.astype(bool), 'truncated': zeros.astype(bool),
         'ep_step': zeros.astype(int), 'episode_id': zeros.astype(int),
         'seq': zeros.astype(int), 'actor': zeros.astype(int)}
    f.update(change)
    header = {'version': version if header_version is None else header_version,
              'n_actors': 1, 'batch_seq': batch_seq, 'n_steps': T, 'num_envs': N,
              'value_loss': 0.0, 'explained_variance': 0.0, 'run': run}
    return table_msg.to_msg(*messages.pack_batch(messages.Batch(**f), header))


def episodes_of(bag):
    """Return the parsed ``/pg_node/episode`` summaries of a bag, in log order."""
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == '/pg_node/episode']
        return [parse_episode(TYPESTORE.deserialize_cdr(raw_, c.msgtype))
                for c, _, raw_ in reader.messages(conns)]


# --- the recorder and the running returns across a simulator restart (no processes) --------

def test_recorder_cuts_short_the_episodes_of_a_restarted_simulator(tmp_path):
    """Episode ids start again at 0 after a simulator restart: old ones cut short, no mix-up."""
    def batch(ids, steps, seq0, done_last=False):
        T = len(steps)
        trunc = np.zeros((T, N), bool)
        trunc[-1] = done_last
        return messages.Batch(
            obs=np.zeros((T, N, OBS)), act=np.zeros((T, N, ACT)), logp=np.zeros((T, N)),
            adv=np.zeros((T, N)), ret=np.zeros((T, N)), rew=np.ones((T, N)),
            terminated=np.zeros((T, N), bool), truncated=trunc,
            ep_step=np.repeat(np.array(steps)[:, None], N, 1),
            episode_id=np.repeat(np.array([ids]), T, 0),
            seq=np.repeat(np.arange(seq0, seq0 + T)[:, None], N, 1),
            actor=np.zeros((T, N), int))

    rec = EpisodeRecorder(tmp_path / 'bag', 'reacher2', record_arms=N)
    stats = EpisodeStats()
    first = batch([0, 1], [0, 1, 2], 0)
    rec.record_batch(first, 1, 10**18)
    stats.update(first.rew, first.terminated, first.truncated, first.episode_id, first.actor)
    # the simulator restarts: the same ids 0 and 1 come again, from step 0
    assert rec.cut_short_actor(0, 10**18 + 10**9, 1) == 2
    assert stats.forget_actor(0) == 2
    again = batch([0, 1], [0, 1, 2, 3], 0, done_last=True)
    rec.record_batch(again, 2, 10**18 + 2 * 10**9)
    assert stats.update(again.rew, again.terminated, again.truncated, again.episode_id,
                        again.actor) == 2
    assert stats.returns == [4.0, 4.0]          # the new episodes only, not 3 + 4
    rec.close()
    eps = episodes_of(tmp_path / 'bag')
    assert [(e['episode_id'], e['cut_short'], e['return']) for e in eps] == [
        (0, 1.0, 3.0), (1, 1.0, 3.0), (0, 0.0, 4.0), (1, 0.0, 4.0)]


# --- bad configuration: refused fast, naming the key ---------------------------------------

BAD_CONFIG = [  # key, value, the node that reads it
    ('gamma', '1.5', 'critic_node'),
    ('gamma', '-0.1', 'critic_node'),
    ('learning_rate', '-0.001', 'learner_node'),
    ('estimator', 'magic_phi', 'critic_node'),
    ('model', '/nonexistent/arm.xml', 'sim_node'),
    ('gamm', '0.9', 'critic_node'),          # an unknown key (a typo)
    ('n_steps', 'eight', 'actor_node'),      # the wrong type
]


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.parametrize('key,value,node', BAD_CONFIG)
def test_bad_config_is_refused_fast_naming_the_key(tmp_path, key, value, node):
    """``python -m pg_node train key=value`` and ``<node> -p key:=value`` stop at once."""
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'train', '--run-dir',
                          str(tmp_path / 'run'), '--no-progress', f'{key}={value}'],
                         env=env(GRAPH), cwd=REPO, capture_output=True, text=True, timeout=60)
    took = time.monotonic() - t0
    assert res.returncode == 2, res.stdout + res.stderr
    assert key in res.stderr and value in res.stderr, res.stderr
    assert 'configuration error' in res.stderr
    assert took < 20 and not (tmp_path / 'run' / 'logs').exists()   # nothing was started
    t0 = time.monotonic()
    res = subprocess.run([sys.executable, '-m', f'pg_node.ros.{node}', '--ros-args', '-p',
                          f'{key}:={value}', '-p', f'run_dir:={tmp_path / "node"}'],
                         env=env(GRAPH), cwd=REPO, capture_output=True, text=True, timeout=90)
    took = time.monotonic() - t0
    out = res.stdout + res.stderr
    assert res.returncode == 2, out
    assert f'{node}.{key}' in out and 'configuration error' in out, out
    assert 'Traceback' not in out
    assert took < 45


# --- bad input to running nodes ------------------------------------------------------------

@pytest.fixture(scope='module')
def nodes(tmp_path_factory):
    """Start one node of each kind, each alone in its own domain; stop them at the end."""
    tmp = tmp_path_factory.mktemp('bad_input')
    # the learner resumes a run whose newest checkpoint is corrupted
    run_dir = tmp / 'learner_run'
    learner = Learner(OBS, ACT, policy_cfg())
    learner.version = 5
    learner.save(run_dir / 'checkpoints')
    learner.version = 10
    newest = learner.save(run_dir / 'checkpoints')
    newest.write_bytes(newest.read_bytes()[:200])       # torn in the middle
    procs = {
        # one message per step: the commands below are for all arms (groups: test_sim_node)
        'sim': start('sim_node', SIM, tmp / 'sim.log', f'num_envs:={N}', 'lock_step_groups:=1'),
        'actor': start('actor_node', ACTOR, tmp / 'actor.log', f'num_envs:={N}'),
        'critic': start('critic_node', CRITIC, tmp / 'critic.log', f'num_envs:={N}',
                        f'run_dir:={tmp / "critic_run"}'),
        'learner': start('learner_node', LEARNER, tmp / 'learner.log', f'num_envs:={N}',
                         f'run_dir:={run_dir}'),
    }
    procs['newest_checkpoint'] = newest
    procs['burst'] = {}
    yield procs
    for name in ('sim', 'actor', 'critic', 'learner'):
        if procs[name].poll() is None:
            stop(procs[name])


@pytest.mark.e2e
@pytest.mark.slow
def test_sim_node_survives_bad_commands(nodes):
    c = Client(SIM, nodes['sim'])
    try:
        trs = c.listen('/pg_node/transition', LATCHED_10, transition.from_msg)
        pub = c.node.create_publisher(Float64MultiArray, '/pg_node/commands', 10)
        c.spin_until(lambda: trs and pub.get_subscription_count() >= 1)
        seq = trs[-1].seq
        # the answer to the current transition, but from another run: dropped, counted
        c.each(pub, [command.tag(raw([0.1, -0.1, 0.2, 0.0]), seq, run=7)],
               'sim_node: simulated arms', ('foreign_messages',))
        nan, inf = float('nan'), float('inf')
        name = 'sim_node: simulated arms'
        keys = ('commands_dropped_size', 'commands_dropped_nonfinite',
                'commands_dropped_absurd')
        c.each(pub, [raw([1, 2, 3]), raw([nan, 0, 0, 0]), raw([0, inf, 0, 0]),
                     raw([0, 0, 0, -inf]), raw([1e300, 0, 0, 0])], name, keys)
        window = c.burst(pub, raw([-1e300] * 4), name, keys)
        # good (the answer to the current transition): exactly one step
        pub.publish(command.tag(raw([0.1, -0.1, 0.2, 0.0]), seq))
        c.spin_until(lambda: trs[-1].seq > seq)
        assert trs[-1].seq == seq + 1                       # no bad command stepped the sim
        pub.publish(command.tag(raw([5.0, 0.0, 0.0, 0.0]), seq + 1))  # clipped, a step
        c.spin_until(lambda: trs[-1].seq > seq + 1)
        assert trs[-1].seq == seq + 2
        c.spin_until(lambda: c.counter(name, 'commands_clipped') == 1)
        assert c.counter(name, 'commands_dropped_size') == 1
        assert c.counter(name, 'commands_dropped_nonfinite') == 3
        assert c.counter(name, 'commands_dropped_absurd') >= 2
        assert c.counter(name, 'steps') == 2
        nodes['burst']['sim'] = window
    finally:
        c.close()
    assert nodes['sim'].poll() is None


@pytest.mark.e2e
@pytest.mark.slow
def test_actor_node_survives_bad_weights_and_transitions(nodes):
    c = Client(ACTOR, nodes['actor'])
    try:
        cmds = c.listen('/pg_node/commands', 10, lambda m: list(m.data))
        pub_w = c.node.create_publisher(Float64MultiArray, '/pg_node/policy_weights',
                                        LATCHED_10)
        pub_t = c.node.create_publisher(Float64MultiArray, '/pg_node/transition', LATCHED_10)
        c.spin_until(lambda: pub_w.get_subscription_count() >= 1
                     and pub_t.get_subscription_count() >= 1)
        cfg = policy_cfg()
        layout, vec = flatten_state(make_policy(OBS, ACT, cfg))
        small = flatten_state(make_policy(OBS, ACT, {**cfg, 'hidden_sizes': [8]}))
        vec_nan = vec.copy()
        vec_nan[3] = float('nan')
        status = 'actor_node 0'
        c.each(pub_w, [table_msg.to_msg(*messages.pack_weights(*small, 0, 0)),  # layout
                       table_msg.to_msg(*messages.pack_weights(layout, vec_nan, 0, 0)),
                       raw([0.0] * 7, offset=2)], status, ('weights_dropped',))
        # good weights, but another run's: not loaded, and no command comes of them
        c.each(pub_w, [table_msg.to_msg(*messages.pack_weights(layout, vec, 0, 0, run=7))],
               status, ('foreign_messages',))
        pub_w.publish(table_msg.to_msg(*messages.pack_weights(layout, vec, 0, 0)))
        c.spin_until(lambda: c.counter(status, 'weights_received') == 1)
        assert c.counter(status, 'weights_dropped') == 3
        keys = ('transitions_dropped',)
        c.each(pub_t, [make_transition(0, obs=np.zeros((N, 5)), final_obs=np.zeros((N, 5))),
                       make_transition(0, obs=np.full((N, OBS), np.nan)),
                       make_transition(0, reward=np.full(N, 1e300)),
                       make_transition(0, terminated=np.full(N, 0.5)),
                       raw([0.0] * 9, offset=1)], status, keys)
        window = c.burst(pub_t, make_transition(0, obs=np.full((N, OBS), np.inf)), status, keys)
        c.each(pub_t, [make_transition(0, run=7)], status, ('foreign_messages',))
        assert cmds == []                                    # nothing acted on
        pub_t.publish(make_transition(0))                    # good: answered
        c.spin_until(lambda: len(cmds) == 1)
        pub_t.publish(make_transition(1))
        c.spin_until(lambda: len(cmds) == 2)
        assert all(len(x) == N * ACT and np.all(np.abs(x) <= 1.0) for x in cmds)
        c.spin_until(lambda: c.counter(status, 'commands') == 2)
        # the simulator re-sends transition 1, as when our command never reached it (a
        # restarted simulator that had not yet heard of the actor): the same command again
        pub_t.publish(make_transition(1))
        c.spin_until(lambda: len(cmds) == 3)
        assert cmds[2] == cmds[1] and cmds[1] != cmds[0]
        c.spin_until(lambda: c.counter(status, 'commands_resent') == 1)
        assert c.counter(status, 'commands') == 2
        nodes['burst']['actor'] = window
    finally:
        c.close()
    assert nodes['actor'].poll() is None


@pytest.mark.e2e
@pytest.mark.slow
def test_critic_node_survives_bad_rollouts(nodes):
    c = Client(CRITIC, nodes['critic'])
    try:
        batches = c.listen('/pg_node/batch', RELIABLE_10,
                           lambda m: messages.unpack_batch(*table_msg.from_msg(m))[0])
        pub = c.node.create_publisher(Float64MultiArray, '/pg_node/rollout', RELIABLE_10)
        c.spin_until(lambda: pub.get_subscription_count() >= 1)
        keys = ('rollouts_dropped',)
        c.each(pub, [raw([float('nan')] * 12, offset=5),
                     make_rollout(0, obs=np.full((4, N, OBS), np.nan)),
                     make_rollout(0, obs=np.full((4, N, OBS), 1e300)),
                     make_rollout(0, terminated=np.full((4, N), 0.5))], 'critic_node', keys)
        window = c.burst(pub, make_rollout(0, rew=np.full((4, N), -np.inf)), 'critic_node',
                         keys)
        c.each(pub, [make_rollout(0, run=7)], 'critic_node', ('foreign_messages',))
        pub.publish(make_rollout(0))                         # good: a batch comes out
        c.spin_until(lambda: len(batches) == 1)
        # a layout that does not match the first rollout's observation size
        c.each(pub, [make_rollout(1, obs_dim=5)], 'critic_node', keys)
        pub.publish(make_rollout(1))
        c.spin_until(lambda: len(batches) == 2)
        assert [b['batch_seq'] for b in batches] == [0, 1]
        assert all(math.isfinite(b['value_loss']) for b in batches)
        c.spin_until(lambda: c.counter('critic_node', 'batches') == 2)
        nodes['burst']['critic'] = window
    finally:
        c.close()
    assert nodes['critic'].poll() is None


@pytest.mark.e2e
@pytest.mark.slow
def test_learner_node_skips_a_corrupted_checkpoint_and_survives_bad_batches(nodes):
    c = Client(LEARNER, nodes['learner'])
    try:
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        versions = c.listen('/pg_node/policy_weights', qos,
                            lambda m: messages.unpack_weights(*table_msg.from_msg(m))[0]
                            ['version'])
        pub = c.node.create_publisher(Float64MultiArray, '/pg_node/batch', RELIABLE_10)
        c.spin_until(lambda: versions and pub.get_subscription_count() >= 1, timeout=60)
        assert versions == [5]          # ckpt 10 is torn: resumed from 5, not from scratch
        keys = ('dropped_batches',)
        c.each(pub, [raw([float('nan')] * 12, offset=7),
                     make_batch(5, obs_dim=5),                                   # layout
                     make_batch(5, adv=np.full((3, N), np.nan)),                 # NaN
                     make_batch(5, adv=np.full((3, N), np.inf)),                 # inf
                     make_batch(5, obs=np.full((3, N, OBS), 1e300)),             # absurd
                     make_batch(5, header_version=5.5)], 'learner_node', keys)   # version
        window = c.burst(pub, make_batch(5, act=np.full((3, N, ACT), np.nan)), 'learner_node',
                         keys)
        assert versions == [5]
        c.each(pub, [make_batch(5, run=7)], 'learner_node', ('foreign_messages',))
        pub.publish(make_batch(5))
        c.spin_until(lambda: versions[-1] == 6)
        c.spin_until(lambda: c.counter('learner_node', 'batches') == 1)
        assert c.counter('learner_node', 'skipped_updates') == 0
        nodes['burst']['learner'] = window
    finally:
        c.close()
    assert nodes['learner'].poll() is None


@pytest.mark.e2e
@pytest.mark.slow
def test_bad_input_was_reported_at_most_once_a_second(nodes):
    """Each node is still alive, stops cleanly, and logged its drops throttled to 1/s."""
    expect = {  # node: the warning its burst of 20 bad messages in 0.4 s triggers
        'sim': 'dropped a command with an absurd value',
        'actor': 'dropped a transition',
        'critic': 'dropped a rollout',
        'learner': 'dropped a batch',
    }
    logs = {}
    for name in expect:
        assert nodes[name].poll() is None, f'{name} died'
        code, logs[name] = stop(nodes[name])
        assert code == 0, logs[name][-2000:]
    for name, text in expect.items():
        t0, t1 = nodes['burst'][name]
        stamps = [float(m.group(1)) for ln in logs[name].splitlines() if text in ln
                  for m in [re.search(r'\]\s*\[(\d+\.\d+)\]', ln)] if m]
        assert stamps, (name, logs[name][-2000:])
        during = [t for t in stamps if t0 <= t <= t1 + 0.5]
        assert len(during) <= math.ceil(t1 + 0.5 - t0) + 1, (name, t1 - t0, during)
    assert 'clipped a command' in logs['sim'] and 'absurd value' in logs['sim']
    learner_log = logs['learner']
    assert 'skipping unreadable checkpoint' in learner_log
    assert nodes['newest_checkpoint'].name in learner_log
    assert 'resumed policy version 5' in learner_log


# --- SIGKILL of each node in one training run ----------------------------------------------

# the critic and the learner checkpoint every CHECKPOINT_EVERY batches or versions of 512
# steps (100 by default) and are killed past their first checkpoints; the run ends 20k steps
# later, well past the version the learner was killed at (until issue 34: the default
# checkpoints and kills at 40k, 90k, 140k, 190k of 300k, then 15k, 30k, 60k, 80k of 130k,
# which proved nothing more for 40 s longer)
CHECKPOINT_EVERY = 10
KILLS = ((6_000, 'sim_node'), (12_000, 'actor_node'), (20_000, 'critic_node'),
         (30_000, 'learner_node'))
KILL_STEPS = 50_000


def log_tails(run_dir, lines=15):
    """Return the last lines of each node log of a run, for a failing assertion's message."""
    tails = []
    for log in sorted((run_dir / 'logs').glob('*.log')):
        text = log.read_text(errors='replace').splitlines()
        tails.append(f'--- {log.name}:\n' + '\n'.join(text[-lines:]))
    return '\n'.join(tails)


def wait_for_progress(proc, run_dir, deadline, min_steps=0.0):
    """Return the newest progress row once it has ``min_steps``; fail if train ends first."""
    while True:
        if time.monotonic() >= deadline or proc.poll() is not None:
            row = last_progress(run_dir / 'progress.csv')
            pytest.fail(f'no progress to {min_steps:g} steps (train exit code {proc.poll()}, '
                        f'newest row {row}); the node logs end:\n{log_tails(run_dir)}')
        row = last_progress(run_dir / 'progress.csv')
        if row is not None and row['env_steps'] >= min_steps:
            return row
        time.sleep(0.2)


def kill_run(proc, run_dir):
    """Kill ``train`` (a test that failed) and every node of its run, if still running."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    for pid in node_pids(run_dir):     # in sessions of their own: killpg does not reach them
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def node_pids(run_dir, node=r'.*_node|sim_and_actor|critic_and_learner'):
    """Return the pids of a run's node processes (all, or ``node``), named by its run dir."""
    out = subprocess.run(['pgrep', '-f', f'pg_node[.]ros[.]({node}) .*{run_dir}'],
                         capture_output=True, text=True).stdout.split()
    return [int(p) for p in out]


@pytest.mark.e2e
@pytest.mark.slow
def test_sigkill_of_each_node_mid_run(tmp_path):
    """
    Kill sim, actor, critic and learner in turn; the run finishes and nothing is lost.

    The supervisor restarts each. The restarted simulator starts again at transition 0 and
    episode id 0: the learner marks the episodes it cut short as such. The restarted critic
    resumes V from its checkpoint, the learner its policy. Both bags (the killed learner's,
    which train made whole before it exited) are read by rosbags and hold, for each arm,
    every episode id in order: none skipped except at most one at the learner's crash (an
    episode whose end was in the batch the learner died with), every completed one 50 steps
    long and truncated.
    """
    run_dir = tmp_path / 'run'
    # --separate: each node a process of its own, so that each can be killed alone
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir), '--separate',
           '--no-progress', '--total-steps', str(KILL_STEPS), '--eval-episodes', '10',
           '--restart-delay', '0.1', f'critic_node.checkpoint_every={CHECKPOINT_EVERY}',
           f'learner_node.checkpoint_every={CHECKPOINT_EVERY}']
    proc = subprocess.Popen(cmd, env=env(GRAPH), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    killed_at = {}
    try:
        deadline = time.monotonic() + 600
        for threshold, node in KILLS:
            row = wait_for_progress(proc, run_dir, deadline, threshold)
            pids = node_pids(run_dir, node)
            assert len(pids) == 1, (node, pids)
            killed_at[node] = int(row['policy_version'])
            os.kill(pids[0], signal.SIGKILL)
        text = proc.communicate(timeout=600)[0]
    finally:
        kill_run(proc, run_dir)
    assert proc.returncode == 0, text[-3000:]
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['total_steps'] >= KILL_STEPS
    for _, node in KILLS:
        assert f'{node} exited with code -9; restarting' in text
        assert summary['restarts'][node] == 1
    logs = {n: (run_dir / 'logs' / f'{n}.log').read_text() for _, n in KILLS}
    assert 'the simulator of actor 0 restarted' in logs['learner_node']
    assert 'resumed V from' in logs['critic_node']
    # the restarted learner continues from its newest checkpoint (one every CHECKPOINT_EVERY
    # versions): at least the last one before the version read just before the kill
    resumed = [int(v) for v in re.findall(r'resumed policy version (\d+)',
                                          logs['learner_node'])]
    assert len(resumed) == 1, resumed
    resumed, every = resumed[0], CHECKPOINT_EVERY
    assert resumed % every == 0 and resumed >= killed_at['learner_node'] // every * every > 0
    # the policy version rises by one per update. The killed learner may have flushed rows
    # past that checkpoint (progress.csv is flushed every second and at each checkpoint):
    # then the restarted learner's first row, resumed + 1, is one drop. When the kill came
    # before any such row was flushed there is none (a clean-clone CI run saw this once).
    versions = [int(r['policy_version']) for r in read_progress(run_dir / 'progress.csv')]
    drops = [i for i in range(1, len(versions)) if versions[i] != versions[i - 1] + 1]
    assert len(drops) <= 1, drops
    assert resumed + 1 in versions and versions[-1] == summary['policy_version']
    if drops:
        assert versions[drops[0]] == resumed + 1 and versions[drops[0] - 1] > resumed
        assert versions[-1] > max(versions[:drops[0]])
    # bags: the killed learner's (made whole by train, as ros2 bag reindex would) and the
    # new one's
    assert f"made {run_dir / 'bag'} whole" in text
    eps = episodes_of(run_dir / 'bag') + episodes_of(run_dir / 'bag_1')
    n_envs = 64
    cut = [e for e in eps if e['cut_short']]
    done = [e for e in eps if not e['cut_short']]
    assert all(e['length'] == 50 and e['truncated'] == 1.0 for e in done)
    # the episodes open when the simulator died (none if it died on an episode boundary)
    # are in the bag as cut short, and so are at most those of the actor and learner kills
    at_sim_restart = int(re.search(r'(\d+) open episodes marked cut short',
                                   logs['learner_node']).group(1))
    assert at_sim_restart <= len(cut) <= 3 * n_envs
    sim_restarts = skipped = 0
    for arm in range(n_envs):
        ids = [int(e['episode_id']) for e in eps if e['arm'] == arm]
        assert ids[0] == arm
        for prev, cur in zip(ids, ids[1:]):
            if cur == arm:
                sim_restarts += 1                   # ids start again: a new simulator
            elif cur == prev + 2 * n_envs:
                skipped += 1
            else:
                assert cur == prev + n_envs, (arm, prev, cur)
    assert sim_restarts == n_envs                   # every arm saw the restart once
    assert skipped <= n_envs                        # at most one per arm, at the crash
    assert len(done) > 5 * n_envs


# --- SIGTERM and SIGINT of each node in one run ---------------------------------------------

# SIGKILL of each node is test_sigkill_of_each_node_mid_run's (with more checked after it);
# this run took it as a third round until issue 34, 4 of its 12 stops, about 30 s.
SIGNALS = (signal.SIGTERM, signal.SIGINT)
STOPS = [(node, sig) for sig in SIGNALS
         for node in ('sim_node', 'actor_node', 'critic_node', 'learner_node')]
# 10 updates of 512 steps between stops (25,000, then 10,240 until issue 34), and 40 after
# the last: a learner that reaches total_steps as its stop comes exits as done, not stopped
# (with 10 after it, 3.5 s here, that happened in one run of three)
STOP_EVERY = 5_120
STOP_TAIL = 20_480


def full_mcap_check(path):
    """Read an MCAP file as a strict reader does: every record and CRC, the summary, all data."""
    from mcap.reader import make_reader
    from mcap.stream_reader import StreamReader
    with open(path, 'rb') as f:
        records = list(StreamReader(f, skip_magic=False, validate_crcs=True).records)
    assert type(records[-1]).__name__ == 'Footer', (path, type(records[-1]).__name__)
    assert any(type(r).__name__ == 'DataEnd' for r in records), path
    with open(path, 'rb') as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, path
        count = sum(1 for _ in reader.iter_messages())
    assert count == summary.statistics.message_count, path


def bag_dirs(run_dir):
    """Return the learner's bag directories of a run in the order they were written."""
    return sorted(run_dir.glob('bag*'), key=lambda p: int(p.name.partition('_')[2] or 0))


@pytest.mark.e2e
@pytest.mark.slow
def test_sigterm_and_sigint_of_each_node_mid_run(tmp_path):
    """
    Stop each node mid-run with SIGTERM, then each with SIGINT.

    SIGTERM is what ``ros2 launch`` escalates to, and what docker and systemd send; it must
    do what Ctrl-C does: the node closes its bag whole, writes its checkpoint, exits with 0
    and prints no traceback. The supervisor restarts every node that stopped before the
    learner finished (a learner's exit code 0 means done only when it learned
    ``total_steps``). The run finishes; every MCAP file of a learner stopped by SIGTERM or
    SIGINT passes the mcap reader's full validation without reindex.
    """
    run_dir = tmp_path / 'run'
    total = STOP_EVERY * len(STOPS) + STOP_TAIL
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir), '--separate',
           '--no-progress', '--total-steps', str(total), '--eval-episodes', '10',
           '--max-restarts', str(len(SIGNALS)), '--restart-delay', '0.1']
    proc = subprocess.Popen(cmd, env=env(GRAPH), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 900
        for k, (node, sig) in enumerate(STOPS):
            wait_for_progress(proc, run_dir, deadline, STOP_EVERY * (k + 1))
            pids = node_pids(run_dir, node)
            while len(pids) != 1:                   # restarted a moment ago, not up yet
                assert time.monotonic() < deadline and proc.poll() is None, (node, pids)
                time.sleep(0.2)
                pids = node_pids(run_dir, node)
            os.kill(pids[0], sig)
        text = proc.communicate(timeout=900)[0]
    finally:
        kill_run(proc, run_dir)
    assert proc.returncode == 0, text[-3000:]
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['total_steps'] >= total
    for node in ('sim_node', 'actor_node', 'critic_node', 'learner_node'):
        assert summary['restarts'][node] == len(SIGNALS), (node, summary['restarts'])
        assert text.count(f'{node} exited with code 0; restarting') == 2, text[-3000:]
        log = (run_dir / 'logs' / f'{node}.log').read_text()
        assert 'Traceback' not in log, log[-3000:]
    bags = bag_dirs(run_dir)
    assert len(bags) == 3, bags                  # the first learner's, then one per restart
    for bag in bags:
        files = sorted(bag.glob('*.mcap'))
        assert files, bag
        for f in files:
            full_mcap_check(f)
        Reader(bag).open()
    # each restarted simulator drew new episodes: a seed of its own, logged
    sim_log = (run_dir / 'logs' / 'sim_node.log').read_text()
    seeds = re.findall(r'dt [0-9.]+ s, seed (\d+)', sim_log)
    assert len(seeds) == 3 and len(set(seeds)) == 3 and seeds[0] == '0', seeds
    # the learner saved a checkpoint at each of its two clean stops and resumed from it
    resumed = re.findall(r'resumed policy version (\d+)',
                         (run_dir / 'logs' / 'learner_node.log').read_text())
    assert len(resumed) == 2, resumed


@pytest.mark.e2e
@pytest.mark.slow
def test_sigterm_stops_each_node_cleanly_with_sigint_ignored(tmp_path):
    """
    Nodes started as a non-interactive shell starts ``cmd &`` (SIGINT ignored), then SIGTERM.

    The graph trains; SIGTERM to each node (what docker, systemd and ``ros2 launch`` send)
    ends it with exit code 0 and no traceback, whatever callback was running: the loop
    stops after that callback (``runtime.stop_on_signals``). The learner
    closes its bag whole: every file passes the mcap reader's full validation.
    """
    run_dir = tmp_path / 'run'
    params = [f'run_dir:={run_dir}', 'num_envs:=8', 'total_steps:=100000000']
    ignore_sigint = lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)  # noqa: E731
    procs = {}
    for node in ('sim_node', 'actor_node', 'critic_node', 'learner_node'):
        args = [sys.executable, '-m', f'pg_node.ros.{node}', '--ros-args']
        for p in params:
            args += ['-p', p]
        log = open(tmp_path / f'{node}.log', 'w+')
        procs[node] = subprocess.Popen(args, env=env(GRAPH), cwd=REPO, stdout=log,
                                       stderr=subprocess.STDOUT, start_new_session=True,
                                       preexec_fn=ignore_sigint)
        procs[node].log = log
    try:
        deadline = time.monotonic() + 120
        while (last_progress(run_dir / 'progress.csv') or {}).get('env_steps', 0) < 20_000:
            assert time.monotonic() < deadline, 'the graph did not train'
            assert all(p.poll() is None for p in procs.values())
            time.sleep(0.2)
        for node, proc in procs.items():
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
    for node, proc in procs.items():
        proc.log.seek(0)
        log = proc.log.read()
        assert proc.returncode == 0, (node, log[-3000:])
        assert 'Traceback' not in log, (node, log[-3000:])
    files = sorted((run_dir / 'bag').glob('*.mcap'))
    assert files
    for f in files:
        full_mcap_check(f)
    Reader(run_dir / 'bag').open()


# --- a short soak ---------------------------------------------------------------------------

def test_soak_sends_garbage_only_when_every_restarted_node_has_spoken_since():
    """
    The soak's ``garbage`` fault waits for every node's diagnostics after its newest start.

    A learner killed just before would otherwise be sent its malformed batch while it is
    still importing torch: the message reaches nobody and the drop counter stays at 0.
    """
    from diagnostic_msgs.msg import DiagnosticStatus
    from bench import soak

    def diag(name):
        return DiagnosticArray(status=[DiagnosticStatus(name=name)])

    injector = soak.Injector.__new__(soak.Injector)     # its diagnostics book-keeping only
    injector.counters, injector.carried, injector.heard = {}, {}, {}
    for name in ('sim_node: simulated arms', 'actor_node 0', 'critic_node', 'learner_node'):
        injector.on_diag(diag(name))
    sup = SimpleNamespace(started_at=dict.fromkeys(soak.NODES, time.monotonic() - 60.0))
    assert soak.all_nodes_up(sup, injector)
    sup.started_at['learner_node'] = time.monotonic() + 1e-3     # restarted after it spoke
    assert not soak.all_nodes_up(sup, injector)
    time.sleep(2e-3)
    injector.on_diag(diag('learner_node'))
    assert soak.all_nodes_up(sup, injector)


@pytest.mark.e2e
@pytest.mark.slow
def test_two_minute_soak_keeps_memory_flat_and_bags_readable(tmp_path):
    """
    ``python -m bench.soak --minutes 2``: every fault recovered, bags readable, flat memory.

    Memory is judged per process from a baseline taken 20 s (the soak's ``--warmup``) after
    the process started, not from its start: in its first seconds a node imports torch and
    MuJoCo, builds its networks, discovers its DDS peers and fills its first buffers and bag
    chunks, a one-off growth of hundreds of MB that says nothing about a leak and would
    make any bound from process start meaningless. From the baseline on, a leak grows with
    the messages handled (tens of thousands here); more than 10% over the remaining 40 s
    or more would show it. A node restarted by a fault is a new process with its own
    baseline; the soak schedules the kills early so that the new processes are judged too.
    """
    res = subprocess.run([sys.executable, '-m', 'bench.soak', '--minutes', '2', '--json',
                          '--run-dir', str(tmp_path / 'soak')], env=env(GRAPH), cwd=REPO,
                         capture_output=True, text=True, timeout=600)
    assert res.stdout.strip(), res.stderr[-3000:]
    report = json.loads(res.stdout)
    kinds = [f['fault'] for f in report['faults']]
    nodes = ('sim_node', 'actor_node', 'critic_node', 'learner_node')
    for node in nodes:
        assert f'kill {node}' in kinds and report['restarts'][node] >= 1
    assert 'garbage' in kinds and any(k.startswith('stall') for k in kinds)
    assert report['recovered'] == report['faults_injected'], report['faults']
    assert not report['failed']
    assert len(report['bags']) >= 2                 # the killed learner's and the new one's
    assert report['all_bags_readable'], report['bags']
    assert all(b['episodes'] > 0 for b in report['bags'])
    # every malformed message was dropped and counted by the node it was sent to (the
    # actor may never read a malformed transition that the simulator's next one superseded
    # in its keep-last-1 queue: that one is not counted, see bench.soak.Injector.garbage)
    rounds = kinds.count('garbage')
    dropped = report['malformed_reported_dropped']
    assert report['malformed_sent']['commands'] == 3 * rounds
    for key in ('commands_dropped_size', 'commands_dropped_nonfinite',
                'commands_dropped_absurd', 'rollouts_dropped', 'dropped_batches',
                'weights_dropped'):
        assert dropped[key] == rounds, dropped
    assert dropped['transitions_dropped'] <= report['malformed_sent']['transitions']
    judged = [m for m in report['memory'] if m['judged']]
    assert {m['node'] for m in judged} == set(nodes)
    assert all(m['growth_pct'] <= 10.0 for m in judged), report['memory']
    assert report['ok'] and res.returncode == 0


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGHUP, signal.SIGINT],
                         ids=['SIGTERM', 'SIGHUP', 'SIGINT-inherited-ignored'])
def test_signal_to_train_alone_stops_every_node(tmp_path, sig):
    """
    ``kill``/``timeout`` signal the bring-up alone, not the nodes' sessions: it stops them.

    Before this was handled, a SIGTERM killed ``train`` at once and left its four nodes
    running (each in a session of its own), busy with nobody to stop them. The SIGINT case
    starts ``train`` as ``train &`` in a script does, with SIGINT ignored, which Python
    keeps: a ``kill -INT`` was lost on it while the nodes (rclpy) take SIGINT in any case.
    """
    run_dir = tmp_path / 'run'
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir),
           '--no-progress', '--total-steps', '10000000', '--eval-episodes', '2']
    as_if_started_with_amp = (lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) \
        if sig == signal.SIGINT else None
    proc = subprocess.Popen(cmd, env=env(GRAPH), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True,
                            preexec_fn=as_if_started_with_amp)
    try:
        wait_for_progress(proc, run_dir, time.monotonic() + 240)
        # train's default: sim_and_actor and critic_and_learner
        assert len(node_pids(run_dir)) == 2
        os.kill(proc.pid, sig)                 # the bring-up only, as timeout(1) does
        text = proc.communicate(timeout=120)[0]
    finally:
        kill_run(proc, run_dir)
    assert proc.returncode == 130, text[-3000:]         # interrupted, whatever the signal
    said = 'interrupted' if sig == signal.SIGINT else f'interrupted by signal {sig.name}'
    assert f'{said}: stopping the nodes' in text
    assert node_pids(run_dir) == []
    summary = json.loads((run_dir / 'summary.json').read_text())
    assert summary['interrupted'] and 0 < summary['total_steps'] < 10_000_000
    # a fresh run: all it learned, it learned in this session, rows written while stopping too
    n = summary['total_steps']
    assert summary['session_steps'] == n, summary
    assert f'{n} steps learned in this session ({n} in all)' in text, text[-3000:]


@pytest.mark.e2e
@pytest.mark.slow
def test_sigkill_of_train_stops_every_node_cleanly(tmp_path):
    """
    ``kill -9`` of the bring-up: the kernel sends its nodes SIGHUP and they stop cleanly.

    ``train`` cannot stop its nodes when it is killed by SIGKILL (or the OOM killer); they
    run in sessions of their own, so a killpg of ``train`` does not reach them either. Each
    node asked the kernel for SIGHUP on its supervisor's death (``stop_with_supervisor``):
    all stop, the learner's bag is whole without a reindex. Before, they ran on for good: a
    CI run's failed test left a graph that fed the next test's simulator foreign commands.
    """
    run_dir = tmp_path / 'run'
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir),
           '--no-progress', '--total-steps', '10000000', '--eval-episodes', '2']
    proc = subprocess.Popen(cmd, env=env(GRAPH), cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        wait_for_progress(proc, run_dir, time.monotonic() + 240)
        pids = node_pids(run_dir)
        assert len(pids) == 2                  # sim_and_actor and critic_and_learner
        os.killpg(proc.pid, signal.SIGKILL)    # train and its group; the nodes have their own
        proc.wait(timeout=30)
        deadline = time.monotonic() + 60
        while node_pids(run_dir) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert node_pids(run_dir) == [], log_tails(run_dir)
    finally:
        kill_run(proc, run_dir)
    for log in (run_dir / 'logs').glob('*.log'):
        assert 'Traceback' not in log.read_text(), log.read_text()[-3000:]
    # the cleanup ran: the learner's and the critic's checkpoints on the way out
    assert list((run_dir / 'checkpoints').glob('*.pt')) and (run_dir / 'critic').is_dir()
    files = sorted((run_dir / 'bag').glob('*.mcap'))
    assert files
    for f in files:
        full_mcap_check(f)


@pytest.mark.e2e
def test_a_failed_run_prints_only_what_exists(tmp_path):
    """
    A node that keeps dying fails the run: exit 1, no evaluation of nothing, no missing path.

    Before, a failed run printed 'return nan +/- nan over 0 episodes' and the paths of a bag
    and a curve that did not exist (issue 33).
    """
    run_dir = tmp_path / 'run'
    cmd = [sys.executable, '-m', 'pg_node', 'train', '--run-dir', str(run_dir),
           '--no-progress', '--total-steps', '10000000', '--max-restarts', '0']
    proc = subprocess.Popen(cmd, env=env(GRAPH), cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not node_pids(run_dir, 'sim_and_actor') and time.monotonic() < deadline:
            time.sleep(0.05)
        pids = node_pids(run_dir, 'sim_and_actor')
        assert pids, 'sim_and_actor did not start'
        os.kill(pids[0], signal.SIGKILL)        # at start-up: nothing learned yet
        out, err = proc.communicate(timeout=120)
    finally:
        kill_run(proc, run_dir)
    assert proc.returncode == 1, out + err
    assert 'training failed: sim_and_actor exited with code -9 1 times' in err, err
    assert 'Traceback' not in out + err and 'nan' not in out, out
    assert 'no policy to evaluate: the learner wrote no checkpoint' in out, out
    listed = [m.groups() for m in (re.match(r'(run dir|bag|checkpoint|summary|curve): +(.+)$', ln)
                                   for ln in out.splitlines()) if m]
    assert ('summary', str(run_dir / 'summary.json')) in listed, out
    assert all(Path(path).exists() for _, path in listed), listed
    assert not any(label == 'curve' for label, _ in listed)       # no update, no curve
    json.loads((run_dir / 'summary.json').read_text(),
               parse_constant=lambda c: pytest.fail(f'summary.json holds {c}'))
