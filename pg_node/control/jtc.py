"""
The joint trajectory controller as Jazzy's ros2_controllers has it: what it accepts, how it holds.

ros2_controllers' ``joint_trajectory_controller`` (JTC) takes
``trajectory_msgs/JointTrajectory`` on ``~/joint_trajectory``; a message it rejects only
logs an error, nothing else (no reply, no counter). This module holds, ROS-free:

* :data:`RULES` and :func:`jtc_rejects`: the checks of ``validate_trajectory_msg``, in its
  order, with the Jazzy defaults of the ``allow_*`` flags that change them (:data:`FLAGS`);
* :func:`interfaces_reject`: the command/state interface combinations JTC takes;
* :data:`JTC_PARAMETERS` and :data:`FORWARD_PARAMETERS`: the controllers' parameter names,
  transcribed, which the shipped ``config/controllers/*.yaml`` use;
* :class:`JtcFollower`: what JTC then does with an accepted message of the kind ``policy_node``
  sends (apply the point, hold it past its end, and after ``cmd_timeout`` the JTC hold),
  which ``sim_node`` follows as the robot's stand-in.

Citations are to ros2_controllers, branch ``jazzy``, commit ed360c97d; ``jtc.cpp`` is
``joint_trajectory_controller/src/joint_trajectory_controller.cpp``, ``params.yaml``
``joint_trajectory_controller/src/joint_trajectory_controller_parameters.yaml``,
``trajectory.cpp`` ``joint_trajectory_controller/src/trajectory.cpp``.
"""
from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

#: the tolerance of rule 5: C++ ``std::numeric_limits<float>::epsilon()`` (jtc.cpp:1717-1730)
FLOAT_EPSILON = float(np.finfo(np.float32).eps)

#: the flags that change acceptance, with their Jazzy defaults (params.yaml:75-79, 101-105,
#: 129-133; humble defaulted allow_nonzero_velocity_at_trajectory_end to true)
FLAGS: Dict[str, bool] = {
    'allow_partial_joints_goal': False,
    'allow_integration_in_goal_trajectories': False,
    'allow_nonzero_velocity_at_trajectory_end': False,
}

#: a point's fields (``trajectory_msgs/JointTrajectoryPoint``) that carry one value per joint
POINT_FIELDS = ('positions', 'velocities', 'accelerations', 'effort')


@dataclass
class Point:
    """One trajectory point: its fields (name -> values, one per joint name) and its time."""

    fields: Dict[str, List[float]]
    time_from_start: float = 0.0        # s from the trajectory's start

    def get(self, name: str) -> List[float]:
        """Return field ``name``'s values (empty when the point has none)."""
        return list(self.fields.get(name, ()))


@dataclass
class Trajectory:
    """A ``trajectory_msgs/JointTrajectory``; ``stamp`` 0: start now (trajectory.cpp:128-131)."""

    joint_names: List[str]
    points: List[Point]
    stamp: float = 0.0                  # header.stamp in s


@dataclass(frozen=True)
class Rule:
    """One check of ``validate_trajectory_msg``: what it rejects, its flag and its source."""

    number: str
    rejects: str
    flag: Optional[str]
    source: str


#: the checks of ``validate_trajectory_msg`` (jtc.cpp:1671-1816), in the order JTC runs them
RULES: Tuple[Rule, ...] = (
    Rule('1', "the number of joint_names differs from the controller's joints",
         'allow_partial_joints_goal', 'jtc.cpp:1676-1685; params.yaml:75-79'),
    Rule('2', 'joint_names is empty', None, 'jtc.cpp:1688-1692'),
    Rule('3', 'points is empty (the userdoc says it cancels; the code rejects)', None,
         'jtc.cpp:1695-1699'),
    Rule('4', "a joint name is not one of the controller's joints (any order is fine)", None,
         'jtc.cpp:1702-1713'),
    Rule('5', 'a velocity of the last point is not zero (above float epsilon)',
         'allow_nonzero_velocity_at_trajectory_end', 'jtc.cpp:1717-1730; params.yaml:129-133'),
    Rule('6', 'header.stamp is not zero and the trajectory ended before now', None,
         'jtc.cpp:1733-1749'),
    Rule('7', 'time_from_start does not increase strictly from point to point (the first '
              'point is not checked: 0 is legal)', None, 'jtc.cpp:1751-1764'),
    Rule('8', 'integration off: positions missing or of another size, or velocities or '
              'accelerations given in another size; on: a point with none of them, or one '
              'of another size', 'allow_integration_in_goal_trajectories',
         'jtc.cpp:1771-1804; params.yaml:101-105'),
    Rule('9', 'effort given while the controller has no effort command interface', None,
         'jtc.cpp:1806-1813'),
)


