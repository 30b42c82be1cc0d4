"""
The velocity interface end to end (issue 46): a policy of velocity servos through policy_node.

reacher2 with velocity servos (u is 2 u rad/s, kv 10) is trained for one update in-process;
``sim_node`` (real time, ``command_interface:=velocity``) stands in for a robot with Jazzy's
joint trajectory controller on the velocity interface (``config/controllers/jtc_velocity.yaml``'s
flags), or with a forward velocity controller, and ``policy_node``
(``command_interface:=velocity``) drives it. Checked: every command is a one-point
trajectory of speeds in rad/s within the card's range with the measured angles as
positions (or a ``Float64MultiArray`` of them), the stand-in accepts every one (none
rejected by JTC's rules, none dropped or clipped), the commanded speed (sampled actions:
jumps) changes by at most ``max_acceleration x period`` per tick, the arm moves, and
stopping ``policy_node`` leaves a zero-velocity hold. A few seconds of node time each.
"""
from pathlib import Path
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from domains import ros_domain
from node_procs import start_node
import numpy as np
from pg_node.common.config_files import load_config
from pg_node.common.paths import resolve_model
from pg_node.common.run import COMMANDS, CONTROLLER_COMMANDS
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory

pytestmark = pytest.mark.e2e
DOMAIN_ID = ros_domain(base=150, spread=20)
#: reacher2 with velocity servos: u in [-1, 1] is the speed 2 u rad/s (kv 10)
VELOCITY_XML = (Path(resolve_model('reacher2')).read_text()
                .replace('<motor name="joint0" joint="joint0" gear="200.0"',
                         '<general name="joint0" joint="joint0" gainprm="20" '
                         'biasprm="0 0 -10"')
                .replace('<motor name="joint1" joint="joint1" gear="200.0"',
                         '<general name="joint1" joint="joint1" gainprm="20" '
                         'biasprm="0 0 -10"'))
MAX_ACCELERATION = 5.0        # rad/s^2: 0.1 rad/s per 20 ms tick


@pytest.fixture(scope='module')
def velocity_policy(tmp_path_factory):
    """Train one update of reacher2 with velocity servos; return its run directory."""
    from pg_node.rl.train_inprocess import train_inprocess
    assert VELOCITY_XML.count('biasprm="0 0 -10"') == 2
    run = tmp_path_factory.mktemp('velocity_run')
    (run / 'reacher2_velocity.xml').write_text(VELOCITY_XML)
    cfg = load_config(None, [f'model={run / "reacher2_velocity.xml"}', 'num_envs=4',
                             'n_steps=8', 'seed=0'])
    train_inprocess(cfg, 32, eval_episodes=1)['learner'].save(run / 'checkpoints')
    return run


def start(tmp_path, module, *params, remap=()):
    """Start a node in this file's domain (test_policy_node's way)."""
    return start_node(DOMAIN_ID, tmp_path, module, *params, remap=remap)


