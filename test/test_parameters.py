"""
``ros2 param`` against pg_node's nodes: limits described, live changes applied, others refused.

The nodes run as real processes; the test calls their parameter services as ``ros2 param``
does (``rclpy``'s parameter client): describe, set, get.
"""
import os
from pathlib import Path
import sys
import time

from domains import ros_domain
from pg_node.common.params import params_for
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock

REPO = Path(__file__).resolve().parent.parent
DOMAIN_ID = ros_domain(base=40, spread=60)


class Client:
    """A node of its own context that asks a node's parameter services, as ``ros2 param``."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.node = rclpy.create_node('param_test_client', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.clock = []
        self.node.create_subscription(Clock, '/clock', self.on_clock, 100)

    def on_clock(self, msg):
        self.clock.append((time.monotonic(), msg.clock.sec + msg.clock.nanosec * 1e-9))

    def wait(self, future, timeout=20.0):
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), 'no answer from the node'
        return future.result()

    def params(self, node):
        client = AsyncParameterClient(self.node, node)
        assert client.wait_for_services(timeout_sec=30.0), f'{node} has no parameter services'
        # The services are discovered, but the node's answer may still find no reader of
        # ours (discovery runs each way on its own): ask a harmless question until one
        # comes back, so that the test's own requests all have a way back.
        end = time.monotonic() + 30.0
        while True:
            probe = client.list_parameters([], 1)
            self.executor.spin_until_future_complete(probe, timeout_sec=1.0)
            if probe.done():
                return client
            assert time.monotonic() < end, f'{node} answers no parameter request'

    def spin(self, seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def start(module, log_path, *params):
    args = [sys.executable, '-m', f'pg_node.ros.{module}', '--ros-args']
    for p in params:
        args += ['-p', p]
    env = dict(processes.child_env(DOMAIN_ID), AMENT_PREFIX_PATH=os.environ.get(
        'AMENT_PREFIX_PATH', sys.prefix))
    return processes.start_logged(args, log_path, env)


@pytest.fixture(scope='module')
def client():
    c = Client()
    yield c
    c.close()


def sim_rate(client, seconds=2.0):
    """Return simulated seconds per wall second over the next ``seconds``, from /clock."""
    client.spin(0.5)                        # what queued before now is not this window's
    client.clock.clear()
    client.spin(seconds)
    (w0, s0), (w1, s1) = client.clock[0], client.clock[-1]
    return (s1 - s0) / (w1 - w0)


@pytest.mark.e2e
def test_sim_node_describes_limits_applies_live_changes_and_refuses_the_rest(client, tmp_path):
    sim = start('sim_node', tmp_path / 'sim.log', 'mode:=real_time', 'num_envs:=2',
                'marker_rate:=0.0')
    try:
        params = client.params('/sim_node')
        described = {d.name: d for d in client.wait(params.describe_parameters(
            ['num_envs', 'real_time_factor', 'mode', 'marker_rate'])).descriptors}
        num_envs = described['num_envs']
        assert num_envs.read_only and num_envs.integer_range[0].from_value == 1
        rtf = described['real_time_factor']
        assert not rtf.read_only and rtf.floating_point_range[0].from_value == 0.0
        assert 'can change at run time' in rtf.description
        assert "one of 'lock_step', 'real_time'" in described['mode'].additional_constraints
        assert described['marker_rate'].floating_point_range[0].from_value == 0.0

        before = sim_rate(client)
        # read-only: refused by ROS, the value stays
        res = client.wait(params.set_parameters([Parameter('num_envs', value=3)])).results[0]
        assert not res.successful and 'read-only' in res.reason
        got = client.wait(params.get_parameters(['num_envs'])).values[0]
        assert got.integer_value == 2
        # live, out of the descriptor's range: refused by ROS
        res = client.wait(params.set_parameters(
            [Parameter('real_time_factor', value=-1.0)])).results[0]
        assert not res.successful and 'out of range' in res.reason
        # on the range's edge but not allowed (> 0): refused with the table's reason
        res = client.wait(params.set_parameters(
            [Parameter('real_time_factor', value=0.0)])).results[0]
        assert not res.successful and 'real_time_factor' in res.reason
        assert 'expected a float with 0.0 < value' in res.reason
        # live, allowed: applied, and the simulator runs 4x faster
        res = client.wait(params.set_parameters(
            [Parameter('real_time_factor', value=4.0)])).results[0]
        assert res.successful, res.reason
        after = sim_rate(client)
        assert 0.6 < before < 1.2, before
        assert after > 2.5 * before, (before, after)
    finally:
        code, log = processes.stop_logged(sim)
    assert code == 0, log[-2000:]
    assert 'parameter real_time_factor: 1.0 -> 4.0' in log


@pytest.mark.e2e
def test_learner_and_critic_apply_live_hyperparameters(client, tmp_path):
    run = f'run_dir:={tmp_path / "run"}'
    learner = start('learner_node', tmp_path / 'learner.log', run)
    critic = start('critic_node', tmp_path / 'critic.log', run)
    try:
        lp = client.params('/learner_node')
        res = client.wait(lp.set_parameters([Parameter('learning_rate', value=3e-4),
                                             Parameter('ent_coef', value=0.01)])).results
        assert all(r.successful for r in res), [r.reason for r in res]
        res = client.wait(lp.set_parameters([Parameter('algo', value='ppo')])).results[0]
        assert not res.successful and 'read-only' in res.reason
        # what would end or stretch the run from outside is read-only
        for name, value in (('total_steps', 10), ('exit_when_done', False)):
            res = client.wait(lp.set_parameters([Parameter(name, value=value)])).results[0]
            assert not res.successful and 'read-only' in res.reason, name
        res = client.wait(lp.set_parameters([Parameter('n_epochs', value=0)])).results[0]
        assert not res.successful
        # a setting the learner's update (a2c) lacks: refused, naming the ones it has; its
        # default given back (a `ros2 param load` of a dump) is accepted
        res = client.wait(lp.set_parameters([Parameter('clip_range', value=0.3)])).results[0]
        assert not res.successful and "algo 'a2c' has no clip_range" in res.reason
        assert 'its settings: learning_rate, optimizer, ent_coef' in res.reason
        res = client.wait(lp.set_parameters([Parameter('clip_range', value=0.2)])).results[0]
        assert res.successful, res.reason
        cp = client.params('/critic_node')
        res = client.wait(cp.set_parameters([Parameter('gamma', value=0.99)])).results[0]
        assert res.successful, res.reason
        res = client.wait(cp.set_parameters([Parameter('gamma', value=1.5)])).results[0]
        assert not res.successful and 'gamma' in res.reason
        res = client.wait(cp.set_parameters([Parameter('estimator', value='gae')])).results[0]
        assert not res.successful and 'read-only' in res.reason
    finally:
        logs = {name: processes.stop_logged(proc) for name, proc in
                (('learner', learner), ('critic', critic))}
    for name, (code, log) in logs.items():
        assert code == 0, (name, log[-2000:])
    assert 'parameter learning_rate: 0.001 -> 0.0003' in logs['learner'][1]
    assert 'parameter ent_coef: 0.0 -> 0.01' in logs['learner'][1]
    assert 'parameter gamma: 0.95 -> 0.99' in logs['critic'][1]


def test_every_parameter_is_live_or_read_only_with_its_range():
    """The descriptor of every table entry carries the range that the table checks."""
    from pg_node.common.param_schema import ConfigError
    from pg_node.ros.parameters import descriptor
    for node in ('sim_node', 'actor_node', 'critic_node', 'learner_node'):
        for name, param in params_for(node).items():
            d = descriptor(param)
            assert d.read_only == (not param.live), name
            assert d.additional_constraints == param.allowed()
            ranges = list(d.integer_range) + list(d.floating_point_range)
            if param.choices is not None or param.low is None:
                assert not ranges, name
                continue
            low = type(param.default)(ranges[0].from_value)
            assert low == param.low, name
            if param.low_inclusive:
                assert param.check(name, low) == low
            else:                               # the range's edge; the table refuses it
                with pytest.raises(ConfigError):
                    param.check(name, low)
    sim = params_for('sim_node')
    assert not sim['num_envs'].live and not sim['model'].live and sim['real_time_factor'].live
    learner = params_for('learner_node')
    assert learner['learning_rate'].live and not learner['algo'].live
    assert 'read-only' in descriptor(sim['mode']).description


@pytest.mark.parametrize('node', ['policy_node', 'sim_node'])
def test_a_node_run_by_hand_prints_its_parameters_for_help(node):
    """``policy_node --help`` (ros2 run, on a robot) lists each parameter and exits 0."""
    import subprocess
    from pg_node.common.params import params_for, POLICY_PARAMS
    table = POLICY_PARAMS if node == 'policy_node' else params_for(node)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, '-m', f'pg_node.ros.{node}', '--help'],
                          env=env, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and done.stderr == '', done.stderr
    assert done.stdout.startswith(f'usage: ros2 run pg_node {node}')
    for key, param in table.items():
        assert f'\n  {key} ({param.default!r}' in done.stdout, key
        assert ' '.join(param.description.split()[:4]) in done.stdout, key
