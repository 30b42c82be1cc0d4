"""sim_node as a real process over DDS: joint states, commands, lock-step, services."""
import math
import os
from pathlib import Path
import re
import signal
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from domains import ros_domain
from geometry_msgs.msg import PointStamped
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.ros import command
from pg_node.ros import transition
from pg_node.sim.arm_task import ArmTask
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

REPO = Path(__file__).resolve().parent.parent
# one DDS domain per test process, so parallel runs do not hear each other
DOMAIN_ID = ros_domain(base=120, spread=100)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def start_node(tmp_path, *params, module='pg_node.ros.sim_node'):
    """Start ``python -m <module>`` (sim_node) in its own session with ``-p`` overrides."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONUNBUFFERED='1',
               PYTHONPATH=str(REPO), AMENT_PREFIX_PATH=os.environ.get(
                   'AMENT_PREFIX_PATH', str(Path(sys.executable).parent.parent)))
    args = [sys.executable, '-m', module, '--ros-args']
    # one arm and one message per step unless the test says otherwise (the shipped config
    # trains with 64 arms); a later -p wins over an earlier one
    for param in ('num_envs:=1', 'lock_step_groups:=1') + params:
        args += ['-p', param]
    return processes.start_logged(args, tmp_path / f'sim_node_{time.monotonic_ns()}.log', env)


stop_node = processes.stop_logged


class Client:
    """The test's side of the wire: subscribers, a command publisher, service clients."""

    def __init__(self):
        """Join the test's DDS domain."""
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('sim_node_test', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.joint_states, self.transitions, self.diagnostics, self.clocks = [], [], [], []
        self.node.create_subscription(JointState, '/joint_states',
                                      self.joint_states.append, 100)
        # as deep as the groups of a lock-step simulator: each group's message counts
        self.node.create_subscription(Float64MultiArray, '/pg_node/transition',
                                      self._on_transition,
                                      QoSProfile(depth=10, reliability=LATCHED.reliability,
                                                 durability=LATCHED.durability))
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics.append, 10)
        self.node.create_subscription(Clock, '/clock', self.clocks.append, 100)
        self.markers, self.targets = [], []
        self.node.create_subscription(MarkerArray, '/pg_node/markers', self.markers.append, 10)
        targets_qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(PointStamped, '/target', self.targets.append,
                                      targets_qos)
        self.commands = self.node.create_publisher(Float64MultiArray,
                                                   '/pg_node/commands', 10)

    def _on_transition(self, msg):
        self.transitions.append(transition.from_msg(msg))

    def spin_until(self, condition, timeout=15.0):
        """Spin until ``condition()`` holds; fail the test after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < deadline, 'timed out waiting for the node'
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds):
        """Spin for ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def wait_ready(self, *more):
        """Wait for the first transition, the command topic's match and ``more`` lists."""
        self.spin_until(lambda: self.transitions and self.commands.get_subscription_count()
                        and all(more))

    def send(self, values, answers='current'):
        """
        Publish one command: by default as the actor does, answering the last transition.

        ``answers=None`` sends a plain ros2_control-style command (no tag), a number tags it
        as the answer to that transition.
        """
        msg = Float64MultiArray(data=[float(v) for v in values])
        if answers == 'current':
            answers = self.transitions[-1].seq if self.transitions else None
        self.commands.publish(msg if answers is None else command.tag(msg, answers))

    def step(self, values, timeout=15.0):
        """Send a command and return the next transition (lock-step)."""
        seq = self.transitions[-1].seq
        self.send(values)
        self.spin_until(lambda: self.transitions[-1].seq > seq, timeout)
        assert self.transitions[-1].seq == seq + 1
        return self.transitions[-1]

    def call(self, srv_type, name, request, timeout=10.0):
        """Call a service and return its response."""
        client = self.node.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=timeout), name
        future = client.call_async(request)
        self.spin_until(future.done, timeout)
        return future.result()

    @staticmethod
    def values(msg):
        """Return one ``/diagnostics`` message's key/values as a dict."""
        return {kv.key: kv.value for kv in msg.status[0].values}

    def windows(self):
        """Return the key/values of every diagnostics window received, oldest first."""
        return [self.values(msg) for msg in self.diagnostics]

    def counters(self):
        """Return the latest diagnostics key/values as a dict (guard: ``self.diagnostics``)."""
        return self.values(self.diagnostics[-1])

    def close(self):
        """Leave the domain."""
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def client():
    c = Client()
    yield c
    c.close()


