r"""
Benchmark: a vendor arm as it ships, learned in 3-D through the ROS graph (issues 31, 46).

Imports an arm of PyPI's ``example-robot-data`` (``--arm ur5``: ``ur5_joint_limited_robot.urdf``,
tip ``tool0``; ``--arm panda``: the Franka Panda's ``panda.urdf``, tip ``panda_hand_tcp``,
fingers fixed) or the UR5e of ``ur_description`` that pg_node ships (``--arm ur5e``,
``pg_node/sim/models/urdf/ur5e.urdf``, with ``--armature 0.05``) with a start pose and
goals in a ball in front of it above the table, trains it
through the graph with the ``arm7`` preset (PPO) and prints the evaluation: mean return, mean
final fingertip distance and the share of episodes that end within 2 cm, with the steps per
second::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/bench_ur5.py --out /tmp/ur5 \
        [--arm ur5|ur5e|panda] [--steps 5000000] [--seed 0] [--full-workspace] \
        [--actuator damped-motor|velocity|position-delta|position|motor] \
        [--servo-bandwidth 'uniform 5 20'] [--servo-latency 'uniform 0 0.02'] \
        [--position-delta 0.04]

The ``--actuator`` is the command interface the arm is imported and trained on:

- ``damped-motor`` (the UR5's first result, issue 31): effort with ``--velocity-damping
  --timestep 0.02``, an assumed damping the robot lacks, gravity compensation;
- ``velocity`` (a UR driver's velocity controller, issue 46): velocity servos (gain effort /
  velocity limit), no velocity damping, gravity compensation, each servo's tracking bandwidth
  (Hz) and dead time (s) randomized per episode (``--servo-bandwidth``,
  ``--servo-latency``; ``none`` for neither);
- ``position-delta`` (a UR driver's ``forward_position_controller``, issue 46): position
  servos (:data:`POSITION_SERVO`: ``--kp 500 --kv 20`` at ``--timestep 0.005`` with
  ``frame_skip:=8``, the 0.04 s control step) whose action is a change of at most
  ``--position-delta`` rad per control step around the measured angle, the servo terms
  randomized as for ``velocity`` but with a dead time up to one control step (0-0.04 s,
  what ``policy_node``'s timer adds: the Panda's lesson, docs/own_arm.md; a target
  anchored at an angle measured that long ago lags the moving joint) and
  ``reward_control_weight:=0.05`` (``--control-weight``): a change of 0.04 rad per step is
  1 rad/s at full action where a velocity action of 1 is 3.15 rad/s, so the default weight
  1 charges a move about 20 times what it charges on velocity (0.68 rad/s reached, squared
  ratio to 3.15), and at 400k steps the policy barely moved (its largest change 0.008 rad
  per step, 27 cm final distance; BENCHMARKS.md). The default 0.04 rad is what a UR
  e-Series driver accepts between two of its 2 ms cycles: the driver's URScript ignores a
  servo target that would need more than 20 rad/s (Universal_Robots_Client_Library c5d1e26,
  ``resources/external_control.urscript``:96 ``JOINT_IGNORE_SPEED``, :143-147
  ``targetWithinLimits``, called by ``set_servo_setpoint`` at :197); a CB3 at 125 Hz
  accepts 0.16 rad;
- ``position`` (absolute targets, the same servos, terms and control weight, which here
  also keeps the cost of holding a pose away from mid-range small): the action is a target
  anywhere in the joint range (0.1 of action is 0.314 rad on the UR5's +-pi joints);
- ``motor`` (a Franka in torque mode, issue 46): the importer's defaults, effort with the
  URDF's damping and nothing more, gravity compensated by the robot, the 0.002 s step with
  ``frame_skip:=20`` (the 0.04 s control step); trained with the terms a torque robot has
  randomized (:data:`TORQUE_TERMS`: damping and dry friction near zero, an unknown payload at
  the fingertip, i.e. a gravity-compensation error, and a dead time; ``--payload`` and
  ``--servo-latency`` replace those, ``none`` drops them). A policy without memory cannot
  tell the payload and settles where the range's heavier end wants it: trained on 0-1 kg,
  the Panda stopped 2 cm off (1 cm high) without one and 0.9 cm off with 1 kg
  (BENCHMARKS.md), hence 0-0.3 kg.

``--full-workspace`` keeps targets anywhere the arm reaches (no region): what the UR5's first
attempt used. Not a test: nothing is asserted. Run nothing else meanwhile (2 cores).
"""
import argparse
from importlib.metadata import distribution
import os
from pathlib import Path
import subprocess
import sys

