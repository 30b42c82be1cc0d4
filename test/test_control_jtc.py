"""
The trajectory message against Jazzy's JTC acceptance rules, the controller YAML, the follower.

The rules are those of ros2_controllers (jazzy ed360c97d)
joint_trajectory_controller/src/joint_trajectory_controller.cpp:1671-1816
(``validate_trajectory_msg``), encoded in :data:`pg_node.control.jtc.RULES`:

====  ======================================================  ==========================
rule  rejects                                                 source
====  ======================================================  ==========================
1     joint_names count != controller joints                  jtc.cpp:1676-1685
      (unless allow_partial_joints_goal)
2     empty joint_names                                       jtc.cpp:1688-1692
3     no points                                               jtc.cpp:1695-1699
4     a name that is not a controller joint                   jtc.cpp:1702-1713
5     last point velocity > float eps (unless                 jtc.cpp:1717-1730,
      allow_nonzero_velocity_at_trajectory_end, Jazzy false)  params.yaml:129-133
6     stamp != 0 and stamp + last time_from_start < now       jtc.cpp:1733-1749
7     time_from_start not strictly increasing after point 0   jtc.cpp:1751-1764
8     positions missing / a field of the wrong size           jtc.cpp:1771-1804
      (allow_integration_in_goal_trajectories false)
9     effort without an effort command interface              jtc.cpp:1806-1813
====  ======================================================  ==========================
"""
import doctest
from pathlib import Path

import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.control import jtc
from pg_node.control.composers import command_trajectory, POINT_FIELDS
from pg_node.control.controller_check import Controller, refusal
from pg_node.control.interfaces import INTERFACES
from pg_node.control.joint_map import arm_joint_names
from pg_node.control.jtc import (FLAGS, interfaces_reject, jtc_rejects, JtcFollower, Point,
                                 RULES, Trajectory)
from pg_node.sim.actuation import actuators
import pytest
import yaml

CONTROLLERS = Path(__file__).resolve().parents[1] / 'config' / 'controllers'
J = ['j0', 'j1']
OK = {'positions': [0.1, 0.2]}


def msg(fields=None, names=J, times=(0.0,), stamp=0.0):
    """Return a trajectory of ``len(times)`` points, each with ``fields``."""
    fields = fields if fields is not None else OK
    return Trajectory(list(names), [Point(dict(fields), t) for t in times], stamp)


#: per rule: a message that breaks it alone, the controller's command interfaces, and the
#: flag that lets it through (None: none does); rule 2 is reached only past rule 1's count
#: check, i.e. with partial goals allowed
PARTIAL = {'allow_partial_joints_goal': True}
CASES = {
    '1': (msg({'positions': [0.1]}, names=['j0']), ['position'],
          {'allow_partial_joints_goal': True}),
    '2': (msg(names=[]), ['position'], None),
    '3': (Trajectory(J, []), ['position'], None),
    '4': (msg(names=['j0', 'elbow']), ['position'], None),
    '5': (msg({'positions': [0.1, 0.2], 'velocities': [0.0, 1e-6]}), ['position'],
          {'allow_nonzero_velocity_at_trajectory_end': True}),
    '6': (msg(stamp=100.0, times=(0.5,)), ['position'], None),
    '7': (msg(times=(0.0, 0.1, 0.1)), ['position'], None),
    '8': (msg({'velocities': [0.0, 0.0]}), ['velocity'],
          {'allow_integration_in_goal_trajectories': True}),
    '9': (msg({'positions': [0.1, 0.2], 'effort': [1.0, 2.0]}), ['position'], None),
}


def test_worked_examples():
    failures, tried = doctest.testmod(jtc)
    assert tried > 0 and failures == 0


def test_the_rules_table_is_jazzys_order_and_defaults():
    assert [r.number for r in RULES] == [str(i) for i in range(1, 10)]
    assert all(r.source.startswith('jtc.cpp:') for r in RULES)
    # Jazzy's defaults (params.yaml:75-79, 101-105, 129-133); humble had true for rule 5
    assert FLAGS == {'allow_partial_joints_goal': False,
                     'allow_integration_in_goal_trajectories': False,
                     'allow_nonzero_velocity_at_trajectory_end': False}
    assert {r.flag for r in RULES} - {None} == set(FLAGS)


