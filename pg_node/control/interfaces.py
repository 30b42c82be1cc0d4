"""
Command interfaces: the policy's normalised controls as a robot's controller takes them.

A pg_node policy acts in control units (``ctrl``, usually ``[-1, 1]``); a robot's ros2_control
controller takes joint efforts in N m or joint positions in rad (REP-103). The arm's actuators
say how one maps to the other. Each actuator of a pg_node arm drives one joint with the affine
law of MuJoCo's actuators (no activation dynamics)::

    force = gain * ctrl + b0 + b1 * q + b2 * qdot,        joint torque = gear * force

* a **motor** (``b1 = b2 = 0``): the joint effort is ``gear * (gain * ctrl + b0)`` N m, the
  ``effort`` interface;
* a **position servo** (``b1 = -kp < 0``, as ``arm import --actuator position`` writes, the
  target angle mapped from ``ctrl`` over the joint range): the force vanishes at rest at
  ``q* = (gain * ctrl + b0) / -b1`` rad, the ``position`` interface;
* a **velocity servo** (``b1 = 0``, ``b2 = -kv < 0``, as ``arm import --actuator velocity``
  writes, the target speed mapped from ``ctrl`` over the URDF's velocity limits, MuJoCo's
  ``<velocity>`` actuator): the force vanishes at ``qdot* = (gain * ctrl + b0) / -b2``
  rad/s, the ``velocity`` interface.

The maps are affine and invertible, so an interface turns controls into SI commands
(``policy_node``) and SI commands back into controls (``sim_node`` as the robot's stand-in)
exactly. :data:`INTERFACES` holds one :class:`CommandInterface` per name, with all that
differs between them (unit, actuator kind, hold, trajectory field, the maps); an arm whose
actuators are not all of one kind offers only the interfaces each of them has, and
:func:`check` says in one line why an interface is refused. The numbers come in a plain
:class:`Actuators` record (:func:`pg_node.sim.actuation.actuators` reads one from a MuJoCo
model).
"""
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Tuple

import numpy as np


@dataclass(frozen=True)
class Actuators:
    """
    An arm's actuators, one entry per actuator: the affine law's numbers and what it drives.

    ``affine``: the actuator follows the law above (fixed gain, no activation dynamics, one
    joint, non-zero gain and gear); ``ctrl_low``/``ctrl_high`` and ``joint_low``/
    ``joint_high`` are infinite where unlimited. What the guards take their defaults from,
    per actuator's joint: ``damping`` (N m s/rad, the model's joint damping), ``force_limit``
    (N m, the largest torque the model lets the actuator apply; infinite where none) and
    ``inertia`` (kg m^2, the joint's largest over the model's poses, armature included).
    """

    names: Tuple[str, ...]
    joints: Tuple[str, ...]             # the joint each actuator drives
    gain: np.ndarray
    b0: np.ndarray
    b1: np.ndarray
    b2: np.ndarray
    gear: np.ndarray
    ctrl_low: np.ndarray
    ctrl_high: np.ndarray
    joint_low: np.ndarray
    joint_high: np.ndarray
    affine: np.ndarray
    damping: np.ndarray
    force_limit: np.ndarray
    inertia: np.ndarray

    @property
    def kind(self) -> np.ndarray:
        """Return each actuator's kind: ``motor``, ``position``, ``velocity`` or ``other``."""
        return np.where(~self.affine, 'other',
                        np.where((self.b1 == 0) & (self.b2 == 0), 'motor',
                                 np.where(self.b1 < 0, 'position',
                                          np.where((self.b1 == 0) & (self.b2 < 0), 'velocity',
                                                   'other'))))

    @property
    def zero_effort(self) -> np.ndarray:
        """Return the controls of zero joint effort."""
        return -self.b0 / self.gain


#: the hold of an interface (:meth:`pg_node.control.guards.CommandGuard.hold`): a damping
#: torque against the measured velocity (and a spring to the angle where the hold began), or
#: the last commanded angle kept. Not zero effort: on an arm whose driver compensates gravity
#: (libfranka (main 155ddac) include/franka/control_types.h:43: torques "without gravity and
#: friction") zero torque lets it float and coast.
HOLD_DAMPING = 'damping'
HOLD_LAST_COMMAND = 'last commanded angles'
#: the velocity interface's hold: a target speed of zero, the servo brakes the joint
HOLD_ZERO_VELOCITY = 'zero velocity'
#: what the joint-limit guard does near a limit: brake a joint whose braking distance
#: reaches the limit, or keep a target angle inside the range
LIMIT_BRAKING = 'braking distance'
LIMIT_INSIDE = 'target kept inside'
#: ... or cap the speed towards a limit so that the joint can still stop before it
LIMIT_VELOCITY_CAP = 'speed capped by the braking distance'


