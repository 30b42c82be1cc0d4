"""The command interfaces' registry on hand-made actuator records (no MuJoCo)."""
from dataclasses import replace

from control_records import POSITION_SERVOS, REACHER2
import numpy as np
from pg_node.control.interfaces import (card, check, HOLD_DAMPING, HOLD_LAST_COMMAND,
                                        INTERFACES)
import pytest

U = np.array([[0.5, -1.0], [0.0, 0.25]])


@pytest.mark.parametrize('name,record,unit,si,hold,field', [
    ('effort', REACHER2, 'N m', 200 * U, HOLD_DAMPING, 'effort'),
    ('position', POSITION_SERVOS, 'rad', 3 * U, HOLD_LAST_COMMAND, 'positions'),
])
def test_each_interface_has_its_unit_map_hold_and_trajectory_field(name, record, unit, si,
                                                                   hold, field):
    interface = INTERFACES[name]
    assert (interface.name, interface.unit, interface.hold, interface.trajectory_field) == \
        (name, unit, hold, field)
    np.testing.assert_allclose(interface.to_si(record, U), si)
    np.testing.assert_allclose(interface.from_si(record, interface.to_si(record, U)), U)
    low, high = interface.si_range(record)
    scale = si[0, 0] / U[0, 0]                   # 200 N m or 3 rad at u = 1
    np.testing.assert_allclose([low, high], [[-scale] * 2, [scale] * 2])
    assert check(record, name) is None


def test_an_offset_motor_maps_through_its_bias():
    shifted = replace(REACHER2, b0=np.array([0.1, -0.2]))
    effort = INTERFACES['effort']
    np.testing.assert_allclose(effort.to_si(shifted, U), 200 * (U + [0.1, -0.2]))
    np.testing.assert_allclose(effort.to_si(shifted, shifted.zero_effort), 0.0)


def test_kinds_card_and_refusals_in_one_line():
    assert REACHER2.kind.tolist() == ['motor', 'motor']
    assert POSITION_SERVOS.kind.tolist() == ['position', 'position']
    assert card(REACHER2) == {'effort': {'unit': 'N m', 'low': [-200.0] * 2,
                                         'high': [200.0] * 2}}
    assert list(card(POSITION_SERVOS)) == ['position']
    assert check(REACHER2, 'position') == (
        "command_interface position needs position actuators; this arm's are joint0 (motor), "
        'joint1 (motor) (use command_interface effort, or an arm imported with --actuator '
        'position)')
    assert 'needs motor actuators' in check(POSITION_SERVOS, 'effort')
    assert 'use command_interface position' in check(POSITION_SERVOS, 'effort')
    assert check(REACHER2, 'acceleration') == ("unknown command interface 'acceleration' "
                                               '(choose one of effort, position, velocity)')
    other = replace(REACHER2, affine=np.array([True, False]))
    assert other.kind.tolist() == ['motor', 'other'] and card(other) == {}
    assert 'joint1 (other)' in check(other, 'effort')
    unlimited = replace(REACHER2, ctrl_low=np.array([-np.inf, -1.0]))
    assert card(unlimited)['effort']['low'] == [None, -200.0]


def test_the_parameter_table_offers_exactly_the_registrys_interfaces():
    """common/ cannot import control/, so the two lists are held equal here."""
    from pg_node.common.params import POLICY_PARAMS, SIM_PARAMS
    assert tuple(POLICY_PARAMS['command_interface'].choices) == tuple(INTERFACES)
    assert tuple(SIM_PARAMS['command_interface'].choices) == ('control',) + tuple(INTERFACES)
