"""
How far a torque robot moves after each kind of stop: the Panda on PyBullet, gravity compensated.

Issue 54, item 3. The Panda is imported as its recipe imports it (motors, no joint damping:
libfranka's torques come without it), so ``hold_damping`` from the model is the braking gain
``I / (BRAKE_TICKS T)`` (:mod:`pg_node.control.guards`). PyBullet plays the robot: the arm's
weight compensated by the robot (``gravity_compensation``), each command held for a control
period as a controller holds it. Every joint moves at ``--speed`` rad/s when the stop comes
(from Franka's ready pose, each joint turning away from its nearer limit); each row says how
far the joints went (largest, rad) and when every joint was below 0.01 rad/s:

* ``hold (e-stop, over-speed)``: policy_node's hold from fresh joint states at every tick;
* ``stale states``: the states stop at the stop; policy_node brakes from the last one, its
  share falling from 1 at ``state_timeout`` to 0 at twice that (``hold_decay``);
* ``policy_node killed, JTC cmd_timeout``: the last command (0 N m here) held for
  ``cmd_timeout``, then JTC's own hold, which on the effort interface is 0 N m
  (ros2_controllers jazzy ed360c97d joint_trajectory_controller.cpp:2063-2086);
* ``zero torque (before)``: every hold 0 N m, as the Panda recipe's holds were before the
  braking gain;
* ``controller_hold pd``: a JTC with a ``d`` gain per joint
  (``config/controllers/jtc_effort_pd.yaml``; here each joint's inertia at the start pose
  over 4 control periods) at 1 kHz, policy_node's points carrying the measured speeds: its
  PID sends ``-d qdot`` from the controller's own state in a hold policy_node sends
  (e-stop: at once; stale states: from ``state_timeout`` on, policy_node's hold point) and
  after ``cmd_timeout`` when policy_node is killed (jtc.cpp:416-426, 2063-2086); before
  that, the last command (0 N m here).

Run: ``.venv/bin/python bench/bench_brake.py`` (prints a table; about 10 s).
"""
import argparse
from pathlib import Path
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.bench_ur5 import ARMS  # noqa: E402
import numpy as np  # noqa: E402
from pg_node.control.guards import BRAKE_TICKS, CommandGuard, GuardSettings  # noqa: E402
from pg_node.control.watchdog import hold_decay  # noqa: E402

#: a joint at rest: slower than this (rad/s)
REST = 0.01


def panda_model(out: Path) -> Path:
    """Import the Panda as its recipe does (motors, no damping); return the MJCF."""
    from pg_node.tools import arm
    urdf, tip, home, region, extra = ARMS['panda']
    model = out / 'panda.xml'
    code = arm.main(['import', str(urdf), '--tip', tip, '--home', *home,
                     '--target-region', *region, *extra, '-o', str(model)])
    if code:
        raise SystemExit(f'arm import failed ({code})')
    return model


def run(kind: str, guard: CommandGuard, sim, act_names, q0, v0, period: float,
        state_timeout: float, cmd_timeout: float, seconds: float):
    """Stop the arm moving at ``v0`` in the way ``kind`` says; return (travel, rest time)."""
    sim.set_state(q0, v0)
    guard._arms(1)
    guard.held[:] = False
    start = q0.copy()
    stale_q, stale_v = q0[None].copy(), v0[None].copy()
    rest_at, t = None, 0.0
    for tick in range(int(seconds / period)):
        q, v, _ = sim.state()
        if kind == 'hold (e-stop, over-speed)':
            torque = guard.interface.to_si(guard.act, guard.hold_tick(q[None], v[None]))[0]
        elif kind == 'stale states':
            age = t                              # no state since the stop
            if age <= state_timeout:             # the policy's last command: 0 N m here
                torque = np.zeros(len(act_names))
            else:                                # the deployment's stale hold
                torque = guard.interface.to_si(guard.act, guard.hold_tick(
                    stale_q, stale_v, hold_decay(age, state_timeout), age - state_timeout))[0]
        else:                                    # killed, or zero torque: 0 N m from the start
            torque = np.zeros(len(act_names))
        sim.step(torque, 'effort')
        t += period
        q, v, _ = sim.state()
        if rest_at is None and np.all(np.abs(v) < REST):
            rest_at = t
    travel = float(np.max(np.abs(sim.state()[0] - start)))
    return travel, rest_at


