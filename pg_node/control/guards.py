"""
The safety habits of a controller between a policy and a robot (no ROS, no engine here).

:class:`CommandGuard` turns the policy's action for a measured joint state into the command
a robot may get, in the policy's control units (its :class:`~pg_node.control.interfaces.
CommandInterface` converts to N m or rad), one control tick at a time. Each guard is a step of
its own, acting in this order, per arm:

0. **relative targets** (:meth:`CommandGuard.relative`; a policy whose card has a
   ``max_position_delta``): the action becomes the target ``q + a d`` around the measured
   angle (:mod:`pg_node.control.position_delta`);
1. **range** (:meth:`CommandGuard.clip_range`): a non-finite action becomes the hold command; the
   rest is clipped to the actuators' control range;
2. **ramp** (:meth:`CommandGuard.ramp`): after every hold (activation, stale states, an
   e-stop, a non-finite action, over-speed) the command is blended from the hold command to
   the policy's over ``ramp_time`` s, linearly, so the output is continuous where the hold
   ends (ros2_control controllers and MoveIt Servo start from hold too, rather than jumping
   to the first command);
3. **smoothing** (:meth:`CommandGuard.smooth`): a first-order low-pass filter,
   ``u = s * previous + (1 - s) * u`` with ``s = smoothing`` (0: off);
4. **rate limit** (:meth:`CommandGuard.rate_limit`): each actuator changes by at most
   ``max_change`` of its control range per tick;
4b. **acceleration** (:meth:`CommandGuard.accelerate`, velocity interface): the commanded
   speed changes by at most ``max_acceleration`` rad/s^2 (from the model: half the joint's
   torque over its largest inertia);
5. **joint limits** (:meth:`CommandGuard.joint_limits`): with the effort interface a joint
   whose braking distance at its speed reaches a limit is braked; with the position
   interface the target is kept ``joint_limit_margin`` inside the range; with the velocity
   interface the speed towards a limit is capped at ``sqrt(2 max_deceleration s)``, ``s``
   the distance left to the margin;
5b. **position change** (:meth:`CommandGuard.bound_change`, position interface): each
   target within ``max_position_delta`` rad of the measured angle (0: the card's delta;
   none for a policy with absolute targets);
6. **over-speed** (:meth:`CommandGuard.over_speed`): an arm with a joint faster than its
   velocity limit gets the hold command.

Steps 5 and 6 act after the rate limit, so a brake or a hold is never delayed by it (with the
rate limit after the brake, reacher2 driven at full torque at its limit overshoots it by
0.28 rad: ``test_control_guards``). They still never make the output flip between the
policy's full command and a hold tick after tick: the brake is a continuous function of the
joint's state (it grows as the braking distance reaches the limit, it does not switch), and
an over-speed hold is followed by the ramp of step 2 from the hold, whose end the rate limit
smooths.

The **hold** (:meth:`CommandGuard.hold`) is an active stop for the interface it speaks
(:data:`pg_node.control.interfaces.INTERFACES`), never zero torque: an arm whose driver
compensates gravity floats and coasts on zero torque.

* effort: a damping torque ``tau = -D qdot - K (q - q_hold)`` from the measured state,
  computed at every tick, clipped to the actuators' effort range; ``D`` is ``hold_damping``
  when it is given, else (from the model) the braking matrix ``M_a(q) / (BRAKE_TICKS T)``
  of the arm's inertia at the measured pose (``mass_at``,
  :func:`pg_node.sim.actuation.mass_matrix_at`): the torque that takes ``1 / BRAKE_TICKS``
  of every joint's speed off per tick, coupled joints too, on a robot with no joint damping
  of its own (a Franka's torques come without it; the Panda URDF's 0.003 N m s/rad is a
  trace). Without ``mass_at``: the model's joint damping, or where it has none the gain
  ``I / (BRAKE_TICKS T)`` of the joint's largest inertia. ``K`` is
  ``hold_stiffness`` (0 by default: pure damping), ``q_hold`` the angles where the hold
  began. A stale state's velocity is no measure of the arm's: the
  damping computed from it is scaled by ``decay`` (:func:`pg_node.control.watchdog.hold_decay`:
  full while the state is fresh, down to zero torque one more ``state_timeout`` later), since
  a brake from a velocity that has long stopped pushes the arm back; the braking matrix's
  torque also by ``(1 - 1 / BRAKE_TICKS)`` per tick it has braked from that state already
  (the speed it leaves), so that its torques add up to at most the state's speed. A hold
  sent once and
  then left in force (deactivate, shutdown: a forward controller keeps it forever,
  ros2_controllers (jazzy ed360c97d) forward_command_controller/src/
  forward_controllers_base.cpp:154-158) is zero torque, for the same reason; the joint
  trajectory controller's own hold after ``cmd_timeout`` is zero effort as well with zero
  gains (ros2_controllers (jazzy ed360c97d)
  joint_trajectory_controller/src/joint_trajectory_controller.cpp:2063-2086), ``-d qdot``
  with a ``d`` gain (``policy_node``'s ``controller_hold`` ``pd``,
  :mod:`pg_node.control.composers`).
* position: the last commanded angles, which the guard remembers (what it sent), never the
  measured angles of a stale state; before any command, the measured angles.
* velocity: a speed of zero (the robot's velocity loop brakes the joint); JTC's hold after
  ``cmd_timeout`` is zero velocity too (ros2_controllers (jazzy ed360c97d)
  joint_trajectory_controller.cpp:2063-2086, with the zero PID gains of
  ``config/controllers/jtc_velocity.yaml``), and JointGroupVelocityController writes 0 on
  deactivate (velocity_controllers/src/joint_group_velocity_controller.cpp:54-70).

Defaults from the model (:func:`model_limits`): a parameter at 0 takes its value from the
actuators' record, per actuator, and :meth:`CommandGuard.describe` says which was taken.
"""
from dataclasses import dataclass
import functools
from typing import Callable, Dict, Optional, Sequence, Tuple

