"""
What configure asks of the arm controller: that it carries the card's commands and has a dead-man.

The controller manager says what the arm controller is (its ``list_controllers``: name, type,
state) and the controller, a node, says how it is set up (its parameters). :func:`refusal`
reads both, ROS-free, and returns one line naming the parameter that is wrong, or None:

* the controller is not ``active`` (an inactive controller drops every command);
* its type is not one that ``command_message`` speaks to (a joint trajectory controller for
  ``trajectory``, a forward command controller for ``forward``);
* it cannot carry the card's commands: a JTC without the card's interface in
  ``command_interfaces`` (effort to a JTC without effort: rule 9 rejects every message;
  velocity to a position-only JTC: it writes positions only), a velocity JTC whose PID
  adapter scales the commanded speed by ``ff_velocity_scale`` 0, or one that rejects every
  moving command (``allow_nonzero_velocity_at_trajectory_end`` false); a forward controller of
  another ``interface_name``;
* it has no dead-man, nothing that stops the arm when the commands stop: every forward
  command controller, a JTC without ``cmd_timeout`` above ``constraints.goal_time``, unless
  the user opts out with :data:`OPT_OUT`;
* on the effort interface, its PID does not fit ``controller_hold`` (:func:`_effort_pid`):
  with ``pd`` (points that carry the measured speeds, holds of velocity 0) every joint needs
  a ``d`` gain (its timeout hold is ``-d qdot``, 0 N m without), ``ff_velocity_scale`` 0 (it
  would add the carried speed as a torque) and ``allow_nonzero_velocity_at_trajectory_end``
  true (rule 5 rejects a last point with a speed); with ``none`` (no velocities: a desired
  speed of 0) a ``p`` or ``d`` gain acts on every command, pulling towards the one-tick-old
  angles or damping towards rest.

Citations are to ros2_controllers, branch jazzy, commit ed360c97d (``jtc.cpp``,
``params.yaml``: as in :mod:`pg_node.control.jtc`; ``forward_controllers_base.cpp``:
``forward_command_controller/src/forward_controllers_base.cpp``) and to
Universal_Robots_ROS2_Driver, branch jazzy, commit a16a26876.
"""
from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

#: the parameter that lets a set-up without a dead-man pass configure
OPT_OUT = 'allow_no_dead_man'

#: joint trajectory controllers: Jazzy's, and the UR driver's scaled one, a subclass of it with
#: the same parameters plus speed scaling (ur_controllers/src/
#: scaled_joint_trajectory_controller_parameters.yaml:1-6), which honours cmd_timeout
#: (scaled_joint_trajectory_controller.cpp:178) but is shipped without one
#: (ur_robot_driver/config/ur_controllers.yaml:117-143)
TRAJECTORY_TYPES = ('joint_trajectory_controller/JointTrajectoryController',
                    'ur_controllers/ScaledJointTrajectoryController')
#: forward command controllers -> the interface they command (None: their ``interface_name``);
#: the JointGroup* types set ``interface_name`` themselves (e.g.
#: velocity_controllers/src/joint_group_velocity_controller.cpp:27, 43)
FORWARD_TYPES = {
    'forward_command_controller/ForwardCommandController': None,
    'position_controllers/JointGroupPositionController': 'position',
    'velocity_controllers/JointGroupVelocityController': 'velocity',
    'effort_controllers/JointGroupEffortController': 'effort',
}
#: what each command_message needs, and the types that provide it
NEEDS = {'trajectory': ('a joint trajectory controller', TRAJECTORY_TYPES),
         'forward': ('a forward command controller', tuple(FORWARD_TYPES))}

#: the parameters configure reads (``gains.<joint>.ff_velocity_scale``, ``.p`` and ``.d`` per
#: joint besides)
PARAMETERS = ('joints', 'command_interfaces', 'state_interfaces', 'open_loop_control',
              'cmd_timeout', 'constraints.goal_time', 'allow_nonzero_velocity_at_trajectory_end',
              'interface_name')


