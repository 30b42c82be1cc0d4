"""
A command as Jazzy's joint trajectory controller takes it: "apply this now, hold it", ROS-free.

ros2_controllers' joint trajectory controller (JTC, :mod:`pg_node.control.jtc` for its rules)
takes ``trajectory_msgs/JointTrajectory``. ``policy_node`` sends each command as the message
that JTC accepts under its Jazzy defaults and applies at once: ``header.stamp`` 0 (start
now), every joint's name, **one point** at ``time_from_start`` 0. JTC applies such a point
on its first cycle, without interpolating from the current state (trajectory.cpp:148,
208-253), holds it past its end until the next message (trajectory.cpp:208-253), and
``cmd_timeout`` s after it came, with no new one, holds the arm its own way
(jtc.cpp:350-369): the stop that holds when ``policy_node`` dies.

The point's fields per command interface are :data:`POINT_FIELDS`, one row per interface:

* ``effort``: ``effort`` = the torques, ``positions`` = the measured angles, no
  ``velocities``. Positions are required (rule 8: ``allow_integration_in_goal_trajectories``
  is false); with the zero gains of ``config/controllers/jtc_effort.yaml`` the PID adds
  nothing and the efforts pass through (jtc.cpp:416-426), so the positions are unused;
  should someone set gains, measured angles give the P term no error to fight, where NaN
  would make the command NaN. Velocities stay empty: Jazzy rejects a last point with a
  non-zero velocity (rule 5, ``allow_nonzero_velocity_at_trajectory_end`` false,
  jtc.cpp:1717-1730), and an empty field is a desired velocity of 0. With ``policy_node``'s
  ``controller_hold`` ``pd`` (:func:`command_trajectory`'s ``qdot``) the point carries the
  measured speeds as its ``velocities``, and a hold is the point ``effort`` 0, ``velocities``
  0: a JTC with ``d`` gains (``config/controllers/jtc_effort_pd.yaml``, which allows a
  non-zero velocity at the end) finds no speed error while commands come and brakes from its
  own fresh state, ``-d qdot``, in a hold and after ``cmd_timeout`` when they stop;
* ``position``: ``positions`` = the commanded angles, nothing else;
* ``velocity``: ``velocities`` = the speeds, ``positions`` = the measured angles (required,
  rule 8). JTC on a velocity command interface alone runs its PID adapter (jtc.cpp:890-895)
  and sends ``velocity * ff_velocity_scale + PID(position error, velocity error)``
  (jtc.cpp:412-425, 434-439); ``config/controllers/jtc_velocity.yaml`` sets
  ``ff_velocity_scale: 1.0`` (its default 0.0 would send 0, params.yaml:174-178) and zero
  gains, so the speed passes through; and ``allow_nonzero_velocity_at_trajectory_end:
  true``, without which rule 5 rejects every command that moves.
The forward controllers' ``Float64MultiArray`` is :func:`pg_node.ros.command.to_msg`.
"""
from typing import Dict, List, Optional, Tuple

import numpy as np
from pg_node.control.interfaces import CommandInterface
from pg_node.control.jtc import Point, Trajectory

#: where a point's field comes from: the SI command, or the measured joint positions
COMMAND, MEASURED = 'command', 'measured'
#: per command interface, the point's fields and their sources (the table above)
POINT_FIELDS: Dict[str, Tuple[Tuple[str, str], ...]] = {
    'effort': (('positions', MEASURED), ('effort', COMMAND)),
    'position': (('positions', COMMAND),),
    'velocity': (('positions', MEASURED), ('velocities', COMMAND)),
}


def command_trajectory(interface: CommandInterface, si: np.ndarray, q: np.ndarray,
                       joint_names: List[str], qdot: Optional[np.ndarray] = None,
                       hold: bool = False) -> Trajectory:
    """
    Return SI commands ``si`` ``(arms, nu)`` as the one-point trajectory JTC applies at once.

    ``q``: the measured angles of the actuated joints ``(arms, nu)``; ``joint_names``: their
    names, arm-major. ``qdot`` (effort; ``controller_hold`` ``pd``): their measured speeds,
    carried as the point's velocities; then a ``hold`` is velocity 0 and effort 0, the
    controller's PD brake.

    >>> from pg_node.control.interfaces import INTERFACES
    >>> t = command_trajectory(INTERFACES['effort'], np.array([[2.0, -1.0]]),
    ...                        np.array([[0.1, 0.2]]), ['a', 'b'])
    >>> t.stamp, t.points[0].fields, t.points[0].time_from_start
    (0.0, {'positions': [0.1, 0.2], 'effort': [2.0, -1.0]}, 0.0)
    >>> command_trajectory(INTERFACES['effort'], np.array([[2.0, -1.0]]), np.array([[0.1, 0.2]]),
    ...                    ['a', 'b'], qdot=np.array([[0.5, 0.0]])).points[0].fields
    {'positions': [0.1, 0.2], 'effort': [2.0, -1.0], 'velocities': [0.5, 0.0]}
    """
    source = {COMMAND: si, MEASURED: q}
    fields = {name: np.asarray(source[what], dtype=float).ravel().tolist()
              for name, what in POINT_FIELDS[interface.name]}
    if qdot is not None and interface.name == 'effort':
        speeds = np.zeros_like(np.asarray(si, dtype=float)) if hold else qdot
        fields['velocities'] = np.asarray(speeds, dtype=float).ravel().tolist()
        if hold:
            fields['effort'] = [0.0] * len(fields['effort'])
    return Trajectory(list(joint_names), [Point(fields, 0.0)], 0.0)