@pytest.mark.parametrize('message', ['trajectory', 'forward'])
def test_a_velocity_policy_drives_the_stand_in_as_a_velocity_controller(
        tmp_path, velocity_policy, message):
    """trajectory: JTC on the velocity interface; forward: JointGroupVelocityController."""
    from pg_node.rl.trained_policy import load_trained_policy
    card = load_trained_policy(velocity_policy).card
    assert card['command_interfaces'] == {'velocity': {'unit': 'rad/s', 'low': [-2.0, -2.0],
                                                       'high': [2.0, 2.0]}}
    assert card['physics']['interfaces'] == ['velocity']
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    node = rclpy.create_node('velocity_test', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    lock = threading.Lock()
    commands, states, diagnostics = [], [], {}
    if message == 'trajectory':
        node.create_subscription(JointTrajectory, 'arm_controller/joint_trajectory',
                                 lambda m: commands.append(m), 100)
    else:
        node.create_subscription(Float64MultiArray, CONTROLLER_COMMANDS,
                                 lambda m: commands.append(m), 100)
    node.create_subscription(JointState, 'joint_states',
                             lambda m: states.append(np.array(m.velocity)), 100)

    def on_diag(msg):
        for s in msg.status:
            if s.name.startswith('sim_node'):
                with lock:
                    diagnostics.update({kv.key: kv.value for kv in s.values})
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    sim = start(tmp_path, 'pg_node.ros.sim_node', 'mode:=real_time',
                'command_interface:=velocity',
                f'model:={velocity_policy / "reacher2_velocity.xml"}',
                'seed:=3', 'num_envs:=1', 'diagnostics_rate:=5.0',
                remap=[f'{COMMANDS}:={CONTROLLER_COMMANDS}'])
    pol = start(tmp_path, 'pg_node.ros.policy_node', f'policy:={velocity_policy}',
                'autostart:=true', 'use_sim_time:=true', 'controller_timeout:=0.0',
                'command_interface:=velocity', 'ramp_time:=0.0',
                f'command_message:={message}',
                # samples (std about 1 after one update): jumps the acceleration limit caps
                'deterministic:=false',
                f'max_acceleration:={MAX_ACCELERATION}', f'record:={tmp_path / "ticks"}')
    try:
        deadline = time.monotonic() + 90
        counted = 'trajectories_received' if message == 'trajectory' else 'commands_received'

        def heard():        # the commands, and the stand-in's count of them in /diagnostics
            with lock:
                return len(commands) >= 40 and int(diagnostics.get(counted, 0)) >= 40
        while not heard() and time.monotonic() < deadline:
            assert pol.poll() is None and sim.poll() is None
            time.sleep(0.1)
        code, log = processes.stop_logged(pol)      # SIGINT: one hold left in force
        time.sleep(0.5)
        with lock:
            seen = dict(diagnostics)
    finally:
        if pol.poll() is None:
            processes.stop_logged(pol)
        sim_code, sim_log = processes.stop_logged(sim)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    assert code == 0, log[-2000:]
    assert len(commands) >= 40, log[-2000:]
    assert 'commands velocity in rad/s, [-2, 2]' in log
    if message == 'trajectory':
        speeds = np.array([m.points[0].velocities for m in commands])
        for m in commands:
            (point,) = m.points
            assert list(m.joint_names) == ['joint0', 'joint1']     # one arm: plain names
            assert len(point.positions) == 2 and len(point.effort) == 0
    else:
        speeds = np.array([m.data for m in commands])     # rad/s, the joints' order
    assert np.all(np.abs(speeds) <= 2.0)
    assert np.abs(speeds).max() > 0.1                   # the policy commands motion
    # tick by tick from policy_node's own record: a reliable keep-last writer may overwrite
    # a sample a loaded subscriber has not taken yet, so the received list can skip ticks
    from mcap_ros2.reader import read_ros2_messages
    from pg_node.ros.policy_node import tick_from_msg
    from pg_node.control.status import GuardEvent
    ticks = [tick_from_msg(m.ros_msg)[1] for m in read_ros2_messages(
        str(next((tmp_path / 'ticks').glob('*.mcap'))))]
    sent = np.array([t['command_si'][0] for t in ticks])
    # the bound holds where nothing acted after it: not on a hold tick (stale state, stop) nor
    # where the joint-limit brake or the over-speed hold (guard steps after 4b) acted
    after = sum(1 << list(GuardEvent).index(e) for e in (
        GuardEvent.JOINT_LIMIT, GuardEvent.OVER_SPEED, GuardEvent.NONFINITE))
    free = np.array([not np.isnan(t['observation'][0]).any()
                     and not int(np.ravel(t['guards'])[0]) & after for t in ticks])
    assert free.sum() >= 20, len(ticks)
    steps = np.abs(np.diff(sent, axis=0))[free[1:]]
    period = card['control_step']                       # 0.02 s: one command a step
    assert steps.max() <= MAX_ACCELERATION * period + 1e-9, steps.max()
    assert np.isclose(steps.max(), MAX_ACCELERATION * period)   # and it did act
    np.testing.assert_array_equal(sent[-1], [0.0, 0.0])     # the hold: zero velocity
    if message == 'trajectory':
        assert int(seen.get('trajectories_received', 0)) >= 40, seen
        assert seen.get('trajectories_rejected') == '0', seen
    else:
        assert int(seen.get('commands_received', 0)) >= 40, seen
        assert all(seen.get(f'commands_{k}') == '0'
                   for k in ('dropped_size', 'dropped_nonfinite', 'dropped_absurd',
                             'clipped')), seen
    assert np.abs(np.array(states)).max() > 0.05        # the arm moved
    assert sim_code == 0, sim_log[-2000:]