@pytest.mark.e2e
@pytest.mark.slow
def test_joint_states_commands_rejections_and_clean_shutdown(tmp_path, client):
    proc = start_node(tmp_path, 'num_envs:=2', 'diagnostics_rate:=5.0',
                      'lock_step_timeout:=0.5')
    try:
        names = ArmTask(resolve_model('reacher2')).spec.joint_names
        expected = [f'arm{i}/{name}' for i in range(2) for name in names]
        client.wait_ready(client.joint_states)
        first = client.joint_states[-1]
        assert list(first.name) == expected
        pos0 = np.array(first.position)
        for field in (first.position, first.velocity, first.effort):
            assert len(field) == 4 and np.all(np.isfinite(field))
        assert client.transitions[-1].obs.shape == (2, 10)
        # the targets (latched, one per arm) and the markers: all links, fingertips, targets
        client.spin_until(lambda: len(client.targets) >= 2 and client.markers)
        assert [t.header.frame_id for t in client.targets[:2]] == ['arm0', 'arm1']
        goals = client.transitions[-1].obs[:, 4:6]
        for i, target in enumerate(client.targets[:2]):
            np.testing.assert_allclose([target.point.x, target.point.y], goals[i], atol=1e-12)
        markers = {m.ns: m for m in client.markers[-1].markers}
        assert sorted(markers) == ['fingertips', 'links', 'targets']
        assert len(markers['fingertips'].points) == len(markers['targets'].points) == 2
        # two links per reacher2 arm, two points per segment of the LINE_LIST
        assert len(markers['links'].points) % 2 == 0 and len(markers['links'].points) >= 8
        assert all(np.isfinite([p.x for m in markers.values() for p in m.points]))
        # arm 1's target is drawn shifted by its grid offset from arm 0's
        shift = markers['targets'].points[1].x - markers['targets'].points[0].x
        assert shift == pytest.approx(0.7 + goals[1, 0] - goals[0, 0], abs=1e-9)

        n_js = len(client.joint_states)
        tr = client.step([1.0, -1.0, -1.0, 1.0])
        client.spin_until(lambda: len(client.joint_states) > n_js)
        moved = client.joint_states[-1]
        assert np.all(np.abs(np.array(moved.position) - pos0) > 1e-4)
        np.testing.assert_allclose(moved.effort, [200, -200, -200, 200])
        assert tr.reward.shape == (2,) and np.all(tr.reward < -2.0)  # both pay |a|^2 = 2

        seq = tr.seq
        client.send([0.5, 0.5, 0.5])                # wrong size
        client.send([0.5, float('nan'), 0.0, 0.0])  # non-finite
        client.send([0.0, float('inf'), 0.0, 0.0])
        # bytes that are no Float64MultiArray (the node subscribes raw and decodes itself)
        client.commands.publish(b'\x00\x01\x00\x00\x07\x00\x00\x00not a message')
        client.spin_until(lambda: client.diagnostics and int(
            client.counters()['commands_dropped_nonfinite']) >= 2 and int(
            client.counters()['commands_dropped_size']) >= 2)
        counters = client.counters()
        assert counters['commands_dropped_size'] == '2'
        assert counters['commands_dropped_nonfinite'] == '2'
        assert counters['steps'] == '1'
        assert client.diagnostics[-1].status[0].level == DiagnosticStatus.WARN
        assert client.transitions[-1].seq == seq            # nothing was stepped
        assert proc.poll() is None

        tr = client.step([5.0, 0.0, 0.0, 0.0])  # clipped to [-1, 1]
        assert tr.seq == seq + 1
        client.spin_until(lambda: client.joint_states[-1].effort[0] != 0.0)
        assert client.joint_states[-1].effort[0] == pytest.approx(200.0)
        client.spin_until(lambda: int(client.counters()['commands_clipped']) == 1)
        assert client.clocks[-1].clock.nanosec == 40_000_000  # 2 steps x 0.02 s
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert 'dropped a command of 3 values' in log and 'non-finite' in log
    assert 'dropped a command: not a serialised Float64MultiArray' in log
    assert 'Traceback' not in log