@pytest.mark.parametrize('rule', [r.number for r in RULES])
def test_each_rule_rejects_its_case_and_its_flag_lets_it_through(rule):
    message, command_interfaces, flag = CASES[rule]
    reason = jtc_rejects(message, J, command_interfaces, now=101.0,
                         flags=PARTIAL if rule == '2' else None)
    assert reason is not None and reason.startswith(f'rule {rule}:'), reason
    if flag is not None:
        assert jtc_rejects(message, J, command_interfaces, now=101.0, flags=flag) is None


def test_the_edges_of_the_rules_accept():
    # rule 5: within float epsilon and velocities that are not the last point's pass
    small = msg({'positions': [0.1, 0.2], 'velocities': [1e-8, 0.0]})
    assert jtc_rejects(small, J, ['position']) is None
    early = Trajectory(J, [Point({'positions': [0, 0], 'velocities': [1.0, 1.0]}, 0.1),
                           Point(OK, 0.2)])
    assert jtc_rejects(early, J, ['position']) is None
    # rule 6: a stamp in the future, or a trajectory not yet ended, is taken
    assert jtc_rejects(msg(stamp=100.0, times=(0.5,)), J, ['position'], now=100.2) is None
    # rule 7: the first point may be at 0; rule 4: names in any order
    assert jtc_rejects(msg(names=['j1', 'j0'], times=(0.0, 0.1)), J, ['position']) is None
    # rule 9: efforts with an effort interface; NaN is not checked by JTC at all
    nan = msg({'positions': [np.nan, 0.0], 'effort': [np.nan, 1.0]})
    assert jtc_rejects(nan, J, ['effort']) is None


def test_policy_nodes_old_message_is_rejected_by_rule_5():
    """Measured q, measured qdot, tau, one period ahead: what Jazzy refused 259 times in 8 s."""
    old = msg({'positions': [0.3, -1.2], 'velocities': [0.5, -0.25], 'effort': [2.0, -1.0]},
              times=(0.04,))
    assert jtc_rejects(old, J, ['effort']).startswith('rule 5: velocity of the last '
                                                      'trajectory point of joint j0')


@pytest.mark.parametrize('arms', [1, 3])
@pytest.mark.parametrize('interface', sorted(POINT_FIELDS) + ['effort_pd'])
def test_every_message_policy_node_composes_passes_its_shipped_controller(interface, arms):
    section = load(f'jtc_{interface}.yaml')['arm_controller']['ros__parameters']
    flags = {k: v for k, v in section.items() if k in FLAGS}
    names = arm_joint_names(section['joints'], arms, plain=arms == 1)
    rng = np.random.default_rng(arms)
    pd = interface == 'effort_pd'                       # controller_hold pd: speeds carried
    for _ in range(20):
        si, q, qdot = rng.normal(size=(3, arms, len(section['joints']))) * 3
        for hold in (False, True):
            t = command_trajectory(INTERFACES[interface.split('_')[0]], si, q, names,
                                   qdot=qdot if pd else None, hold=hold)
            assert jtc_rejects(t, names, section['command_interfaces'], now=1e9,
                               flags=flags) is None
    # the same points to the zero-gain file: rejected (rule 5), as configure says
    if pd:
        zero = load('jtc_effort.yaml')['arm_controller']['ros__parameters']
        moving = command_trajectory(INTERFACES['effort'], si, q, names, qdot=qdot)
        assert 'rule 5' in jtc_rejects(moving, names, zero['command_interfaces'], now=1e9,
                                       flags={k: v for k, v in zero.items() if k in FLAGS})


@pytest.mark.parametrize('command,state,ok', [
    (['effort'], ['position', 'velocity'], True),
    (['position'], ['position'], True),
    (['position', 'velocity'], ['position', 'velocity'], True),
    (['position', 'effort'], ['position', 'velocity'], True),
    (['effort'], ['position'], False),                   # a PID needs both states
    (['velocity'], ['position'], False),
    (['velocity', 'position'], ['position', 'velocity'], False),
    (['effort', 'velocity'], ['position', 'velocity'], False),
    (['position'], ['velocity', 'position'], False),
    (['position'], ['position', 'effort'], False),       # no effort state (params.yaml:45)
])
def test_interface_combinations(command, state, ok):
    """validate_jtc_parameters.hpp:27-99, jtc.cpp:931-956."""
    assert (interfaces_reject(command, state) is None) == ok


