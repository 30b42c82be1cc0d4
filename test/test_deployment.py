"""
Every stop path of the deployment's decisions, without rclpy (:mod:`pg_node.control.deployment`).

A :class:`Deployment` over reacher2's hand-made motors (200 N m per unit of control, damping
1 N m s/rad) with a policy that answers a fixed mean: an e-stop holds, no joint state waits,
a stale one holds with a fading damping and its spell ends with one FRESH event, a missing
goal waits naming the arm, the robot's own stop (a UR's program, its speed scaling) holds
and is ramped out of, commanding runs the guards, and a hold is ramped out of.
"""
import doctest

from control_records import REACHER2
import numpy as np
from pg_node.control import deployment
from pg_node.control.deployment import (Deployment, Event, JointSample, LIFECYCLE, NO_STATE,
                                        RobotState, Status)
from pg_node.control.guards import CommandGuard, GuardSettings
from pg_node.control.status import GuardEvent, NodeState
from pg_node.control.watchdog import hold_decay, Watchdog
import pytest

TIMEOUT = 0.2
GOALS = np.array([[0.1, 0.0, 0.0]])
MEAN = np.array([[0.5, -0.25]])


def core(mean=MEAN, std=0.1, deterministic=True, **settings):
    """Return a deployment of one reacher2, with the calls to its policy in ``core.calls``."""
    guard = CommandGuard(REACHER2, ['joint0', 'joint1'], 'effort', GuardSettings(**settings))
    calls = []

    def observe(q, qdot, goals):
        calls.append(goals)
        return np.concatenate([q, qdot, goals], axis=1)

    d = Deployment(guard, observe, lambda obs: (mean, np.full_like(mean, std)),
                   {'state_timeout': TIMEOUT, 'deterministic': deterministic},
                   np.random.default_rng(7))
    d.calls = calls
    return d


def joints(now, age=0.0, qdot=(0.0, 0.0)):
    """Return a joint state at rest at the origin (moving at ``qdot``), ``age`` s old."""
    return JointSample(np.zeros((1, 2)), np.array([qdot], dtype=float), now - age)


def tick(d, state, now, goals=GOALS, estop=False, robot_stop=''):
    return d.tick(state, goals, now, 0.0, estop, robot_stop)


def test_an_estop_holds_with_the_damping_torque_and_never_asks_the_policy():
    d = core()
    d.activate(0.0)
    t = tick(d, joints(1.0, qdot=(2.0, -4.0)), 1.0, estop=True)
    assert t.status.state is NodeState.ESTOP and t.status.lifecycle == 'active'
    assert t.hold and 'reset_estop' in t.status.text
    # -1 N m s/rad x qdot, in controls of 200 N m
    np.testing.assert_allclose(t.command, [[-2.0 / 200, 4.0 / 200]])
    assert np.isnan(t.age) and t.obs is None and not d.calls
    # before the first joint state there is nothing to hold from: nothing is sent
    t = tick(d, None, 1.0, estop=True)
    assert t.status.state is NodeState.ESTOP and t.command is None
    # an e-stop wins over a stale state; the stale state's damping fades (half at 1.5 x)
    t = tick(d, joints(2.0, age=1.5 * TIMEOUT, qdot=(2.0, 0.0)), 2.0, estop=True)
    np.testing.assert_allclose(t.command, [[-1.0 / 200, 0.0]])
    assert t.status.state is NodeState.ESTOP and not t.events


def test_no_joint_state_yet_waits_and_sends_nothing():
    d = core()
    assert d.activate(0.0) == NO_STATE
    t = tick(d, None, 1.0)
    assert t.status == NO_STATE == Status(NodeState.WAITING, 'waiting: no joint_states yet')
    assert t.command is None and not t.hold and not t.events and not d.calls


def test_a_stale_state_holds_with_decay_then_a_fresh_one_commands_with_one_event():
    d = core()
    d.activate(0.0)
    ticks = [tick(d, joints(now, age=age, qdot=(2.0, 0.0)), now)
             for now, age in ((1.0, 0.25), (1.1, 0.3), (1.2, 0.5))]
    assert [t.status.state for t in ticks] == [NodeState.STALE] * 3
    assert [t.events for t in ticks] == [(Event.STALE,), (), ()]     # one spell, one event
    assert all(t.hold for t in ticks) and not d.calls
    assert ticks[0].status.text == ('stale: joint states 0.25 s old since arrival, hold '
                                    'command, waiting for fresh ones')
    np.testing.assert_allclose([t.age for t in ticks], [0.25, 0.3, 0.5])
    # the damping fades from 1 at the timeout to 0 at twice it: 0.75, 0.5, 0
    np.testing.assert_allclose([t.command[0, 0] for t in ticks],
                               [-0.75 * 2 / 200, -0.5 * 2 / 200, 0.0], atol=1e-15)
    assert d.watchdog.stale
    fresh = [tick(d, joints(now), now) for now in (1.3, 1.4)]
    assert [t.status.state for t in fresh] == [NodeState.COMMANDING] * 2
    assert [t.events for t in fresh] == [(Event.FRESH,), ()]
    assert not fresh[0].hold and not d.watchdog.stale