@pytest.mark.e2e
@pytest.mark.slow
def test_lock_step_through_the_node_equals_the_task_in_process(tmp_path, client):
    n, seed, steps = 3, 21, 60
    proc = start_node(tmp_path, f'num_envs:={n}', f'seed:={seed}', 'marker_rate:=0.0')
    acts = np.random.default_rng(4).uniform(-1, 1, (steps, n, 2))
    try:
        client.wait_ready()
        got = [client.transitions[-1]] + [client.step(a.ravel()) for a in acts]
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    task = ArmTask(resolve_model('reacher2'), num_envs=n, seed=seed)
    np.testing.assert_array_equal(got[0].obs, task.reset())
    assert got[0].seq == 0 and np.all(got[0].episode_step == 0)
    for k, act in enumerate(acts):
        obs, reward, terminated, truncated, info = task.step(act)
        tr = got[k + 1]
        assert tr.seq == k + 1
        np.testing.assert_array_equal(tr.obs, obs)
        np.testing.assert_array_equal(tr.reward, reward)
        np.testing.assert_array_equal(tr.truncated, truncated)
        np.testing.assert_array_equal(tr.terminated, terminated)
        np.testing.assert_array_equal(tr.final_obs, info['final_obs'])
        np.testing.assert_array_equal(tr.episode_id, info['episode_id'])
        np.testing.assert_array_equal(tr.episode_step, info['episode_step'])
    assert got[50].truncated.all() and np.all(got[50].episode_id == [3, 4, 5])


@pytest.mark.e2e
def test_lock_step_round_trips_in_the_diagnostics_and_the_log(tmp_path, client):
    """
    Every accepted answer's round trip is kept, and it is the interval it claims to be.

    The client holds some answers back 40 ms. With the client's own clock only: the sim's
    round trip k (transition k published -> its answer arrived) is at least the client's
    hold (the answer left after ``sent[k]``, the transition was published before the client
    had it, ``got[k]``) and at most ``got[k + 1] - sent[k - 1]``.
    """
    log = tmp_path / 'trips.npy'
    proc = start_node(tmp_path, f'round_trip_log:={log}', 'diagnostics_rate:=5.0',
                      'lock_step_timeout:=5.0')
    got, sent = [], []
    try:
        # a first window received: the diagnostics are matched both ways before any trip
        client.wait_ready(client.diagnostics)
        got.append(time.perf_counter_ns())
        for k in range(12):
            if k % 2:
                time.sleep(0.04)
            if k == 5:
                client.send([0.3, 0.3], answers=None)   # not an answer: no round trip
            sent.append(time.perf_counter_ns())
            client.step([0.1, -0.1])
            got.append(time.perf_counter_ns())
        # until the windows hold 12 trips (a loaded machine can delay the last window)
        client.spin_until(lambda: sum(int(w['round_trips']) for w in client.windows()) >= 12)
        client.spin_for(0.3)                              # a window too many would show
    finally:
        rc, text = stop_node(proc)
    assert rc == 0, text
    assert '12 lock-step round trips written to' in text
    trips = np.load(log)
    assert trips.dtype == np.int64 and trips.size == 12
    for k in range(1, 12):
        assert sent[k] - got[k] <= trips[k] <= got[k + 1] - sent[k - 1], k
        assert trips[k] >= 40e6 if k % 2 else True
    windows = client.windows()
    assert sum(int(w['round_trips']) for w in windows) == 12
    for w in windows:
        if int(w['round_trips']):
            assert 0 < float(w['round_trip_ms_median']) <= float(w['round_trip_ms_p99'])
        else:
            assert w['round_trip_ms_median'] == w['round_trip_ms_p99'] == '-'


@pytest.mark.e2e
def test_a_round_trip_log_in_a_missing_directory_is_refused_at_start(tmp_path):
    proc = start_node(tmp_path, f'round_trip_log:={tmp_path}/no/such/dir/trips.npy')
    rc = proc.wait(timeout=60)
    _, text = stop_node(proc)
    assert rc == 2, text
    missing = tmp_path / 'no' / 'such' / 'dir'
    assert text.strip().splitlines()[-1] == (
        f"configuration error: parameter 'sim_node.round_trip_log': '{missing}/trips.npy' "
        f"is not allowed: no directory '{missing}' to write it in")