import numpy as np
from pg_node.control import position_delta
from pg_node.control.interfaces import (Actuators, CommandInterface, HOLD_LAST_COMMAND,
                                        HOLD_ZERO_VELOCITY, INTERFACES, LIMIT_INSIDE,
                                        LIMIT_VELOCITY_CAP)
from pg_node.control.status import GuardEvent

#: the share of the actuator's torque the braking guard plans with (the rest is slack for
#: the tick's delay, the rate limit and the inertia's pose dependence)
BRAKING_SHARE = 0.5
#: the effort hold's brake: ``D = M_a(q) / (BRAKE_TICKS T)`` takes ``1 / BRAKE_TICKS`` of
#: every joint's speed off per control period ``T``; held for a whole tick, as a controller
#: holds a command, the speeds fall by ``1 - 1 / BRAKE_TICKS`` a tick, stable while the
#: robot's inertia is within ``2 BRAKE_TICKS - 1`` times the model's. Without the pose's
#: matrix, ``I / (BRAKE_TICKS T)`` with ``I`` a joint's largest inertia: the speed changes by
#: ``1 - I_max / (BRAKE_TICKS I)`` a tick, stable for a pose whose inertia is above
#: ``I / (2 BRAKE_TICKS)`` (the Panda's lightest shoulder is 5x lighter than its largest)
BRAKE_TICKS = 4.0


@dataclass
class GuardSettings:
    """The guard's parameters (policy_node's of the same names; 0: from the model)."""

    smoothing: float = 0.0
    max_change: float = 0.0
    joint_limit_margin: float = 0.05
    max_velocity: float = 0.0
    ramp_time: float = 0.0
    hold_damping: float = 0.0
    hold_stiffness: float = 0.0
    max_deceleration: float = 0.0
    max_position_delta: float = 0.0
    max_acceleration: float = 0.0