REPO = Path(__file__).resolve().parent.parent
SHARE = Path(distribution('example-robot-data').locate_file('cmeel.prefix/share'))
ROBOTS = SHARE / 'example-robot-data' / 'robots'
#: per arm: URDF, tip link, start pose, goals' ball (centre x y z, radius; m), import flags
#: of its own: the URs raised with the tool down, the Panda in Franka's "ready" pose, the
#: goals in front of each above the table. The UR5e is ur_description's as its driver loads
#: it (scripts/ur_description_urdf.py); its wrists are 40 times lighter than
#: example-robot-data's UR5's (0.0026 against 0.11 kg m^2), and velocity servos at the
#: 0.02 s step chatter on them without the motors' rotor inertia: 0.05 kg m^2 per joint, an
#: assumption the card records
ARMS = {
    'ur5': (ROBOTS / 'ur_description' / 'urdf' / 'ur5_joint_limited_robot.urdf', 'tool0',
            ['0', '-1.571', '1.571', '-1.571', '-1.571', '0'], ['0.4', '0', '0.3', '0.3'], []),
    'ur5e': (REPO / 'pg_node' / 'sim' / 'models' / 'urdf' / 'ur5e.urdf', 'tool0',
             ['0', '-1.571', '1.571', '-1.571', '-1.571', '0'], ['0.4', '0', '0.3', '0.3'],
             ['--armature', '0.05']),
    'panda': (ROBOTS / 'panda_description' / 'urdf' / 'panda.urdf', 'panda_hand_tcp',
              ['0', '-0.785', '0', '-2.356', '0', '1.571', '0.785'],
              ['0.45', '0', '0.35', '0.3'], []),
}
#: what a torque robot's physics leaves uncertain (docs/robustness.md, "Torque physics"):
#: joint damping (N m s/rad) and dry friction (N m) near zero, a payload (kg) its gravity
#: compensation does not know of, a dead time (s) below the control step
TORQUE_TERMS = {'damping': 'abs uniform 0 0.1', 'frictionloss': 'abs uniform 0 0.2',
                'payload': 'uniform 0 0.3', 'servo_latency': 'uniform 0 0.04'}
#: the position servos' import flags and frame_skip: stiff enough to follow a 0.04 rad change
#: within a control step (about 70% of it on the UR5 from rest), force within the wrists'
#: 28 N m at that error, and at 0.005 s no joint chatters (at 0.01-0.02 s the UR5's light
#: last wrist did, at 3-33 rad/s, under the same commands)
POSITION_SERVO = (['--actuator', 'position', '--kp', '500', '--kv', '20', '--timestep',
                   '0.005'], ['frame_skip:=8'])


def import_and_train_args(args):
    """Return the ``arm import`` flags and the extra ``train`` arguments of ``args``."""
    if args.actuator in ('velocity', 'position-delta', 'position'):
        physics, extra = ['--actuator', 'velocity', '--timestep', '0.02'], []
        if args.actuator != 'velocity':
            physics, extra = list(POSITION_SERVO[0]), list(POSITION_SERVO[1])
        if args.actuator != 'velocity':
            extra.append(f'reward_control_weight:={args.control_weight}')
        if args.actuator == 'position-delta':
            physics += ['--position-delta', str(args.position_delta)]
        terms = {'servo_bandwidth': args.servo_bandwidth,
                 'servo_latency': args.servo_latency}
    elif args.actuator == 'motor':
        physics = []
        terms = dict(TORQUE_TERMS, payload=args.payload)
        if args.servo_latency != TORQUE_TERMS['servo_latency']:
            terms['servo_latency'] = args.servo_latency
        extra = ['frame_skip:=20']
    else:
        physics = ['--velocity-damping', '--timestep', '0.02']
        terms = {}
        extra = []
    if args.nominal:
        terms = {}
    servo = [f'randomize_{name}={value}' for name, value in terms.items() if value != 'none']
    return physics, extra + servo


