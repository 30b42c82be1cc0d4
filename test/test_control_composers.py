"""The one-point trajectory for a joint trajectory controller, per interface (no ROS)."""
import doctest

from control_records import POSITION_SERVOS, REACHER2
import numpy as np
from pg_node.control import composers
from pg_node.control.composers import COMMAND, command_trajectory, POINT_FIELDS
from pg_node.control.interfaces import INTERFACES
from pg_node.control.joint_map import arm_joint_names

SI = np.array([[10.0, -20.0], [30.0, 40.0]])
Q = np.array([[0.1, 0.2], [0.3, 0.4]])


def test_worked_examples():
    failures, tried = doctest.testmod(composers)
    assert tried > 0 and failures == 0


def test_every_interface_has_a_row_whose_command_field_is_the_interfaces():
    assert set(POINT_FIELDS) == set(INTERFACES)
    for name, row in POINT_FIELDS.items():
        assert [f for f, what in row if what == COMMAND] == [INTERFACES[name].trajectory_field]


def test_effort_goes_in_the_efforts_with_the_measured_angles_no_velocities_arm_major():
    names = arm_joint_names(REACHER2.joints, 2, plain=False)
    t = command_trajectory(INTERFACES['effort'], SI, Q, names)
    assert t.joint_names == ['arm0/joint0', 'arm0/joint1', 'arm1/joint0', 'arm1/joint1']
    assert t.stamp == 0.0 and len(t.points) == 1           # start now, one point
    (point,) = t.points
    assert point.fields == {'effort': [10.0, -20.0, 30.0, 40.0],
                            'positions': [0.1, 0.2, 0.3, 0.4]}
    assert point.time_from_start == 0.0                    # applied at once, no ramp


def test_position_goes_in_the_positions_alone():
    t = command_trajectory(INTERFACES['position'], SI[:1], Q[:1], list(POSITION_SERVOS.joints))
    assert t.points[0].fields == {'positions': [10.0, -20.0]}
    assert t.joint_names == ['joint0', 'joint1'] and t.points[0].time_from_start == 0.0