# --- the shipped controller YAML ---------------------------------------------------------

def flat_parameters(section):
    """Return a controller's YAML section as its parameter service names them."""
    flat = {k: v for k, v in section.items() if k not in ('gains', 'constraints')}
    flat.update({f'gains.{j}.{k}': v for j, gains in section.get('gains', {}).items()
                 for k, v in gains.items()})
    flat['constraints.goal_time'] = section.get('constraints', {}).get('goal_time', 0.0)
    return flat


def load(name):
    return yaml.safe_load((CONTROLLERS / name).read_text())


def reacher2_actuated_joints():
    return list(actuators(mujoco.MjModel.from_xml_path(str(resolve_model('reacher2')))).joints)


#: file -> controller type, command interface of policy_node it serves
SHIPPED = {
    'jtc_effort.yaml': ('joint_trajectory_controller/JointTrajectoryController', 'effort'),
    'jtc_effort_pd.yaml': ('joint_trajectory_controller/JointTrajectoryController', 'effort'),
    'jtc_position.yaml': ('joint_trajectory_controller/JointTrajectoryController', 'position'),
    'forward_effort.yaml': ('effort_controllers/JointGroupEffortController', 'effort'),
    'forward_position.yaml': ('position_controllers/JointGroupPositionController',
                              'position'),
    'jtc_velocity.yaml': ('joint_trajectory_controller/JointTrajectoryController', 'velocity'),
    'forward_velocity.yaml': ('velocity_controllers/JointGroupVelocityController',
                              'velocity'),
}


def test_the_shipped_files_are_these():
    assert sorted(p.name for p in CONTROLLERS.glob('*.yaml')) == sorted(SHIPPED)


@pytest.mark.parametrize('name', sorted(SHIPPED))
def test_controller_yaml_is_complete_and_keeps_the_rules(name):
    kind, interface = SHIPPED[name]
    doc = load(name)
    cm = doc['controller_manager']['ros__parameters']
    assert cm['update_rate'] > 0
    assert cm['arm_controller']['type'] == kind        # read at cm.cpp:1391
    section = doc['arm_controller']['ros__parameters']
    joints = section['joints']
    assert joints == reacher2_actuated_joints()        # the model's actuated joints, in order
    keys = jtc.parameter_keys(section, joints)
    known = jtc.JTC_PARAMETERS if 'trajectory' in kind else jtc.FORWARD_PARAMETERS
    assert set(keys) <= set(known), set(keys) - set(known)
    if 'trajectory' not in kind:
        return
    assert interfaces_reject(section['command_interfaces'],
                             section['state_interfaces']) is None
    assert section['command_interfaces'] == [interface]
    # a stop the controller keeps: cmd_timeout on, and above goal_time (jtc.cpp:1231-1250)
    assert section['cmd_timeout'] > section['constraints']['goal_time']
    assert section['cmd_timeout'] > 0
    d_gain = max((g.get('d', 0.0) for g in section.get('gains', {}).values()), default=0.0)
    for flag, default in FLAGS.items():                 # the flags it relies on, said
        assert section[flag] is jtc.stand_in_flags(interface, d_gain).get(flag, default)
    if interface == 'velocity':
        # the PID adapter sends velocity x ff_velocity_scale + PID (jtc.cpp:412-425): the
        # speed passes through with scale 1 and zero gains; the default 0 would send 0
        assert section['open_loop_control'] is False
        assert list(section['gains']) == joints
        for gains in section['gains'].values():
            assert all(gains[k] == 0.0 for k in ('p', 'i', 'd'))
            assert gains['ff_velocity_scale'] == 1.0
    elif interface == 'effort' and name.endswith('_pd.yaml'):
        # a d gain on every joint, nothing else: ~0 while the points carry the measured
        # speed, -d qdot in a hold and after cmd_timeout; what configure asks of it
        assert list(section['gains']) == joints
        for gains in section['gains'].values():
            assert gains['d'] > 0
            assert all(gains[k] == 0.0 for k in ('p', 'i', 'ff_velocity_scale'))
        ctrl = Controller('arm_controller', kind, 'active', flat_parameters(section))
        assert refusal(ctrl, 'effort', 'trajectory', controller_hold='pd') is None
        assert 'gains.joint0.d 12.5' in refusal(ctrl, 'effort', 'trajectory')
    elif interface == 'effort':
        # zero gains: the point's effort passes through (jtc.cpp:416-426)
        assert list(section['gains']) == joints
        for gains in section['gains'].values():
            assert all(gains[k] == 0.0 for k in ('p', 'i', 'd', 'ff_velocity_scale'))
        ctrl = Controller('arm_controller', kind, 'active', flat_parameters(section))
        assert refusal(ctrl, 'effort', 'trajectory') is None
        assert 'gains.joint0.d 0' in refusal(ctrl, 'effort', 'trajectory', controller_hold='pd')
    else:
        assert 'gains' not in section                   # no PID on position (jtc.cpp:892-903)