def run_controller(sim, d: np.ndarray, q0, v0, delay: float, seconds: float):
    """
    Brake with a JTC's ``-d qdot`` at 1 kHz from ``delay`` s on; return (travel, rest).

    0 N m before ``delay``.

    ``sim``: the arm stepped every 1 ms, as the controller runs.
    """
    sim.set_state(q0, v0)
    rest_at, t, dt = None, 0.0, sim.control_period
    for _ in range(int(round(seconds / dt))):
        _, v, _ = sim.state()
        sim.step(-d * v if t >= delay - 1e-12 else np.zeros(len(v)), 'effort')
        t += dt
        if rest_at is None and np.all(np.abs(sim.state()[1]) < REST):
            rest_at = t
    return float(np.max(np.abs(sim.state()[0] - q0))), rest_at


def main(argv=None) -> int:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--speed', type=float, default=1.0, help='rad/s of every joint')
    parser.add_argument('--seconds', type=float, default=3.0, help='how long each stop runs')
    args = parser.parse_args(argv)
    import mujoco
    from pg_node.sim.actuation import actuators, inertia_at, mass_matrix_at
    from pg_node.sim.pybullet_arm import PybulletArm
    with tempfile.TemporaryDirectory() as tmp:
        path = panda_model(Path(tmp))
        model = mujoco.MjModel.from_xml_path(str(path))
        act = actuators(model)
        frame_skip = 20
        period = frame_skip * model.opt.timestep
        urdf = ARMS['panda'][0]
        sim = PybulletArm(urdf, act.joints, control_period=period, gravity_compensation=True)
        guard = CommandGuard(act, act.joints, 'effort', GuardSettings(), period=period,
                             inertia_at=inertia_at(model, act.joints),
                             mass_at=mass_matrix_at(model, act.joints))
        home = np.array([float(x) for x in ARMS['panda'][2]])
        mid = (sim.lower + sim.upper) / 2
        v0 = args.speed * np.where(home >= mid, -1.0, 1.0)      # away from the nearer limit
        gains = np.diag(guard.mass_at(home[None])[0]) / (BRAKE_TICKS * period)
        print(f'Panda (example-robot-data), PyBullet, gravity compensated; control period '
              f'{period:g} s; every joint at {args.speed:g} rad/s when the stop comes; '
              f'the hold brakes with M(q) / ({BRAKE_TICKS:g} T), the inertia at the measured pose '
              f'(its diagonal at the start: {", ".join(f"{g:.3g}" for g in gains)} N m s/rad; '
              f'the model\'s damping: {", ".join(f"{d:g}" for d in act.damping)})')
        print()
        print('| stop | largest travel (rad) | all joints below 0.01 rad/s after |')
        print('|---|---|---|')
        for kind in ('hold (e-stop, over-speed)', 'stale states',
                     'policy_node killed, JTC cmd_timeout 0.2 s', 'zero torque (before)'):
            travel, rest = run(kind, guard, sim, act.joints, home, v0, period, 0.2, 0.2,
                               args.seconds)
            when = f'{rest:.2f} s' if rest is not None else f'not within {args.seconds:g} s'
            print(f'| {kind} | {travel:.3f} | {when} |')
        sim.close()
        # the controller's own brake (controller_hold pd), a JTC at 1 kHz
        fast = PybulletArm(urdf, act.joints, control_period=0.001, gravity_compensation=True)
        d = np.diag(guard.mass_at(home[None])[0]) / (BRAKE_TICKS * period)
        for kind, delay in (('controller_hold pd: hold (e-stop, over-speed)', 0.0),
                            ('controller_hold pd: stale states', 0.2),
                            ('controller_hold pd: policy_node killed, cmd_timeout 0.2 s', 0.2)):
            travel, rest = run_controller(fast, d, home, v0, delay, args.seconds)
            when = f'{rest:.2f} s' if rest is not None else f'not within {args.seconds:g} s'
            print(f'| {kind} | {travel:.3f} | {when} |')
        print()
        print(f'controller_hold pd: d = {", ".join(f"{g:.3g}" for g in d)} N m s/rad (each '
              f"joint's inertia at the start pose over {BRAKE_TICKS:g} control periods)")
        fast.close()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
