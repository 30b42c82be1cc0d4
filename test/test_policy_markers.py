"""policy_node's markers (:mod:`pg_node.ros.policy_markers`), without a node."""
from builtin_interfaces.msg import Time
import numpy as np
from pg_node.control.status import NodeState
from pg_node.ros.policy_markers import (COLOURS, GOAL, policy_markers, REQUESTED,
                                        REQUESTED_RGBA, TIP)
from visualization_msgs.msg import Marker


def by_id(array, ns):
    return {m.id: m for m in array.markers if m.ns == ns}


def position(marker):
    return [marker.pose.position.x, marker.pose.position.y, marker.pose.position.z]


def test_a_clamped_goal_shows_the_requested_one_beside_it_and_drops_it_once_taken_as_is():
    goals = np.array([[0.14, 0.14, 0.01], [0.1, 0.0, 0.01]])
    asked = np.array([[5.0, 5.0, 0.01], [0.1, 0.0, 0.01]])      # arm0 clamped, arm1 not
    tips = np.zeros((2, 3))
    out = policy_markers(goals, tips, NodeState.ROBOT_STOPPED, ['arm0', 'arm1'], Time(),
                         requested=asked)
    arm0, arm1 = by_id(out, 'arm0'), by_id(out, 'arm1')
    assert set(arm0) == set(arm1) == {GOAL, TIP, REQUESTED}
    assert position(arm0[GOAL]) == goals[0].tolist()
    assert position(arm0[REQUESTED]) == asked[0].tolist()
    assert arm0[REQUESTED].action == Marker.ADD
    assert (arm0[REQUESTED].color.r, arm0[REQUESTED].color.a) == (
        np.float32(REQUESTED_RGBA[0]), np.float32(REQUESTED_RGBA[3]))
    assert arm1[REQUESTED].action == Marker.DELETE            # taken as it came
    # the robot's own stop is a hold: the fingertip is the hold's orange
    tip = arm0[TIP].color
    assert (tip.r, tip.g, tip.b) == tuple(np.float32(COLOURS[NodeState.STALE][:3]))
    # no requested goals given: every one as taken, no requested marker shown
    plain = by_id(policy_markers(goals, None, NodeState.COMMANDING, ['a', 'b'], Time()), 'arm0')
    assert set(plain) == {GOAL, REQUESTED} and plain[REQUESTED].action == Marker.DELETE
