"""
The guards step by step on hand-made actuator records, and the severities they report.

:class:`pg_node.control.guards.CommandGuard`: range, ramp, smoothing, rate limit, joint limits
with both interfaces (the braking distance with effort), over-speed, the holds (effort: a
damping torque, position: the last command) and the ramp after each kind of hold, the
defaults taken from the model; :mod:`pg_node.control.status`: which events warn, and the
/diagnostics level from a node's state and its latched faults.
"""
from dataclasses import replace
import doctest

from control_records import POSITION_SERVOS, REACHER2
import numpy as np
from pg_node.control import status, watchdog
from pg_node.control.guards import CommandGuard, GuardSettings, model_limits
from pg_node.control.interfaces import INTERFACES
from pg_node.control.status import (diagnostic_level, Fault, GuardEvent, NodeState,
                                    RepeatedWarnings, Severity)
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
    # the holds: damping, -1 N m s/rad x qdot (200 N m per unit of control)
    np.testing.assert_allclose(u, [[1.0, -0.5], [0.0, 0.0], [0.0, 6.0 / 200]])
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
    g.hold_tick(q, qdot)                     # a hold of zero torque (at rest) was sent
    out = [g(np.array([[1.0, -1.0]]), q, qdot, 0.0)[0][0, 0] for _ in range(3)]
    np.testing.assert_allclose(out, [0.25, 0.4375, 0.578125])
    g = guard(max_change=0.1)                 # 0.1 of the range [-1, 1]: 0.2 per tick
    g.hold_tick(q, qdot)                     # a hold of zero torque (at rest) was sent
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


def to_si(u, record=REACHER2, interface='effort'):
    return INTERFACES[interface].to_si(record, u)


def test_effort_hold_is_a_damping_torque_and_a_spring_to_where_it_began():
    """Hold with tau = -D qdot - K (q - q_hold), D from the model (1 N m s/rad): never zero."""
    g = guard(hold_stiffness=50.0)
    q0, qdot = np.array([[0.4, -1.2]]), np.array([[2.0, -4.0]])
    np.testing.assert_allclose(to_si(g.hold(q0, qdot)), [[-2.0, 4.0]])    # no spring yet
    np.testing.assert_allclose(to_si(g.hold_tick(q0, qdot)), [[-2.0, 4.0]])  # begins at q0
    q1 = q0 + [[0.1, -0.2]]
    np.testing.assert_allclose(to_si(g.hold_tick(q1, qdot)), [[-2.0 - 5.0, 4.0 + 10.0]])
    # from a stale state: full up to state_timeout, to zero torque one timeout later
    for age, share in ((0.25, 1.0), (0.375, 0.5), (0.5, 0.0), (np.nan, 0.0)):
        np.testing.assert_allclose(to_si(g.hold_tick(q1, qdot, watchdog.hold_decay(age, 0.25))),
                                   share * np.array([[-7.0, 14.0]]), atol=1e-12)
    # clipped to the effort range; hold_damping given: the parameter, not the model
    np.testing.assert_allclose(guard(hold_damping=100.0).hold(q0, qdot), [[-1.0, 1.0]])
    np.testing.assert_allclose(to_si(guard(hold_damping=30.0).hold(q0, qdot)), [[-60, 120]])


def test_position_hold_is_the_last_command_never_a_stale_measurement():
    """Before any command the measured angles; after, the last command, whatever q says."""
    p = guard(POSITION_SERVOS, 'position', max_change=1.0)
    q, still = np.array([[0.4, -1.2], [3.5, 2.0]]), np.zeros((2, 2))
    # joint0 is continuous (its servo's range is [-3, 3] rad here): clipped to what it takes
    np.testing.assert_allclose(to_si(p.hold(q, still), POSITION_SERVOS, 'position'),
                               [[0.4, -1.2], [3.0, 2.0]])
    p(np.array([[0.5, 0.2], [-0.1, 0.3]]), q, still, 0.0)     # 1.5, 0.6 and -0.3, 0.9 rad
    for stale in (q + 1.0, q - 2.0):                          # what stale states say
        held = p.hold_tick(stale, still)
        np.testing.assert_allclose(to_si(held, POSITION_SERVOS, 'position'),
                                   [[1.5, 0.6], [-0.3, 0.9]])
    # an over-speed hold inside the guard holds the last command too
    fast = guard(POSITION_SERVOS, 'position', max_change=1.0, max_velocity=1.0)
    fast(np.array([[0.5, 0.2]]), q[:1], still[:1], 0.0)
    u, acted = fast(np.array([[-0.9, 0.9]]), q[:1] + 1, np.array([[2.0, 0.0]]), 0.1)
    assert acted[E.OVER_SPEED].tolist() == [True]
    np.testing.assert_allclose(to_si(u, POSITION_SERVOS, 'position'), [[1.5, 0.6]])