@pytest.mark.e2e
def test_a_command_interface_the_arm_lacks_is_refused_at_start(tmp_path):
    """reacher2 has motors: commands in rad (position servos) cannot drive it."""
    proc = start_node(tmp_path, 'mode:=real_time', 'command_interface:=position')
    rc = proc.wait(timeout=60)
    _, text = stop_node(proc)
    assert rc == 2, text
    assert text.strip().splitlines()[-1] == (
        "configuration error: parameter 'sim_node.command_interface': command_interface "
        "position needs position actuators; this arm's are joint0 (motor), joint1 (motor) "
        '(use command_interface effort, or an arm imported with --actuator position)')


@pytest.mark.e2e
def test_lock_step_steps_only_on_the_answer_to_its_transition(tmp_path, client):
    """A second publisher of valid commands cannot step a lock-step simulator out of turn."""
    proc = start_node(tmp_path, 'lock_step_timeout:=5.0')
    try:
        client.wait_ready()
        tr = client.step([0.1, 0.1])
        client.send([0.2] * 2, answers=None)            # ros2_control-style, no tag
        client.send([0.2] * 2, answers=tr.seq - 1)      # a late duplicate
        client.send([0.2] * 2, answers=tr.seq + 3)      # another actor's numbering
        client.spin_until(lambda: client.diagnostics and int(
            client.counters()['commands_ignored']) == 3)
        assert client.transitions[-1].seq == tr.seq     # none of them stepped it
        assert client.counters()['steps'] == '1'
        after = client.step([0.1, 0.1])       # the answer still does
        assert after.seq == tr.seq + 1
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert 'ignored a command for transition None' in log


def latest_target(received, arm):
    """Return the x, y of the newest ``/target`` message of ``arm`` received (NaN: none)."""
    mine = [t.point for t in received if t.header.frame_id == f'arm{arm}']
    return [mine[-1].x, mine[-1].y] if mine else [math.nan, math.nan]


@pytest.mark.e2e
def test_a_target_subscriber_that_joins_late_gets_every_current_target(tmp_path, client):
    """Targets are published while someone listens; one who joins gets them all at once."""
    for sub in [s for s in client.node.subscriptions if s.topic_name == '/target']:
        client.node.destroy_subscription(sub)     # nobody listens to /target at first
    proc = start_node(tmp_path, 'num_envs:=3', 'max_episode_steps:=2', 'lock_step_timeout:=5.0')
    try:
        client.wait_ready()
        for _ in range(5):                  # two episode starts after the first
            tr = client.step([0.0] * 6)
        late = []
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        client.node.create_subscription(PointStamped, '/target', late.append, qos)
        client.spin_until(lambda: len(late) >= 3)
        assert [t.header.frame_id for t in late[:3]] == ['arm0', 'arm1', 'arm2']
        for i, target in enumerate(late[:3]):   # the goals of the episodes running now
            np.testing.assert_allclose([target.point.x, target.point.y], tr.obs[i, 4:6],
                                       atol=1e-12)
        old = tr.obs[:3, 4:6].copy()
        # and the next episode's targets come as its episodes start
        tr = client.step([0.0] * 6)
        assert np.all(tr.episode_step == 0)
        new = tr.obs[:3, 4:6]
        client.spin_until(lambda: all(np.allclose(latest_target(late, i), new[i], atol=1e-12)
                                      for i in range(3)))
        # before them, only the current targets again: the join can be answered twice, by
        # the matched event and by the reader count (a suite run saw both), never stale
        for target in late:
            i = int(target.header.frame_id.removeprefix('arm'))
            xy = [target.point.x, target.point.y]
            assert np.allclose(xy, old[i], atol=1e-12) or np.allclose(xy, new[i], atol=1e-12)
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log