def test_a_short_cmd_timeout_is_off_as_jtc_turns_it_off():
    """cmd_timeout <= goal_time: JTC logs a warning and disables it (jtc.cpp:1231-1250)."""
    follower = JtcFollower(J, 'effort', cmd_timeout=0.1, goal_time=0.1)
    follower.receive(msg({'positions': [0, 0], 'effort': [1.0, 2.0]}), now=0.0)
    assert list(follower.command(100.0, np.zeros(2))) == [1.0, 2.0]
    assert follower.timeouts == 0


# --- the follower: what JTC does with what it accepted ------------------------------------

def test_effort_is_applied_at_once_held_then_zero_after_cmd_timeout():
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2)
    assert follower.command(0.0, np.zeros(2)) is None         # nothing before a message
    assert follower.receive(msg({'positions': [9, 9], 'effort': [2.0, -1.0]}), 10.0) is None
    np.testing.assert_array_equal(follower.command(10.0, np.zeros(2)), [2.0, -1.0])
    np.testing.assert_array_equal(follower.command(10.19, np.zeros(2)), [2.0, -1.0])
    assert follower.timeouts == 0
    np.testing.assert_array_equal(follower.command(10.21, np.zeros(2)), [0.0, 0.0])
    np.testing.assert_array_equal(follower.command(50.0, np.zeros(2)), [0.0, 0.0])
    assert follower.timeouts == 1                             # once per silence
    # the next message is followed again
    follower.receive(msg({'positions': [0, 0], 'effort': [3.0, 4.0]}), 60.0)
    np.testing.assert_array_equal(follower.command(60.1, np.zeros(2)), [3.0, 4.0])


def test_a_d_gain_adds_nothing_while_the_points_carry_the_speed_and_brakes_after_timeout():
    """Effort + d (point speed - measured speed) (jtc.cpp:416-426); the hold: -d qdot."""
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2, d=[12.5],
                           flags=jtc.stand_in_flags('effort', 12.5))
    point = {'positions': [0.1, 0.2], 'effort': [2.0, -1.0], 'velocities': [0.5, -0.3]}
    assert follower.receive(msg(point), 10.0) is None
    np.testing.assert_allclose(follower.command(10.0, [0.1, 0.2], [0.5, -0.3]), [2.0, -1.0])
    # the speed changed within the tick: the d term resists the change only
    np.testing.assert_allclose(follower.command(10.1, [0.15, 0.17], [0.6, -0.3]),
                               [2.0 - 12.5 * 0.1, -1.0])
    # a hold from policy_node (velocity 0, effort 0): -d qdot from the measured speed
    hold = {'positions': [0.1, 0.2], 'effort': [0.0, 0.0], 'velocities': [0.0, 0.0]}
    follower.receive(msg(hold), 11.0)
    np.testing.assert_allclose(follower.command(11.0, [0.3, 0.2], [0.8, -0.4]), [-10.0, 5.0])
    # no message for cmd_timeout: JTC's hold point, -d qdot (p 0: no pull to the angles)
    follower.receive(msg(point), 12.0)
    np.testing.assert_allclose(follower.command(12.3, [0.9, 0.9], [1.0, 2.0]), [-12.5, -25.0])
    assert follower.timeouts == 1
    # zero gains (jtc_effort.yaml): 0 N m whatever the speed
    zero = JtcFollower(J, 'effort', cmd_timeout=0.2)
    zero.receive(msg({'positions': [0, 0], 'effort': [2.0, -1.0]}), 0.0)
    np.testing.assert_array_equal(zero.command(0.3, [0.9, 0.9], [1.0, 2.0]), [0.0, 0.0])


