"""
The safety habits of a controller between a policy and a robot (no ROS, no engine here).

:class:`CommandGuard` turns the policy's action for a measured joint state into the command
a robot may get, in the policy's control units (its :class:`~pg_node.control.interfaces.
CommandInterface` converts to N m or rad), one control tick at a time. Each guard is a step of
its own, acting in this order, per arm:

1. **range** (:meth:`CommandGuard.clip_range`): a non-finite action becomes the hold command; the
   rest is clipped to the actuators' control range;
2. **ramp** (:meth:`CommandGuard.ramp`): for ``ramp_time`` s after activation the command is
   blended from the hold command to the policy's, linearly (ros2_control controllers and
   MoveIt Servo start from hold too, rather than jumping to the first command);
3. **smoothing** (:meth:`CommandGuard.smooth`): a first-order low-pass filter,
   ``u = s * previous + (1 - s) * u`` with ``s = smoothing`` (0: off);
4. **rate limit** (:meth:`CommandGuard.rate_limit`): each actuator changes by at most
   ``max_change`` of its control range per tick (0: off);
5. **joint limits** (:meth:`CommandGuard.joint_limits`): a limited joint within
   ``joint_limit_margin`` rad of (or past) a limit gets no command that drives it further:
   with the effort interface the torque towards the limit becomes zero; with the position
   interface the target is kept ``margin`` inside the range;
6. **over-speed** (:meth:`CommandGuard.over_speed`): an arm with a joint faster than
   ``max_velocity`` rad/s (0: off) gets the hold command for this tick.

The **hold** command is the interface's (:data:`pg_node.control.interfaces.INTERFACES`):
zero effort (the robot's gravity compensation holds the arm, if it has any), or the measured
joint angles (the robot's position loop holds them). Steps 3 and 4 act on the sequence of
published commands, holds included, so a command resuming after a hold is smoothed and
rate-limited from the hold.
"""
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
from pg_node.control.interfaces import Actuators, HOLD_MEASURED, INTERFACES, LIMIT_INSIDE
from pg_node.control.status import GuardEvent


@dataclass
class GuardSettings:
    """The guard's parameters (policy_node's of the same names)."""

    smoothing: float = 0.0
    max_change: float = 0.0
    joint_limit_margin: float = 0.05
    max_velocity: float = 0.0
    ramp_time: float = 0.0


