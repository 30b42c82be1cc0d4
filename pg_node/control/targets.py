"""
A policy's goals: which arm a target's frame names, and a target clamped onto the arm's reach.

A target comes in the arm's base frame (``frame_id`` the base frame, or empty: every arm) or
in ``arm<i>``, ``sim_node``'s frame of arm ``i``'s base; another frame is the ROS side's to
transform (tf2). A goal beyond the arm's reach is moved onto the sphere of the reach, along
the line from the base, so the policy never sees a goal it was not trained on.

A target comes from two subscriptions, as no one subscription takes every publisher: a
transient-local one gets a latched publisher's last sample (``sim_node``'s), which a volatile
one never does; a volatile one matches the volatile publishers of ``ros2 topic pub`` and
RViz's Publish Point, which a transient-local one does not (DDS refuses the pair: durability
incompatible). A latched publisher's messages reach both; :class:`Twins` drops the second copy.
"""
import re
import time
from typing import Dict, Hashable, List, Optional, Tuple, Union

import numpy as np

#: sim_node's frame of arm ``i``'s base
ARM_FRAME = re.compile(r'arm(\d+)')
#: a target this much beyond the arm's reach (ObservationBuilder.reach) is clamped
REACH_MARGIN = 1.05
#: the key of a goal for every arm
BASE = 'base'


def frame_key(frame: str, base_frame: str) -> Union[str, int, None]:
    """
    Return :data:`BASE` for the base frame (or none), ``i`` for ``arm<i>``, else None.

    >>> frame_key('', 'base_link'), frame_key('base_link', 'base_link'), frame_key('arm3', 'b')
    ('base', 'base', 3)
    >>> frame_key('camera', 'base_link') is None
    True
    """
    if frame in ('', base_frame):
        return BASE
    match = ARM_FRAME.fullmatch(frame)
    return int(match.group(1)) if match else None


def clamp_to_reach(point: np.ndarray, base: np.ndarray, reach: float
                   ) -> Tuple[np.ndarray, Optional[float]]:
    """
    Return the goal and, when it was beyond :data:`REACH_MARGIN` times the reach, its distance.

    A goal too far is moved onto the reach, in the same direction from the base.

    >>> clamp_to_reach(np.array([0.0, 0.3, 0.0]), np.zeros(3), 0.2)
    (array([0. , 0.2, 0. ]), 0.3)
    >>> clamp_to_reach(np.array([0.0, 0.205, 0.0]), np.zeros(3), 0.2)[1] is None
    True
    """
    distance = float(np.linalg.norm(point - base))
    if distance > REACH_MARGIN * reach:
        return base + (point - base) * (reach / distance), distance
    return point, None


def target_array(targets: Dict[object, np.ndarray], num_arms: int, plain: bool
                 ) -> Union[np.ndarray, str]:
    """
    Return the goals ``(arms, 3)``, or the name of an arm without one.

    ``targets``: :data:`BASE` or an arm index -> goal; an arm's own goal wins over the base's.
    One arm with plain joint names is arm 0 (``sim_node`` names one arm's joints plainly and
    sends its goal in ``arm0``).

    >>> target_array({'base': np.ones(3), 1: np.zeros(3)}, 2, plain=False).tolist()
    [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]
    >>> target_array({1: np.zeros(3)}, 2, plain=False)
    'arm0'
    """
    out = np.empty((num_arms, 3))
    for i in range(num_arms):
        point = targets.get(i, targets.get(BASE))
        if point is None:
            return 'the arm' if plain else f'arm{i}'
        out[i] = point
    return out


#: s: the second copy of a message, through the other subscription, comes within this
TWIN_WINDOW = 0.5


class Twins:
    """
    Drop the copy of a message that came through the other of two subscriptions.

    A message is a twin when the other subscription delivered an equal one (same key: here
    stamp, frame and point) less than :data:`TWIN_WINDOW` s ago that has no twin yet. An
    equal message through the *same* subscription is new (a user publishing the same goal
    twice); so is one after the window.

    >>> t = Twins()
    >>> [t.twin('latched', 'a', 0.0), t.twin('volatile', 'a', 0.01), t.twin('volatile', 'a', 0.02)]
    [False, True, False]
    >>> t.twin('latched', 'b', 0.03), t.twin('volatile', 'b', 0.03 + TWIN_WINDOW)
    (False, False)
    """

    def __init__(self):
        """Remember nothing yet."""
        self._pending: List[Tuple[float, str, Hashable]] = []   # (arrival, source, key)

    def twin(self, source: str, key: Hashable, now: Optional[float] = None) -> bool:
        """Return whether ``key`` from ``source`` is the copy of one the other source gave."""
        now = time.monotonic() if now is None else now
        self._pending = [p for p in self._pending if now - p[0] < TWIN_WINDOW]
        for i, (_, other, seen) in enumerate(self._pending):
            if other != source and seen == key:
                del self._pending[i]
                return True
        self._pending.append((now, source, key))
        return False