def test_position_hold_is_the_angle_measured_at_the_timeout_not_later():
    follower = JtcFollower(J, 'position', cmd_timeout=0.2)
    follower.receive(msg({'positions': [0.5, -0.5]}), 0.0)
    np.testing.assert_array_equal(follower.command(0.1, np.array([9.0, 9.0])), [0.5, -0.5])
    np.testing.assert_array_equal(follower.command(0.3, np.array([0.4, -0.4])), [0.4, -0.4])
    np.testing.assert_array_equal(follower.command(1.0, np.array([0.0, 0.0])), [0.4, -0.4])


def test_names_in_another_order_are_sorted_to_the_controllers():
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2)
    follower.receive(msg({'positions': [0, 0], 'effort': [5.0, 7.0]}, names=['j1', 'j0']), 0.0)
    np.testing.assert_array_equal(follower.command(0.0, np.zeros(2)), [7.0, 5.0])


def test_a_rejected_message_changes_nothing():
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2)
    follower.receive(msg({'positions': [0, 0], 'effort': [1.0, 1.0]}), 0.0)
    old = msg({'positions': [0, 0], 'velocities': [0.5, 0.0], 'effort': [9.0, 9.0]})
    assert follower.receive(old, 0.05).startswith('rule 5:')
    np.testing.assert_array_equal(follower.command(0.1, np.zeros(2)), [1.0, 1.0])


def test_what_jtc_passes_unchecked_the_stand_in_refuses():
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2)
    assert 'efforts for 2 joints' in follower.receive(
        msg({'positions': [0, 0], 'effort': [1.0]}), 0.0)
    assert 'non-finite' in follower.receive(msg({'positions': [0, 0],
                                                 'effort': [np.inf, 1.0]}), 0.0)
    assert follower.points is None
    with pytest.raises(ValueError, match="no JTC stand-in for command interface 'accel"):
        JtcFollower(J, 'acceleration', cmd_timeout=0.2)


def test_points_take_effect_at_their_time_and_the_timeout_counts_from_the_last():
    follower = JtcFollower(J, 'effort', cmd_timeout=0.2)
    two = Trajectory(J, [Point({'positions': [0, 0], 'effort': [1.0, 1.0]}, 0.1),
                         Point({'positions': [0, 0], 'effort': [2.0, 2.0]}, 0.5)])
    follower.receive(two, 0.0)
    assert follower.command(0.05, np.zeros(2)) is None        # before point 0: as it was
    np.testing.assert_array_equal(follower.command(0.2, np.zeros(2)), [1.0, 1.0])
    np.testing.assert_array_equal(follower.command(0.69, np.zeros(2)), [2.0, 2.0])
    np.testing.assert_array_equal(follower.command(0.71, np.zeros(2)), [0.0, 0.0])


def test_velocity_is_applied_at_once_held_then_zero_after_cmd_timeout():
    """The velocity JTC: the point's speeds pass through, 0 rad/s after cmd_timeout."""
    follower = JtcFollower(J, 'velocity', cmd_timeout=0.2,
                           flags=jtc.SHIPPED_FLAGS['velocity'])
    moving = msg({'positions': [0.1, 0.2], 'velocities': [0.5, -0.3]})
    assert follower.receive(moving, 0.0) is None
    np.testing.assert_array_equal(follower.command(0.1, np.zeros(2)), [0.5, -0.3])
    np.testing.assert_array_equal(follower.command(0.3, np.ones(2)), [0.0, 0.0])
    assert follower.timeouts == 1
    # with Jazzy's default flags the same message is refused (rule 5)
    assert JtcFollower(J, 'velocity', cmd_timeout=0.2).receive(moving, 0.0).startswith(
        'rule 5:')