class CommandGuard:
    """Shape and guard a policy's actions for one arm's actuators, tick by tick."""

    def __init__(self, act: Actuators, joint_names: Sequence[str], interface: str,
                 settings: Optional[GuardSettings] = None):
        """
        Take the actuators, the limits of their joints and the interface that commands them.

        ``joint_names``: the order of the joint angles given to :meth:`__call__` (the
        policy card's); each actuator's joint must be among them.
        """
        self.act = act
        self.interface = INTERFACES[interface]
        self.settings = settings or GuardSettings()
        index = {n: i for i, n in enumerate(joint_names)}
        missing = [n for n in act.joints if n not in index]
        if missing:
            raise ValueError(f'actuated joints {", ".join(missing)} are not among the joints '
                             f'{", ".join(joint_names)}')
        self.cols = np.array([index[n] for n in act.joints], dtype=int)
        self.q_low, self.q_high = act.joint_low, act.joint_high
        self.low, self.high = act.ctrl_low, act.ctrl_high
        span = self.high - self.low
        self.span = np.where(np.isfinite(span), span, 2.0)
        self.zero = act.zero_effort
        self.previous: Optional[np.ndarray] = None
        self.ramp_start: Optional[float] = None

    def hold(self, q: Optional[np.ndarray], arms: int) -> np.ndarray:
        """Return the hold command ``(arms, nu)``: zero effort, or the angles ``q`` held."""
        if self.interface.hold == HOLD_MEASURED and q is not None:
            target = np.clip(q[:, self.cols], self.q_low, self.q_high)
            return np.clip(self.interface.from_si(self.act, target), self.low, self.high)
        return np.tile(self.zero, (arms, 1))

    def start_ramp(self, now: float):
        """Begin the ramp from hold at time ``now`` (s), as on activation."""
        self.ramp_start = now

    def sent(self, command: np.ndarray):
        """Note a command published without :meth:`__call__` (a hold), for steps 3 and 4."""
        self.previous = np.array(command, dtype=float)

    def __call__(self, action: np.ndarray, q: np.ndarray, qdot: np.ndarray,
                 now: float) -> Tuple[np.ndarray, Dict[GuardEvent, np.ndarray]]:
        """
        Return the guarded command ``(arms, nu)`` and which guards acted, per arm.

        ``action`` ``(arms, nu)`` in control units; ``q``, ``qdot`` ``(arms, joints)`` in the
        card's joint order; ``now`` in seconds (for the ramp).
        """
        hold = self.hold(q, len(action))
        acted = {e: np.zeros(len(action), dtype=bool) for e in GuardEvent}
        u = self.clip_range(action, hold, acted)
        u = self.ramp(u, hold, now, acted)
        previous = self.previous if self.previous is not None and \
            self.previous.shape == u.shape else None
        u = self.smooth(u, previous)
        u = self.rate_limit(u, previous, acted)
        u = self.joint_limits(u, q[:, self.cols], acted)
        u = self.over_speed(u, qdot, hold, acted)
        self.previous = u.copy()
        return u, acted

    def clip_range(self, action: np.ndarray, hold: np.ndarray, acted) -> np.ndarray:
        """Step 1: the hold command for a non-finite action, the rest clipped to the range."""
        u = np.array(action, dtype=float)
        bad = ~np.all(np.isfinite(u), axis=1)
        acted[GuardEvent.NONFINITE] = bad
        u[bad] = hold[bad]
        clipped = np.clip(u, self.low, self.high)
        acted[GuardEvent.CLIPPED] = np.any(clipped != u, axis=1)
        return clipped

    def ramp(self, u: np.ndarray, hold: np.ndarray, now: float, acted) -> np.ndarray:
        """Step 2: blend from the hold command over ``ramp_time`` s after :meth:`start_ramp`."""
        if self.ramp_start is None:
            return u
        ramp_time = self.settings.ramp_time
        ratio = 1.0 if ramp_time <= 0 else (now - self.ramp_start) / ramp_time
        if ratio >= 1.0:
            self.ramp_start = None
            return u
        acted[GuardEvent.RAMPED][:] = True
        return hold + max(ratio, 0.0) * (u - hold)

    def smooth(self, u: np.ndarray, previous: Optional[np.ndarray]) -> np.ndarray:
        """Step 3: the low-pass filter on the published commands (``smoothing`` 0: off)."""
        s = self.settings.smoothing
        if previous is None or s <= 0:
            return u
        return s * previous + (1.0 - s) * u

    def rate_limit(self, u: np.ndarray, previous: Optional[np.ndarray], acted) -> np.ndarray:
        """Step 4: at most ``max_change`` of the control range per tick (0: off)."""
        if previous is None or self.settings.max_change <= 0:
            return u
        step = self.settings.max_change * self.span
        limited = np.clip(u, previous - step, previous + step)
        acted[GuardEvent.RATE_LIMITED] = np.any(limited != u, axis=1)
        return limited

    def joint_limits(self, u: np.ndarray, q: np.ndarray, acted) -> np.ndarray:
        """Step 5: no command that drives a joint further past its limit (with the margin)."""
        margin = self.settings.joint_limit_margin
        if self.interface.limit == LIMIT_INSIDE:
            inside_low, inside_high = self.q_low + margin, self.q_high - margin
            narrow = inside_low > inside_high          # a range narrower than two margins
            mid = np.where(narrow, (self.q_low + self.q_high) / 2, 0.0) if narrow.any() else 0.0
            inside_low = np.where(narrow, mid, inside_low)
            inside_high = np.where(narrow, mid, inside_high)
            target = self.interface.to_si(self.act, u)
            kept = np.clip(target, inside_low, inside_high)
            acted[GuardEvent.JOINT_LIMIT] = np.any(kept != target, axis=1)
            return np.where(kept != target, self.interface.from_si(self.act, kept), u)
        torque = self.interface.to_si(self.act, u)
        outward = (((q >= self.q_high - margin) & (torque > 0))
                   | ((q <= self.q_low + margin) & (torque < 0)))
        acted[GuardEvent.JOINT_LIMIT] = np.any(outward, axis=1)
        return np.where(outward, self.zero, u)

    def over_speed(self, u: np.ndarray, qdot: np.ndarray, hold: np.ndarray,
                   acted) -> np.ndarray:
        """Step 6: the hold command for an arm with a joint faster than ``max_velocity``."""
        if self.settings.max_velocity <= 0:
            return u
        fast = np.any(np.abs(qdot) > self.settings.max_velocity, axis=1)
        u[fast] = hold[fast]
        acted[GuardEvent.OVER_SPEED] = fast
        return u