@dataclass(frozen=True)
class Controller:
    """
    The arm controller as the controller manager and its parameter service show it.

    ``params``: the parameters it has, by their full names (``gains.joint0.ff_velocity_scale``);
    one it does not declare is absent. ``path``: its node's full name, for the messages.
    """

    name: str
    controller_type: str
    state: str
    params: Mapping[str, object] = field(default_factory=dict)
    path: str = ''

    def ff_velocity_names(self) -> Sequence[str]:
        """Return the names of its joints' ``ff_velocity_scale`` gains."""
        return [f'gains.{j}.ff_velocity_scale' for j in self.params.get('joints', ())]

    def gain_names(self) -> Sequence[str]:
        """Return the names of its joints' gains configure reads (params.yaml:142-215)."""
        return [f'gains.{j}.{g}' for j in self.params.get('joints', ())
                for g in ('ff_velocity_scale', 'p', 'd')]


def refusal(ctrl: Controller, interface: str, command_message: str,
            allow_no_dead_man: bool = False, controller_hold: str = 'none') -> Optional[str]:
    """
    Return why configure refuses to drive ``ctrl`` with the card's commands, or None.

    ``interface``: the card's command interface (effort, position, velocity);
    ``command_message``: policy_node's (trajectory or forward); ``controller_hold``:
    policy_node's (``pd``: effort points carry the measured speeds).

    >>> jtc = Controller('arm_controller', TRAJECTORY_TYPES[0], 'active',
    ...                  {'command_interfaces': ['position'], 'cmd_timeout': 0.2})
    >>> refusal(jtc, 'position', 'trajectory') is None
    True
    >>> print(refusal(jtc, 'velocity', 'trajectory'))
    controller arm_controller has command_interfaces [position]: it cannot carry the card's \
velocity commands (a JTC writes only its command_interfaces, jtc.cpp:417-440); give it velocity
    """
    who = f'controller {ctrl.path or ctrl.name}'
    if ctrl.state != 'active':
        return (f'{who} is {ctrl.state or "in no state"}, not active: it would drop every '
                'command (activate it with the controller manager before configure)')
    what, types = NEEDS[command_message]
    if ctrl.controller_type not in types:
        return (f'{who} is of type {ctrl.controller_type}, not {what} as command_message '
                f'{command_message} needs ({", ".join(types)})')
    carry = (_jtc_cannot_carry if command_message == 'trajectory' else _forward_cannot_carry)
    reason = carry(ctrl, interface)
    if reason is None and command_message == 'trajectory' and interface == 'effort':
        reason = _effort_pid(ctrl, controller_hold)
    if reason is not None:
        return f'{who} {reason}'
    if allow_no_dead_man:
        return None
    dead_man = (_jtc_no_dead_man if command_message == 'trajectory' else _forward_no_dead_man)
    reason = dead_man(ctrl)
    if reason is not None:
        return f'{who} {reason}, or set {OPT_OUT} true to drive it without one'
    return None


def _jtc_cannot_carry(ctrl: Controller, interface: str) -> Optional[str]:
    p = ctrl.params
    cmd = list(p.get('command_interfaces', ()))
    if interface not in cmd:
        return (f'has command_interfaces [{", ".join(cmd)}]: it cannot carry the card\'s '
                f'{interface} commands (a JTC writes only its command_interfaces, '
                f'jtc.cpp:417-440); give it {interface}')
    if interface != 'velocity':
        return None
    # the PID adapter runs for a velocity interface alone (jtc.cpp:890-895) and writes
    # velocity x ff_velocity_scale + PID (jtc.cpp:412-425); ff_velocity_scale defaults to 0
    # (params.yaml:174-178): 0 rad/s whatever the policy commands
    if cmd == ['velocity'] and not p.get('open_loop_control', False):
        for name in ctrl.ff_velocity_names():
            scale = float(p.get(name, 0.0))
            if scale <= 0.0:
                return (f'has {name} {scale:g}: its PID adapter sends the commanded speed '
                        f'times {scale:g} (jtc.cpp:412-425, 890-895); set it to 1.0')
    # rule 5: a last point with a velocity is rejected (jtc.cpp:1717-1730; params.yaml:129-133)
    if not p.get('allow_nonzero_velocity_at_trajectory_end', False):
        return ('has allow_nonzero_velocity_at_trajectory_end false: it rejects every command '
                'that moves (a one-point trajectory with a velocity, jtc.cpp:1717-1730); set '
                'it true')
    return None


