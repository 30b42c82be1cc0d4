"""
What ``policy_node`` shows of its work: the goal it acts on and the fingertip, as markers.

Per arm ``i``, in namespace ``arm<i>``: the goal (id 0, a red sphere) as the policy takes it
(clamped onto the arm's reach and into the goals it trained on,
:mod:`pg_node.control.targets`), the fingertip (id 1, a sphere) where the policy's model puts
it for the newest joint state (:meth:`pg_node.sim.observation.ObservationBuilder.fingertips`),
coloured by what the node does (:data:`COLOURS`): green while it commands the policy's
action, orange while it holds (stale joint states, the robot's own stop), red for a latched
e-stop, grey while it waits (no target, no state); and while a goal is clamped, the goal as
requested (id 2, a translucent sphere, :data:`REQUESTED_RGBA`; deleted once a goal is taken
as it came).
Frames: the base frame for one arm with plain joint names, ``arm<i>`` for several (as
``sim_node``'s ``/target``), or one given frame.
"""
from typing import Sequence

from builtin_interfaces.msg import Time
import numpy as np
from pg_node.control.status import NodeState
from pg_node.sim.scene import GOAL_RGBA, GOAL_SIZE, TIP_SIZE
from visualization_msgs.msg import Marker, MarkerArray

#: the fingertip's colour (r, g, b, a) by the node's state; another state: WAITING's
COLOURS = {NodeState.COMMANDING: (0.1, 0.8, 0.2, 1.0), NodeState.STALE: (1.0, 0.55, 0.0, 1.0),
           NodeState.ROBOT_STOPPED: (1.0, 0.55, 0.0, 1.0),
           NodeState.ESTOP: (0.9, 0.0, 0.0, 1.0), NodeState.WAITING: (0.6, 0.6, 0.6, 1.0)}
#: the requested goal's colour, while the goal taken is a clamped one
REQUESTED_RGBA = (0.9, 0.2, 0.2, 0.35)
#: marker ids within an arm's namespace
GOAL, TIP, REQUESTED = 0, 1, 2


def _sphere(stamp: Time, frame: str, ns: str, mid: int, point, size: float, rgba) -> Marker:
    m = Marker(ns=ns, id=mid, type=Marker.SPHERE, action=Marker.ADD)
    m.header.stamp = stamp
    m.header.frame_id = frame
    m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in point)
    m.pose.orientation.w = 1.0
    m.scale.x = m.scale.y = m.scale.z = float(size)
    m.color.r, m.color.g, m.color.b, m.color.a = (float(v) for v in rgba)
    return m


def policy_markers(goals, tips, state: NodeState, frames: Sequence[str], stamp: Time,
                   requested=None) -> MarkerArray:
    """
    Return the goal, fingertip and requested goal markers of each arm (module docstring).

    ``goals`` ``(arms, 3)`` or None (no goal yet), ``tips`` ``(arms, 3)`` or None (no joint
    state yet), ``frames`` one per arm; ``requested`` ``(arms, 3)``: the goals as asked
    for, before the clamps (None: as taken).
    """
    out = MarkerArray()
    colour = COLOURS.get(state, COLOURS[NodeState.WAITING])
    for i, frame in enumerate(frames):
        if goals is not None:
            goal = np.asarray(goals)[i]
            out.markers.append(_sphere(stamp, frame, f'arm{i}', GOAL, goal, GOAL_SIZE,
                                       GOAL_RGBA))
            asked = goal if requested is None else np.asarray(requested)[i]
            marker = _sphere(stamp, frame, f'arm{i}', REQUESTED, asked, GOAL_SIZE,
                             REQUESTED_RGBA)
            if np.array_equal(asked, goal):
                marker.action = Marker.DELETE       # no clamp: RViz drops the last one
            out.markers.append(marker)
        if tips is not None:
            out.markers.append(_sphere(stamp, frame, f'arm{i}', TIP, np.asarray(tips)[i],
                                       TIP_SIZE, colour))
    return out
