"""
pybullet_node as a process: the ros2_control chain's semantics on PyBullet (issue 45).

One node for the file (the reacher2 URDF fixture, imported as ``arm import`` would: no
damping, so PyBullet's 1/240 s step and real time), heard over DDS: the description latched,
plain joint names, a forward controller's command held past any timeout, then a joint
trajectory controller's point and, ``jtc_cmd_timeout`` later, its zero-effort hold.
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
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope='module')
def node(tmp_path_factory):
    """Start pybullet_node on the fixture and a client in the test's domain."""
    tmp = tmp_path_factory.mktemp('pybullet_node')
    model = tmp / 'reacher2.xml'
    write_model(import_urdf(URDF, ImportOptions(tip='body1', targets=50, visual_meshes=False),
                            out_path=model, command=f'python -m pg_node arm import {URDF}'),
                model)
    env = dict(os.environ, ROS_DOMAIN_ID=str(DOMAIN_ID), PYTHONUNBUFFERED='1',
               PYTHONPATH=str(REPO), AMENT_PREFIX_PATH=os.environ.get(
                   'AMENT_PREFIX_PATH', str(Path(sys.executable).parent.parent)))
    log = tmp / 'pybullet_node.log'
    proc = processes.start_logged(
        [sys.executable, '-m', 'pg_node.ros.pybullet_node', '--ros-args', '-p',
         f'model:={model}', '-p', 'max_episode_steps:=100000', '-p', 'frame_skip:=20'],
        log, env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    client = rclpy.create_node('pybullet_node_test', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(client)
    heard = {'description': [], 'joints': [], 'target': []}
    client.create_subscription(String, '/robot_description', heard['description'].append,
                               LATCHED)
    client.create_subscription(JointState, '/joint_states', heard['joints'].append, 100)
    client.create_subscription(PointStamped, '/target', heard['target'].append, LATCHED)
    pubs = {'forward': client.create_publisher(Float64MultiArray, '/arm_controller/commands',
                                               10),
            'jtc': client.create_publisher(JointTrajectory,
                                           '/arm_controller/joint_trajectory', 10)}

    def spin_until(condition, timeout=30.0):
        deadline = time.monotonic() + timeout
        while not condition():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            executor.spin_once(timeout_sec=0.05)

    yield {'heard': heard, 'pubs': pubs, 'spin_until': spin_until, 'log': log,
           'client': client}
    processes.stop_logged(proc)
    client.destroy_node()
    rclpy.try_shutdown(context=context)


def efforts_after(node, seconds: float) -> np.ndarray:
    """Return the efforts of the first joint state heard ``seconds`` of simulated time on."""
    joints = node['heard']['joints']
    node['spin_until'](lambda: joints)
    start = joints[-1].header.stamp.sec + 1e-9 * joints[-1].header.stamp.nanosec

    def stamp(m):
        return m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
    node['spin_until'](lambda: stamp(joints[-1]) >= start + seconds)
    return np.array(joints[-1].effort)


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
    reset = node['client'].create_client(Trigger, '/pybullet_node/reset_world')
    node['spin_until'](reset.service_is_ready)
    answer = reset.call_async(Trigger.Request())
    node['spin_until'](answer.done)
    assert answer.result().success
    assert re.fullmatch(r'new episodes \[[1-9]\d*\]', answer.result().message)
    node['spin_until'](lambda: len(targets) > 1)
    again = targets[-1].point
    assert (again.x, again.y, again.z) == (first.x, first.y, first.z)


def test_play_refuses_what_the_pybullet_stand_in_does_not_do(tmp_path):
    import subprocess
    env = dict(os.environ, PYTHONPATH=str(REPO), ROS_DOMAIN_ID=str(DOMAIN_ID))
    done = subprocess.run([sys.executable, '-m', 'pg_node', 'play', str(tmp_path),
                           '--robot', 'pybullet', '--arms', '2'], env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and 'Traceback' not in done.stderr
    assert 'one arm as it is' in done.stderr