def jtc_rejects(msg: Trajectory, joints: Sequence[str], command_interfaces: Sequence[str],
                now: float = 0.0, flags: Optional[Mapping[str, bool]] = None) -> Optional[str]:
    """
    Return why Jazzy's JTC rejects ``msg`` (``rule N: ...``, the first rule hit), or None.

    ``joints``: the controller's ``joints``; ``command_interfaces`` its command interfaces;
    ``now``: the controller's time in s, on the clock of ``msg.stamp`` (rule 6); ``flags``:
    the ``allow_*`` flags, :data:`FLAGS` where not given. NaN and Inf pass: JTC checks
    neither (jtc.cpp:1671-1816), so a non-finite value reaches the hardware.

    >>> point = Point({'positions': [0.1, 0.2], 'velocities': [0.5, 0.0], 'effort': [1, 2]})
    >>> jtc_rejects(Trajectory(['j0', 'j1'], [point]), ['j0', 'j1'], ['effort'])
    'rule 5: velocity of the last trajectory point of joint j0 is not zero (0.5)'
    >>> jtc_rejects(Trajectory(['j1', 'j0'], [Point({'positions': [0.2, 0.1]})]),
    ...             ['j0', 'j1'], ['position']) is None
    True
    """
    f = {**FLAGS, **(flags or {})}
    names, points = list(msg.joint_names), msg.points
    if not f['allow_partial_joints_goal'] and len(names) != len(joints):
        return (f'rule 1: {len(names)} joint names, the controller has {len(joints)} joints '
                '(allow_partial_joints_goal is false)')
    if not names:
        return 'rule 2: empty joint_names'
    if not points:
        return 'rule 3: empty trajectory (no points)'
    unknown = [n for n in names if n not in joints]
    if unknown:
        return f"rule 4: joint {unknown[0]} is not one of the controller's joints"
    if not f['allow_nonzero_velocity_at_trajectory_end']:
        for name, v in zip(names, points[-1].get('velocities')):
            if abs(v) > FLOAT_EPSILON:
                return (f'rule 5: velocity of the last trajectory point of joint {name} is '
                        f'not zero ({v:g})')
    if msg.stamp != 0 and msg.stamp + points[-1].time_from_start < now:
        return 'rule 6: the trajectory ended in the past (header.stamp + time_from_start)'
    for i in range(1, len(points)):
        if points[i].time_from_start <= points[i - 1].time_from_start:
            return f'rule 7: time_from_start of point {i} is not after that of point {i - 1}'
    n = len(names)
    for i, point in enumerate(points):
        sizes = {k: len(point.get(k)) for k in ('positions', 'velocities', 'accelerations')}
        if f['allow_integration_in_goal_trajectories']:
            if not any(sizes.values()):
                return f'rule 8: point {i} has no positions, velocities or accelerations'
            wrong = [k for k, s in sizes.items() if s not in (0, n)]
        else:
            wrong = ['positions'] if sizes['positions'] != n else []
            wrong += [k for k in ('velocities', 'accelerations') if sizes[k] not in (0, n)]
        if wrong:
            return (f'rule 8: point {i} has {sizes[wrong[0]]} {wrong[0]} for {n} joints'
                    + ('' if f['allow_integration_in_goal_trajectories'] else
                       ' (positions are required: allow_integration_in_goal_trajectories is '
                       'false)'))
        if point.get('effort') and 'effort' not in command_interfaces:
            return (f'rule 9: point {i} has efforts, the controller has no effort command '
                    'interface')
    return None


