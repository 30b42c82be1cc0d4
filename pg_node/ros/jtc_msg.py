"""
A ``trajectory_msgs/JointTrajectory`` as :mod:`pg_node.control.jtc` takes it.

The robot stand-ins (``sim_node``, ``pybullet_node``) hand the
message to :class:`pg_node.control.jtc.JtcFollower` through this one conversion.
"""
from pg_node.control import jtc


def trajectory(msg) -> jtc.Trajectory:
    """Return ``msg``, a ``JointTrajectory``, as a :class:`pg_node.control.jtc.Trajectory`."""
    stamp = msg.header.stamp
    return jtc.Trajectory(
        list(msg.joint_names),
        [jtc.Point({k: list(getattr(p, k)) for k in jtc.POINT_FIELDS},
                   p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec)
         for p in msg.points],
        stamp.sec + 1e-9 * stamp.nanosec)