def test_a_stale_states_brake_adds_up_to_at_most_its_speed_never_a_push_back():
    """
    A stale state's braking hold never pushes back, however long the spell (issue 54, item 3).

    Each tick's torque takes a quarter of the speed it expects off, so the spell's torques
    together take off at most the state's speed; a fade alone would reverse the joints.
    """
    period, inertia = 0.01, np.array([[2.0, 0.6], [0.6, 0.5]])     # coupled joints
    guard = CommandGuard(REACHER2, ['joint0', 'joint1'], 'effort', GuardSettings(),
                         period=period,
                         mass_at=lambda q: np.broadcast_to(inertia, (len(q), 2, 2)))
    d = Deployment(guard, None, None, {'state_timeout': TIMEOUT, 'deterministic': True},
                   np.random.default_rng(0))
    d.activate(0.0)
    qdot = np.array([2.0, -1.0])
    change = np.zeros(2)                                 # the speed the torques take off
    fade = np.zeros(2)                                   # the same with the fade alone
    for k in range(1, int(TIMEOUT / period) + 1):
        age = TIMEOUT + k * period - period / 2
        t = tick(d, joints(1.0 + age, age=age, qdot=qdot), 1.0 + age)
        assert t.status.state is NodeState.STALE
        torque = guard.interface.to_si(REACHER2, t.command)[0]
        change += period * np.linalg.solve(inertia, torque)
        fade += period * np.linalg.solve(inertia, -inertia @ qdot / (4 * period)) \
            * hold_decay(age, TIMEOUT)
    share = change / -qdot
    np.testing.assert_allclose(share, share[0])           # along the speed, every joint alike
    assert 0.5 < share[0] <= 1.0, share                   # a brake, never past a stop
    assert np.all(fade / -qdot > 1.5), fade               # the fade alone: reversed


def test_a_stale_state_by_its_stamp_holds_too():
    d = core()
    d.activate(0.0)
    state = JointSample(np.zeros((1, 2)), np.zeros((1, 2)), 1.0, stamp=99.0)
    t = d.tick(state, GOALS, 1.0, 100.0, False)         # arrived now, stamped 1 s ago
    assert t.status.state is NodeState.STALE and t.how == 'by header.stamp'
    assert t.age == pytest.approx(1.0)


def test_a_missing_goal_waits_naming_the_arm_once():
    d = core()
    d.activate(0.0)
    ticks = [tick(d, joints(now), now, goals=name)
             for now, name in ((1.0, 'arm1'), (1.1, 'arm1'), (1.2, 'arm0'))]
    assert [t.status for t in ticks] == [
        Status(NodeState.WAITING, f'waiting: no target yet for {n}')
        for n in ('arm1', 'arm1', 'arm0')]
    assert [t.events for t in ticks] == [(Event.NO_TARGET,), (), (Event.NO_TARGET,)]
    assert [t.waiting_for for t in ticks] == ['arm1', 'arm1', 'arm0']
    assert all(t.command is None for t in ticks) and not d.calls
    # another state in between, or a new activation, names the arm again
    tick(d, None, 1.3)
    assert tick(d, joints(1.4), 1.4, goals='arm0').events == (Event.NO_TARGET,)
    d.activate(2.0)
    assert tick(d, joints(2.1), 2.1, goals='arm0').events == (Event.NO_TARGET,)


def test_commanding_sends_the_policy_mean_through_the_guards():
    d = core(mean=np.array([[2.0, -0.25]]))
    d.activate(0.0)
    t = tick(d, joints(1.0), 1.0)
    assert t.status == Status(NodeState.COMMANDING, 'commanding') and not t.hold
    np.testing.assert_allclose(t.command, [[1.0, -0.25]])        # clipped to the range
    assert t.guard_events == [GuardEvent.CLIPPED]
    assert t.acted[GuardEvent.CLIPPED].tolist() == [True]
    np.testing.assert_array_equal(d.calls[0], GOALS)
    np.testing.assert_array_equal(t.obs, [[0, 0, 0, 0, 0.1, 0, 0]])
    np.testing.assert_array_equal(t.action, t.mean)
    assert t.age == pytest.approx(0.0)


def test_sampling_when_not_deterministic_reads_the_setting_at_each_tick():
    d = core(std=0.1, deterministic=False)
    d.activate(0.0)
    t = tick(d, joints(1.0), 1.0)
    z = np.random.default_rng(7).standard_normal(MEAN.shape)
    np.testing.assert_allclose(t.action, MEAN + 0.1 * z)
    np.testing.assert_allclose(t.command, t.action)
    d.settings['deterministic'] = True                  # a live parameter change
    np.testing.assert_allclose(tick(d, joints(1.1), 1.1).command, MEAN)