#: the command interface sets JTC takes (validate_jtc_parameters.hpp:27-99, jtc.cpp:931-956)
COMMAND_INTERFACE_SETS = (('effort',), ('velocity',), ('position',), ('position', 'velocity'),
                          ('position', 'velocity', 'acceleration'), ('position', 'effort'))
#: the state interfaces JTC takes (params.yaml:45), in this order
STATE_INTERFACES = ('position', 'velocity', 'acceleration')
#: command sets that need the position and velocity states (a PID, jtc.cpp:931-956)
NEED_POSITION_AND_VELOCITY = (('effort',), ('velocity',), ('position', 'effort'))


def interfaces_reject(command_interfaces: Sequence[str],
                      state_interfaces: Sequence[str]) -> Optional[str]:
    """
    Return why JTC refuses this interface combination at configure, or None.

    >>> interfaces_reject(['effort'], ['position'])
    'command interfaces [effort] need the state interfaces position and velocity'
    """
    cmd, state = tuple(command_interfaces), tuple(state_interfaces)
    if cmd not in COMMAND_INTERFACE_SETS:
        return (f'command interfaces [{", ".join(cmd)}] are not one of '
                + ' | '.join(f'[{", ".join(s)}]' for s in COMMAND_INTERFACE_SETS))
    if not state or any(s not in STATE_INTERFACES for s in state) or \
            list(state) != sorted(state, key=STATE_INTERFACES.index):
        return (f'state interfaces [{", ".join(state)}] are not a subset of '
                f'[{", ".join(STATE_INTERFACES)}] in that order')
    if cmd in NEED_POSITION_AND_VELOCITY and not {'position', 'velocity'} <= set(state):
        return (f'command interfaces [{", ".join(cmd)}] need the state interfaces position '
                'and velocity')
    return None


#: the parameters JTC declares (params.yaml; lines as cited), ``<joint>`` for a joint's name
JTC_PARAMETERS: Dict[str, str] = {
    'joints': 'params.yaml:2-11',
    'command_joints': 'params.yaml:12-24',
    'command_interfaces': 'params.yaml:25-36',
    'state_interfaces': 'params.yaml:37-48',
    'speed_scaling.initial_scaling_factor': 'params.yaml:49-74',
    'speed_scaling.state_interface': 'params.yaml:49-74',
    'speed_scaling.command_interface': 'params.yaml:49-74',
    'allow_partial_joints_goal': 'params.yaml:75-79',
    'open_loop_control': 'params.yaml:80-85',
    'interpolate_from_desired_state': 'params.yaml:86-100',
    'allow_integration_in_goal_trajectories': 'params.yaml:101-105',
    'set_last_command_interface_value_as_state_on_activation': 'params.yaml:106-110',
    'action_monitor_rate': 'params.yaml:111-119',
    'interpolation_method': 'params.yaml:120-128',
    'allow_nonzero_velocity_at_trajectory_end': 'params.yaml:129-133',
    'cmd_timeout': 'params.yaml:134-141',
    **{f'gains.<joint>.{k}': 'params.yaml:142-215' for k in (
        'p', 'i', 'd', 'i_clamp_max', 'i_clamp_min', 'u_clamp_max', 'u_clamp_min',
        'ff_velocity_scale', 'antiwindup_strategy', 'tracking_time_constant',
        'error_deadband')},
    **{f'constraints.{k}': 'params.yaml:216-258' for k in (
        'stopped_velocity_tolerance', 'goal_time', 'decelerate_on_cancel',
        '<joint>.trajectory', '<joint>.goal', '<joint>.max_deceleration_on_cancel')},
}
#: the forward command controllers' parameters
#: (forward_command_controller/src/forward_command_controller_parameters.yaml:1-11; the
#: JointGroup* types set interface_name themselves, joint_group_effort_controller.cpp:30-51)
FORWARD_PARAMETERS: Dict[str, str] = {
    'joints': 'forward_command_controller_parameters.yaml:1-11',
    'interface_name': 'forward_command_controller_parameters.yaml:1-11',
}


