"""
A deployed policy's decisions, tick by tick: what the arm receives, and why.

:class:`Deployment` is built when a node is configured, from the guard
(:class:`pg_node.control.guards.CommandGuard`) and, as plain callables, the observation
(training's, :class:`pg_node.sim.observation.ObservationBuilder`) and the policy's Gaussian
(:mod:`pg_node.rl.trained_policy`). Each :meth:`Deployment.tick` takes the newest joint state,
the goals, the time and the e-stop latch and returns a :class:`Tick`: the command to send
(the guarded action, the hold, or nothing), the node's state with the text saying why, and
the events to count and log. The node around it subscribes, times, publishes and logs.

The stop paths, in the order they win (the hold: :meth:`CommandGuard.hold_tick`, an active
stop; its damping fades with a stale state's age, :func:`pg_node.control.watchdog.hold_decay`):

1. an e-stop latched: the hold at every tick (nothing before the first joint state);
2. no joint state yet: nothing sent, waiting;
3. a stale joint state (older than ``state_timeout``, :func:`pg_node.control.watchdog.state_age`):
   the hold at every tick, never one message only (a forward command controller keeps the
   last command it got); a spell begins with one :attr:`Event.STALE`;
4. no goal for an arm: nothing sent, waiting, naming the arm (one :attr:`Event.NO_TARGET`
   while the same arm is waited for);
5. the robot stopped itself (``robot_stop``, :class:`RobotState`: a UR's program not
   running, its speed scaling 0 in a protective stop or a pause): the hold at every tick,
   the text saying why; a spell begins with one :attr:`Event.ROBOT_STOPPED`;
6. else commanding: the policy's mean action (or a sample) through the guards, which ramp in
   from the last hold; the first command after a stale spell comes with one
   :attr:`Event.FRESH`, after the robot's own stop with one :attr:`Event.ROBOT_READY`.
"""
from dataclasses import dataclass
from enum import Enum
from typing import Callable, Dict, List, Mapping, NamedTuple, Optional, Tuple, Union

import numpy as np
from pg_node.control.guards import CommandGuard
from pg_node.control.status import GuardEvent, NodeState
from pg_node.control.watchdog import hold_decay, state_age, Watchdog

#: the managed node's primary state (``lifecycle`` in /diagnostics) of each node state
LIFECYCLE = {NodeState.UNCONFIGURED: 'unconfigured', NodeState.INACTIVE: 'inactive',
             NodeState.WAITING: 'active', NodeState.COMMANDING: 'active',
             NodeState.STALE: 'active', NodeState.ESTOP: 'active',
             NodeState.ROBOT_STOPPED: 'active',
             NodeState.FINALIZED: 'finalized'}


class Status(NamedTuple):
    """What the node does (its state, which sets its level) and the text saying why."""

    state: NodeState
    text: str

    @property
    def lifecycle(self) -> str:
        """
        Return the lifecycle state the node is in.

        >>> Status(NodeState.STALE, 'stale').lifecycle
        'active'
        """
        return LIFECYCLE[self.state]


#: the status on activation, and at each tick before the first joint state
NO_STATE = Status(NodeState.WAITING, 'waiting: no joint_states yet')
#: ... and while an e-stop is latched
ESTOP = Status(NodeState.ESTOP, 'e-stop latched: hold command (clear with ~/reset_estop)')
COMMANDING = Status(NodeState.COMMANDING, 'commanding')


@dataclass(frozen=True)
class JointSample:
    """
    The newest joint state, the model's joints only, with when it came.

    ``q``, ``qdot``: ``(arms, joints)`` in the policy card's joint order; ``arrival``: steady
    time in s; ``stamp``: its ``header.stamp`` in s of the node's clock (None: a zero stamp).
    """

    q: np.ndarray
    qdot: np.ndarray
    arrival: float
    stamp: Optional[float] = None


class Event(Enum):
    """What a tick found that the node counts or logs once."""

    STALE = 'stale'             # a spell of stale joint states began
    FRESH = 'fresh'             # it ended: commanding again
    NO_TARGET = 'no_target'     # waiting for a goal for an arm not waited for at the last tick
    ROBOT_STOPPED = 'robot_stopped'     # a spell of the robot's own stop began
    ROBOT_READY = 'robot_ready'         # it ended: commanding again, ramping in from the hold


