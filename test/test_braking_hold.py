"""
The effort hold brakes a coupled 7-joint arm to rest, whatever its damping (issue 54, item 3).

A Franka's torques come without gravity and friction (libfranka), and the Panda URDF's
damping is 0.003 N m s/rad: a hold of ``-damping x qdot`` lets such an arm coast. The hold's
brake from the model is ``M(q) qdot / (BRAKE_TICKS T)`` with ``M(q)`` the arm's inertia at
the measured pose (:meth:`pg_node.control.guards.CommandGuard.hold`). Here the shipped Panda
(arm7) without its damping and friction, its weight compensated, each joint at 1 rad/s,
gets the hold command at every control tick, held for the tick as a controller holds it
(MuJoCo's 2 ms steps): at rest within a few ``BRAKE_TICKS``, the joints travelling about
``BRAKE_TICKS T`` times their speed. The same brake with each joint's largest inertia alone
(no pose, no coupling: the brake before) is still moving after as long.
"""
import mujoco
import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.control.guards import BRAKE_TICKS, CommandGuard, GuardSettings
from pg_node.sim.actuation import actuators, mass_matrix_at
import pytest

FRAME_SKIP = 20
#: Franka's ready pose, and a folded one (the shoulder 5x lighter than its largest inertia)
POSES = {'ready': [0, -0.785, 0, -2.356, 0, 1.571, 0.785],
         'folded': [0, -0.8, 2.0, -2.1, 2.8, 2.4, 1.9]}
#: at rest: every joint slower than this (rad/s)
REST = 0.01
TICKS = 30


def franka_like():
    """Return the shipped Panda as a Franka presents it: no damping, friction or weight."""
    model = mujoco.MjModel.from_xml_path(str(resolve_model('arm7')))
    model.dof_damping[:] = 0.0
    model.dof_frictionloss[:] = 0.0
    model.opt.gravity[:] = 0.0
    model.opt.timestep = 0.002      # a robot's 500 Hz-1 kHz loop, not the training's 0.02 s
    return model


def brake(model, guard, q0):
    """Stop the arm moving at 1 rad/s from ``q0``; return (ticks to rest or None, travel)."""
    act = guard.act
    data = mujoco.MjData(model)
    adr = np.array([model.joint(n).qposadr[0] for n in act.joints])
    dof = np.array([model.joint(n).dofadr[0] for n in act.joints])
    data.qpos[adr] = q0
    mid = (act.joint_low + act.joint_high) / 2
    data.qvel[dof] = np.where(np.asarray(q0) >= mid, -1.0, 1.0)     # away from the nearer limit
    mujoco.mj_forward(model, data)
    for tick in range(TICKS):
        q, qdot = data.qpos[adr][None].copy(), data.qvel[dof][None].copy()
        if np.all(np.abs(qdot) < REST):
            return tick, float(np.max(np.abs(data.qpos[adr] - q0)))
        data.ctrl[:] = guard.hold_tick(q, qdot)[0]
        for _ in range(FRAME_SKIP):
            mujoco.mj_step(model, data)
    return None, float(np.max(np.abs(data.qpos[adr] - q0)))


@pytest.mark.parametrize('pose', sorted(POSES))
def test_the_hold_brakes_every_joint_of_a_coupled_arm_to_rest(pose):
    model = franka_like()
    act = actuators(model)
    period = FRAME_SKIP * model.opt.timestep
    guard = CommandGuard(act, act.joints, 'effort', GuardSettings(), period=period,
                         mass_at=mass_matrix_at(model, act.joints))
    assert guard.describe()['hold_damping_taken'].startswith('M(q) / (4 x 0.04 s)')
    rest, travel = brake(model, guard, POSES[pose])
    # the speeds fall by 3/4 a tick: 1 -> 0.01 rad/s in 16 ticks, 1 rad/s x 4 T on the way
    assert rest is not None and rest <= 4 * BRAKE_TICKS + 4, rest
    assert travel < 1.5 * BRAKE_TICKS * period, travel
    # the brake before: each joint's largest inertia, no coupling, where no damping
    before = CommandGuard(act, act.joints, 'effort', GuardSettings(), period=period)
    assert before.describe()['hold_damping_taken'].endswith('N m s/rad (from the model)')
    assert brake(model, before, POSES[pose])[0] is None


def test_a_given_hold_damping_is_the_diagonal_gain_it_says():
    model = franka_like()
    act = actuators(model)
    guard = CommandGuard(act, act.joints, 'effort', GuardSettings(hold_damping=40.0),
                         period=0.04, mass_at=mass_matrix_at(model, act.joints))
    qdot = np.full((1, 7), 0.1)
    torque = guard.interface.to_si(act, guard.hold_tick(np.array([POSES['ready']]), qdot))
    np.testing.assert_allclose(torque, -40.0 * qdot)
    assert guard.describe()['hold_damping_taken'] == ', '.join(['40'] * 7) + \
        ' N m s/rad (parameter)'
