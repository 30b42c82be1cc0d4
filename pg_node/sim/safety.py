"""
The safety habits of a controller between a policy and a robot (no ROS here).

:class:`CommandGuard` turns the policy's action for a measured joint state into the command
a robot may get, in the policy's control units (:mod:`pg_node.sim.actuation` converts to
N m or rad), one control tick at a time. In order, per arm:

1. **range**: a non-finite action becomes the hold command; the rest is clipped to the
   actuators' control range;
2. **ramp**: for ``ramp_time`` s after activation the command is blended from the hold
   command to the policy's, linearly (ros2_control controllers and MoveIt Servo start from
   hold too, rather than jumping to the first command);
3. **smoothing**: a first-order low-pass filter, ``u = s * previous + (1 - s) * u`` with
   ``s = smoothing`` (0: off);
4. **rate limit**: each actuator changes by at most ``max_change`` of its control range per
   tick (0: off);
5. **joint limits**: a limited joint within ``joint_limit_margin`` rad of (or past) a limit
   gets no command that drives it further: with the effort interface the torque towards the
   limit becomes zero; with the position interface the target is kept ``margin`` inside
   the range;
6. **over-speed**: an arm with a joint faster than ``max_velocity`` rad/s (0: off) gets the
   hold command for this tick.

The **hold** command is what an arm gets when it must not move on its own: zero effort
(with the effort interface; the robot's gravity compensation holds it, if it has any), or
the measured joint angles (with the position interface: the robot's position loop holds
them). Steps 3 and 4 act on the sequence of published commands, holds included, so a
command resuming after a hold is smoothed and rate-limited from the hold.
"""
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

import mujoco
import numpy as np
from pg_node.sim.actuation import Actuation


@dataclass
class GuardSettings:
    """The guard's parameters (policy_node's of the same names)."""

    smoothing: float = 0.0
    max_change: float = 0.0
    joint_limit_margin: float = 0.05
    max_velocity: float = 0.0
    ramp_time: float = 0.0


#: the guards that can act on a tick, as counted in /diagnostics
EVENTS = ('nonfinite', 'clipped', 'ramped', 'rate_limited', 'joint_limit', 'over_speed')


class CommandGuard:
    """Shape and guard a policy's actions for one arm model, tick by tick."""

    def __init__(self, model: mujoco.MjModel, joint_names, interface: str,
                 settings: Optional[GuardSettings] = None):
        """
        Read the actuators and the limits of their joints.

        ``joint_names``: the order of the joint angles given to :meth:`__call__` (the
        policy card's); each actuator's joint must be among them.
        """
        self.act = Actuation(model)
        self.interface = interface
        self.settings = settings or GuardSettings()
        names = [model.joint(int(j)).name for j in self.act.joint]
        index = {n: i for i, n in enumerate(joint_names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise ValueError(f'actuated joints {", ".join(missing)} are not among the joints '
                             f'{", ".join(joint_names)}')
        self.cols = np.array([index[n] for n in names], dtype=int)
        limited = model.jnt_limited[self.act.joint].astype(bool)
        rng = model.jnt_range[self.act.joint]
        self.q_low = np.where(limited, rng[:, 0], -np.inf)
        self.q_high = np.where(limited, rng[:, 1], np.inf)
        self.low, self.high = self.act.ctrl_low, self.act.ctrl_high
        span = self.high - self.low
        self.span = np.where(np.isfinite(span), span, 2.0)
        self.zero = -self.act.b0 / self.act.gain          # the control of zero effort
        self.previous: Optional[np.ndarray] = None
        self.ramp_start: Optional[float] = None

    def hold(self, q: Optional[np.ndarray], arms: int) -> np.ndarray:
        """Return the hold command ``(arms, nu)``: zero effort, or the angles ``q`` held."""
        if self.interface == 'position' and q is not None:
            target = np.clip(q[:, self.cols], self.q_low, self.q_high)
            return np.clip(self.act.from_si(target, 'position'), self.low, self.high)
        return np.tile(self.zero, (arms, 1))

    def start_ramp(self, now: float):
        """Begin the ramp from hold at time ``now`` (s), as on activation."""
        self.ramp_start = now

    def sent(self, command: np.ndarray):
        """Note a command published without :meth:`__call__` (a hold), for steps 3 and 4."""
        self.previous = np.array(command, dtype=float)

    def __call__(self, action: np.ndarray, q: np.ndarray, qdot: np.ndarray,
                 now: float) -> Tuple[np.ndarray, Dict[str, np.ndarray]]:
        """
        Return the guarded command ``(arms, nu)`` and which guards acted, per arm.

        ``action`` ``(arms, nu)`` in control units; ``q``, ``qdot`` ``(arms, joints)`` in the
        card's joint order; ``now`` in seconds (for the ramp).
        """
        s = self.settings
        arms = len(action)
        hold = self.hold(q, arms)
        acted = {k: np.zeros(arms, dtype=bool) for k in EVENTS}
        u = np.array(action, dtype=float)
        bad = ~np.all(np.isfinite(u), axis=1)
        acted['nonfinite'] = bad
        u[bad] = hold[bad]
        clipped = np.clip(u, self.low, self.high)
        acted['clipped'] = np.any(clipped != u, axis=1)
        u = clipped
        if self.ramp_start is not None:
            ratio = 1.0 if s.ramp_time <= 0 else (now - self.ramp_start) / s.ramp_time
            if ratio >= 1.0:
                self.ramp_start = None
            else:
                u = hold + max(ratio, 0.0) * (u - hold)
                acted['ramped'][:] = True
        previous = self.previous if self.previous is not None and \
            self.previous.shape == u.shape else None
        if previous is not None and s.smoothing > 0:
            u = s.smoothing * previous + (1.0 - s.smoothing) * u
        if previous is not None and s.max_change > 0:
            step = s.max_change * self.span
            limited = np.clip(u, previous - step, previous + step)
            acted['rate_limited'] = np.any(limited != u, axis=1)
            u = limited
        u, acted['joint_limit'] = self._joint_limits(u, q[:, self.cols])
        if s.max_velocity > 0:
            fast = np.any(np.abs(qdot) > s.max_velocity, axis=1)
            u[fast] = hold[fast]
            acted['over_speed'] = fast
        self.previous = u.copy()
        return u, acted

    def _joint_limits(self, u: np.ndarray, q: np.ndarray):
        """Step 5: no command that drives a joint further past its limit (with the margin)."""
        margin = self.settings.joint_limit_margin
        if self.interface == 'position':
            inside_low, inside_high = self.q_low + margin, self.q_high - margin
            narrow = inside_low > inside_high          # a range narrower than two margins
            mid = np.where(narrow, (self.q_low + self.q_high) / 2, 0.0) if narrow.any() else 0.0
            inside_low = np.where(narrow, mid, inside_low)
            inside_high = np.where(narrow, mid, inside_high)
            target = self.act.to_si(u, 'position')
            kept = np.clip(target, inside_low, inside_high)
            out = np.where(kept != target, self.act.from_si(kept, 'position'), u)
            return out, np.any(kept != target, axis=1)
        torque = self.act.to_si(u, 'effort')
        outward = (((q >= self.q_high - margin) & (torque > 0))
                   | ((q <= self.q_low + margin) & (torque < 0)))
        out = np.where(outward, self.zero, u)
        return out, np.any(outward, axis=1)
