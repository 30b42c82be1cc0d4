"""The one-point trajectory for a joint trajectory controller, per interface (no ROS)."""
import doctest

from control_records import POSITION_SERVOS, REACHER2
import numpy as np
from pg_node.control import composers
from pg_node.control.composers import trajectory_point
from pg_node.control.interfaces import INTERFACES
from pg_node.control.joint_map import arm_joint_names

SI = np.array([[10.0, -20.0], [30.0, 40.0]])
Q = np.array([[0.1, 0.2], [0.3, 0.4]])
QDOT = np.array([[1.0, 2.0], [3.0, 4.0]])


def test_worked_examples():
    failures, tried = doctest.testmod(composers)
    assert tried > 0 and failures == 0


def test_effort_goes_in_the_efforts_with_the_measured_state_arm_major():
    names = arm_joint_names(REACHER2.joints, 2, plain=False)
    p = trajectory_point(INTERFACES['effort'], SI, Q, QDOT, names, 50.0)
    assert p.joint_names == ['arm0/joint0', 'arm0/joint1', 'arm1/joint0', 'arm1/joint1']
    assert p.fields == {'effort': [10.0, -20.0, 30.0, 40.0], 'positions': [0.1, 0.2, 0.3, 0.4],
                        'velocities': [1.0, 2.0, 3.0, 4.0]}
    assert p.time_from_start == (0, 20_000_000)


def test_position_goes_in_the_positions_alone():
    p = trajectory_point(INTERFACES['position'], SI[:1], Q[:1], QDOT[:1],
                         list(POSITION_SERVOS.joints), 0.5)
    assert p.fields == {'positions': [10.0, -20.0]}
    assert p.joint_names == ['joint0', 'joint1'] and p.time_from_start == (2, 0)