@pytest.mark.parametrize('interface,record', [('effort', REACHER2),
                                              ('position', POSITION_SERVOS)])
@pytest.mark.parametrize('kind', ['stale', 'estop_reset', 'deactivate_activate', 'over_speed',
                                  'nonfinite'])
def test_after_every_hold_the_command_ramps_in_from_the_hold(kind, interface, record):
    """The output is continuous where a hold ends: it blends from the hold over ramp_time."""
    g = guard(record, interface, ramp_time=0.5, max_change=1.0, max_velocity=5.0)
    q, moving = np.array([[0.3, 0.2]]), np.array([[1.0, -2.0]])
    a, b = np.array([[0.8, -0.6]]), np.array([[-0.4, 0.5]])
    g.start_ramp(0.0)
    g(a, q, moving, 0.0)
    u, acted = g(a, q, moving, 0.75)                      # the first ramp is over
    np.testing.assert_allclose(u, a)
    assert not acted[E.RAMPED].any()
    if kind == 'stale':
        for age in (0.25, 0.3, 0.45):                      # the node's hold at every tick
            g.hold_tick(q, moving, watchdog.hold_decay(age, 0.2))
    elif kind == 'estop_reset':
        g.hold_tick(q, moving)
    elif kind == 'deactivate_activate':
        g.hold_tick(q, moving, 0.0)                       # the one hold left in force
        g.start_ramp(1.0)
    elif kind == 'over_speed':
        u, acted = g(a, q, np.array([[6.0, 0.0]]), 0.875)
        assert acted[E.OVER_SPEED].all()
    else:
        u, acted = g(np.array([[np.nan, 0.0]]), q, moving, 0.875)
        assert acted[E.NONFINITE].all()
    # the hold it ramps from: the damping torque of the state now, or the last command (a)
    hold = -moving / 200 if interface == 'effort' else a
    steps = [g(b, q, moving, t) for t in (1.0, 1.125, 1.25, 1.375, 1.5)]
    np.testing.assert_allclose([u[0] for u, _ in steps],
                               [(hold + r * (b - hold))[0] for r in (0, 0.25, 0.5, 0.75, 1)],
                               atol=1e-12)
    assert [bool(e[E.RAMPED][0]) for _, e in steps] == [True] * 4 + [False]


def drive_at_the_limit(max_change: float, ticks: int = 200, period: float = 0.02,
                       limit_rule=None, inertia=REACHER2.inertia, inertia_at=None):
    """
    Push joint1 of reacher2 (no damping here) at full torque towards its limit at 3 rad.

    ``inertia``: the joints' true inertia (the record's, the largest, unless given);
    ``inertia_at``: the guard's (:class:`CommandGuard`'s argument).
    """
    g = CommandGuard(REACHER2, JOINTS, 'effort', GuardSettings(max_change=max_change), period,
                     inertia_at=inertia_at)
    if limit_rule is not None:
        g.joint_limits = limit_rule.__get__(g)
    q, qdot = np.zeros((1, 2)), np.zeros((1, 2))
    cmds, angles = [], []
    for k in range(ticks):
        u, _ = g(np.array([[0.0, 1.0]]), q, qdot, k * period)
        qdot = qdot + to_si(u) / inertia * period      # semi-implicit Euler
        q = q + qdot * period
        cmds.append(u[0, 1])
        angles.append(q[0, 1])
    return np.array(cmds), np.array(angles), qdot[0, 1]