@dataclass(frozen=True)
class Limits:
    """The numbers the guards act with, per actuator, and which came from the model."""

    max_change: np.ndarray          # share of the control range per tick
    max_velocity: np.ndarray        # rad/s (inf: no check)
    hold_damping: np.ndarray        # N m s/rad
    max_deceleration: np.ndarray    # rad/s^2
    from_model: Tuple[str, ...]     # the names taken from the model
    max_acceleration: np.ndarray = None     # rad/s^2 (velocity interface)


def effort_limit(act: Actuators, interface: CommandInterface) -> np.ndarray:
    """Return the largest joint torque each actuator may apply (N m; inf where unbounded)."""
    if interface.name != 'effort':
        return act.force_limit
    low, high = interface.si_range(act)
    return np.minimum(act.force_limit, np.maximum(np.abs(low), np.abs(high)))


def model_limits(act: Actuators, interface: CommandInterface, settings: GuardSettings,
                 period: float) -> Limits:
    """
    Return the guards' numbers: each parameter's value, or at 0 the model's.

    From the model, per actuator (``tau`` its torque bound, :func:`effort_limit`):

    * ``hold_damping``: the joint's damping in the model, or where it has none the braking
      gain ``inertia / (BRAKE_TICKS * period)`` (:data:`BRAKE_TICKS`);
    * ``max_velocity``: ``tau / damping``, the speed at which the full torque is spent on
      the model's damping (``arm import --velocity-damping`` sets the damping so that this
      is the URDF's velocity limit); infinite (no check) without damping or torque bound;
    * ``max_deceleration``: :data:`BRAKING_SHARE` of ``tau / inertia`` (the largest
      inertia over the model's poses);
    * ``max_change``: effort: ``inertia * max_deceleration`` as a share of the range (a
      step of the braking torque per tick: a switch to braking in a few ticks); position:
      ``max_velocity * period`` as a share of the range (the target never runs ahead of
      what the joint can follow); velocity: ``max_acceleration * period``; at most 1;
    * ``max_acceleration`` (velocity interface): as ``max_deceleration``;
    * ``max_velocity`` of the velocity interface: the largest speed its range commands
      (``arm import --actuator velocity``: the URDF's velocity limit).
    """
    tau = effort_limit(act, interface)
    taken = []

    def pick(name, model_value):
        given = getattr(settings, name)
        if given > 0:
            return np.full(len(act.names), float(given))
        taken.append(name)
        return np.asarray(model_value, dtype=float)

    with np.errstate(divide='ignore', invalid='ignore'):
        # a torque robot brakes with the model's damping, or where the model has none (a
        # Franka's torques come without it) with the braking gain: a hold is never 0 N m
        brake = np.asarray(act.inertia, dtype=float) / (BRAKE_TICKS * period)
        damping = pick('hold_damping', np.where(act.damping > 0, act.damping, brake))
        low, high = interface.si_range(act)
        if interface.limit == LIMIT_VELOCITY_CAP:
            # a velocity servo's range is the robot's velocity limit (the URDF's)
            speed = np.maximum(np.abs(low), np.abs(high))
        else:
            speed = np.where(act.damping > 0, tau / act.damping, np.inf)
        velocity = pick('max_velocity', speed)
        decel = pick('max_deceleration', BRAKING_SHARE * tau / act.inertia)
        accel = (pick('max_acceleration', BRAKING_SHARE * tau / act.inertia)
                 if interface.limit == LIMIT_VELOCITY_CAP else np.full(len(act.names), np.inf))
        span = high - low
        if interface.limit == LIMIT_INSIDE:
            share = velocity * period / span
        elif interface.limit == LIMIT_VELOCITY_CAP:
            share = accel * period / span
        else:
            share = act.inertia * decel / span
        change = pick('max_change', np.minimum(np.nan_to_num(share, nan=1.0, posinf=1.0), 1.0))
    return Limits(change, velocity, damping, decel, tuple(taken), accel)


