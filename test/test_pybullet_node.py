"""
pybullet_node as a process: the ros2_control chain's semantics on PyBullet (issue 45).

The reacher2 URDF fixture, imported as ``arm import`` would (no damping, so PyBullet's
1/240 s step and real time), heard over DDS, once per command interface (each node in a
namespace of its own): on effort, the description latched, plain joint names, a forward
controller's command held past any timeout, then a joint trajectory controller's point and,
``jtc_cmd_timeout`` later, its zero-effort hold; on velocity, rad/s held forever and the
zero-velocity holds.
"""
import os
from pathlib import Path
import re
import sys
import time

from domains import ros_domain
from geometry_msgs.msg import PointStamped
import numpy as np
from pg_node.sim.urdf_import import import_urdf, ImportOptions, write_model
from pg_node.tools import processes
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

REPO = Path(__file__).resolve().parent.parent
URDF = REPO / 'test' / 'fixtures' / 'reacher2.urdf'
DOMAIN_ID = ros_domain(base=120, spread=100)
#: the actuators ``arm import`` gives the model for each command interface
ACTUATOR = {'effort': 'motor', 'velocity': 'velocity'}
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def start_node(tmp, interface: str, namespace: str, urdf: Path = URDF):
    """Start pybullet_node on ``urdf`` (``interface``) in ``namespace``, and a client."""
    model = tmp / 'reacher2.xml'
    write_model(import_urdf(urdf, ImportOptions(tip='body1', targets=50, visual_meshes=False,
                                                actuator=ACTUATOR[interface]),
                            out_path=model, command=f'python -m pg_node arm import {urdf}'),
                model)
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONUNBUFFERED='1',
               PYTHONPATH=str(REPO), AMENT_PREFIX_PATH=os.environ.get(
                   'AMENT_PREFIX_PATH', str(Path(sys.executable).parent.parent)))
    log = tmp / 'pybullet_node.log'
    proc = processes.start_logged(
        [sys.executable, '-m', 'pg_node.ros.pybullet_node', '--ros-args', '-r',
         f'__ns:={namespace}', '-p', f'model:={model}', '-p', 'max_episode_steps:=100000',
         '-p', 'frame_skip:=20', '-p', f'command_interface:={interface}'], log, env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    client = rclpy.create_node('pybullet_node_test', namespace=namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(client)
    heard = {'description': [], 'joints': [], 'target': []}
    client.create_subscription(String, 'robot_description', heard['description'].append,
                               LATCHED)
    client.create_subscription(JointState, 'joint_states', heard['joints'].append, 100)
    client.create_subscription(PointStamped, 'target', heard['target'].append, LATCHED)
    pubs = {'forward': client.create_publisher(Float64MultiArray, 'arm_controller/commands',
                                               10),
            'jtc': client.create_publisher(JointTrajectory,
                                           'arm_controller/joint_trajectory', 10)}

    def spin_until(condition, timeout=30.0):
        deadline = time.monotonic() + timeout
        while not condition():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            executor.spin_once(timeout_sec=0.05)

    def stop():
        processes.stop_logged(proc)
        client.destroy_node()
        rclpy.try_shutdown(context=context)
    return {'heard': heard, 'pubs': pubs, 'spin_until': spin_until, 'log': log,
            'stop': stop, 'client': client}


def velocity_urdf(tmp, speed: float) -> Path:
    """
    Write the fixture with a ``<limit velocity>`` of ``speed`` rad/s on both joints.

    A velocity servo needs a speed limit: the continuous joint0 has none in the fixture.
    """
    urdf = tmp / 'reacher2.urdf'
    urdf.write_text(URDF.read_text().replace(
        '<axis xyz="0 0 1"/>\n  </joint>',
        '<axis xyz="0 0 1"/>\n    <limit effort="200" velocity="20"/>\n  </joint>', 1)
        .replace('velocity="20"', f'velocity="{speed:g}"'))
    return urdf


@pytest.fixture(scope='module')
def node(tmp_path_factory):
    """pybullet_node on the effort interface."""
    started = start_node(tmp_path_factory.mktemp('pybullet_node'), 'effort', '/effort')
    yield started
    started['stop']()


@pytest.fixture(scope='module')
def velocity_node(tmp_path_factory):
    """pybullet_node on the velocity interface (the fixture imported with velocity servos)."""
    tmp = tmp_path_factory.mktemp('pybullet_velocity')
    started = start_node(tmp, 'velocity', '/velocity', velocity_urdf(tmp, 20.0))
    yield started
    started['stop']()


def state_after(node, seconds: float) -> JointState:
    """Return the first joint state heard ``seconds`` of simulated time on."""
    joints = node['heard']['joints']
    node['spin_until'](lambda: joints)
    start = stamp(joints[-1])
    node['spin_until'](lambda: stamp(joints[-1]) >= start + seconds)
    return joints[-1]


def stamp(msg) -> float:
    """Return a message's header stamp in s."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def efforts_after(node, seconds: float) -> np.ndarray:
    """Return the efforts of the first joint state heard ``seconds`` of simulated time on."""
    return np.array(state_after(node, seconds).effort)


def test_the_stand_in_offers_itself_as_a_robot(node):
    heard = node['heard']
    node['spin_until'](lambda: heard['description'] and heard['target'] and heard['joints'])
    assert heard['description'][0].data == URDF.read_text()
    assert list(heard['joints'][-1].name) == ['joint0', 'joint1']
    assert heard['target'][0].header.frame_id == 'base_link'
    text = node['log'].read_text()
    assert 'joints, limits and masses agree' in text and 'control period 0.04 s' in text


def test_a_forward_command_is_held_then_a_trajectory_point_until_its_cmd_timeout(node):
    forward = [0.0, 1e-4]
    node['spin_until'](lambda: node['heard']['joints'])
    node['pubs']['forward'].publish(Float64MultiArray(data=forward))
    node['spin_until'](lambda: np.allclose(node['heard']['joints'][-1].effort, forward))
    # held: a second later (twice sim_node's command_timeout) the effort is the command
    np.testing.assert_allclose(efforts_after(node, 1.0), forward)
    point = [-1e-4, 0.0]
    node['pubs']['jtc'].publish(JointTrajectory(
        joint_names=['joint1', 'joint0'],
        points=[JointTrajectoryPoint(positions=[0.0, 0.0], effort=point[::-1])]))
    node['spin_until'](lambda: np.allclose(node['heard']['joints'][-1].effort, point))
    # jtc_cmd_timeout (0.2 s) after the point: JTC's hold, zero effort, and it stays
    np.testing.assert_allclose(efforts_after(node, 0.3), [0.0, 0.0])
    node['pubs']['forward'].publish(Float64MultiArray(data=forward))
    np.testing.assert_allclose(efforts_after(node, 0.2), [0.0, 0.0])
    assert 'aborted due to command timeout' in node['log'].read_text()


def test_velocity_commands_are_rad_per_s_held_forever_and_zero_holds(velocity_node):
    """
    The velocity interface as ros2_control's velocity controllers: rad/s, the last held.

    Before any command 0 rad/s holds the arm; a forward command turns the joints at its
    speed (the angle grows by speed x simulated time) for as long as no other comes; a
    trajectory point's velocities (non-zero at its end, as the shipped jtc_velocity.yaml
    allows) take over, and ``jtc_cmd_timeout`` later JTC's hold stops the arm where it is.
    """
    n = velocity_node
    n['spin_until'](lambda: n['heard']['joints'])
    assert 'velocity commands' in n['log'].read_text()
    first = state_after(n, 0.0)
    still = state_after(n, 0.5)
    np.testing.assert_allclose(still.velocity, [0.0, 0.0], atol=1e-6)
    # the start's 0.005 rad/s of noise is stopped within the first control period
    np.testing.assert_allclose(still.position, first.position, atol=2e-4)
    speed = np.array([0.5, -0.25])
    n['pubs']['forward'].publish(Float64MultiArray(data=speed.tolist()))
    n['spin_until'](lambda: np.allclose(n['heard']['joints'][-1].velocity, speed, atol=1e-6))
    a = state_after(n, 0.0)
    b = state_after(n, 1.0)     # held: five times sim_node's command_timeout later
    np.testing.assert_allclose(b.velocity, speed, atol=1e-6)
    np.testing.assert_allclose(np.subtract(b.position, a.position), speed * (stamp(b) - stamp(a)),
                               atol=1e-6)
    point = np.array([-0.2, 0.4])
    n['pubs']['jtc'].publish(JointTrajectory(
        joint_names=['joint1', 'joint0'], points=[JointTrajectoryPoint(
            positions=list(b.position)[::-1], velocities=point[::-1].tolist())]))
    n['spin_until'](lambda: np.allclose(n['heard']['joints'][-1].velocity, point, atol=1e-6))
    # jtc_cmd_timeout (0.2 s) after the point: JTC's hold, 0 rad/s, the arm stays put
    held = state_after(n, 0.3)
    np.testing.assert_allclose(held.velocity, [0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(state_after(n, 0.5).position, held.position, atol=1e-6)
    text = n['log'].read_text()
    assert 'aborted due to command timeout' in text and 'rejected' not in text, text


#: the reaching policy's training: test_policy_node's settings, 100k steps (10-20 s)
REACH_TRAIN = ['seed=0', 'num_envs=8', 'learning_rate=0.003', 'n_steps=16', 'gamma=0.9',
               'vf_epochs=1']
REACH_STEPS = 100_000


def test_a_short_policy_reaches_its_goal_through_policy_node_in_pybullet(tmp_path):
    """
    A policy trained here reaches its goal through ``policy_node`` and ``pybullet_node``.

    The fixture imported with velocity servos of 5 rad/s and one goal (``targets`` 1, about
    17 cm from the start pose: a task 100k steps learn, seed 0), played by ``play --robot
    pybullet``: ``policy_node`` sends rad/s on the joint trajectory controller's topic in
    real time, ``pybullet_node`` turns PyBullet's velocity motors. The tolerance is the
    spread of the same policy in PyBullet lock-step (``eval --engine pybullet``, 100
    episodes, the starts' noise only): every played episode ends within its mean + 4
    standard deviations. Seen: 1.58 +/- 0.21 cm lock-step, 1.19-1.83 cm played (5 episodes).
    """
    from pg_node.common.config_files import load_config
    from pg_node.rl.evaluate import evaluate_in_pybullet
    from pg_node.rl.onnx_export import export_policy
    from pg_node.rl.train_inprocess import train_inprocess
    from pg_node.rl.trained_policy import find_checkpoint, TorchPolicy
    import subprocess
    urdf = velocity_urdf(tmp_path, 5.0)
    model = tmp_path / 'reacher2.xml'
    write_model(import_urdf(urdf, ImportOptions(tip='body1', targets=1, visual_meshes=False,
                                                actuator='velocity'),
                            out_path=model, command=f'python -m pg_node arm import {urdf}'),
                model)
    summary = train_inprocess(load_config(None, [*REACH_TRAIN, f'model={model}']),
                              REACH_STEPS, eval_episodes=4)
    run = tmp_path / 'run'
    summary['learner'].save(run / 'checkpoints')
    trained = TorchPolicy(*find_checkpoint(run))
    export_policy(trained.policy, trained.card, run / 'policy.onnx')
    lock = np.array(evaluate_in_pybullet(summary['learner'].policy, str(model), urdf, 100, 0,
                                         frame_skip=2)['eval_final_distances'])
    bound = lock.mean() + 4 * lock.std()
    assert bound < 0.05, lock       # 17 cm to go at the start: the policy reaches
    res = subprocess.run([sys.executable, '-m', 'pg_node', 'play', str(run / 'policy.onnx'),
                          '--robot', 'pybullet', '--episodes', '3', '--log-dir',
                          str(tmp_path / 'logs')], env=processes.child_env(DOMAIN_ID),
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    finals = [float(line.split('final fingertip distance')[1].split()[0]) / 100
              for line in res.stdout.splitlines() if line.startswith('episode')]
    assert len(finals) >= 3 and max(finals) < bound, (finals, lock.mean(), lock.std())
    assert 'velocity commands' in (tmp_path / 'logs' / 'pybullet_node.log').read_text()
    assert 'kinematics match robot_description' in (
        tmp_path / 'logs' / 'policy_node.log').read_text()


def test_play_refuses_what_the_pybullet_stand_in_does_not_do(tmp_path):
    import subprocess
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID))
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'play', str(tmp_path),
                           '--robot', 'pybullet', '--arms', '2'], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and 'Traceback' not in done.stderr
    assert 'one arm as it is' in done.stderr


def test_reset_world_starts_the_first_episode_again(node):
    """
    ``~/reset_world`` as ``sim_node``'s: the first goal again, a new episode id (issue 46).

    ``play --robot pybullet`` waits for it before it counts episodes: without it the play
    never counted one ("no episodes finished in time").
    """
    from std_srvs.srv import Trigger
    targets = node['heard']['target']
    node['spin_until'](lambda: targets)
    first = targets[0].point
    reset = node['client'].create_client(Trigger, '/effort/pybullet_node/reset_world')
    node['spin_until'](reset.service_is_ready)
    answer = reset.call_async(Trigger.Request())
    node['spin_until'](answer.done)
    assert answer.result().success
    assert re.fullmatch(r'new episodes \[[1-9]\d*\]', answer.result().message)
    node['spin_until'](lambda: len(targets) > 1)
    again = targets[-1].point
    assert (again.x, again.y, again.z) == (first.x, first.y, first.z)