@dataclass
class RobotState:
    """
    The robot's own state, as its driver publishes it; '' as a topic: not followed.

    A UR's (Universal_Robots_ROS2_Driver): ``program_running`` the ``std_msgs/Bool`` of
    ``io_and_status_controller``'s ``~/robot_program_running``; ``speed_scaling`` the
    ``std_msgs/Float64`` of ``speed_scaling_state_broadcaster``'s ``~/speed_scaling``, in
    percent (0 in a protective stop or a pause). None: no message yet.

    >>> RobotState().stop_reason()
    ''
    >>> RobotState(program_topic='/p').stop_reason()
    'robot stopped: no message yet on /p (robot_program_running_topic)'
    >>> RobotState(program_topic='/p', program_running=True, speed_topic='/s',
    ...            speed_scaling=0.0).stop_reason()
    'robot stopped: speed scaling 0 % on /s (a protective stop or a pause)'
    """

    program_topic: str = ''
    speed_topic: str = ''
    program_running: Optional[bool] = None
    speed_scaling: Optional[float] = None

    def stop_reason(self) -> str:
        """Return why the robot does not move (commands would not act), or '' if it does."""
        if self.program_topic:
            if self.program_running is None:
                return (f'robot stopped: no message yet on {self.program_topic} '
                        '(robot_program_running_topic)')
            if not self.program_running:
                return f'robot stopped: its program is not running ({self.program_topic} false)'
        if self.speed_topic:
            if self.speed_scaling is None:
                return f'robot stopped: no message yet on {self.speed_topic} (speed_scaling_topic)'
            if not self.speed_scaling > 0:
                return (f'robot stopped: speed scaling {self.speed_scaling:g} % on '
                        f'{self.speed_topic} (a protective stop or a pause)')
        return ''


@dataclass(frozen=True)
class Tick:
    """
    One tick's decision: the command to send, the state, the events.

    ``command``: controls ``(arms, actuators)``, or None: send nothing; ``hold``: it is the
    hold. ``age``: the joint state's age in s that the command was computed from or that
    made it a hold (NaN on an e-stop's hold), ``how`` it was measured. ``waiting_for``: the
    arm without a goal. A commanding tick has the observation, the policy's mean, the action
    taken and the guards' events per arm (``acted``); a hold has none of them.
    """

    status: Status
    command: Optional[np.ndarray] = None
    hold: bool = False
    age: float = np.nan
    how: str = ''
    events: Tuple[Event, ...] = ()
    waiting_for: str = ''
    obs: Optional[np.ndarray] = None
    mean: Optional[np.ndarray] = None
    action: Optional[np.ndarray] = None
    acted: Optional[Dict[GuardEvent, np.ndarray]] = None

    @property
    def guard_events(self) -> List[GuardEvent]:
        """Return the guards that acted on some arm, in :class:`GuardEvent`'s order."""
        return [e for e, arms in (self.acted or {}).items() if arms.any()]