class CommandGuard:
    """Shape and guard a policy's actions for one arm's actuators, tick by tick."""

    def __init__(self, act: Actuators, joint_names: Sequence[str], interface: str,
                 settings: Optional[GuardSettings] = None, period: float = 0.02,
                 position_delta: Optional[np.ndarray] = None,
                 inertia_at: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                 mass_at: Optional[Callable[[np.ndarray], np.ndarray]] = None):
        """
        Take the actuators, the limits of their joints and the interface that commands them.

        ``joint_names``: the order of the joint angles given to :meth:`__call__` (the
        policy card's); each actuator's joint must be among them. ``period``: the control
        period in s (the braking guard's and the position rate limit's tick).
        ``position_delta`` (rad per actuator, the card's ``max_position_delta``): the
        actions are changes around the measured angles (step 0), not absolute targets.
        ``inertia_at``: a function of the angles ``(arms, joints)`` (``joint_names``' order)
        returning each actuator's inertia at that pose ``(arms, actuators)`` in kg m^2, the
        braking guard's ``I`` (:func:`pg_node.sim.actuation.inertia_at`); None: the
        record's largest, ``Actuators.inertia``. ``mass_at``: a function of the angles
        returning the actuated joints' inertia matrix ``(arms, nu, nu)``
        (:func:`pg_node.sim.actuation.mass_matrix_at`), the effort hold's brake; None: the
        model's damping (see the module's docstring).
        """
        self.act = act
        self.inertia_at = inertia_at
        self.mass_at = mass_at
        self.interface = INTERFACES[interface]
        self.settings = settings or GuardSettings()
        self.period = period
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
        self.position_delta = (None if position_delta is None
                               else np.asarray(position_delta, dtype=float))
        if self.position_delta is not None and self.interface.limit != LIMIT_INSIDE:
            raise ValueError('a position delta needs the position interface')
        self.previous: Optional[np.ndarray] = None      # the last command sent
        self.pending_ramp: Optional[float] = None        # start_ramp's time, until a tick
        self.held = np.zeros(0, dtype=bool)              # per arm: its last command a hold
        self.ramp_start = np.zeros(0)                    # per arm: NaN when not ramping
        self.anchor_q = self.anchor_u = np.zeros((0, len(act.names)))

    def limits(self) -> Limits:
        """Return the numbers the guards act with now (the settings may change live)."""
        return model_limits(self.act, self.interface, self.settings, self.period)

    def braking_matrix(self) -> bool:
        """Whether the effort hold brakes with the pose's inertia matrix (:meth:`hold`)."""
        return (self.interface.name == 'effort' and self.mass_at is not None
                and self.settings.hold_damping <= 0)

    def describe(self) -> Dict[str, str]:
        """Return the values taken, per actuator, each saying whether from the model."""
        lim = self.limits()
        out = {}
        if self.braking_matrix():
            out['hold_damping_taken'] = (f'M(q) / ({BRAKE_TICKS:g} x {self.period:g} s): the '
                                         "arm's inertia at the measured pose (from the model)")
        for name, unit in (('max_change', 'of the range per tick'), ('max_velocity', 'rad/s'),
                           ('hold_damping', 'N m s/rad'), ('max_deceleration', 'rad/s^2'),
                           ('max_acceleration', 'rad/s^2')):
            if name == 'max_acceleration' and self.interface.hold != HOLD_ZERO_VELOCITY:
                continue
            if f'{name}_taken' in out:
                continue
            values = ', '.join(f'{v:.4g}' for v in getattr(lim, name))
            how = 'from the model' if name in lim.from_model else 'parameter'
            out[f'{name}_taken'] = f'{values} {unit} ({how})'
        return out

    def _arms(self, arms: int):
        """Size the per-arm state for ``arms`` arms (a new count starts afresh)."""
        if len(self.held) != arms:
            nu = len(self.act.names)
            self.held = np.zeros(arms, dtype=bool)
            self.ramp_start = np.full(arms, np.nan)
            self.anchor_q = np.full((arms, nu), np.nan)
            self.anchor_u = np.full((arms, nu), np.nan)
            if self.previous is not None and len(self.previous) != arms:
                self.previous = None

    def _measured(self, q: np.ndarray) -> np.ndarray:
        """Return the controls that hold the measured angles ``q`` (position interface)."""
        target = np.clip(q[:, self.cols], self.q_low, self.q_high)
        return np.clip(self.interface.from_si(self.act, target), self.low, self.high)

    def hold(self, q: np.ndarray, qdot: np.ndarray, decay: float = 1.0,
             coasting: float = 0.0) -> np.ndarray:
        """
        Return the hold command ``(arms, nu)``: a damping torque, or the last commanded angles.

        Effort: ``-(D qdot + K (q - q_hold)) * decay`` N m, clipped to the effort range
        (``decay``: 1 from a fresh state, less from a stale one, 0 for a hold left in force);
        ``q_hold`` the angles where this arm's hold began (no spring before one began).
        ``D``: ``hold_damping``, or the braking matrix ``M_a(q) / (BRAKE_TICKS T)`` at ``q``
        (:meth:`braking_matrix`), whose torque a ``coasting`` s old hold (the time a stale
        state's hold has braked already) scales by ``(1 - 1 / BRAKE_TICKS)`` per tick.
        Position: the angles this arm's hold began with, else the last command sent, else
        (before any) the measured ``q``.
        """
        self._arms(len(q))
        if self.interface.hold == HOLD_ZERO_VELOCITY:
            stop = self.interface.from_si(self.act, np.zeros((len(q), len(self.act.names))))
            return np.clip(stop, self.low, self.high)
        if self.interface.hold == HOLD_LAST_COMMAND:
            last = self.previous if self.previous is not None else self._measured(q)
            return np.where(np.isnan(self.anchor_u), last, self.anchor_u)
        qa = q[:, self.cols]
        spring = np.where(np.isnan(self.anchor_q), 0.0, qa - self.anchor_q)
        if self.braking_matrix():
            left = (1.0 - 1.0 / BRAKE_TICKS) ** (max(coasting, 0.0) / self.period)
            brake = np.einsum('aij,aj->ai', self.mass_at(q), qdot[:, self.cols])
            damping = brake * left / (BRAKE_TICKS * self.period)
        else:
            damping = self.limits().hold_damping * qdot[:, self.cols]
        torque = -(damping + self.settings.hold_stiffness * spring) * decay
        low, high = self.interface.si_range(self.act)
        return np.clip(self.interface.from_si(self.act, np.clip(torque, low, high)),
                       self.low, self.high)

    def _begin_hold(self, q: np.ndarray, arms: np.ndarray):
        """Note that ``arms`` (bool per arm) hold from now: anchor a hold that begins."""
        new = arms & ~self.held
        if new.any():
            self.anchor_q[new] = q[new][:, self.cols]
            last = self.previous if self.previous is not None else self._measured(q)
            self.anchor_u[new] = last[new]
        self.held |= arms

    def hold_tick(self, q: np.ndarray, qdot: np.ndarray, decay: float = 1.0,
                  coasting: float = 0.0) -> np.ndarray:
        """
        Return the hold command the node sends for every arm (stale, e-stop, stop); note it.

        The next :meth:`__call__` ramps from the hold again (step 2), and steps 3 and 4 run
        from it. ``decay``, ``coasting``: as :meth:`hold`'s.
        """
        self._arms(len(q))
        self._begin_hold(q, np.ones(len(q), dtype=bool))
        self.ramp_start[:] = np.nan
        u = self.hold(q, qdot, decay, coasting)
        self.previous = u.copy()
        return u

    def start_ramp(self, now: float):
        """Ramp every arm in from hold, from time ``now`` (s), as on activation."""
        self.pending_ramp = now

    def __call__(self, action: np.ndarray, q: np.ndarray, qdot: np.ndarray,
                 now: float) -> Tuple[np.ndarray, Dict[GuardEvent, np.ndarray]]:
        """
        Return the guarded command ``(arms, nu)`` and which guards acted, per arm.

        ``action`` ``(arms, nu)`` in control units; ``q``, ``qdot`` ``(arms, joints)`` in the
        card's joint order; ``now`` in seconds (for the ramp).
        """
        arms = len(action)
        self._arms(arms)
        if self.pending_ramp is not None:
            self._begin_hold(q, np.ones(arms, dtype=bool))
            self.ramp_start[:] = self.pending_ramp
            self.held[:] = False
            self.pending_ramp = None
        self.ramp_start[self.held] = now        # a hold ended: ramp in from it
        self.held[:] = False
        # computed only on a tick that needs it (a non-finite action, a ramp, an over-speed):
        # the braking matrix costs a mass matrix per arm
        hold = functools.cache(lambda: self.hold(q, qdot))
        acted = {e: np.zeros(arms, dtype=bool) for e in GuardEvent}
        action = self.relative(action, q)
        u = self.clip_range(action, hold, acted)
        u = self.ramp(u, hold, now, acted)
        previous = self.previous
        u = self.smooth(u, previous)
        u = self.rate_limit(u, previous, acted)
        u = self.accelerate(u, previous, acted)
        inertia = None if self.inertia_at is None else self.inertia_at(q)
        u = self.joint_limits(u, q[:, self.cols], qdot[:, self.cols], acted, inertia)
        u = self.bound_change(u, q[:, self.cols], acted)
        u = self.over_speed(u, qdot[:, self.cols], hold, acted)
        self._begin_hold(q, acted[GuardEvent.NONFINITE] | acted[GuardEvent.OVER_SPEED])
        self.previous = u.copy()
        return u, acted

    def relative(self, action: np.ndarray, q: np.ndarray) -> np.ndarray:
        """
        Step 0: a relative action as the controls of its target angles (else unchanged).

        With ``position_delta`` ``d``: ``clip(q + clip(a, -1, 1) d)`` within the servos'
        range (:func:`pg_node.control.position_delta.targets`); a non-finite action stays so.
        """
        if self.position_delta is None:
            return action
        low, high = self.interface.si_range(self.act)
        target = position_delta.targets(action, q[:, self.cols], self.position_delta, low,
                                        high)
        return self.interface.from_si(self.act, target)

    def bound_change(self, u: np.ndarray, q: np.ndarray, acted) -> np.ndarray:
        """
        Step 5b (position): each target within ``max_position_delta`` rad of the measured angle.

        The bound is the parameter, or at 0 the card's delta (none for absolute targets):
        with it, an old policy's absolute targets (or the ramp from a hold) never ask a
        joint for more than that change in one tick. The control range still holds: a
        joint beyond what its servo reaches (an unlimited joint spun past it) gets the
        range's end.
        """
        if self.interface.limit != LIMIT_INSIDE:
            return u
        given = self.settings.max_position_delta
        bound = (np.full(len(self.act.names), given) if given > 0 else self.position_delta)
        if bound is None:
            return u
        target = self.interface.to_si(self.act, u)
        kept = position_delta.bound_change(target, q, bound)
        changed = kept != target
        acted[GuardEvent.POSITION_DELTA] = np.any(changed, axis=1)
        # the range wins: a joint outside what its servo reaches gets the nearest target
        return np.where(changed, np.clip(self.interface.from_si(self.act, kept), self.low,
                                         self.high), u)

    def clip_range(self, action: np.ndarray, hold: Callable[[], np.ndarray],
                   acted) -> np.ndarray:
        """
        Step 1: the hold command for a non-finite action, the rest clipped to the range.

        ``hold``: returns the hold command (:meth:`hold`), asked for only when needed.
        """
        u = np.array(action, dtype=float)
        bad = ~np.all(np.isfinite(u), axis=1)
        acted[GuardEvent.NONFINITE] = bad
        if bad.any():
            u[bad] = hold()[bad]
        clipped = np.clip(u, self.low, self.high)
        acted[GuardEvent.CLIPPED] = np.any(clipped != u, axis=1)
        return clipped

    def ramp(self, u: np.ndarray, hold: Callable[[], np.ndarray], now: float,
             acted) -> np.ndarray:
        """Step 2: blend from the hold command over ``ramp_time`` s since the hold ended."""
        ramping = ~np.isnan(self.ramp_start)
        if not ramping.any():
            return u
        ramp_time = self.settings.ramp_time
        with np.errstate(invalid='ignore'):
            ratio = np.ones(len(u)) if ramp_time <= 0 else (now - self.ramp_start) / ramp_time
            done = ramping & (ratio >= 1.0)
        active = ramping & ~done
        if active.any() or done.any():
            hold()          # from the anchors as they are, before a finished ramp drops them
        self.ramp_start[done] = np.nan          # the hold is over: no anchors kept
        self.anchor_q[done] = np.nan
        self.anchor_u[done] = np.nan
        acted[GuardEvent.RAMPED] = active
        if not active.any():
            return u
        share = np.clip(np.nan_to_num(ratio), 0.0, 1.0)[:, None]
        return np.where(active[:, None], hold() + share * (u - hold()), u)

    def smooth(self, u: np.ndarray, previous: Optional[np.ndarray]) -> np.ndarray:
        """Step 3: the low-pass filter on the published commands (``smoothing`` 0: off)."""
        s = self.settings.smoothing
        if previous is None or s <= 0:
            return u
        return s * previous + (1.0 - s) * u

    def joint_limits(self, u: np.ndarray, q: np.ndarray, qdot: np.ndarray, acted,
                     inertia: Optional[np.ndarray] = None) -> np.ndarray:
        """
        Step 5: brake a joint whose braking distance reaches a limit; keep targets inside.

        Effort: with ``a`` the deceleration bound and ``m`` ``joint_limit_margin``, a joint
        ``s`` rad from ``limit - m`` may move towards it at ``v_allowed = sqrt(2 a s)`` at
        most (its stop distance ``qdot^2 / (2 a)`` is then ``s``). The torque towards the
        limit is capped at ``I (v_allowed - qdot) / period``, the torque that brings the
        joint to ``v_allowed`` in one tick (``I`` its inertia, ``inertia``: at this pose,
        or else the largest over the model's poses): far from the limit the cap
        is out of reach, on the braking curve it is zero, past it a brake, at rest within
        the margin it is zero (no push outward). The cap is a continuous function of the
        state, so the command follows it smoothly instead of switching between the policy's
        command and a hold. The cap is a one-tick controller of gain ``I / I_pose``: sized
        with the largest inertia where the joint is light (the Panda's shoulder, folded,
        meets 18 times less) it overshot, reversed at full torque tick after tick and threw
        the arm 130 cm off its goal (issue 46); hence the pose's inertia where it is known.
        Position: the target is kept ``m`` inside the range (the robot's position loop
        brakes).
        """
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
        if self.interface.limit == LIMIT_VELOCITY_CAP:
            return self._velocity_cap(u, q, acted)
        torque = self.interface.to_si(self.act, u)
        lim = self.limits()
        inertia = self.act.inertia if inertia is None else inertia
        tau = effort_limit(self.act, self.interface)
        with np.errstate(invalid='ignore'):
            up = np.sqrt(2 * lim.max_deceleration * np.maximum(self.q_high - margin - q, 0.0))
            down = np.sqrt(2 * lim.max_deceleration * np.maximum(q - self.q_low - margin, 0.0))
            cap_high = np.clip(np.nan_to_num(inertia * (up - qdot) / self.period, nan=np.inf),
                               -tau, np.inf)
            cap_low = np.clip(np.nan_to_num(inertia * (-down - qdot) / self.period,
                                            nan=-np.inf), -np.inf, tau)
        kept = np.minimum(np.maximum(torque, cap_low), cap_high)
        changed = kept != torque
        acted[GuardEvent.JOINT_LIMIT] = np.any(changed, axis=1)
        return np.where(changed, np.clip(self.interface.from_si(self.act, kept), self.low,
                                         self.high), u)

    def _velocity_cap(self, u: np.ndarray, q: np.ndarray, acted) -> np.ndarray:
        """
        Step 5 (velocity): the speed towards a limit at most ``sqrt(2 a s)``.

        ``s`` is the distance left to ``limit - joint_limit_margin`` and ``a``
        ``max_deceleration``: the joint can still stop there; zero at the margin and
        beyond it. A speed away from the limit is never capped. Continuous in ``q``.
        """
        margin = self.settings.joint_limit_margin
        decel = self.limits().max_deceleration
        with np.errstate(invalid='ignore'):
            up = np.sqrt(2 * decel * np.maximum(self.q_high - margin - q, 0.0))
            down = np.sqrt(2 * decel * np.maximum(q - self.q_low - margin, 0.0))
        v = self.interface.to_si(self.act, u)
        kept = np.minimum(np.maximum(v, np.nan_to_num(-down, nan=-np.inf)),
                          np.nan_to_num(up, nan=np.inf))
        changed = kept != v
        acted[GuardEvent.JOINT_LIMIT] = np.any(changed, axis=1)
        return np.where(changed, np.clip(self.interface.from_si(self.act, kept), self.low,
                                         self.high), u)

    def over_speed(self, u: np.ndarray, qdot: np.ndarray, hold: Callable[[], np.ndarray],
                   acted) -> np.ndarray:
        """Step 6: the hold command for an arm with a joint faster than its velocity limit."""
        fast = np.any(np.abs(qdot) > self.limits().max_velocity, axis=1)
        acted[GuardEvent.OVER_SPEED] = fast
        return np.where(fast[:, None], hold(), u) if fast.any() else u

    def accelerate(self, u: np.ndarray, previous: Optional[np.ndarray], acted) -> np.ndarray:
        """
        Step 4b (velocity): the commanded speed changes by at most ``max_acceleration`` per s.

        ``|v - v_previous| <= max_acceleration x period`` rad/s per tick: the policy's
        commands and the ramp out of a hold (the first command from rest too). The change
        into a hold is not bounded: the joint-limit cap and the over-speed hold act after
        it, so that no stop is delayed; the robot's velocity loop decelerates the stop
        (docs/deploy.md, "A change into a hold is not acceleration-limited").
        """
        if self.interface.hold != HOLD_ZERO_VELOCITY:
            return u
        step = self.limits().max_acceleration * self.period
        if previous is None:                    # the first command: from rest
            previous = self.interface.from_si(self.act, np.zeros_like(u))
        v, before = self.interface.to_si(self.act, u), self.interface.to_si(self.act, previous)
        kept = np.clip(v, before - step, before + step)
        changed = kept != v
        acted[GuardEvent.ACCELERATION_LIMITED] = np.any(changed, axis=1)
        return np.where(changed, np.clip(self.interface.from_si(self.act, kept), self.low,
                                         self.high), u)

    def rate_limit(self, u: np.ndarray, previous: Optional[np.ndarray], acted) -> np.ndarray:
        """Step 4: at most ``max_change`` of the control range per tick (holds included)."""
        if previous is None:
            return u
        step = self.limits().max_change * self.span
        limited = np.clip(u, previous - step, previous + step)
        acted[GuardEvent.RATE_LIMITED] = np.any(limited != u, axis=1)
        return limited
