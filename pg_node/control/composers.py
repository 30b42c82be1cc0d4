"""
A command as a joint trajectory controller takes it: a one-point trajectory, ROS-free.

ros2_controllers' joint trajectory controller (JTC) takes ``trajectory_msgs/JointTrajectory``;
``policy_node`` sends each command as one point reached one control period ahead, so that
JTC's ``cmd_timeout`` holds the arm if the commands stop. The point carries the SI command in
its interface's field (:data:`pg_node.control.interfaces.INTERFACES`); when that is not the
positions (effort), its positions and velocities are the measured ones, so that the
controller's PID (on the effort interface) sees no error and passes the efforts through as
its feed-forward (ros2_controllers' JTC documentation: "it adds trajectory's effort as
feedforward effort to the PID output"). The ROS side fills the message from
:class:`TrajectoryPoint`; the forward controllers' ``Float64MultiArray`` (arms x actuators,
arm-major) is :func:`pg_node.ros.command.to_msg`.
"""
from dataclasses import dataclass
from typing import Dict, List, Tuple

import numpy as np
from pg_node.control.interfaces import CommandInterface


@dataclass
class TrajectoryPoint:
    """A one-point trajectory: joint names, the point's fields, and when it is to be reached."""

    joint_names: List[str]
    fields: Dict[str, List[float]]      # JointTrajectoryPoint field -> values, arm-major
    time_from_start: Tuple[int, int]    # (sec, nanosec)


def trajectory_point(interface: CommandInterface, si: np.ndarray, q: np.ndarray,
                     qdot: np.ndarray, joint_names: List[str], rate: float) -> TrajectoryPoint:
    """
    Return SI commands ``si`` ``(arms, nu)`` as a point reached one period of ``rate`` Hz on.

    ``q``, ``qdot``: the measured angles and velocities of the actuated joints ``(arms, nu)``;
    ``joint_names``: their names, arm-major.

    >>> from pg_node.control.interfaces import INTERFACES
    >>> p = trajectory_point(INTERFACES['effort'], np.array([[2.0, -1.0]]),
    ...                      np.array([[0.1, 0.2]]), np.array([[0.0, 0.5]]), ['a', 'b'], 25.0)
    >>> p.fields, p.time_from_start
    ({'effort': [2.0, -1.0], 'positions': [0.1, 0.2], 'velocities': [0.0, 0.5]}, (0, 40000000))
    """
    fields = {interface.trajectory_field: si.ravel().tolist()}
    if interface.trajectory_field != 'positions':
        fields['positions'] = q.ravel().tolist()
        fields['velocities'] = qdot.ravel().tolist()
    period = int(1e9 / rate)
    return TrajectoryPoint(list(joint_names), fields, divmod(period, 1_000_000_000))