def reversals(x: np.ndarray) -> int:
    step = np.sign(np.round(np.diff(x), 9))
    step = step[step != 0]
    return int(np.sum(step[1:] != step[:-1]))


@pytest.mark.parametrize('max_change', [0.0, 1.0])       # from the model (0.25), none
def test_braking_guard_stops_a_joint_at_its_limit_without_flip_flop(max_change):
    """
    Braked from its braking distance: stops inside the limit, the command never flip-flops.

    At 200 rad/s^2 the joint gains 4 rad/s a tick: the fixed 0.05 rad margin of zero torque
    it replaces let it coast 0.3 rad past the limit.
    """
    cmds, angles, speed = drive_at_the_limit(max_change)
    assert angles.max() < 3.0, angles.max()                          # never past the limit
    assert 3.0 - 0.1 < angles[-1] < 3.0 and abs(speed) < 1e-9        # at rest by it
    assert np.all(cmds[:5] == 1.0) and cmds.min() < -0.3             # full, then a brake
    # no flip between full command and hold: a few reversals while it settles, then still
    assert reversals(cmds) <= 3 and np.all(cmds[-150:] == cmds[-1]), cmds[:30]


@pytest.mark.parametrize('given', [False, True])
def test_braking_guard_sizes_its_brake_with_the_poses_inertia(given):
    """
    A joint 10 times lighter than its largest inertia (a folded arm's shoulder) brakes calmly.

    The cap is a one-tick controller of gain ``I / I_pose``: sized with the record's largest
    inertia it overshot and reversed at full torque tick after tick (issue 46: the Panda
    thrown 130 cm off its goal); with ``inertia_at`` it stops the joint as the heavy one.
    """
    light = REACHER2.inertia / 10
    cmds, angles, speed = drive_at_the_limit(
        0.0, inertia=light, inertia_at=(lambda q: np.tile(light, (len(q), 1))) if given
        else None)
    if given:
        assert angles.max() < 3.0 and 3.0 - 0.1 < angles[-1] and abs(speed) < 1e-9
        assert reversals(cmds) <= 3, cmds[:30]
    else:           # the record's largest inertia: a brake that flip-flops, for the record
        assert reversals(cmds) > 20, cmds[:30]


def test_the_old_fixed_margin_let_the_joint_coast_past_its_limit():
    """The rule the braking guard replaced (zero torque within 0.05 rad), for the record."""
    def fixed_margin(self, u, q, qdot, acted, inertia=None):
        torque = to_si(u)
        outward = (((q >= self.q_high - 0.05) & (torque > 0))
                   | ((q <= self.q_low + 0.05) & (torque < 0)))
        return np.where(outward, 0.0, u)
    _, angles, _ = drive_at_the_limit(1.0, limit_rule=fixed_margin)
    assert angles.max() > 3.2, angles.max()


