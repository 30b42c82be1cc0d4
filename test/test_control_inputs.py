"""
What policy_node makes of its inputs, without a live node: joints, targets, watchdog, e-stop.

:mod:`pg_node.control.joint_map` (one arm by plain names or several prefixed, the one-line
refusal), :mod:`pg_node.control.targets` (frames, the reach clamp, the clamp to the trained goals,
goals per arm),
:mod:`pg_node.control.watchdog` (state age by arrival or stamp, stale spells) and
:mod:`pg_node.control.estop` (the latch).
"""
import doctest
from types import SimpleNamespace

import numpy as np
from pg_node.common.param_schema import ConfigError
from pg_node.control import joint_map, targets, watchdog
from pg_node.control.estop import EStop
from pg_node.control.joint_map import arm_joint_names, controller_mismatch, joint_columns
from pg_node.control.targets import (clamp_to_reach, frame_key, GoalSet, REACH_MARGIN,
                                     target_array, TWIN_WINDOW, Twins)
from pg_node.control.watchdog import state_age, Watchdog
import pytest


@pytest.mark.parametrize('module', [joint_map, targets, watchdog])
def test_worked_examples(module):
    failures, tried = doctest.testmod(module)
    assert tried > 0 and failures == 0


def test_joint_columns_plain_prefixed_and_missing():
    names = ['arm0/joint0', 'arm0/joint1', 'arm1/joint1', 'arm1/joint0', 'gripper']
    assert joint_columns(names, ['joint0', 'joint1']).tolist() == [[0, 1], [3, 2]]
    assert joint_columns(names, ['joint0', 'joint1'], num_arms=1).tolist() == [[0, 1]]
    with pytest.raises(ConfigError, match=r"no joint 'arm2/joint0'"):
        joint_columns(names, ['joint0', 'joint1'], num_arms=3)
    with pytest.raises(ConfigError) as err:
        joint_columns(['joint0', 'wrist'], ['joint0', 'joint1'])
    assert str(err.value) == (
        "joint_states has no joint 'joint1': the policy's arm has joints joint0, joint1 "
        '(plain, or as arm<i>/<joint> for several arms); the message names [joint0, wrist] '
        '(remap joint_states, or give a model with these joint names)')
    with pytest.raises(ConfigError, match=r'names \[j0, j1, j2, j3, j4, j5, j6, j7, \.\.\.\]'):
        joint_columns([f'j{i}' for i in range(9)], ['joint0'])
    assert arm_joint_names(['a'], 1, plain=True) == ['a']


@pytest.mark.parametrize('served,ordered,words', [
    (['j0', 'j1', 'j2'], True, None),
    # forward command controllers: element i of the array goes to joints[i]
    # (ros2_controllers (jazzy ed360c97d) forward_command_controller.cpp:48-52)
    (['j2', 'j1', 'j0'], True, 'has joints [j2, j1, j0], the commands are for [j0, j1, j2]: '
                               'the same joints in another order'),
    # JTC: names in any order (joint_trajectory_controller.cpp:1702-1713, sorted 1603-1650)
    (['j2', 'j1', 'j0'], False, None),
    # ... but all of them, and only its own (jtc.cpp:1676-1685, 1702-1713)
    (['j0', 'j1'], False, ': missing j2'),
    (['j0', 'j1', 'j2', 'gripper'], True, ': extra gripper'),
    (['j0', 'x', 'j2'], False, ': missing j1; extra x'),
    (['j0', 'j1', 'j1'], True, ': missing j2'),
    (['j0', 'j1', 'j2', 'j2'], False, ': a joint named twice'),
])
def test_the_controllers_joints_against_the_commanded(served, ordered, words):
    got = controller_mismatch(['j0', 'j1', 'j2'], served, '/left/arm', ordered=ordered)
    if words is None:
        assert got is None
    else:
        assert got.startswith('controller /left/arm has joints [') and words in got, got


def test_a_latched_targets_twin_through_the_other_subscription_is_dropped():
    t = Twins()
    assert not t.twin('latched', 'a', 0.0) and t.twin('volatile', 'a', 0.001)
    # the same goal again from the same subscription is a new message (a user's repeat)
    assert not t.twin('volatile', 'a', 0.1) and not t.twin('volatile', 'a', 0.2)
    # each copy has one twin: the latched copies of those two
    assert t.twin('latched', 'a', 0.2) and t.twin('latched', 'a', 0.2)
    assert not t.twin('latched', 'a', 0.2)
    # a copy later than the window is a message of its own
    assert not t.twin('volatile', 'b', 1.0) and not t.twin('latched', 'b', 1.0 + TWIN_WINDOW)


def test_frames_and_the_reach_clamp():
    assert frame_key('world', 'world') == 'base' and frame_key('arm12', 'b') == 12
    assert frame_key('arm1x', 'b') is None and frame_key('left/arm1', 'b') is None
    base, reach = np.array([1.0, 0.0, 0.0]), 0.2
    inside = np.array([1.0, REACH_MARGIN * reach, 0.0])          # on the margin: kept
    assert clamp_to_reach(inside, base, reach)[0] is inside
    point, distance = clamp_to_reach(np.array([1.0, 0.0, 0.4]), base, reach)
    np.testing.assert_allclose(point, [1.0, 0.0, 0.2])
    assert distance == pytest.approx(0.4)