def test_commanding_ramps_in_after_activation_and_after_each_hold():
    d = core(ramp_time=1.0)
    d.activate(10.0)
    shares = [tick(d, joints(now), now).command / MEAN for now in (10.0, 10.5, 11.0)]
    np.testing.assert_allclose([s[0, 0] for s in shares], [0.0, 0.5, 1.0])
    # a stale spell holds (zero torque at rest); the fresh state ramps in from it again
    assert tick(d, joints(12.0, age=1.0), 12.0).hold
    ramp = [tick(d, joints(now), now) for now in (13.0, 13.25, 14.0)]
    np.testing.assert_allclose([t.command[0, 0] / MEAN[0, 0] for t in ramp], [0.0, 0.25, 1.0])
    assert GuardEvent.RAMPED in ramp[1].guard_events
    assert GuardEvent.RAMPED not in ramp[2].guard_events
    # ... and so does the first command after an e-stop's reset
    assert tick(d, joints(15.0), 15.0, estop=True).hold
    ramp = [tick(d, joints(now), now).command for now in (16.0, 16.5)]
    np.testing.assert_allclose(ramp, [0 * MEAN, 0.5 * MEAN])


def test_the_one_hold_left_in_force_is_zero_torque_and_none_before_a_state():
    d = core()
    d.activate(0.0)
    assert d.hold(None) is None
    np.testing.assert_array_equal(d.hold(joints(1.0, qdot=(3.0, 3.0))), [[0.0, 0.0]])


def test_a_given_watchdog_keeps_the_spell_and_every_state_has_a_lifecycle():
    watchdog = Watchdog()
    d = core()
    d = Deployment(d.guard, d.observe, d.mean_std, d.settings, watchdog=watchdog)
    d.activate(0.0)
    tick(d, joints(1.0, age=1.0), 1.0)
    assert watchdog.stale
    assert set(LIFECYCLE) == set(NodeState)
    assert {s.lifecycle for s in (NO_STATE, deployment.ESTOP, deployment.COMMANDING)} == {
        'active'}
    assert Status(NodeState.INACTIVE, '').lifecycle == 'inactive'
    failures, tried = doctest.testmod(deployment)
    assert tried > 0 and failures == 0


def test_the_robots_own_stop_holds_with_the_reason_then_ramps_in_with_one_event():
    d = core(ramp_time=1.0)
    d.activate(0.0)
    assert tick(d, joints(1.0), 1.0).command[0, 0] == pytest.approx(MEAN[0, 0])  # ramped in
    why = RobotState('/io/robot_program_running', program_running=False).stop_reason()
    held = [tick(d, joints(now, qdot=(2.0, 0.0)), now, robot_stop=why) for now in (2.0, 2.1)]
    assert [t.status.state for t in held] == [NodeState.ROBOT_STOPPED] * 2
    assert held[0].status.text == ('robot stopped: its program is not running '
                                   '(/io/robot_program_running false): hold command, waiting '
                                   'for it to run again')
    assert held[0].status.lifecycle == 'active'
    assert [t.events for t in held] == [(Event.ROBOT_STOPPED,), ()]   # one spell, one event
    # the active hold from the fresh state: the full damping, -1 N m s/rad x 2 rad/s
    assert all(t.hold for t in held) and held[0].obs is None
    np.testing.assert_allclose(held[0].command, [[-2.0 / 200, 0.0]])
    calls = len(d.calls)
    # running again: commanding, ramping in from the hold over ramp_time, one READY event
    ramp = [tick(d, joints(now), now) for now in (3.0, 3.5, 4.0, 4.5)]
    assert [t.events for t in ramp] == [(Event.ROBOT_READY,), (), (), ()]
    assert [t.status.state for t in ramp] == [NodeState.COMMANDING] * 4
    np.testing.assert_allclose([t.command[0, 0] / MEAN[0, 0] for t in ramp], [0, 0.5, 1, 1])
    assert len(d.calls) == calls + 4 and not ramp[0].hold
    # an e-stop and stale states win over it; a missing goal too (nothing sent before one)
    assert tick(d, joints(5.0), 5.0, estop=True, robot_stop=why).status.state is NodeState.ESTOP
    t = tick(d, joints(6.0, age=1.0), 6.0, robot_stop=why)
    assert t.status.state is NodeState.STALE
    t = tick(d, joints(7.0), 7.0, goals='arm0', robot_stop=why)
    assert t.status.state is NodeState.WAITING and t.command is None


@pytest.mark.parametrize('state,words', [
    (RobotState(), ''),
    (RobotState(program_topic='/p', program_running=True), ''),
    (RobotState(program_topic='/p', program_running=False, speed_topic='/s',
                speed_scaling=0.0), 'its program is not running (/p false)'),
    (RobotState(speed_topic='/s'), 'no message yet on /s (speed_scaling_topic)'),
    (RobotState(speed_topic='/s', speed_scaling=-1.0), 'speed scaling -1 % on /s'),
    (RobotState(speed_topic='/s', speed_scaling=float('nan')), 'speed scaling nan % on /s'),
    (RobotState(speed_topic='/s', speed_scaling=12.5), ''),
    # a topic not followed says nothing, whatever came on it
    (RobotState(program_running=False, speed_scaling=0.0), ''),
])
def test_the_robot_state_says_why_it_stopped(state, words):
    reason = state.stop_reason()
    assert (words in reason and reason.startswith('robot stopped: ')) if words else not reason
