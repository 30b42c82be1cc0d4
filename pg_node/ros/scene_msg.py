"""
A scene (:mod:`pg_node.sim.scene`) as a ``visualization_msgs/MarkerArray`` in one frame.

Per shown arm ``i``, in namespace ``arm<i>``: one marker per link shape (``SPHERE``,
``CUBE``, ``CYLINDER``; ids from 0), then the goal and the fingertip (``SPHERE``) and the
fingertip's trail (``LINE_STRIP``; ``DELETE`` while it has fewer than two points). Every
marker's frame is ``frame_id`` (the scene's fixed frame, ``world`` by default) and its pose
the world pose, so that RViz and Foxglove draw it without TF.
"""
from typing import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from pg_node.sim.scene import ArmView, BOX, CYLINDER, GOAL_RGBA, GOAL_SIZE, SPHERE, \
    TIP_RGBA, TIP_SIZE, TRAIL_RGBA, TRAIL_WIDTH
from visualization_msgs.msg import Marker, MarkerArray

KINDS = {SPHERE: Marker.SPHERE, BOX: Marker.CUBE, CYLINDER: Marker.CYLINDER}


def _marker(stamp: Time, frame_id: str, ns: str, mid: int, kind: int, pos, quat, scale,
            rgba) -> Marker:
    m = Marker(ns=ns, id=mid, type=kind, action=Marker.ADD)
    m.header.stamp = stamp
    m.header.frame_id = frame_id
    m.pose.position.x, m.pose.position.y, m.pose.position.z = (float(v) for v in pos)
    (m.pose.orientation.w, m.pose.orientation.x, m.pose.orientation.y,
     m.pose.orientation.z) = (float(v) for v in quat)
    m.scale.x, m.scale.y, m.scale.z = (float(v) for v in scale)
    m.color.r, m.color.g, m.color.b, m.color.a = (float(v) for v in rgba)
    return m


def scene_markers(views: Sequence[ArmView], stamp: Time, frame_id: str = 'world'
                  ) -> MarkerArray:
    """Return the markers of ``views`` (see the module docstring)."""
    out = MarkerArray()
    unit = (1.0, 0.0, 0.0, 0.0)
    for view in views:
        ns, mid = f'arm{view.arm}', 0
        for shapes in view.links:
            for pos, quat, scale, rgba in zip(shapes.pos, shapes.quat, shapes.scale,
                                              shapes.rgba):
                out.markers.append(_marker(stamp, frame_id, ns, mid, KINDS[shapes.kind], pos,
                                           quat, scale, rgba))
                mid += 1
        for point, size, rgba in ((view.goal, GOAL_SIZE, GOAL_RGBA),
                                  (view.tip, TIP_SIZE, TIP_RGBA)):
            out.markers.append(_marker(stamp, frame_id, ns, mid, Marker.SPHERE, point, unit,
                                       (size,) * 3, rgba))
            mid += 1
        trail = _marker(stamp, frame_id, ns, mid, Marker.LINE_STRIP, (0, 0, 0), unit,
                        (TRAIL_WIDTH, 0, 0), TRAIL_RGBA)
        if len(view.trail) >= 2:
            trail.points = [Point(x=x, y=y, z=z) for x, y, z in view.trail.tolist()]
        else:                           # a new episode: the last one's trail goes
            trail.action = Marker.DELETE
        out.markers.append(trail)
    return out
