"""
Commands in SI units: the policy's normalised controls as a robot's controller takes them.

A pg_node policy acts in MuJoCo's control units (``ctrl``, usually ``[-1, 1]``); a robot's
ros2_control controller takes joint efforts in N m or joint positions in rad (REP-103).
The arm model says how one maps to the other. Each actuator of a pg_node arm drives one
joint with MuJoCo's affine law (no activation dynamics)::

    force = gain * ctrl + b0 + b1 * q + b2 * qdot,        joint torque = gear * force

* a **motor** (``b1 = b2 = 0``): the joint effort is ``gear * (gain * ctrl + b0)`` N m, the
  ``effort`` interface;
* a **position servo** (``b1 = -kp < 0``, as ``arm import --actuator position`` writes, the
  target angle mapped from ``ctrl`` over the joint range): the force vanishes at rest at
  ``q* = (gain * ctrl + b0) / -b1`` rad, the ``position`` interface.

Both maps are affine and invertible, so :class:`Actuation` turns controls into SI commands
(``policy_node``) and SI commands back into controls (``sim_node`` as the robot's stand-in)
exactly. A model whose actuators are not all of one kind offers only the interfaces each
of them has; :meth:`Actuation.check` says in one line why an interface is refused.
"""
from typing import Dict, Optional

import mujoco
import numpy as np

#: the SI command interfaces, with their units
UNITS = {'effort': 'N m', 'position': 'rad'}


class Actuation:
    """The affine maps between an arm model's controls and its SI commands."""

    def __init__(self, model: mujoco.MjModel):
        """Read each actuator's gain, bias and gear (``model``: a pg_node arm model)."""
        self.names = [model.actuator(i).name for i in range(model.nu)]
        self.gain = model.actuator_gainprm[:, 0].copy()
        self.b0, self.b1, self.b2 = (model.actuator_biasprm[:, k].copy() for k in range(3))
        self.gear = model.actuator_gear[:, 0].copy()
        self.joint = model.actuator_trnid[:, 0].copy()
        self.ctrl_low, self.ctrl_high = ctrl_range(model)
        affine = ((model.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
                  & (model.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
                  & (model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT)
                  & (self.gain != 0) & (self.gear != 0))
        self.kind = np.where(~affine, 'other',
                             np.where((self.b1 == 0) & (self.b2 == 0), 'motor',
                                      np.where(self.b1 < 0, 'position', 'other')))

    def check(self, interface: str) -> Optional[str]:
        """Return why ``interface`` cannot command this arm (one line), or None if it can."""
        want = {'effort': 'motor', 'position': 'position'}.get(interface)
        if want is None:
            return (f'unknown command interface {interface!r} (choose one of '
                    f'{", ".join(UNITS)})')
        wrong = [f'{n} ({k})' for n, k in zip(self.names, self.kind) if k != want]
        if wrong:
            other = {'effort': 'position', 'position': 'effort'}[interface]
            return (f"command_interface {interface} needs {want} actuators; this arm's are "
                    f"{', '.join(wrong[:4])}{', ...' if len(wrong) > 4 else ''} "
                    f'(use command_interface {other}, or an arm imported with '
                    f'--actuator {want})')
        return None

    def to_si(self, ctrl: np.ndarray, interface: str) -> np.ndarray:
        """Return the SI command (``N m`` or ``rad``) of controls ``ctrl`` (``(..., nu)``)."""
        force = self.gain * np.asarray(ctrl, dtype=float) + self.b0
        if interface == 'effort':
            return self.gear * force
        return force / -self.b1

    def from_si(self, command: np.ndarray, interface: str) -> np.ndarray:
        """Return the controls whose SI command is ``command`` (inverse of :meth:`to_si`)."""
        command = np.asarray(command, dtype=float)
        if interface == 'effort':
            return (command / self.gear - self.b0) / self.gain
        return (-self.b1 * command - self.b0) / self.gain

    def si_range(self, interface: str):
        """Return ``(low, high)``: the SI commands of the control range, per actuator."""
        a, b = self.to_si(self.ctrl_low, interface), self.to_si(self.ctrl_high, interface)
        return np.minimum(a, b), np.maximum(a, b)

    def card(self) -> Dict:
        """Return, per interface this arm takes, its unit and range (for the policy card)."""
        out = {}
        for interface, unit in UNITS.items():
            if self.check(interface) is None:
                low, high = self.si_range(interface)
                out[interface] = {'unit': unit, 'low': [_finite(v) for v in low],
                                  'high': [_finite(v) for v in high]}
        return out


def ctrl_range(model: mujoco.MjModel):
    """Return each actuator's control range ``(low, high)``, infinite where unlimited."""
    limited = model.actuator_ctrllimited.astype(bool)
    return (np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf),
            np.where(limited, model.actuator_ctrlrange[:, 1], np.inf))


def _finite(value: float):
    return float(value) if np.isfinite(value) else None
