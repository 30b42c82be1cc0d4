"""The rules configure applies to the arm controller: each rule refuses, naming its parameter."""
import doctest

from pg_node.control import controller_check
from pg_node.control.controller_check import (Controller, FORWARD_TYPES, OPT_OUT, refusal,
                                              TRAJECTORY_TYPES)
import pytest

JTC, SCALED = TRAJECTORY_TYPES
JOINTS = ['joint0', 'joint1']


def jtc(interfaces=('velocity',), type_=JTC, state='active', **params):
    """Return a JTC set up as config/controllers/jtc_<interface>.yaml ships it, then ``params``."""
    base = {'joints': JOINTS, 'command_interfaces': list(interfaces),
            'state_interfaces': ['position', 'velocity'], 'cmd_timeout': 0.2,
            'constraints.goal_time': 0.0, 'allow_nonzero_velocity_at_trajectory_end':
            'velocity' in interfaces, **{f'gains.{j}.ff_velocity_scale': 1.0 for j in JOINTS}}
    return Controller('arm_controller', type_, state, {**base, **params}, '/arm_controller')


@pytest.mark.parametrize('interface', ['effort', 'position', 'velocity'])
def test_the_shipped_trajectory_controllers_pass(interface):
    assert refusal(jtc([interface]), interface, 'trajectory') is None


@pytest.mark.parametrize('ctrl, interface, named', [
    # velocity to a position-only JTC: it writes the positions only
    (jtc(['position']), 'velocity', 'command_interfaces [position]'),
    # effort to a JTC without effort: rule 9 rejects every message
    (jtc(['position', 'velocity']), 'effort', 'command_interfaces [position, velocity]'),
    (jtc(['effort']), 'position', 'command_interfaces [effort]'),
    # velocity alone: the PID adapter multiplies by ff_velocity_scale, default 0
    (jtc(['velocity'], **{'gains.joint1.ff_velocity_scale': 0.0}), 'velocity',
     'gains.joint1.ff_velocity_scale 0'),
    (jtc(['velocity'], allow_nonzero_velocity_at_trajectory_end=False), 'velocity',
     'allow_nonzero_velocity_at_trajectory_end false'),
])
def test_a_controller_that_cannot_carry_the_commands_is_refused_naming_the_parameter(
        ctrl, interface, named):
    line = refusal(ctrl, interface, 'trajectory', allow_no_dead_man=True)
    assert line is not None and named in line and '\n' not in line, line
    assert line.startswith('controller /arm_controller ')


def test_ff_velocity_scale_does_not_matter_open_loop_or_beside_position():
    no_ff = {f'gains.{j}.ff_velocity_scale': 0.0 for j in JOINTS}
    assert refusal(jtc(['velocity'], open_loop_control=True, **no_ff), 'velocity',
                   'trajectory') is None
    assert refusal(jtc(['position', 'velocity'], **no_ff), 'velocity', 'trajectory') is None


@pytest.mark.parametrize('params, named', [
    ({'cmd_timeout': 0.0}, 'has cmd_timeout 0: no dead-man'),
    ({'cmd_timeout': 0.2, 'constraints.goal_time': 0.5},
     'cmd_timeout 0.2 not above constraints.goal_time 0.5'),
])
def test_a_trajectory_controller_without_a_dead_man_is_refused_unless_opted_out(params, named):
    line = refusal(jtc(['velocity'], **params), 'velocity', 'trajectory')
    assert line is not None and named in line and OPT_OUT in line, line
    assert refusal(jtc(['velocity'], **params), 'velocity', 'trajectory',
                   allow_no_dead_man=True) is None


def test_the_ur_scaled_controller_as_the_driver_ships_it_has_no_dead_man():
    # ur_robot_driver/config/ur_controllers.yaml:117-143 (jazzy a16a26876): no cmd_timeout,
    # so JTC's default 0 (params.yaml:134-141)
    shipped = jtc(['position'], type_=SCALED)
    del shipped.params['cmd_timeout']
    assert 'has cmd_timeout 0: no dead-man' in refusal(shipped, 'position', 'trajectory')
    assert refusal(jtc(['position'], type_=SCALED), 'position', 'trajectory') is None


@pytest.mark.parametrize('type_, interface', [
    ('velocity_controllers/JointGroupVelocityController', 'velocity'),
    ('effort_controllers/JointGroupEffortController', 'effort'),
    ('position_controllers/JointGroupPositionController', 'position'),
])
def test_every_forward_controller_has_no_dead_man_and_the_opt_out_lets_it_pass(type_, interface):
    ctrl = Controller('arm_controller', type_, 'active', {'joints': JOINTS})
    line = refusal(ctrl, interface, 'forward')
    assert 'no dead-man' in line and OPT_OUT in line, line
    assert refusal(ctrl, interface, 'forward', allow_no_dead_man=True) is None


def test_a_forward_controller_of_another_interface_is_refused_even_opted_out():
    group = Controller('c', 'velocity_controllers/JointGroupVelocityController', 'active', {})
    assert 'interface_name velocity' in refusal(group, 'effort', 'forward', True)
    plain = Controller('c', 'forward_command_controller/ForwardCommandController', 'active',
                       {'interface_name': 'position'})
    assert 'interface_name position' in refusal(plain, 'velocity', 'forward', True)
    assert refusal(plain, 'position', 'forward', True) is None
    assert set(FORWARD_TYPES) >= {group.controller_type, plain.controller_type}


@pytest.mark.parametrize('ctrl, message, named', [
    (jtc(['velocity']), 'forward', f'type {JTC}, not a forward command controller'),
    (Controller('c', 'velocity_controllers/JointGroupVelocityController', 'active'),
     'trajectory', 'not a joint trajectory controller'),
    (Controller('c', 'admittance_controller/AdmittanceController', 'active'), 'trajectory',
     'type admittance_controller/AdmittanceController'),
])
def test_a_type_the_command_message_cannot_reach_is_refused(ctrl, message, named):
    assert named in refusal(ctrl, 'velocity', message, allow_no_dead_man=True)


@pytest.mark.parametrize('state', ['inactive', 'unconfigured', ''])
def test_a_controller_that_is_not_active_is_refused(state):
    line = refusal(jtc(['velocity'], state=state), 'velocity', 'trajectory')
    assert 'not active' in line, line


def test_the_docstring_examples_hold():
    failures, tried = doctest.testmod(controller_check)
    assert tried and not failures