class Deployment:
    """A trained policy commanding arms through the guards, with its stop paths."""

    def __init__(self, guard: CommandGuard,
                 observe: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
                 mean_std: Callable[[np.ndarray], Tuple[np.ndarray, np.ndarray]],
                 settings: Mapping, rng: Optional[np.random.Generator] = None,
                 watchdog: Optional[Watchdog] = None):
        """
        Take the guard, the observation and the policy, and the settings read at each tick.

        ``observe(q, qdot, goals)``: the observation ``(arms, obs_dim)`` as training builds
        it; ``mean_std(obs)``: the policy's Gaussian, ``(mean, std)`` ``(arms, act_dim)``.
        ``settings``: ``state_timeout`` (s) and ``deterministic`` (the mean; else a sample
        drawn with ``rng``), read at every tick so that a live change applies.
        ``watchdog``: the stale spells; a node's own, when a spell must outlive this object.
        """
        self.guard, self.observe, self.mean_std = guard, observe, mean_std
        self.settings = settings
        self.rng = rng if rng is not None else np.random.default_rng()
        self.watchdog = watchdog if watchdog is not None else Watchdog()
        self.waiting_for: Optional[str] = None      # the arm the last tick had no goal for
        self.robot_stopped = False                  # a spell of the robot's own stop

    def activate(self, now: float) -> Status:
        """Start commanding at steady time ``now`` (s): ramp in from the hold."""
        self.guard.start_ramp(now)
        self.waiting_for = None
        self.robot_stopped = False
        return NO_STATE

    def hold(self, joints: Optional[JointSample], decay: float = 0.0,
             age: float = 0.0) -> Optional[np.ndarray]:
        """
        Return the hold command from ``joints``, or None before the first joint state.

        ``decay`` 0, as the one hold left in force on deactivate or a stop: zero torque (a
        damping torque from one velocity, kept forever by a forward controller, would push
        the arm), or the last commanded angles. The next command ramps in from it. ``age``:
        the state's age in s; past ``state_timeout`` the hold has braked from it that long
        already (``coasting``, :meth:`CommandGuard.hold`).
        """
        if joints is None:
            return None
        coasting = age - self.settings['state_timeout'] if age == age else 0.0
        return self.guard.hold_tick(joints.q, joints.qdot, decay, max(coasting, 0.0))

    def tick(self, joints: Optional[JointSample], goals: Union[np.ndarray, str], now: float,
             clock_now: float, estop: bool, robot_stop: str = '') -> Tick:
        """
        Decide this tick: the guarded command, the hold, or nothing, and the state.

        ``joints``: the newest joint state (None: none yet); ``goals``: ``(arms, 3)``, or the
        name of an arm without one (:func:`pg_node.control.targets.target_array`); ``now``:
        steady time in s; ``clock_now``: the node's clock in s (0: not running yet), against
        which a state's stamp is aged; ``estop``: the e-stop is latched; ``robot_stop``: why
        the robot stopped itself (:meth:`RobotState.stop_reason`; '': it did not).
        """
        timeout = self.settings['state_timeout']
        age, how = np.nan, ''
        if joints is not None:
            age, how = state_age(now, joints.arrival, clock_now, joints.stamp, timeout)
        waiting_for, self.waiting_for = self.waiting_for, None
        if estop:
            # the active hold from the newest state (a stale one's damping decays)
            return Tick(ESTOP, self.hold(joints, hold_decay(age, timeout), age), hold=True,
                        how=how)
        if joints is None:
            return Tick(NO_STATE)
        if age > timeout:
            events = (Event.STALE,) if self.watchdog.begin() else ()
            return Tick(Status(NodeState.STALE, f'stale: joint states {age:.2f} s old {how}, '
                                                'hold command, waiting for fresh ones'),
                        self.hold(joints, hold_decay(age, timeout), age), hold=True, age=age,
                        how=how, events=events)
        if isinstance(goals, str):
            self.waiting_for = goals
            return Tick(Status(NodeState.WAITING, f'waiting: no target yet for {goals}'),
                        age=age, how=how, waiting_for=goals,
                        events=(Event.NO_TARGET,) if goals != waiting_for else ())
        if robot_stop:
            # the hold from the fresh state: the next command ramps in from it
            began, self.robot_stopped = not self.robot_stopped, True
            return Tick(Status(NodeState.ROBOT_STOPPED, f'{robot_stop}: hold command, '
                                                        'waiting for it to run again'),
                        self.hold(joints, hold_decay(age, timeout), age), hold=True, age=age,
                        how=how, events=(Event.ROBOT_STOPPED,) if began else ())
        events = (Event.FRESH,) if self.watchdog.end() else ()
        if self.robot_stopped:
            self.robot_stopped = False
            events += (Event.ROBOT_READY,)
        obs = self.observe(joints.q, joints.qdot, goals)
        mean, std = self.mean_std(obs)
        action = mean if self.settings['deterministic'] else \
            mean + std * self.rng.standard_normal(mean.shape)
        command, acted = self.guard(action, joints.q, joints.qdot, now)
        return Tick(COMMANDING, command, age=age, how=how, events=events, obs=obs, mean=mean,
                    action=action, acted=acted)