def _effort_pid(ctrl: Controller, controller_hold: str) -> Optional[str]:
    """
    Return why a JTC's effort PID does not fit ``controller_hold``, or None.

    The effort is ``ff_velocity_scale v + effort + p (positions - q) + d (velocities - qdot)``
    (jtc.cpp:416-426, 1494-1520; a point without velocities desires 0, trajectory.cpp:
    238-250); its hold after ``cmd_timeout`` is the measured positions with velocity and
    effort 0 (jtc.cpp:2063-2086).

    >>> jtc = Controller('arm', TRAJECTORY_TYPES[0], 'active', {'joints': ['j0'],
    ...                  'gains.j0.d': 0.0, 'allow_nonzero_velocity_at_trajectory_end': True})
    >>> print(_effort_pid(jtc, 'pd'))
    has gains.j0.d 0: its hold after cmd_timeout is 0 N m, which lets an arm whose weight the \
robot carries coast (controller_hold pd brakes with -d x qdot); give every joint a d gain, \
e.g. its inertia / (4 x the command period)
    """
    p = ctrl.params
    joints = list(p.get('joints', ()))
    if controller_hold == 'pd':
        for j in joints:
            d = float(p.get(f'gains.{j}.d', 0.0))
            if d <= 0.0:
                return (f'has gains.{j}.d {d:g}: its hold after '
                        'cmd_timeout is 0 N m, which lets an arm whose weight the robot carries '
                        'coast (controller_hold pd brakes with -d x qdot); give every joint a d '
                        'gain, e.g. its inertia / (4 x the command period)')
            scale = float(p.get(f'gains.{j}.ff_velocity_scale', 0.0))
            if scale != 0.0:
                return (f'has gains.{j}.ff_velocity_scale {scale:g}: it would add the measured '
                        'speed the points carry (controller_hold pd) as a torque '
                        '(jtc.cpp:416-426); set it to 0')
        if not p.get('allow_nonzero_velocity_at_trajectory_end', False):
            return ('has allow_nonzero_velocity_at_trajectory_end false: it rejects every point '
                    'that carries a speed (controller_hold pd; rule 5, jtc.cpp:1717-1730); set '
                    'it true')
        return None
    for j in joints:
        for gain, does in (('p', 'pulls every command towards the one-tick-old angles the '
                                 'points carry'),
                           ('d', 'damps every command towards rest (the points carry no '
                                 'speed)')):
            value = float(p.get(f'gains.{j}.{gain}', 0.0))
            if value != 0.0:
                return (f'has gains.{j}.{gain} {value:g}: its PID {does} (jtc.cpp:416-426); '
                        'set controller_hold pd for a d gain, or the gains to 0')
    return None


def _forward_cannot_carry(ctrl: Controller, interface: str) -> Optional[str]:
    commanded = FORWARD_TYPES[ctrl.controller_type] or ctrl.params.get('interface_name', '')
    if commanded != interface:
        return (f'has interface_name {commanded or "(empty)"}: it cannot carry the card\'s '
                f'{interface} commands (forward_command_controller_parameters.yaml:7-11)')
    return None


def _jtc_no_dead_man(ctrl: Controller) -> Optional[str]:
    # cmd_timeout 0 is off; at or below constraints.goal_time JTC turns it off on activate
    # (params.yaml:134-141; jtc.cpp:1231-1250)
    timeout = float(ctrl.params.get('cmd_timeout', 0.0))
    goal_time = float(ctrl.params.get('constraints.goal_time', 0.0))
    if timeout <= 0.0:
        return (f'has cmd_timeout {timeout:g}: no dead-man, it keeps the last command when the '
                'commands stop (params.yaml:134-141); set cmd_timeout to a few command periods')
    if timeout <= goal_time:
        return (f'has cmd_timeout {timeout:g} not above constraints.goal_time {goal_time:g}: '
                'JTC turns the timeout off (jtc.cpp:1231-1250), no dead-man; raise cmd_timeout')
    return None


def _forward_no_dead_man(ctrl: Controller) -> Optional[str]:
    return (f'is a forward command controller ({ctrl.controller_type}): no dead-man, it keeps '
            'the last command forever when the commands stop (forward_controllers_base.cpp:'
            '151-185); drive a joint trajectory controller with cmd_timeout (command_message '
            'trajectory)')