@pytest.fixture
def paused_sim(client, monkeypatch):
    """
    Return a factory of a paused 3-arm sim_node in the test's process and DDS participant.

    Paused, it starts no episodes, so only a join can make it publish targets; nobody
    subscribes ``/target`` at first. ``lose_matched_events`` replaces the matched-event
    callback by one that does nothing.
    """
    from pg_node.ros.sim_node import SimNode
    from rclpy.parameter import Parameter
    for sub in [s for s in client.node.subscriptions if s.topic_name == '/target']:
        client.node.destroy_subscription(sub)
    nodes = []

    def make(lose_matched_events=False):
        if lose_matched_events:
            monkeypatch.setattr(SimNode, 'on_target_matched', lambda self, info: None)
        node = SimNode(context=client.context, parameter_overrides=[
            Parameter('num_envs', value=3), Parameter('start_paused', value=True)])
        client.executor.add_node(node)
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        client.executor.remove_node(node)
        node.task.close()
        node.destroy_node()


def late_target_subscriber(client):
    """Subscribe ``/target`` as a latecomer would; return the list its messages go to."""
    late = []
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client.node.create_subscription(PointStamped, '/target', late.append, qos)
    return late


def test_a_matched_event_without_a_count_change_still_serves_the_newcomer(client, paused_sim):
    """
    Fast DDS can report the first match with ``current_count_change`` 0; the count decides.

    It did so in CI: a subscriber that was there before the node got no targets.
    """
    from types import SimpleNamespace
    node = paused_sim()
    sent = []
    node.publish_targets = lambda arms, stamp: sent.append(list(arms))
    assert node.target_readers == 0
    node.on_target_matched(SimpleNamespace(current_count=1, current_count_change=0))
    assert sent == [[0, 1, 2]] and node.target_readers == 1
    node.on_target_matched(SimpleNamespace(current_count=1, current_count_change=0))
    assert sent == [[0, 1, 2]]             # nobody new
    node.on_target_matched(SimpleNamespace(current_count=1, current_count_change=1))
    assert sent == [[0, 1, 2]] * 2         # one left, one joined


def test_a_late_target_subscriber_is_served_even_when_the_matched_event_is_lost(
        client, paused_sim):
    """With no matched event at all, the subscriber-count watch gives the targets."""
    node = paused_sim(lose_matched_events=True)
    client.spin_for(0.3)
    late = late_target_subscriber(client)
    client.spin_until(lambda: len(late) >= 3, timeout=5.0)
    assert [t.header.frame_id for t in late] == ['arm0', 'arm1', 'arm2']
    goals = node.task.target_pos()
    for i, target in enumerate(late):
        np.testing.assert_allclose([target.point.x, target.point.y], goals[i, :2])


@pytest.mark.e2e
@pytest.mark.slow
def test_lock_step_groups_step_on_their_own_commands_and_equal_one_step_of_all(
        tmp_path, client):
    """
    Three arms in two groups (arm 0; arms 1-2): each group's transition and command alone.

    Group ``g``'s seq numbers are ``2k + g``; a command steps only its group, must have its
    group's size, and answers only the group's current transition; after both groups have
    stepped with their halves of a command, the arms are where one step of all of them with
    the whole command puts them, to the bit.
    """
    proc = start_node(tmp_path, 'num_envs:=3', 'lock_step_groups:=2', 'lock_step_timeout:=5.0',
                      'diagnostics_rate:=5.0')
    ref = ArmTask(resolve_model('reacher2'), num_envs=3, seed=0)
    try:
        client.spin_until(lambda: len({t.seq for t in client.transitions}) >= 2)
        first = {t.seq: t for t in client.transitions}
        assert sorted(first) == [0, 1]
        assert (first[0].arms, first[1].arms) == (slice(0, 1), slice(1, 3))
        assert first[0].groups == first[1].groups == 2
        np.testing.assert_array_equal(np.concatenate([first[0].obs, first[1].obs]),
                                      ref.reset())
        rng = np.random.default_rng(1)
        current = {0: 0, 1: 1}
        for k in range(1, 4):
            act = rng.uniform(-1, 1, (3, 2))
            got = {}
            for g, arms in ((1, slice(1, 3)), (0, slice(0, 1))):     # any order
                client.send(act[arms].ravel(), answers=current[g])
                client.spin_until(lambda: client.transitions[-1].seq == 2 * k + g)
                current[g] = 2 * k + g
                got[g] = client.transitions[-1]
                assert got[g].arms == arms
            obs, reward = ref.step(act)[:2]
            np.testing.assert_array_equal(np.concatenate([got[0].obs, got[1].obs]), obs)
            np.testing.assert_array_equal(np.concatenate([got[0].reward, got[1].reward]),
                                          reward)
        client.send([0.0] * 4, answers=current[0])      # group 0 has one arm: 2 values
        client.send([0.0] * 2, answers=current[0] - 2)  # an answer to its previous one
        client.spin_for(0.5)
        assert client.transitions[-1].seq == current[0]
        client.spin_until(lambda: client.diagnostics
                          and client.counters()['commands_dropped_size'] == '1'
                          and client.counters()['commands_ignored'] == '1')
        assert client.counters()['steps'] == '3'        # control steps: rounds of both
    finally:
        ref.close()
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert 'expected 2 (1 arms of group 0 x 2 actuators)' in log