def parameter_keys(section: Mapping, joints: Sequence[str], prefix: str = '') -> List[str]:
    """
    Return the keys of a controller's ``ros__parameters`` flattened, joint names as ``<joint>``.

    >>> parameter_keys({'gains': {'j0': {'p': 0.0}}, 'cmd_timeout': 0.2}, ['j0'])
    ['gains.<joint>.p', 'cmd_timeout']
    """
    keys = []
    for key, value in section.items():
        name = prefix + ('<joint>' if key in joints else str(key))
        if isinstance(value, Mapping):
            keys += parameter_keys(value, joints, name + '.')
        else:
            keys.append(name)
    return keys


#: the stand-in's command interfaces: per interface, the point field it writes
FOLLOWED_FIELD = {'effort': 'effort', 'position': 'positions', 'velocity': 'velocities'}
#: the ``allow_*`` flags each interface's shipped controller sets (config/controllers/
#: jtc_<interface>.yaml), where they differ from :data:`FLAGS`
SHIPPED_FLAGS = {'velocity': {'allow_nonzero_velocity_at_trajectory_end': True}}


def stand_in_flags(interface: str, d_gain: float = 0.0) -> Dict[str, bool]:
    """
    Return the ``allow_*`` flags of the shipped controller a stand-in follows.

    ``jtc_<interface>.yaml``'s (:data:`SHIPPED_FLAGS`); on the effort interface with a ``d``
    gain, ``jtc_effort_pd.yaml``'s: points that end with the measured speed are taken.

    >>> stand_in_flags('effort', 6.25)
    {'allow_nonzero_velocity_at_trajectory_end': True}
    """
    flags = dict(SHIPPED_FLAGS.get(interface, {}))
    if interface == 'effort' and d_gain > 0:
        flags['allow_nonzero_velocity_at_trajectory_end'] = True
    return flags