def test_limits_from_the_model_unless_given_and_said_where_they_came_from():
    """max_change, max_velocity, hold_damping and max_deceleration: 0 takes the model's."""
    lim = model_limits(REACHER2, INTERFACES['effort'], GuardSettings(), 0.02)
    # 200 N m: 200 rad/s against damping 1; half of 200 N m / inertia; a 100 N m step a tick
    np.testing.assert_allclose(lim.max_velocity, [200.0, 200.0])
    np.testing.assert_allclose(lim.max_deceleration, 100.0 / REACHER2.inertia)
    np.testing.assert_allclose(lim.max_change, [0.25, 0.25])
    np.testing.assert_allclose(lim.hold_damping, [1.0, 1.0])
    assert set(lim.from_model) == {'max_change', 'max_velocity', 'hold_damping',
                                   'max_deceleration'}
    given = GuardSettings(max_change=0.1, max_velocity=3.0, hold_damping=2.0,
                          max_deceleration=5.0)
    lim = model_limits(REACHER2, INTERFACES['effort'], given, 0.02)
    assert (lim.max_change.tolist(), lim.max_velocity.tolist(), lim.from_model) == \
        ([0.1, 0.1], [3.0, 3.0], ())
    # position: the target moves at most max_velocity x period (here none: no force limit)
    servos = replace(POSITION_SERVOS, force_limit=np.array([50.0, 50.0]))
    lim = model_limits(servos, INTERFACES['position'], GuardSettings(), 0.02)
    np.testing.assert_allclose(lim.max_velocity, [50.0, 50.0])
    np.testing.assert_allclose(lim.max_change, 50.0 * 0.02 / 6.0)
    lim = model_limits(POSITION_SERVOS, INTERFACES['position'], GuardSettings(), 0.02)
    assert np.isinf(lim.max_velocity).all() and lim.max_change.tolist() == [1.0, 1.0]
    # no damping in the model: no speed limit from it (the check is off for that joint)
    assert np.isinf(model_limits(replace(REACHER2, damping=np.zeros(2)), INTERFACES['effort'],
                                 GuardSettings(), 0.02).max_velocity).all()
    described = guard(max_velocity=3.0).describe()
    assert described['max_velocity_taken'] == '3, 3 rad/s (parameter)'
    assert described['max_change_taken'] == '0.25, 0.25 of the range per tick (from the model)'


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
    # appended, never renumbered: a record's guards bits number them in this order
    assert [e.key for e in GuardEvent] == ['nonfinite', 'clipped', 'ramped', 'rate_limited',
                                           'joint_limit', 'over_speed', 'position_delta',
                                           'acceleration_limited']
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


@pytest.mark.parametrize('module', [status, watchdog])
def test_worked_examples(module):
    failures, tried = doctest.testmod(module)
    assert tried > 0 and failures == 0


def test_a_repeated_warning_is_logged_once_then_once_a_period_with_its_count():
    """A guard acting every tick: its first line at once, then one per period, counted."""
    warnings = RepeatedWarnings(period=30.0)
    ticks = np.arange(0.0, 95.0, 0.04)              # 25 Hz for 95 s
    lines = [(t, line) for t in ticks
             if (line := warnings.line(GuardEvent.JOINT_LIMIT, 'joint limit guard', t))]
    assert [round(t, 2) for t, _ in lines] == [0.0, 30.0, 60.0, 90.0]
    assert lines[0][1] == 'joint limit guard'
    assert lines[1][1] == 'joint limit guard (750 times in the last 30 s)'
    # another guard has its own first line and count
    assert warnings.line(GuardEvent.OVER_SPEED, 'over-speed', 91.0) == 'over-speed'


@pytest.mark.parametrize('lighter', [1.0, 5.0])
def test_a_model_without_damping_still_brakes_a_moving_joint_to_rest(lighter):
    """
    No joint damping (a Franka recipe): the hold is the braking gain, never 0 N m.

    A joint of the model's largest inertia, or one ``lighter`` times lighter (the Panda's
    shoulder, folded), moving at 1 rad/s, under the hold command held a whole tick as a
    controller holds it: at rest (below 1 mrad/s) within 30 ticks, after at most
    ``BRAKE_TICKS`` ticks' worth of its first speed.
    """
    from pg_node.control.guards import BRAKE_TICKS
    undamped = replace(REACHER2, damping=np.zeros(2))
    period = 0.04
    g = CommandGuard(undamped, undamped.joints, 'effort', GuardSettings(), period=period)
    inertia = undamped.inertia / lighter
    q, qdot = np.zeros((1, 2)), np.array([[1.0, -1.0]])
    travelled = np.zeros(2)
    for tick in range(30):
        torque = to_si(g.hold_tick(q, qdot))[0]
        if tick == 0:
            assert np.all(np.abs(torque) > 0), torque                      # not 0 N m
        for _ in range(40):                                  # the robot's 1 ms steps
            qdot = qdot + torque / inertia * (period / 40)
            q = q + qdot * (period / 40)
            travelled += np.abs(qdot[0]) * (period / 40)
    assert np.all(np.abs(qdot) < 1e-3), qdot
    assert np.all(travelled < BRAKE_TICKS * period * 1.0 + 1e-9), travelled
    # the model's damping, where it has some, stays the hold's gain
    assert model_limits(REACHER2, INTERFACES['effort'], GuardSettings(), period).hold_damping \
        .tolist() == [1.0, 1.0]