def spec(center=(0.0, 0.0), radius=0.2, dim=2, points=None):
    """Return the goal fields of an ArmSpec (pg_node.sim.arm_task), as GoalSet.of reads them."""
    return SimpleNamespace(target_center=np.array(center), target_radius=radius,
                           target_dim=dim, target_points=points)


def test_a_goal_outside_the_trained_region_is_moved_onto_its_edge():
    # reacher2's disc: radius 0.2 about the origin in x, y; z is not observed and passes
    disc = GoalSet.of(spec())
    for point in ([0.1, 0.1, 0.01], [0.0, -0.2, 3.0], [0.0, 0.0, -1.0]):
        goal, moved = disc.clamp(np.array(point))
        assert not moved and goal.tolist() == point
    goal, moved = disc.clamp(np.array([5.0, 5.0, 0.01]))
    assert moved
    np.testing.assert_allclose(goal, [0.2 / np.sqrt(2), 0.2 / np.sqrt(2), 0.01])
    # a ball off the origin: along the line from its centre
    ball = GoalSet.of(spec(center=(0.5, 0.0, 0.3), radius=0.1, dim=3))
    goal, moved = ball.clamp(np.array([0.5, 0.0, -0.2]))     # under the table
    assert moved and np.allclose(goal, [0.5, 0.0, 0.2])
    assert ball.describe() == 'the ball of radius 0.1 m about (0.5, 0, 0.3)'


def test_a_goal_away_from_the_trained_points_is_moved_onto_the_nearest():
    # a grid of goals 0.1 m apart, from z 0.05 up: the tolerance is twice the spacing
    grid = np.array([[x, y, z] for x in (0.3, 0.4, 0.5) for y in (-0.1, 0.0, 0.1)
                     for z in (0.05, 0.15)])
    cloud = GoalSet.of(spec(center=(0, 0, 0), dim=3, points=grid))
    assert cloud.tolerance == pytest.approx(0.2) and cloud.floor == pytest.approx(0.05)
    goal, moved = cloud.clamp(np.array([0.43, 0.02, 0.1]))      # among them: as it is
    assert not moved and goal.tolist() == [0.43, 0.02, 0.1]
    goal, moved = cloud.clamp(np.array([0.69, 0.0, 0.15]))      # 0.19 m out: as it is
    assert not moved
    goal, moved = cloud.clamp(np.array([0.9, 0.0, 0.15]))       # beyond: the nearest
    assert moved and goal.tolist() == [0.5, 0.0, 0.15]
    goal, moved = cloud.clamp(np.array([0.4, 0.0, 0.0]))        # below the lowest goal
    assert moved and goal.tolist() == [0.4, 0.0, 0.05]
    assert cloud.describe() == ('its 18 goal points (within 0.2 m of one, none below z '
                                '0.05 m)')
    # one point alone: that goal, exactly
    one = GoalSet.of(spec(points=grid[:1]))
    assert one.clamp(grid[0] + 0.01)[1] and one.clamp(grid[0] + 0.01)[0].tolist() == [
        0.3, -0.1, 0.05]
    assert not one.clamp(grid[0])[1]


def test_goals_per_arm():
    goals = {'base': np.zeros(3), 1: np.ones(3)}
    np.testing.assert_array_equal(target_array(goals, 2, plain=False), [[0, 0, 0], [1, 1, 1]])
    # one arm with plain names is arm 0 (sim_node's one arm): its goal or the base frame's
    np.testing.assert_array_equal(target_array({0: np.ones(3)}, 1, plain=True), [[1, 1, 1]])
    assert target_array({1: np.ones(3)}, 1, plain=True) == 'the arm'
    np.testing.assert_array_equal(target_array({0: np.ones(3)}, 1, plain=False), [[1, 1, 1]])


def test_state_age_by_arrival_or_stamp():
    assert state_age(5.0, 4.0, 100.0, 99.5, 0.2) == (1.0, 'since arrival')   # older by arrival
    assert state_age(5.0, 4.9, 0.0, 50.0, 0.2)[1] == 'since arrival'         # clock not running
    # slightly ahead (within the timeout) does not count: clocks differ a little
    assert state_age(5.0, 4.9, 100.0, 100.1, 0.2)[1] == 'since arrival'
    age, how = state_age(5.0, 4.99, 1e9, 10.0, 0.2)                         # sim time stamps
    assert age == pytest.approx(1e9 - 10.0) and how == 'by header.stamp'


def test_a_stale_spell_is_one_event_and_ends_on_commanding():
    w = Watchdog()
    assert not w.end()                          # fresh and commanding: no spell
    assert [w.begin() for _ in range(3)] == [True, False, False] and w.stale
    assert w.end() and not w.stale and not w.end()
    assert w.begin()                            # a second spell


def test_the_estop_latches_until_reset():
    e = EStop()
    assert not e.reset()
    assert e.trip() and e.latched and not e.trip()
    assert e.reset() and not e.latched and not e.reset()
