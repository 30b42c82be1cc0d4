"""
The stale-state watchdog: how old the newest joint state is, and the spells it is too old.

A joint state is stale when it is older than ``state_timeout`` since it arrived, or by its
``header.stamp`` against the node's clock; a stamp more than ``state_timeout`` in the future
counts too (the clocks differ). While stale, the hold command goes out at every tick; a spell
of stale states is counted (and warned about) once.
"""
from typing import Optional, Tuple


def state_age(now: float, arrival: float, clock_now: float, stamp: Optional[float],
              timeout: float) -> Tuple[float, str]:
    """
    Return the state's age in s and how it was measured: since arrival, or by its stamp.

    ``now`` and ``arrival``: steady time; ``clock_now`` and ``stamp``: the node's clock (0:
    not running yet) and the state's ``header.stamp`` (None: a zero stamp). The stamp counts
    when it makes the state older than its arrival does, or when it lies more than
    ``timeout`` in the future.

    >>> state_age(10.0, 9.9, 100.0, 99.5, 0.2)
    (0.5, 'by header.stamp')
    >>> state_age(10.0, 9.9, 100.0, 100.5, 0.2)
    (0.5, 'by header.stamp, in the future')
    >>> state_age(10.0, 9.5, 100.0, None, 0.2)
    (0.5, 'since arrival')
    """
    age, how = now - arrival, 'since arrival'
    if stamp is not None and clock_now > 0:
        by_stamp = clock_now - stamp
        if by_stamp > age or by_stamp < -timeout:
            age, how = abs(by_stamp), ('by header.stamp' if by_stamp > 0
                                       else 'by header.stamp, in the future')
    return age, how


class Watchdog:
    """The spells of stale joint states: one begins with a stale tick, ends on commanding."""

    def __init__(self):
        """Start fresh: no spell."""
        self.stale = False

    def begin(self) -> bool:
        """Note a stale tick; return True when it begins a spell (warn and count it once)."""
        began, self.stale = not self.stale, True
        return began

    def end(self) -> bool:
        """Note a commanding tick; return True when it ends a spell."""
        ended, self.stale = self.stale, False
        return ended


def hold_decay(age: float, timeout: float) -> float:
    """
    Return the share of the effort hold's damping torque a state of age ``age`` s earns.

    1 while the state is fresh (``age <= timeout``), then linearly down to 0 at ``2 timeout``:
    a velocity that old says nothing about how the arm moves now, and a brake computed from
    a motion that has since stopped would push the arm back. A NaN age (no state) gives 0.

    >>> [hold_decay(a, 0.25) for a in (0.1, 0.25, 0.375, 0.5, 9.0)]
    [1.0, 1.0, 0.5, 0.0, 0.0]
    """
    if not age == age:
        return 0.0
    return min(max(2.0 - age / timeout, 0.0), 1.0)