@dataclass
class JtcFollower:
    """
    Jazzy's JTC following the trajectories it accepts, for one command interface.

    What it does (the hardware's command at each :meth:`command` call):

    * before any accepted message: nothing (``None``; the interface keeps what it had);
    * an accepted message replaces the one being followed (``stamp`` 0: it starts now,
      trajectory.cpp:128-131); each point takes effect at its ``time_from_start``, held
      until the next (JTC's ``interpolation_method: none``, trajectory.cpp:148-169; with
      ``splines`` JTC would ramp there instead: the same for the one point at
      ``time_from_start`` 0 that ``policy_node`` sends, which JTC applies on its first
      cycle). The effort interface sends the point's effort plus its PID of the errors,
      here ``d (velocities - measured speeds)`` (``p`` and ``i`` 0; jtc.cpp:416-426,
      1494-1520; an empty field is 0, trajectory.cpp:238-250): with the zero gains of
      ``config/controllers/jtc_effort.yaml`` (params.yaml:144-178) the effort passes through;
      with ``d`` gains and points that carry the measured speeds
      (``config/controllers/jtc_effort_pd.yaml``) the PID finds no error while commands come
      and brakes once they stop;
    * past the last point, the last point is held (trajectory.cpp:208-253), empty efforts
      as 0;
    * ``cmd_timeout`` s after the last point's time, JTC's hold (jtc.cpp:350-369,
      2063-2086): the positions measured at that moment, velocity 0 and effort 0: on the
      effort interface 0 N m with zero gains, ``-d qdot`` with a ``d`` gain, on the
      velocity interface 0 rad/s (zero gains; ``ff_velocity_scale`` times the hold point's
      0), on the position interface those positions; held until the next accepted message.
      A ``cmd_timeout`` not above ``goal_time`` is off (jtc.cpp:1231-1250). The stand-in
      computes the command once per call (its control step), a JTC at its update rate.

    Beyond JTC, the stand-in refuses what JTC would pass on unchecked (no hardware to spare):
    non-finite values (JTC has no check, jtc.cpp:1671-1816) and efforts of another size
    (JTC reads past them, jtc.cpp:1617-1621, trajectory.cpp:296-312).
    """

    joints: List[str]
    interface: str                      # a key of FOLLOWED_FIELD
    cmd_timeout: float
    goal_time: float = 0.0
    flags: Dict[str, bool] = field(default_factory=dict)
    timeouts: int = 0                   # JTC holds after cmd_timeout so far
    #: the effort PID's ``d`` gain per joint (``gains.<joint>.d``; one value: every joint); empty:
    #: 0. Its ``p`` and ``i`` are 0, as in the shipped jtc_effort*.yaml
    d: Sequence[float] = ()

    def __post_init__(self):
        """Apply the ``cmd_timeout`` rule and start with nothing to follow."""
        if self.interface not in FOLLOWED_FIELD:
            raise ValueError(f'no JTC stand-in for command interface {self.interface!r} '
                             f'(one of {", ".join(FOLLOWED_FIELD)})')
        self.timeout_used = self.cmd_timeout if self.cmd_timeout > self.goal_time else 0.0
        self.kd = np.broadcast_to(np.asarray(self.d if len(self.d) else 0.0, dtype=float),
                                  len(self.joints))
        # (time, command, desired speeds); the speeds for the effort PID
        self.points: Optional[List[Tuple[float, np.ndarray, np.ndarray]]] = None
        self.start = 0.0
        self.holding = False

    def receive(self, msg: Trajectory, now: float) -> Optional[str]:
        """Take ``msg`` at time ``now`` (s) and follow it; return why it is rejected, or None."""
        reason = jtc_rejects(msg, self.joints, [self.interface], now, self.flags)
        if reason is not None:
            return reason
        n = len(msg.joint_names)
        for i, point in enumerate(msg.points):
            if len(point.get('effort')) not in (0, n):
                return (f'point {i} has {len(point.get("effort"))} efforts for {n} joints '
                        '(JTC does not check it and reads past them)')
            if not all(np.all(np.isfinite(point.get(k))) for k in POINT_FIELDS):
                return (f'point {i} has a non-finite value (JTC does not check it and sends '
                        'it to the hardware)')
        # names in any order: to the controller's order (jtc.cpp:1603-1650)
        order = [msg.joint_names.index(j) for j in self.joints]

        def field_of(point, key):
            values = point.get(key)
            return (np.asarray(values, dtype=float)[order] if values
                    else np.zeros(len(self.joints)))
        key = FOLLOWED_FIELD[self.interface]
        self.points = [(p.time_from_start, field_of(p, key), field_of(p, 'velocities'))
                       for p in msg.points]
        self.start = msg.stamp if msg.stamp else now
        self.holding = False
        return None

    def command(self, now: float, measured: np.ndarray,
                speeds: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        """
        Return the command at time ``now`` (s), in the controller's joint order, or None.

        ``measured``: the joints' measured positions (the hold's, on a timeout); ``speeds``:
        their measured speeds (the effort PID's velocity error; None: 0).
        """
        if self.points is None:
            return None
        t = now - self.start
        end = self.points[-1][0]
        zero = np.zeros(len(self.joints))
        if not self.holding and self.timeout_used > 0 and t - end > self.timeout_used:
            # "Aborted due to command timeout": the hold point, now (jtc.cpp:350-369): the
            # measured positions, velocity and effort 0 (jtc.cpp:2063-2086)
            hold = np.array(measured, dtype=float) if self.interface == 'position' else zero
            self.points, self.start, self.holding = [(0.0, hold, zero)], now, True
            self.timeouts += 1
            t = 0.0
        due = [point for point in self.points if point[0] <= t]
        if not due:
            return None
        _, cmd, velocities = due[-1]
        if self.interface != 'effort':
            return cmd.copy()
        qdot = zero if speeds is None else np.asarray(speeds, dtype=float)
        return cmd + self.kd * (velocities - qdot)