def main() -> int:
    """Import, train, print the evaluation."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, required=True, help='folder for model and run')
    parser.add_argument('--arm', choices=sorted(ARMS), default='ur5')
    parser.add_argument('--steps', type=int, default=5_000_000)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--full-workspace', action='store_true')
    parser.add_argument('--nominal', action='store_true',
                        help='no randomized term at all: the nominal policy of the sim-to-sim '
                        'table (docs/sim_to_sim.md)')
    parser.add_argument('--actuator', choices=('damped-motor', 'velocity', 'position-delta',
                                               'position', 'motor'),
                        default='damped-motor',
                        help='damped-motor: effort with --velocity-damping (the first '
                        'result); velocity: velocity servos, no damping; position-delta: '
                        'position servos, bounded changes around the measured angle; '
                        'position: the same servos, absolute targets; motor: effort, no '
                        'damping, torque terms randomized')
    parser.add_argument('--position-delta', type=float, default=0.04,
                        help='position-delta: rad per control step (default: %(default)s)')
    parser.add_argument('--control-weight', type=float, default=0.05,
                        help='position, position-delta: reward_control_weight (default: '
                        '%(default)s)')
    parser.add_argument('--servo-bandwidth', default='uniform 5 20',
                        help="velocity, position: randomize_servo_bandwidth (Hz), or 'none'")
    parser.add_argument('--servo-latency', default=None,
                        help="randomize_servo_latency (s), or 'none' (default: 'uniform 0 "
                        "0.02' for velocity, 'uniform 0 0.04' for position and motor)")
    parser.add_argument('--payload', default=TORQUE_TERMS['payload'],
                        help='motor: randomize_payload (kg at the fingertip that the gravity '
                        "compensation does not know), or 'none'")
    args = parser.parse_args()
    if args.servo_latency is None:
        args.servo_latency = ('uniform 0 0.02' if args.actuator == 'velocity'
                              else TORQUE_TERMS['servo_latency'])
    urdf, tip, home, region, own = ARMS[args.arm]
    args.out.mkdir(parents=True, exist_ok=True)
    model = (args.out / f'{args.arm}.xml').resolve()
    region = [] if args.full_workspace else ['--target-region', *region]
    run = [sys.executable, '-m', 'pg_node']
    physics, train_extra = import_and_train_args(args)
    subprocess.run([*run, 'arm', 'import', str(urdf), '--tip', tip, '--package-path',
                    str(SHARE), *physics, *own, '--home', *home, *region, '-o', str(model)],
                   check=True)
    run_dir = args.out / f'run_s{args.seed}'
    subprocess.run([*run, 'train', '--config', 'arm7', f'model:={model}',
                    f'total_steps:={args.steps}', '--seed', str(args.seed), '--run-dir',
                    str(run_dir), *train_extra], check=True, env=os.environ)
    from pg_node.common.run_dir import RunDir
    summary = RunDir(run_dir).read_summary()
    print('| arm | interface | targets | steps | steps/s | return | final distance (cm) '
          '| within 2 cm |')
    print('|---|---|---|---:|---:|---:|---:|---:|')
    print(f'| {args.arm} | {args.actuator} | '
          f"{'workspace' if args.full_workspace else 'ball 0.3 m'} | "
          f"{summary['total_steps']:,} | "
          f"{summary['steps_per_second']:,.0f} | "
          f"{summary['eval_return']:.2f} | {100 * summary['eval_final_distance']:.2f} | "
          f"{100 * summary['eval_reached']:.0f}% |")
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
