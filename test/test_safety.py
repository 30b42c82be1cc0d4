"""
The controller's guards, SI commands and the kinematics check, without ROS.

:class:`pg_node.sim.safety.CommandGuard` step by step (range, ramp, smoothing, rate limit,
joint limits with both interfaces, over-speed, hold), :class:`pg_node.sim.actuation.Actuation`
(N m and rad from controls and back, and its refusals), and
:func:`pg_node.sim.kinematics_check.compare_kinematics` on a URDF of reacher2 and on
URDFs that differ from it.
"""
from pathlib import Path

import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.actuation import Actuation
from pg_node.sim.kinematics_check import compare_kinematics
from pg_node.sim.safety import CommandGuard, GuardSettings
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


def test_si_commands_are_the_models_torque_and_angle_and_invert():
    act = Actuation(REACHER)
    u = np.array([[0.5, -1.0], [0.0, 0.25]])
    np.testing.assert_allclose(act.to_si(u, 'effort'), 200 * u)
    np.testing.assert_allclose(act.from_si(act.to_si(u, 'effort'), 'effort'), u)
    # the simulator agrees: the joint torque of a control is what to_si says
    data = mujoco.MjData(REACHER)
    data.ctrl[:] = u[0]
    mujoco.mj_forward(REACHER, data)
    np.testing.assert_allclose(data.qfrc_actuator[:2], act.to_si(u[0], 'effort'))
    pos = Actuation(position_model())
    np.testing.assert_allclose(pos.to_si(u, 'position'), 3 * u)
    np.testing.assert_allclose(pos.from_si(pos.to_si(u, 'position'), 'position'), u)
    assert act.card()['effort'] == {'unit': 'N m', 'low': [-200.0] * 2, 'high': [200.0] * 2}
    assert 'position' not in act.card() and list(pos.card()) == ['position']
    assert act.check('effort') is None and pos.check('position') is None
    assert 'needs position actuators' in act.check('position')
    assert 'needs motor actuators' in pos.check('effort')
    assert 'unknown command interface' in act.check('velocity')


def guard(model=REACHER, interface='effort', **settings):
    return CommandGuard(model, JOINTS, interface, GuardSettings(**settings))


def test_range_nonfinite_and_over_speed_give_clipped_or_hold_commands():
    g = guard(max_velocity=5.0)
    q = np.zeros((3, 2))
    qdot = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, -6.0]])
    u, acted = g(np.array([[2.0, -0.5], [np.nan, 0.1], [0.3, 0.3]]), q, qdot, 0.0)
    np.testing.assert_array_equal(u, [[1.0, -0.5], [0.0, 0.0], [0.0, 0.0]])
    assert acted['clipped'].tolist() == [True, False, False]
    assert acted['nonfinite'].tolist() == [False, True, False]
    assert acted['over_speed'].tolist() == [False, False, True]


def test_ramp_blends_from_hold_then_lets_the_command_through():
    g = guard(ramp_time=1.0)
    g.start_ramp(10.0)
    q, qdot, a = np.zeros((1, 2)), np.zeros((1, 2)), np.array([[0.8, -0.4]])
    seen = [g(a, q, qdot, t)[0][0] for t in (10.0, 10.25, 10.5, 11.0, 12.0)]
    np.testing.assert_allclose(seen, [[0, 0], [0.2, -0.1], [0.4, -0.2], [0.8, -0.4],
                                      [0.8, -0.4]])


def test_smoothing_is_a_first_order_filter_and_max_change_a_rate_limit():
    q, qdot = np.zeros((1, 2)), np.zeros((1, 2))
    g = guard(smoothing=0.75)
    g.sent(np.zeros((1, 2)))
    out = [g(np.array([[1.0, -1.0]]), q, qdot, 0.0)[0][0, 0] for _ in range(3)]
    np.testing.assert_allclose(out, [0.25, 0.4375, 0.578125])
    g = guard(max_change=0.1)                 # 0.1 of the range [-1, 1]: 0.2 per tick
    g.sent(np.zeros((1, 2)))
    steps = [g(np.array([[1.0, 0.1]]), q, qdot, 0.0) for _ in range(6)]
    np.testing.assert_allclose([u[0, 0] for u, _ in steps], [0.2, 0.4, 0.6, 0.8, 1.0, 1.0])
    assert [bool(a['rate_limited'][0]) for _, a in steps] == [True] * 4 + [False] * 2


def test_joint_limit_guard_holds_back_commands_towards_the_limit():
    g = guard(joint_limit_margin=0.05)                  # joint1 is limited to [-3, 3]
    qdot = np.zeros((4, 2))
    q = np.array([[0.0, 2.96], [0.0, 2.96], [0.0, -2.99], [5.0, 2.9]])
    a = np.array([[0.5, 0.5], [0.5, -0.5], [0.5, -0.5], [0.5, 0.5]])
    u, acted = g(a, q, qdot, 0.0)
    # outward at the upper limit: zero; inward: kept; joint0 is unlimited: never touched
    np.testing.assert_array_equal(u, [[0.5, 0.0], [0.5, -0.5], [0.5, 0.0], [0.5, 0.5]])
    assert acted['joint_limit'].tolist() == [True, False, True, False]
    p = guard(position_model(), 'position', joint_limit_margin=0.1)
    u, acted = p(np.array([[0.0, 1.0], [0.0, 0.5]]), np.zeros((2, 2)), np.zeros((2, 2)), 0.0)
    # a target angle of 3 rad is kept 0.1 rad inside the range; 1.5 rad is left alone
    np.testing.assert_allclose(p.act.to_si(u, 'position'), [[0.0, 2.9], [0.0, 1.5]])
    assert acted['joint_limit'].tolist() == [True, False]


def test_hold_is_zero_effort_or_the_measured_angles():
    q = np.array([[0.4, -1.2], [3.5, 2.0]])
    np.testing.assert_array_equal(guard().hold(q, 2), np.zeros((2, 2)))
    p = guard(position_model(), 'position')
    # joint0 is continuous (its servo's range is [-3, 3] rad here): clipped to what it takes
    np.testing.assert_allclose(p.act.to_si(p.hold(q, 2), 'position'), [[0.4, -1.2],
                                                                       [3.0, 2.0]])


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