@dataclass(frozen=True)
class CommandInterface:
    """
    One command interface: what a controller of that name takes, and how controls map to it.

    ``actuator``: the actuator kind that has it; ``hold``: the command that stops the arm
    where it is (:data:`HOLD_DAMPING`, :data:`HOLD_LAST_COMMAND` or
    :data:`HOLD_ZERO_VELOCITY`); ``limit``: the joint-limit guard's rule
    (:data:`LIMIT_BRAKING`, :data:`LIMIT_INSIDE` or :data:`LIMIT_VELOCITY_CAP`);
    ``trajectory_field``: the ``trajectory_msgs/JointTrajectoryPoint`` field that carries
    it; ``to_si`` and ``from_si``: the maps between controls ``(..., nu)`` and SI commands,
    inverse to each other.
    """

    name: str
    unit: str
    actuator: str
    hold: str
    limit: str
    trajectory_field: str
    to_si: Callable[[Actuators, np.ndarray], np.ndarray]
    from_si: Callable[[Actuators, np.ndarray], np.ndarray]

    def si_range(self, act: Actuators):
        """Return ``(low, high)``: the SI commands of the control range, per actuator."""
        a, b = self.to_si(act, act.ctrl_low), self.to_si(act, act.ctrl_high)
        return np.minimum(a, b), np.maximum(a, b)


def _effort_to_si(act: Actuators, ctrl) -> np.ndarray:
    return act.gear * (act.gain * np.asarray(ctrl, dtype=float) + act.b0)


def _effort_from_si(act: Actuators, command) -> np.ndarray:
    return (np.asarray(command, dtype=float) / act.gear - act.b0) / act.gain


def _position_to_si(act: Actuators, ctrl) -> np.ndarray:
    return (act.gain * np.asarray(ctrl, dtype=float) + act.b0) / -act.b1


def _position_from_si(act: Actuators, command) -> np.ndarray:
    return (-act.b1 * np.asarray(command, dtype=float) - act.b0) / act.gain


def _velocity_to_si(act: Actuators, ctrl) -> np.ndarray:
    return (act.gain * np.asarray(ctrl, dtype=float) + act.b0) / -act.b2


def _velocity_from_si(act: Actuators, command) -> np.ndarray:
    return (-act.b2 * np.asarray(command, dtype=float) - act.b0) / act.gain


#: the SI command interfaces by name (a new one is one entry here)
INTERFACES: Dict[str, CommandInterface] = {
    'effort': CommandInterface('effort', 'N m', 'motor', HOLD_DAMPING, LIMIT_BRAKING,
                               'effort', _effort_to_si, _effort_from_si),
    'position': CommandInterface('position', 'rad', 'position', HOLD_LAST_COMMAND,
                                 LIMIT_INSIDE, 'positions', _position_to_si,
                                 _position_from_si),
    'velocity': CommandInterface('velocity', 'rad/s', 'velocity', HOLD_ZERO_VELOCITY,
                                 LIMIT_VELOCITY_CAP, 'velocities', _velocity_to_si,
                                 _velocity_from_si),
}


def check(act: Actuators, interface: str) -> Optional[str]:
    """Return why ``interface`` cannot command these actuators (one line), or None if it can."""
    if interface not in INTERFACES:
        return (f'unknown command interface {interface!r} (choose one of '
                f'{", ".join(INTERFACES)})')
    want = INTERFACES[interface].actuator
    wrong = [f'{n} ({k})' for n, k in zip(act.names, act.kind) if k != want]
    if wrong:
        # the interface these actuators take, if they are all of one kind that has one
        fits = [name for name, i in INTERFACES.items() if {i.actuator} == set(act.kind)]
        other = fits[0] if fits else ' or '.join(n for n in INTERFACES if n != interface)
        return (f"command_interface {interface} needs {want} actuators; this arm's are "
                f"{', '.join(wrong[:4])}{', ...' if len(wrong) > 4 else ''} "
                f'(use command_interface {other}, or an arm imported with '
                f'--actuator {want})')
    return None


def card(act: Actuators) -> Dict:
    """Return, per interface these actuators take, its unit and range (for the policy card)."""
    out = {}
    for name, interface in INTERFACES.items():
        if check(act, name) is None:
            low, high = interface.si_range(act)
            out[name] = {'unit': interface.unit, 'low': [_finite(v) for v in low],
                         'high': [_finite(v) for v in high]}
    return out


def _finite(value: float):
    return float(value) if np.isfinite(value) else None
