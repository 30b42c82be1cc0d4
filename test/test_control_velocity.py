"""
The velocity interface in the robot-facing layer (issue 46), on a hand-made record.

reacher2 with velocity servos (``control_records.VELOCITY_SERVOS``: u is 2 u rad/s): the
interface's maps and unit, its hold (zero velocity), the acceleration limit (a step of
the commanded speed of at most ``max_acceleration x period``), the speed cap near a joint
limit (the joint can still stop at ``limit - margin``), over-speed, and the trajectory point
that Jazzy's JTC takes with the shipped ``jtc_velocity.yaml`` flags.
"""
from control_records import REACHER2, VELOCITY_SERVOS
import numpy as np
from pg_node.control.composers import command_trajectory
from pg_node.control.guards import CommandGuard, GuardSettings
from pg_node.control.interfaces import card, check, INTERFACES
from pg_node.control.jtc import jtc_rejects, SHIPPED_FLAGS
from pg_node.control.status import GuardEvent

J = ['joint0', 'joint1']
V = INTERFACES['velocity']
PERIOD = 0.04


def guard(**settings):
    return CommandGuard(VELOCITY_SERVOS, J, 'velocity', GuardSettings(**settings), PERIOD)


def test_the_interface_maps_controls_to_rad_per_s_and_back():
    u = np.array([[0.5, -1.0], [0.0, 0.25]])
    np.testing.assert_allclose(V.to_si(VELOCITY_SERVOS, u), 2 * u)
    np.testing.assert_allclose(V.from_si(VELOCITY_SERVOS, V.to_si(VELOCITY_SERVOS, u)), u)
    assert list(VELOCITY_SERVOS.kind) == ['velocity', 'velocity']
    assert check(VELOCITY_SERVOS, 'velocity') is None
    assert 'use command_interface velocity' in check(VELOCITY_SERVOS, 'effort')
    assert 'needs velocity actuators' in check(REACHER2, 'velocity')
    assert card(VELOCITY_SERVOS) == {'velocity': {'unit': 'rad/s', 'low': [-2.0, -2.0],
                                                  'high': [2.0, 2.0]}}


def test_the_hold_is_zero_velocity_and_ramps_in_from_it():
    g = guard(ramp_time=1.0, max_change=1.0, max_acceleration=100.0)
    q, qd = np.zeros((1, 2)), np.array([[1.5, -1.0]])
    np.testing.assert_array_equal(g.hold(q, qd), [[0.0, 0.0]])
    np.testing.assert_array_equal(g.hold_tick(q, qd), [[0.0, 0.0]])
    g.start_ramp(0.0)
    u, acted = g(np.array([[1.0, -1.0]]), q, np.zeros((1, 2)), 0.25)
    np.testing.assert_allclose(V.to_si(VELOCITY_SERVOS, u), [[0.5, -0.5]])
    assert acted[GuardEvent.RAMPED].all()


def test_the_commanded_speed_changes_by_at_most_max_acceleration_per_second():
    g = guard(max_change=1.0, max_acceleration=5.0)      # 0.2 rad/s per 40 ms tick
    q, qd = np.zeros((1, 2)), np.zeros((1, 2))
    speeds = []
    for _ in range(6):
        u, acted = g(np.array([[1.0, -0.05]]), q, qd, 10.0)
        speeds.append(V.to_si(VELOCITY_SERVOS, u)[0])
    speeds = np.array(speeds)
    steps = np.abs(np.diff(np.vstack([[0.0, 0.0], speeds]), axis=0))   # from the first hold?
    assert np.all(steps[1:] <= 5.0 * PERIOD + 1e-12)
    np.testing.assert_allclose(speeds[1:, 0] - speeds[:-1, 0], 0.2)
    np.testing.assert_allclose(speeds[:, 1], -0.1)                     # small steps pass
    assert acted[GuardEvent.ACCELERATION_LIMITED].all()
    # the model's default: half the torque over the inertia (no torque bound here: none)
    assert np.all(np.isinf(guard().limits().max_acceleration))


def test_the_speed_towards_a_limit_lets_the_joint_stop_before_it():
    """joint1 in [-3, 3]: at s rad from 3 - margin it may approach at sqrt(2 a s) at most."""
    g = guard(max_change=1.0, max_deceleration=2.0, joint_limit_margin=0.1,
              max_acceleration=1e9)
    qd = np.zeros((1, 2))
    for q1, cap in ((2.9, 0.0), (2.65, 1.0), (0.0, 2.0)):     # sqrt(2 * 2 * 0.25) = 1
        u, acted = g(np.array([[0.0, 1.0]]), np.array([[0.0, q1]]), qd, 0.0)
        np.testing.assert_allclose(V.to_si(VELOCITY_SERVOS, u)[0, 1], cap, atol=1e-12)
        assert acted[GuardEvent.JOINT_LIMIT][0] == (cap < 2.0)
        # away from the limit is never capped
        u, _ = g(np.array([[0.0, -1.0]]), np.array([[0.0, q1]]), qd, 0.0)
        np.testing.assert_allclose(V.to_si(VELOCITY_SERVOS, u)[0, 1], -2.0)


def test_over_speed_holds_zero_velocity_and_the_default_is_the_range():
    g = guard(max_change=1.0, max_acceleration=1e9)
    np.testing.assert_array_equal(g.limits().max_velocity, [2.0, 2.0])
    u, acted = g(np.array([[1.0, 1.0]]), np.zeros((1, 2)), np.array([[2.5, 0.0]]), 0.0)
    np.testing.assert_array_equal(u, [[0.0, 0.0]])
    assert acted[GuardEvent.OVER_SPEED].all()


def test_the_point_carries_the_speeds_and_the_measured_angles():
    t = command_trajectory(V, np.array([[0.5, -0.3]]), np.array([[0.1, 0.2]]), J)
    assert t.points[0].fields == {'positions': [0.1, 0.2], 'velocities': [0.5, -0.3]}
    assert jtc_rejects(t, J, ['velocity'], flags=SHIPPED_FLAGS['velocity']) is None
    assert jtc_rejects(t, J, ['velocity']).startswith('rule 5:')   # Jazzy's default flags