@pytest.mark.e2e
@pytest.mark.slow
def test_services_pause_step_reset_and_lock_step_timeout(tmp_path, client):
    proc = start_node(tmp_path, 'lock_step_timeout:=0.3', 'model:=arm5_3d')
    try:
        client.wait_ready()
        client.step([0.5] * 5)
        assert client.call(SetBool, '/sim_node/set_pause', SetBool.Request(data=True)).success
        seq = client.transitions[-1].seq
        client.send([0.2] * 5)
        client.spin_for(0.8)  # held, not stepped, and no re-sends while paused
        assert client.transitions[-1].seq == seq
        response = client.call(Trigger, '/sim_node/step_simulation', Trigger.Request())
        assert response.success
        client.spin_until(lambda: client.transitions[-1].seq == seq + 1)
        assert client.transitions[-1].reward[0] < -0.2  # penalty of the held 0.2 command
        response = client.call(Trigger, '/sim_node/reset_world', Trigger.Request())
        assert response.success
        client.spin_until(lambda: client.transitions[-1].seq == seq + 2)
        tr = client.transitions[-1]
        assert tr.episode_step[0] == 0 and tr.episode_id[0] == 1 and tr.reward[0] == 0.0
        # re-seeded: the episode it started with, again (play's repeatable episodes)
        np.testing.assert_array_equal(tr.obs, client.transitions[0].obs)
        assert client.call(SetBool, '/sim_node/set_pause', SetBool.Request(data=False)).success
        refused = client.call(Trigger, '/sim_node/step_simulation', Trigger.Request())
        assert not refused.success
        # no command: the last transition is re-sent with the same seq
        count = len(client.transitions)
        client.spin_until(lambda: len(client.transitions) >= count + 2, timeout=5.0)
        assert {t.seq for t in client.transitions[count:]} == {seq + 2}
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log


@pytest.mark.e2e
@pytest.mark.slow
def test_real_time_mode_runs_on_its_own_and_drops_to_zero_torque(tmp_path, client):
    proc = start_node(tmp_path, 'mode:=real_time', 'command_timeout:=0.3')
    try:
        client.spin_until(lambda: len(client.clocks) > 10
                          and client.commands.get_subscription_count())
        client.send([1.0, 1.0], answers=None)      # a plain command drives it in real time
        client.spin_until(lambda: client.joint_states[-1].effort[0] == 200.0)
        # the command is held for a while, then the arm gets zero torque
        client.spin_until(lambda: client.joint_states[-1].effort[0] == 0.0, timeout=5.0)
        stamps = [c.clock.sec + 1e-9 * c.clock.nanosec for c in client.clocks]
        assert np.all(np.diff(stamps) > 0)
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log


@pytest.mark.e2e
def test_real_time_logs_each_finished_episode_with_its_final_distance(tmp_path, client):
    """The stand-in says how well whatever drives it reaches: a line per episode, a mean."""
    proc = start_node(tmp_path, 'mode:=real_time', 'max_episode_steps:=5',
                      'real_time_factor:=5.0', 'num_envs:=2')
    lines = re.compile(r'episode (\d+) \(arm (\d)\): final fingertip distance ([\d.]+) m')
    try:
        client.spin_until(lambda: len(lines.findall(proc_log(tmp_path))) >= 4, timeout=60)
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    seen = lines.findall(log)
    assert {(int(ep), int(arm)) for ep, arm, _ in seen[:4]} == {(0, 0), (1, 1), (2, 0), (3, 1)}
    assert all(0 < float(d) < 1 for _, _, d in seen)


