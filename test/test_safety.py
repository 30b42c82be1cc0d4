"""
The robot-facing layer on MuJoCo's arm models, and the kinematics check, without ROS.

:func:`pg_node.sim.actuation.actuators` reads a model's actuators into the plain record of
:mod:`pg_node.control.interfaces`: the SI commands it gives are the simulator's own joint
torques, it equals the hand-made records of ``test_control_*``, and
:class:`pg_node.control.guards.CommandGuard` fed from it gives the commands those tests check.
:func:`pg_node.sim.kinematics_check.compare_kinematics` on a URDF of reacher2 and on
URDFs that differ from it.
"""
from dataclasses import fields
from pathlib import Path

from control_records import POSITION_SERVOS, REACHER2
import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.control.guards import CommandGuard, GuardSettings
from pg_node.control.interfaces import check, INTERFACES
from pg_node.sim.actuation import actuators
from pg_node.sim.kinematics_check import compare_kinematics
import pytest

REACHER = mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))
JOINTS = ['joint0', 'joint1']
#: reacher2 with position servos: u in [-1, 1] is the angle 3 u rad (kp 50, kv 5)
POSITION_XML = (Path(resolve_model('reacher2')).read_text()
                .replace('<motor name="joint0" joint="joint0" gear="200.0"',
                         '<general name="joint0" joint="joint0" gainprm="150" '
                         'biasprm="0 -50 -5"')
                .replace('<motor name="joint1" joint="joint1" gear="200.0"',
                         '<general name="joint1" joint="joint1" gainprm="150" '
                         'biasprm="0 -50 -5"'))
URDF = Path(__file__).parent / 'fixtures' / 'reacher2.urdf'


def position_model():
    assert 'biasprm' in POSITION_XML
    return mujoco.MjModel.from_xml_string(POSITION_XML)


@pytest.mark.parametrize('model,record', [(REACHER, REACHER2),
                                          (position_model(), POSITION_SERVOS)])
def test_the_record_read_from_a_model_is_the_hand_made_one(model, record):
    got = actuators(model)
    for f in fields(record):
        np.testing.assert_array_equal(getattr(got, f.name), getattr(record, f.name), f.name)


def test_si_commands_are_the_simulators_torque_and_the_servos_angle():
    effort, position = INTERFACES['effort'], INTERFACES['position']
    act, pos = actuators(REACHER), actuators(position_model())
    u = np.array([[0.5, -1.0], [0.0, 0.25]])
    np.testing.assert_allclose(effort.to_si(act, u), 200 * u)
    # the simulator agrees: the joint torque of a control is what to_si says
    data = mujoco.MjData(REACHER)
    data.ctrl[:] = u[0]
    mujoco.mj_forward(REACHER, data)
    np.testing.assert_allclose(data.qfrc_actuator[:2], effort.to_si(act, u[0]))
    np.testing.assert_allclose(position.to_si(pos, u), 3 * u)
    assert 'needs position actuators' in check(act, 'position')


def test_a_guard_fed_from_a_model_acts_as_on_the_hand_made_record():
    """The same commands, step for step, from the model's record as from the hand-made one."""
    settings = {'max_velocity': 5.0, 'max_change': 0.3, 'smoothing': 0.2, 'ramp_time': 1.0}
    for model, record, interface in ((REACHER, REACHER2, 'effort'),
                                     (position_model(), POSITION_SERVOS, 'position')):
        a = CommandGuard(actuators(model), JOINTS, interface, GuardSettings(**settings))
        b = CommandGuard(record, JOINTS, interface, GuardSettings(**settings))
        a.start_ramp(0.0)
        b.start_ramp(0.0)
        rng = np.random.default_rng(0)
        for t in np.linspace(0.0, 2.0, 9):
            act = rng.normal(scale=1.5, size=(3, 2))
            q, qdot = rng.uniform(-3.1, 3.1, (3, 2)), rng.normal(scale=4.0, size=(3, 2))
            (ua, ea), (ub, eb) = a(act, q, qdot, t), b(act, q, qdot, t)
            np.testing.assert_array_equal(ua, ub)
            assert all(np.array_equal(ea[k], eb[k]) for k in ea)


@pytest.mark.parametrize('edit,words', [
    (lambda t: t, None),
    (lambda t: t.replace('xyz="0.1 0 0"', 'xyz="0.12 0 0"'),
     'joint joint1 is 20.0 mm away'),
    (lambda t: t.replace('<axis xyz="0 0 1"/>\n    <limit', '<axis xyz="0 1 0"/>\n    <limit'),
     'joint joint1 turns about'),
    (lambda t: t.replace('"joint1"', '"elbow"'), 'robot_description has no joint joint1'),
    (lambda t: t.replace('type="revolute"', 'type="prismatic"'),
     'joint joint1 is of another type'),
    (lambda t: t[:40], 'robot_description does not compile'),
])
def test_kinematics_check_finds_another_arm(edit, words):
    got = compare_kinematics(REACHER, edit(URDF.read_text()))
    assert (got is None) if words is None else (words in got), got


def test_the_guards_defaults_from_arm7_are_the_franka_urdfs_limits():
    """
    The Panda imported with --velocity-damping: its speed limits are the URDF's own.

    The importer sets each joint's damping to effort / velocity limit (urdf_import.py), so
    the over-speed guard's limit from the model, torque / damping, is the URDF's velocity
    limit (panda.urdf: 2.175 rad/s on joints 1-4, 2.61 on 5-7); the hold's damping is the
    model's; the braking deceleration is half the torque over the joint's largest inertia.
    """
    from pg_node.control.guards import model_limits
    arm = actuators(mujoco.MjModel.from_xml_path(str(resolve_model('arm7'))))
    lim = model_limits(arm, INTERFACES['effort'], GuardSettings(), 0.04)
    np.testing.assert_allclose(lim.max_velocity, [2.175] * 4 + [2.61] * 3, rtol=1e-4)
    np.testing.assert_allclose(lim.hold_damping, [40.0] * 4 + [4.5977] * 3)
    np.testing.assert_allclose(lim.max_deceleration, 0.5 * arm.force_limit / arm.inertia)
    assert np.all(arm.inertia > 0.1) and arm.force_limit.tolist() == [87.0] * 4 + [12.0] * 3
