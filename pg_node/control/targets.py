"""
A policy's goals: which arm a target's frame names, and a target clamped onto what it learned.

A target comes in the arm's base frame (``frame_id`` the base frame, or empty: every arm) or
in ``arm<i>``, ``sim_node``'s frame of arm ``i``'s base; another frame is the ROS side's to
transform (tf2). A goal beyond the arm's reach is moved onto the sphere of the reach, along
the line from the base (:func:`clamp_to_reach`); then a goal outside the goals the policy
trained on (:class:`GoalSet`, its model's region or goal points) is moved onto the nearest
of them, so the policy never acts on a goal it was not trained on (one under the table).

A target comes from two subscriptions, as no one subscription takes every publisher: a
transient-local one gets a latched publisher's last sample (``sim_node``'s), which a volatile
one never does; a volatile one matches the volatile publishers of ``ros2 topic pub`` and
RViz's Publish Point, which a transient-local one does not (DDS refuses the pair: durability
incompatible). A latched publisher's messages reach both; :class:`Twins` drops the second copy.
"""
from dataclasses import dataclass
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


@dataclass(frozen=True)
class GoalSet:
    """
    The goals a policy trained on, as its model draws them (:mod:`pg_node.sim.arm_task`).

    Either a region: the first ``dim`` coordinates in the ball (``dim`` 2: the disc) of
    ``radius`` about ``center`` (the rest are not observed, and pass as they are); or
    ``points`` ``(n, 3)``, the goal points an imported arm learned (``pg_target_points``,
    drawn at reachable fingertip positions above a minimum height, within a region). A
    point set is sampled, not dense: a target within ``tolerance`` of one of them and not
    below the lowest (``floor``, the minimum height the import kept) is among them.
    """

    center: np.ndarray
    radius: float
    dim: int = 3
    points: Optional[np.ndarray] = None
    tolerance: float = 0.0
    floor: float = -np.inf

    @classmethod
    def of(cls, spec) -> 'GoalSet':
        """
        Return the goals of a model's :class:`pg_node.sim.arm_task.ArmSpec` (duck-typed).

        The tolerance of a point set: twice the median distance from a point to its nearest
        other one (the spacing at which the policy saw goals); for points drawn uniformly in
        3-D a place among them is farther than that from every one of them with probability
        ``2**-8``, where the median itself would move half the goals. One point: that goal.
        """
        center = np.asarray(spec.target_center, dtype=float)
        if spec.target_points is None:
            return cls(center, float(spec.target_radius), int(spec.target_dim))
        points = np.asarray(spec.target_points, dtype=float)
        gaps = np.full(len(points), np.inf)
        for i in range(0, len(points), 256):        # in blocks: n x n distances for n ~ 1e4
            d = np.linalg.norm(points[i:i + 256, None] - points[None], axis=2)
            d[np.arange(len(d)), np.arange(i, i + len(d))] = np.inf
            gaps[i:i + 256] = d.min(axis=1)
        # one point alone: that goal, exactly
        tolerance = 2 * float(np.median(gaps)) if len(points) > 1 else 0.0
        return cls(center, float(spec.target_radius), 3, points, tolerance,
                   float(points[:, 2].min()))

    def clamp(self, point: np.ndarray) -> Tuple[np.ndarray, bool]:
        """
        Return the goal the policy takes for ``point`` (3), and whether it was moved.

        Outside a region: onto its sphere (circle), along the line from the centre; outside a
        point set: onto the nearest point.

        >>> disc = GoalSet(np.zeros(2), 0.2, dim=2)
        >>> disc.clamp(np.array([0.3, 0.4, 0.01]))
        (array([0.12, 0.16, 0.01]), True)
        >>> disc.clamp(np.array([0.1, 0.1, 5.0]))[1]
        False
        >>> cloud = GoalSet(np.zeros(3), 0.2, points=np.array([[0.3, 0, 0.1], [0.3, 0.1, 0.1]]),
        ...                 tolerance=0.05, floor=0.1)
        >>> cloud.clamp(np.array([0.32, 0.0, 0.1]))[1], cloud.clamp(np.array([0.3, 0, 0.08]))
        (False, (array([0.3, 0. , 0.1]), True))
        """
        point = np.asarray(point, dtype=float)
        if self.points is not None:
            gaps = np.linalg.norm(self.points - point, axis=1)
            nearest = int(np.argmin(gaps))
            if gaps[nearest] <= self.tolerance and point[2] >= self.floor:
                return point, False
            return self.points[nearest].copy(), True
        k = self.dim
        offset = point[:k] - self.center
        distance = float(np.linalg.norm(offset))
        if distance <= self.radius:
            return point, False
        goal = point.copy()
        goal[:k] = self.center + offset * (self.radius / distance)
        return goal, True

    def describe(self) -> str:
        """
        Return the goals in words, for a warning.

        >>> GoalSet(np.zeros(2), 0.2, dim=2).describe()
        'the disc of radius 0.2 m about (0, 0)'
        """
        if self.points is not None:
            return (f'its {len(self.points)} goal points (within {self.tolerance:.3g} m of '
                    f'one, none below z {self.floor:.3g} m)')
        shape = {1: 'segment', 2: 'disc'}.get(self.dim, 'ball')
        return (f'the {shape} of radius {self.radius:g} m about '
                f"({', '.join(f'{c:g}' for c in self.center)})")


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
