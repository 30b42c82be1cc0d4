"""
What a controller reports: its state, the guards' events and the faults, each with a severity.

The severities are ``diagnostic_msgs/DiagnosticStatus``'s levels, used as
``diagnostic_updater`` uses them: OK while working, WARN when idle or degraded, ERROR when
stale or stopped. The ROS side maps :class:`Severity` onto the message's level constants;
the rule that picks the level (:func:`diagnostic_level`) lives here, apart from the status
text, which says why in words.
"""
from enum import Enum, IntEnum
from typing import Dict, Hashable, Iterable, Optional


class Severity(IntEnum):
    """diagnostic_msgs' levels (``DiagnosticStatus.OK`` ... ``ERROR``), ordered."""

    OK = 0
    WARN = 1
    ERROR = 2


class GuardEvent(Enum):
    """
    A guard of :class:`pg_node.control.guards.CommandGuard` that acted on a tick.

    ``key`` names its counter (``guard_<key>`` in /diagnostics); a WARN event is logged with
    ``warning`` (the first time, then at most once per :class:`RepeatedWarnings` period with
    how often it came meanwhile), an OK one only counted.

    >>> GuardEvent.OVER_SPEED.key, GuardEvent.OVER_SPEED.severity.name
    ('over_speed', 'WARN')
    >>> [e.key for e in GuardEvent if e.severity is Severity.OK]
    ['clipped', 'ramped', 'rate_limited', 'position_delta', 'acceleration_limited']
    """

    NONFINITE = ('nonfinite', Severity.WARN,
                 'the policy gave a non-finite action: hold command sent')
    CLIPPED = ('clipped', Severity.OK, '')
    RAMPED = ('ramped', Severity.OK, '')
    RATE_LIMITED = ('rate_limited', Severity.OK, '')
    JOINT_LIMIT = ('joint_limit', Severity.WARN,
                   'joint limit guard: a joint braked (its braking distance reaches a limit), '
                   'or a target kept inside the range')
    OVER_SPEED = ('over_speed', Severity.WARN,
                  'over-speed guard: a joint is faster than max_velocity, hold command')
    #: appended (the record's ``guards`` bits number the events in this order)
    POSITION_DELTA = ('position_delta', Severity.OK, '')
    #: the velocity interface's acceleration limit (``max_acceleration``) acted
    ACCELERATION_LIMITED = ('acceleration_limited', Severity.OK, '')

    def __init__(self, key: str, severity: Severity, warning: str):
        self.key, self.severity, self.warning = key, severity, warning


class NodeState(Enum):
    """What a commanding node is doing, with the level it reports while no fault latches."""

    UNCONFIGURED = ('unconfigured', Severity.WARN)
    INACTIVE = ('inactive', Severity.WARN)
    WAITING = ('waiting', Severity.WARN)
    COMMANDING = ('commanding', Severity.OK)
    STALE = ('stale', Severity.WARN)
    ESTOP = ('estop', Severity.WARN)
    #: the robot stopped itself (its program not running, speed scaling 0): hold command
    ROBOT_STOPPED = ('robot_stopped', Severity.WARN)
    FINALIZED = ('finalized', Severity.WARN)

    def __init__(self, key: str, severity: Severity):
        self.key, self.severity = key, severity


class Fault(Enum):
    """A latched condition that makes a node's level ERROR until it clears."""

    STALE_STATE = ('stale joint states', Severity.ERROR)     # a watchdog spell
    ESTOP = ('e-stop latched', Severity.ERROR)
    #: nobody subscribes to the command topic while commanding: no controller can be
    #: listening (a subscriber proves less: a configured, inactive controller subscribes too)
    NO_LISTENER = ('no subscriber on the command topic', Severity.WARN)
    #: the controller's ``joints`` could not be read: the joint order was not checked
    JOINTS_UNCHECKED = ('joint order not checked', Severity.WARN)

    def __init__(self, text: str, severity: Severity):
        self.text, self.severity = text, severity


def diagnostic_level(state: NodeState, faults: Iterable[Fault] = ()) -> Severity:
    """
    Return the /diagnostics level: the worst of the state's and the faults'.

    A fault outlives the tick that found it: a node deactivated during a stale spell, or
    with an e-stop latched, still reports ERROR. Commanding is OK unless a fault degrades it.

    >>> diagnostic_level(NodeState.COMMANDING).name, diagnostic_level(NodeState.WAITING).name
    ('OK', 'WARN')
    >>> diagnostic_level(NodeState.INACTIVE, [Fault.ESTOP]).name
    'ERROR'
    >>> diagnostic_level(NodeState.COMMANDING, [Fault.NO_LISTENER]).name
    'WARN'
    """
    return max([state.severity] + [f.severity for f in faults])


class RepeatedWarnings:
    """
    Which repeated warnings to log: each the first time, then once a ``period`` with a count.

    A guard that acts every few ticks would log a line a second for as long as it acts; its
    counter in /diagnostics holds the total, and the log needs the news: that it began, and
    that it goes on (how often since the last line). Times are the caller's (monotonic s).

    >>> w = RepeatedWarnings(period=30.0)
    >>> w.line('limit', 'joint limit guard', 0.0)
    'joint limit guard'
    >>> [w.line('limit', 'joint limit guard', t) for t in (1.0, 2.0)]
    [None, None]
    >>> w.line('limit', 'joint limit guard', 31.0)
    'joint limit guard (3 times in the last 31 s)'
    """

    def __init__(self, period: float):
        """Log a warning at most once per ``period`` s, after its first time."""
        self.period = period
        self._last: Dict[Hashable, float] = {}       # key -> when it was last logged
        self._count: Dict[Hashable, int] = {}        # key -> times since then (incl. now)

    def line(self, key: Hashable, text: str, now: float) -> Optional[str]:
        """Return the line to log for this occurrence of ``key``, or None to count it only."""
        last = self._last.get(key)
        if last is None:
            self._last[key], self._count[key] = now, 0
            return text
        self._count[key] += 1
        if now - last < self.period:
            return None
        count = self._count[key]
        self._last[key], self._count[key] = now, 0
        return f'{text} ({count} times in the last {now - last:.0f} s)'
