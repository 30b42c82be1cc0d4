"""
The guards step by step on hand-made actuator records, and the severities they report.

:class:`pg_node.control.guards.CommandGuard`: range, ramp, smoothing, rate limit, joint limits
with both interfaces, over-speed, hold; :mod:`pg_node.control.status`: which events warn, and
the /diagnostics level from a node's state and its latched faults.
"""
import doctest

from control_records import POSITION_SERVOS, REACHER2
import numpy as np
from pg_node.control import status
from pg_node.control.guards import CommandGuard, GuardSettings
from pg_node.control.interfaces import INTERFACES
from pg_node.control.status import diagnostic_level, Fault, GuardEvent, NodeState, Severity
import pytest

JOINTS = ['joint0', 'joint1']
E = GuardEvent


def guard(record=REACHER2, interface='effort', **settings):
    return CommandGuard(record, JOINTS, interface, GuardSettings(**settings))


def test_range_nonfinite_and_over_speed_give_clipped_or_hold_commands():
    g = guard(max_velocity=5.0)
    q = np.zeros((3, 2))
    qdot = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, -6.0]])
    u, acted = g(np.array([[2.0, -0.5], [np.nan, 0.1], [0.3, 0.3]]), q, qdot, 0.0)
    np.testing.assert_array_equal(u, [[1.0, -0.5], [0.0, 0.0], [0.0, 0.0]])
    assert acted[E.CLIPPED].tolist() == [True, False, False]
    assert acted[E.NONFINITE].tolist() == [False, True, False]
    assert acted[E.OVER_SPEED].tolist() == [False, False, True]
    assert set(acted) == set(GuardEvent)


def test_ramp_blends_from_hold_then_lets_the_command_through():
    g = guard(ramp_time=1.0)
    g.start_ramp(10.0)
    q, qdot, a = np.zeros((1, 2)), np.zeros((1, 2)), np.array([[0.8, -0.4]])
    steps = [g(a, q, qdot, t) for t in (10.0, 10.25, 10.5, 11.0, 12.0)]
    np.testing.assert_allclose([u[0] for u, _ in steps],
                               [[0, 0], [0.2, -0.1], [0.4, -0.2], [0.8, -0.4], [0.8, -0.4]])
    assert [bool(e[E.RAMPED][0]) for _, e in steps] == [True] * 3 + [False] * 2


def test_smoothing_is_a_first_order_filter_and_max_change_a_rate_limit():
    q, qdot = np.zeros((1, 2)), np.zeros((1, 2))
    g = guard(smoothing=0.75)
    g.sent(np.zeros((1, 2)))
    out = [g(np.array([[1.0, -1.0]]), q, qdot, 0.0)[0][0, 0] for _ in range(3)]
    np.testing.assert_allclose(out, [0.25, 0.4375, 0.578125])
    g = guard(max_change=0.1)                 # 0.1 of the range [-1, 1]: 0.2 per tick
    g.sent(np.zeros((1, 2)))
    steps = [g(np.array([[1.0, 0.1]]), q, qdot, 0.0) for _ in range(6)]
    np.testing.assert_allclose([u[0, 0] for u, _ in steps], [0.2, 0.4, 0.6, 0.8, 1.0, 1.0])
    assert [bool(a[E.RATE_LIMITED][0]) for _, a in steps] == [True] * 4 + [False] * 2


def test_joint_limit_guard_holds_back_commands_towards_the_limit():
    g = guard(joint_limit_margin=0.05)                  # joint1 is limited to [-3, 3]
    qdot = np.zeros((4, 2))
    q = np.array([[0.0, 2.96], [0.0, 2.96], [0.0, -2.99], [5.0, 2.9]])
    a = np.array([[0.5, 0.5], [0.5, -0.5], [0.5, -0.5], [0.5, 0.5]])
    u, acted = g(a, q, qdot, 0.0)
    # outward at the upper limit: zero; inward: kept; joint0 is unlimited: never touched
    np.testing.assert_array_equal(u, [[0.5, 0.0], [0.5, -0.5], [0.5, 0.0], [0.5, 0.5]])
    assert acted[E.JOINT_LIMIT].tolist() == [True, False, True, False]
    p = guard(POSITION_SERVOS, 'position', joint_limit_margin=0.1)
    u, acted = p(np.array([[0.0, 1.0], [0.0, 0.5]]), np.zeros((2, 2)), np.zeros((2, 2)), 0.0)
    # a target angle of 3 rad is kept 0.1 rad inside the range; 1.5 rad is left alone
    np.testing.assert_allclose(INTERFACES['position'].to_si(POSITION_SERVOS, u),
                               [[0.0, 2.9], [0.0, 1.5]])
    assert acted[E.JOINT_LIMIT].tolist() == [True, False]


def test_hold_is_zero_effort_or_the_measured_angles():
    q = np.array([[0.4, -1.2], [3.5, 2.0]])
    np.testing.assert_array_equal(guard().hold(q, 2), np.zeros((2, 2)))
    p = guard(POSITION_SERVOS, 'position')
    # joint0 is continuous (its servo's range is [-3, 3] rad here): clipped to what it takes
    np.testing.assert_allclose(INTERFACES['position'].to_si(POSITION_SERVOS, p.hold(q, 2)),
                               [[0.4, -1.2], [3.0, 2.0]])


def test_the_joint_order_is_the_cards_and_every_actuated_joint_must_be_in_it():
    g = guard()
    assert CommandGuard(REACHER2, ['x', 'joint1', 'joint0'], 'effort').cols.tolist() == [2, 1]
    assert g.cols.tolist() == [0, 1]
    with pytest.raises(ValueError, match='actuated joints joint1 are not among the joints'):
        CommandGuard(REACHER2, ['joint0'], 'effort')


def test_events_that_warn_and_the_diagnostics_level():
    assert {e for e in GuardEvent if e.severity is Severity.WARN} == \
        {E.NONFINITE, E.JOINT_LIMIT, E.OVER_SPEED}
    assert all(e.warning for e in GuardEvent if e.severity is Severity.WARN)
    assert [e.key for e in GuardEvent] == ['nonfinite', 'clipped', 'ramped', 'rate_limited',
                                           'joint_limit', 'over_speed']
    assert diagnostic_level(NodeState.COMMANDING) is Severity.OK
    # commanding degraded (no subscriber on the command topic, the controller's joints
    # unread: issue 44) is WARN; the ERROR faults (stale, e-stop) stop commanding
    assert diagnostic_level(NodeState.COMMANDING, [Fault.NO_LISTENER]) is Severity.WARN
    for state in set(NodeState) - {NodeState.COMMANDING}:
        assert diagnostic_level(state) is Severity.WARN, state
        for fault in Fault:
            assert diagnostic_level(state, [fault]) is max(Severity.WARN, fault.severity), \
                (state, fault)
    assert [int(s) for s in Severity] == [0, 1, 2]       # diagnostic_msgs' OK, WARN, ERROR


@pytest.mark.parametrize('module', [status])
def test_worked_examples(module):
    failures, tried = doctest.testmod(module)
    assert tried > 0 and failures == 0