def proc_log(tmp_path) -> str:
    """Return what the node started in ``tmp_path`` has logged so far."""
    return ''.join(p.read_text() for p in tmp_path.glob('sim_node_*.log'))


@pytest.mark.e2e
def test_real_time_takes_trajectories_as_jazzys_jtc_and_holds_after_its_cmd_timeout(
        tmp_path, client):
    """
    The stand-in's arm_controller/joint_trajectory: JTC's acceptance rules, then its hold.

    Rules and hold: ros2_controllers (jazzy ed360c97d)
    joint_trajectory_controller.cpp:1717-1730 (rule 5), 350-369 and 2063-2086 (cmd_timeout:
    zero effort with zero gains); pg_node.control.jtc encodes them.
    """
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
    pub = client.node.create_publisher(JointTrajectory, '/arm_controller/joint_trajectory', 10)

    def send(effort, velocities=(), names=('joint1', 'joint0')):   # one arm: plain names
        # names in another order than the controller's: JTC sorts them (jtc.cpp:1603-1650)
        point = JointTrajectoryPoint(positions=[0.0, 0.0], effort=list(effort),
                                     velocities=list(velocities))
        pub.publish(JointTrajectory(joint_names=list(names), points=[point]))

    proc = start_node(tmp_path, 'mode:=real_time', 'command_interface:=effort',
                      'jtc_cmd_timeout:=0.5', 'diagnostics_rate:=10.0')
    try:
        client.spin_until(lambda: len(client.clocks) > 10 and pub.get_subscription_count())
        send([-50.0, 120.0])                    # joint1 -50, joint0 120 N m, applied at once
        client.spin_until(lambda: list(client.joint_states[-1].effort) == [120.0, -50.0])
        # the old policy_node message (measured velocities) is rejected by rule 5: no change
        send([0.0, 0.0], velocities=[0.5, 0.0])
        client.spin_until(lambda: client.diagnostics and
                          client.counters()['trajectories_rejected'] == '1')
        assert list(client.joint_states[-1].effort) == [120.0, -50.0]
        # silence: 0.5 s after the point, JTC's hold with zero gains, 0 N m
        client.spin_until(lambda: list(client.joint_states[-1].effort) == [0.0, 0.0],
                          timeout=5.0)
        client.spin_until(lambda: client.counters()['trajectory_timeouts'] == '1')
        assert client.counters()['trajectories_received'] == '2'
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert ('rejected a trajectory on arm_controller/joint_trajectory as a joint trajectory '
            'controller would: rule 5: velocity of the last trajectory point of joint '
            'joint1 is not zero') in log
    assert log.count('aborted due to command timeout') == 1


def _sim_and_actor(tmp_path, *params):
    return start_node(tmp_path, 'num_envs:=2', *params, module='pg_node.ros.sim_and_actor')


@pytest.mark.e2e
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_sim_and_actor_share_a_process_and_both_stop_cleanly(tmp_path, client, sig):
    """Both nodes up in one process (the actor's subscription matches); a signal stops both."""
    log = tmp_path / 'trips.npy'
    proc = _sim_and_actor(tmp_path, f'round_trip_log:={log}')
    try:
        # the actor subscribes the transitions; without weights it does not answer
        client.wait_ready()
        client.spin_until(lambda: client.node.count_subscribers('/pg_node/transition') >= 2)
        assert proc.poll() is None
        os.killpg(proc.pid, sig)
        assert proc.wait(timeout=20) == 0
    finally:
        _, text = stop_node(proc)
    assert '[sim_node]: lock_step: 2 x reacher2' in text
    assert '[actor_node]: actor 0: 2 arms' in text
    assert '0 lock-step round trips written to' in text and np.load(log).size == 0
    assert 'Traceback' not in text


