r"""
Benchmark: a vendor arm as it ships, learned in 3-D through the ROS graph (issue 31).

Imports the UR5 of PyPI's ``example-robot-data`` (``ur5_joint_limited_robot.urdf``, tip
``tool0``) with the physics the BENCHMARKS figure was learned on (``--velocity-damping
--timestep 0.02``: the importer's defaults before issue 46, an assumed damping the UR5 lacks;
gravity compensation), a start pose and a target region, then trains it through the graph with the
``arm7`` preset (PPO) and prints the evaluation: mean return, mean final fingertip distance
and the share of episodes that end within 2 cm, with the steps per second::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/bench_ur5.py --out /tmp/ur5 \
        [--steps 5000000] [--seed 0] [--full-workspace] \
        [--actuator velocity [--servo-bandwidth 'uniform 5 20'] [--servo-latency 'uniform 0 0.02']]

``--full-workspace`` keeps targets anywhere the arm reaches (no region): what the first
attempt used. ``--actuator velocity`` imports the UR5 as its driver presents it (issue 46):
velocity servos (``arm import --actuator velocity``, gain effort / velocity limit), no
velocity damping, gravity compensation, and trains with each servo's tracking bandwidth
(Hz) and dead time (s) randomized per episode (docs/robustness.md; ``none`` for neither).
Not a test: nothing is asserted. Run nothing else meanwhile (2 cores).
"""
import argparse
from importlib.metadata import distribution
import json
import os
from pathlib import Path
import subprocess
import sys

REPO = Path(__file__).resolve().parent.parent
#: UR5's "home" with the arm raised and the tool down, and the goals' ball in front of it
HOME = ['0', '-1.571', '1.571', '-1.571', '-1.571', '0']
REGION = ['0.4', '0', '0.3', '0.3']


def main() -> int:
    """Import, train, print the evaluation."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, required=True, help='folder for model and run')
    parser.add_argument('--steps', type=int, default=5_000_000)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--full-workspace', action='store_true')
    parser.add_argument('--actuator', choices=('damped-motor', 'velocity'),
                        default='damped-motor',
                        help='damped-motor: effort with --velocity-damping (the first '
                        'result); velocity: velocity servos, no damping')
    parser.add_argument('--servo-bandwidth', default='uniform 5 20',
                        help="velocity: randomize_servo_bandwidth (Hz), or 'none'")
    parser.add_argument('--servo-latency', default='uniform 0 0.02',
                        help="velocity: randomize_servo_latency (s), or 'none'")
    args = parser.parse_args()
    share = Path(distribution('example-robot-data').locate_file('cmeel.prefix/share'))
    urdf = share / 'example-robot-data' / 'robots' / 'ur_description' / 'urdf' / \
        'ur5_joint_limited_robot.urdf'
    args.out.mkdir(parents=True, exist_ok=True)
    model = (args.out / 'ur5.xml').resolve()
    region = [] if args.full_workspace else ['--target-region', *REGION]
    run = [sys.executable, '-m', 'pg_node']
    if args.actuator == 'velocity':
        physics = ['--actuator', 'velocity', '--timestep', '0.02']
        servo = [f'randomize_servo_{name}={value}' for name, value in
                 (('bandwidth', args.servo_bandwidth), ('latency', args.servo_latency))
                 if value != 'none']
    else:
        physics = ['--velocity-damping', '--timestep', '0.02']
        servo = []
    subprocess.run([*run, 'arm', 'import', str(urdf), '--tip', 'tool0', '--package-path',
                    str(share), *physics, '--home', *HOME, *region, '-o', str(model)],
                   check=True)
    run_dir = args.out / f'run_s{args.seed}'
    subprocess.run([*run, 'train', '--config', 'arm7', f'model:={model}',
                    f'total_steps:={args.steps}', '--seed', str(args.seed), '--run-dir',
                    str(run_dir), *servo], check=True, env=os.environ)
    summary = json.loads((run_dir / 'summary.json').read_text())
    print('| arm | interface | targets | steps | steps/s | return | final distance (cm) '
          '| within 2 cm |')
    print('|---|---|---|---:|---:|---:|---:|---:|')
    print(f'| UR5 | {args.actuator} | '
          f"{'workspace' if args.full_workspace else 'ball 0.3 m'} | "
          f"{summary['total_steps']:,} | "
          f"{summary['steps_per_second']:,.0f} | "
          f"{summary['eval_return']:.2f} | {100 * summary['eval_final_distance']:.2f} | "
          f"{100 * summary['eval_reached']:.0f}% |")
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
