"""
What ROS tools see of sim_node: robot_description and joint states they can take.

``robot_description`` is latched (a subscriber that joins late gets it) and has the model's
kinematics; ``arm<i>/joint_states`` carries arm ``i``'s row of ``/joint_states`` with the
plain joint names of that description; one arm's ``/joint_states`` has plain names too;
``pg_node/scene`` draws the ``view_arms`` in the fixed frame.
"""
import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.kinematics_check import compare_kinematics
import pytest
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_sim_node import Client, start_node, stop_node
from visualization_msgs.msg import MarkerArray

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.mark.e2e
def test_description_and_per_arm_joint_states(tmp_path):
    proc = start_node(tmp_path, 'num_envs:=3', 'view_arms:=0, 2')
    client = Client()
    try:
        per_arm = {i: [] for i in (0, 1, 2)}
        for i, got in per_arm.items():
            client.node.create_subscription(JointState, f'/arm{i}/joint_states', got.append, 10)
        client.wait_ready(client.joint_states)
        description = []        # joins after the node published it: latched
        client.node.create_subscription(String, '/robot_description', description.append,
                                        LATCHED)
        scene = []
        client.node.create_subscription(MarkerArray, '/pg_node/scene', scene.append, 10)
        client.spin_until(lambda: description and per_arm[0] and per_arm[2] and scene)
        assert {m.ns for m in scene[-1].markers} == {'arm0', 'arm2'}
        assert {m.header.frame_id for m in scene[-1].markers} == {'world'}
        model = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
        assert compare_kinematics(model, description[0].data, tolerance=1e-6) is None
        client.step([0.3, -0.2] * 3)
        n = len(per_arm[2])
        client.spin_until(lambda: len(per_arm[2]) > n and len(per_arm[0]) > n)
        assert list(client.joint_states[-1].name)[:2] == ['arm0/joint0', 'arm0/joint1']
        for i in (0, 2):
            js = per_arm[i][-1]
            assert list(js.name) == ['joint0', 'joint1']
            client.spin_until(lambda: any(c.header.stamp == js.header.stamp
                                          for c in client.joint_states))
            combined = next(c for c in client.joint_states if c.header.stamp == js.header.stamp)
            np.testing.assert_array_equal(js.position, combined.position[2 * i:2 * i + 2])
            np.testing.assert_array_equal(js.effort, combined.effort[2 * i:2 * i + 2])
        assert not per_arm[1]                           # not in view_arms
    finally:
        client.close()
        rc, log = stop_node(proc)
    assert rc == 0, log
    assert 'robot_description: written from the MuJoCo model' in log


@pytest.mark.e2e
def test_one_arm_has_plain_names_and_a_bad_view_arm_is_refused(tmp_path):
    proc = start_node(tmp_path)
    client = Client()
    try:
        client.wait_ready(client.joint_states)
        assert list(client.joint_states[-1].name) == ['joint0', 'joint1']
    finally:
        client.close()
        rc, log = stop_node(proc)
    assert rc == 0, log
    proc = start_node(tmp_path, 'view_arms:=1')
    proc.wait(timeout=30)
    rc, log = stop_node(proc)
    assert rc != 0 and "view_arms': '1' names an arm beyond the 1 simulated" in log, log
    assert 'Traceback' not in log


def description_of(tmp_path, model):
    """Return what sim_node with ``model`` publishes as robot_description, and its log."""
    proc = start_node(tmp_path, f'model:={model}')
    client = Client()
    try:
        description = []
        client.node.create_subscription(String, '/robot_description', description.append,
                                        LATCHED)
        client.spin_until(lambda: description)
    finally:
        client.close()
        rc, log = stop_node(proc)
    assert rc == 0, log
    return description[0].data, log


@pytest.mark.e2e
def test_an_imported_arm_publishes_its_vendors_urdf(tmp_path):
    """
    The shipped arm7 (imported from ``urdf/panda.urdf``): that file, as it is.

    A copy of the model without the URDF beside it: the URDF written from the model, and
    one warning line that names the missing file.
    """
    vendor = resolve_model('arm7').parent / 'urdf' / 'panda.urdf'
    urdf, log = description_of(tmp_path, 'arm7')
    assert urdf == vendor.read_text()
    assert f'robot_description: {vendor}' in log
    lost = tmp_path / 'arm7.xml'
    lost.write_text(resolve_model('arm7').read_text())
    urdf, log = description_of(tmp_path, lost)
    model = mujoco.MjModel.from_xml_path(str(lost))
    assert compare_kinematics(model, urdf, tolerance=1e-6) is None
    assert urdf != vendor.read_text()
    line = ("robot_description written from the MuJoCo model: the model's vendor URDF "
            f"(pg_source_urdf) {tmp_path / 'urdf' / 'panda.urdf'} cannot be read: No such "
            'file or directory')
    assert [n for n in log.splitlines() if 'robot_description' in n][0].endswith(line)