@pytest.mark.e2e
@pytest.mark.parametrize('hop', [True, False], ids=['in-process-hop', 'over-dds'])
def test_sim_and_actor_publish_every_transition_and_command_for_others(tmp_path, client, hop):
    """
    A subscriber in another process gets every transition and command of the pair.

    With ``in_process_hop`` the two nodes hand them over inside the process and publish
    them for the others; without it they go over DDS. The test plays the learner: each
    policy version lets the actor answer one rollout of ``n_steps`` transitions.
    """
    from pg_node.common.params import defaults
    from pg_node.rl.learner import make_policy
    from pg_node.rl.weights import flatten_state
    from pg_node.ros import messages
    from pg_node.ros import table_msg
    n_steps, versions = 4, 3
    proc = _sim_and_actor(tmp_path, f'in_process_hop:={str(hop).lower()}',
                          f'n_steps:={n_steps}')
    commands = []
    sub = client.node.create_subscription(Float64MultiArray, '/pg_node/commands',
                                          commands.append, 100)
    pub_w = client.node.create_publisher(Float64MultiArray, '/pg_node/policy_weights', LATCHED)
    try:
        client.spin_until(lambda: client.transitions and sub.get_publisher_count()
                          and pub_w.get_subscription_count(), timeout=30.0)
        client.spin_for(0.5)          # the nodes' writers match the test's readers too
        cfg = {**defaults('learner_node'), **defaults('actor_node')}
        layout, vec = flatten_state(make_policy(10, 2, cfg))     # reacher2's policy
        for version in range(versions):
            pub_w.publish(table_msg.to_msg(*messages.pack_weights(layout, vec, version, 0)))
            answered = n_steps * (version + 1)
            client.spin_until(lambda: len(commands) >= answered
                              and len(client.transitions) >= answered + 1, timeout=30.0)
        client.spin_for(0.3)          # nothing more, nothing twice
    finally:
        _, text = stop_node(proc)
    total = n_steps * versions
    # every one, in order (transition 0 comes again while the actor waits for weights:
    # sim_node's lock_step_timeout re-sends it)
    seqs = [tr.seq for tr in client.transitions]
    assert seqs == sorted(seqs) and set(seqs) == set(range(total + 1)), seqs
    assert [command.transition_of(m) for m in commands] == list(range(total))
    assert all(len(m.data) >= 2 * 2 for m in commands)           # 2 arms x 2 actuators
    said = 'handed to actor_node inside the process (in_process_hop)' in text
    assert said == hop, text
    assert 'Traceback' not in text and 'ignored a command' not in text, text


@pytest.mark.e2e
def test_sim_and_actor_refuses_a_bad_actor_parameter_in_one_line(tmp_path):
    proc = _sim_and_actor(tmp_path, 'n_steps:=0')
    assert proc.wait(timeout=60) == 2
    _, text = stop_node(proc)
    assert text.strip().splitlines()[-1].startswith(
        "configuration error: parameter 'actor_node.n_steps': 0 is not allowed"), text
    assert 'Traceback' not in text


@pytest.mark.e2e
def test_an_arm_whose_physics_blows_up_is_reset_counted_and_the_steps_go_on(tmp_path, client):
    """
    Torques far too strong: the arm's episode ends and it starts a new one, counted.

    The count is in /diagnostics and a WARN in the log; every transition stays on the wire.

    Before, the observation left the wire's bound and the actor dropped each re-sent
    transition: the run stalled in silence.
    """
    from pg_node.common.bounds import MAX_ABS
    model = tmp_path / 'strong.xml'
    strong = resolve_model('reacher2').read_text().replace('gear="200.0"', 'gear="2e12"')
    model.write_text(strong)
    proc = start_node(tmp_path, f'model:={model}', 'diagnostics_rate:=5.0')
    try:
        client.wait_ready()
        ended = 0
        for _ in range(6):
            tr = client.step([1.0, -1.0])
            assert np.abs(tr.obs).max() <= MAX_ABS
            ended += int(tr.terminated[0])
        assert ended >= 1
        client.spin_until(lambda: client.diagnostics
                          and int(client.counters().get('physics_resets', 0)) >= ended)
        assert client.diagnostics[-1].status[0].level == DiagnosticStatus.WARN
    finally:
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert 'the physics of arm 0 blew up' in log, log[-2000:]
