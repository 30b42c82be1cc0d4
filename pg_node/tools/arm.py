"""
``python -m pg_node arm import ROBOT.urdf --tip LINK``: your robot's URDF as a pg_node arm.

Writes an MJCF (``-o``, default ``models/<robot>.xml`` in the current folder, a folder
git ignores) that ``model:=FILE`` trains with, and its meshes in ``<model>_meshes/``
beside it; see :mod:`pg_node.sim.urdf_import` for what it holds. A ``.xacro`` file is
expanded first (``--xacro-arg NAME:=VALUE``). What the options leave open (the start pose,
the goal region, hard limits, an armature, the timestep) the import chooses from the
robot, each with its reason. It prints which joints became arm joints and which were
fixed or coupled, the physics and task chosen and why, where the meshes went, how many
goals were kept and why not more, ONE ``train`` command (the recipe measured to learn for
the chosen command interface, :data:`RECIPES`, with the settings that fit the timestep;
the import checked the model under that recipe's randomization), what the recipe gave,
and every warning (inertias balanced, links without mass, meshes converted or replaced).
A bad input, or a model that diverges under the recipe with nothing left to choose, ends
in one line on stderr and exit status 1 (2 for a usage error). Documentation:
docs/own_arm.md.
"""
import argparse
from dataclasses import replace
from pathlib import Path
import shlex
import sys

from pg_node.tools.args import positive_float, positive_int


#: where ``arm import`` writes without ``-o`` (relative to the current folder; the
#: repository's .gitignore ignores it)
MODELS = 'models'


def _acceleration(text: str) -> float:
    """Return ``text`` as a number > 0 (``inf`` too), or raise argparse's type error."""
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {text}')
    return value


def _height(text: str):
    return None if text.lower() == 'none' else float(text)


def _xacro_arg(text: str):
    """Return ``NAME:=VALUE`` as ``(NAME, VALUE)``, or raise argparse's type error."""
    name, sep, value = text.partition(':=')
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f'{text!r} is not NAME:=VALUE')
    return name.strip(), value


def parser() -> argparse.ArgumentParser:
    """Return the command line parser of ``python -m pg_node arm``."""
    top = argparse.ArgumentParser(prog='python -m pg_node arm',
                                  description="Make pg_node arm models from a robot's URDF.")
    sub = top.add_subparsers(dest='action', required=True)
    p = sub.add_parser('import', help='write an MJCF arm model from a URDF',
                       description='Write an MJCF arm model (fingertip site, mocap target, '
                                   'one actuator per arm joint, reachable targets) from a '
                                   "URDF or xacro file, through MuJoCo's URDF compiler; "
                                   'see docs/own_arm.md.')
    p.add_argument('urdf', help='the robot description: a .urdf, or a .xacro that is '
                                'expanded first')
    p.add_argument('--xacro-arg', type=_xacro_arg, action='append', default=[],
                   metavar='NAME:=VALUE', help='an argument of the .xacro file; repeatable')
    p.add_argument('--tip', required=True, help='link whose origin is the fingertip')
    p.add_argument('--base', help='link the arm starts at (default: the root link); joints '
                                  'above it are fixed')
    p.add_argument('-o', '--output', help='MJCF file to write (default: models/<robot '
                                          'name>.xml, a folder git ignores)')
    p.add_argument('--actuator', choices=('motor', 'position', 'velocity'), default='motor',
                   help='motor: torque u * effort; position: target angle mapped from u over '
                        'the joint range; velocity: target speed u * the URDF velocity limit '
                        '(default: %(default)s)')
    p.add_argument('--velocity-gain', type=positive_float,
                   help='velocity actuators: N m s/rad, force = gain x (target speed - joint '
                        'speed), clamped to the effort limit (default: per joint effort / '
                        'velocity limit)')
    p.add_argument('--kp', type=positive_float, default=100.0,
                   help='position actuators: stiffness in N m/rad (default: %(default)s)')
    p.add_argument('--kv', type=positive_float, default=10.0,
                   help='position actuators: damping in N m s/rad (default: %(default)s)')
    p.add_argument('--position-delta', type=positive_float, metavar='RAD',
                   help='position actuators: the action is a change of at most RAD per '
                        'control step around the measured angle, not a target anywhere in '
                        'the joint range (default: absolute targets)')
    p.add_argument('--effort-scale', type=positive_float, default=1.0,
                   help='multiplies every URDF effort limit (default: %(default)s)')
    p.add_argument('--max-acceleration', type=_acceleration, metavar='RAD_S2',
                   help="caps each arm joint's effort at RAD_S2 x its inertia at the start "
                        'pose, so that a full torque does not whip a light wrist (default: 2000 '
                        "for motor actuators, none for servos; inf: the URDF's efforts)")
    p.add_argument('--gravity-compensation', action=argparse.BooleanOptionalAction,
                   default=True,
                   help="compensate the arm's weight (MuJoCo gravcomp), as torque-controlled "
                        'arms do in firmware (default: on)')
    p.add_argument('--tip-offset', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=(0.0, 0.0, 0.0), help="fingertip in the tip link's frame, m")
    p.add_argument('--package-path', action='append', default=[], metavar='DIR',
                   help='folder holding ROS packages (or a package) for package:// meshes, '
                        'tried after the ament index; repeatable')
    p.add_argument('--no-visual-meshes', action='store_true',
                   help='keep only the collision geometry')
    p.add_argument('--contacts', action='store_true',
                   help='keep collision contacts (default: off, as in the shipped arms)')
    p.add_argument('--timestep', type=positive_float,
                   help='physics step in s (default: 0.02, with the default frame_skip 2 a '
                        '0.04 s control step, 50 steps a 2 s episode; 0.002 for motor '
                        'actuators without damping, which blow up at 0.02; halved while the '
                        'model diverges under the recipe and an armature does not hold it)')
    p.add_argument('--integrator', choices=('euler', 'rk4', 'implicit', 'implicitfast'),
                   default='implicitfast', help='default: %(default)s')
    p.add_argument('--armature', type=float,
                   help='rotor inertia added to every arm joint, kg m^2 (default: none, or '
                        'the smallest of 0.01-0.5 that keeps the model finite under the '
                        "recipe's commands and randomization)")
    p.add_argument('--damping', type=float,
                   help='damping of every arm joint (default: the URDF <dynamics>)')
    p.add_argument('--velocity-damping', action=argparse.BooleanOptionalAction,
                   default=False,
                   help='damping of each arm joint = effort / URDF velocity limit, so that '
                        'full torque moves it at most at its velocity limit; an assumption '
                        'the model and the card keep: a robot in torque mode has no such '
                        'damping (default: off)')
    p.add_argument('--hard-limits', action=argparse.BooleanOptionalAction, default=None,
                   help='joint limits as hard as MuJoCo keeps stable (solreflimit 2 x the '
                        "timestep), as a robot's end stops and PyBullet's limits are "
                        "(default: on); --no-hard-limits: MuJoCo's soft limit, a 0.02 s spring "
                        'a policy can learn to lean on (docs/sim_to_sim.md)')
    p.add_argument('--home', type=float, nargs='+', metavar='Q',
                   help='start pose, one angle per arm joint (default: chosen, the pose of '
                        'most manipulability in the middle half of every range, its '
                        'fingertip above the base and in front, without self-collision)')
    p.add_argument('--targets', type=positive_int, default=1000,
                   help='reachable target points to store (default: %(default)s)')
    p.add_argument('--target-min-height', type=_height, default=0.0, metavar='Z',
                   help="lowest target z in m, or 'none' (default: %(default)s)")
    p.add_argument('--target-region', type=float, nargs=4, metavar=('X', 'Y', 'Z', 'R'),
                   help='keep only targets within R m of (X, Y, Z); R inf: anywhere '
                        "(default: chosen, a ball of 0.35 x the arm's reach around the start "
                        "pose's fingertip, goals in self-collision left out)")
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the target sampling (default: %(default)s)')
    return top


#: per command interface, the recipe measured to learn (docs/own_arm.md, "Recipes that
#: learned"; docs/results/BENCHMARKS.md gives the runs): what follows the import flags,
#: the training's arguments (the printed command adds the model and the frame_skip and
#: episode length of its timestep; the import checks the model under its randomization),
#: and what came of it. Only measured figures go here.
RECIPES = {
    'velocity': (
        '--actuator velocity, a --home with the arm raised, --target-region X Y Z R: goals '
        'in front of the robot above the table (UR5: 0.4 0 0.3 0.3); --armature (the '
        "motors' rotor inertia) where light wrists chatter, as the import warns (UR5e: 0.05)",
        "--config arm7 randomize_servo_bandwidth='uniform 5 20' "
        "randomize_servo_latency='uniform 0 0.02'",
        'UR5e of ur_description, 5M steps: 0.46 cm mean final distance, 97% within 2 cm '
        '(PyBullet: 0.45 cm, 97%; through policy_node 0.69 cm, 9 of 10), 24 min on 2 cores '
        'shared with other work; UR5 of example-robot-data: 0.62 cm, 96%'),
    'motor': (
        "the defaults (the URDF's damping and nothing more, --timestep 0.002, gravity "
        'compensation on), a --home away from the limits, --target-region X Y Z R: goals in '
        "front of the robot above the table (Panda: Franka's ready pose, 0.45 0 0.35 0.3); "
        "with only --tip (the import's start pose, goals and caps) 2M steps gave UR5 0.69 cm, "
        '100%, iiwa 1.34 cm, 84%, Panda 1.64 cm, 85%, xArm7 7.39 cm, 4% (BENCHMARKS.md, '
        '"Arms nobody tuned")',
        "--config arm7 randomize_damping='abs uniform 0 0.1' "
        "randomize_frictionloss='abs uniform 0 0.2' randomize_payload='uniform 0 0.3' "
        "randomize_servo_latency='uniform 0 0.04' total_steps:=2000000",
        'Panda of example-robot-data, 2M steps: 1.02 cm mean final distance, 99% within 2 cm '
        '(PyBullet: 1.01 cm, 99%; through policy_node 0.96 cm, 10 of 10), 12 min on 2 quiet '
        'cores; a dead time up to one control step (0.04 s) is what a timer-driven '
        'deployment loop adds: trained on 0-0.01 s, 20.7-27.9 cm with it'),
    'position, bounded changes': (
        '--actuator position --kp 500 --kv 20 --timestep 0.005 --position-delta 0.04 (what a '
        'UR e-Series driver accepts per 2 ms cycle), a --home with the arm raised, '
        '--target-region X Y Z R (UR5: 0.4 0 0.3 0.3)',
        '--config arm7 reward_control_weight:=0.05 '
        "randomize_servo_bandwidth='uniform 5 20' randomize_servo_latency='uniform 0 0.04'",
        'UR5 of example-robot-data, 5M steps: 2.89 cm mean final distance, 33% within 2 cm '
        '(PyBullet: 2.81 cm, 35%), 29 min on 2 shared cores; with '
        "randomize_servo_latency='uniform 0 0.02' instead, 2.5M steps: 1.93 cm, 71% within "
        '2 cm (PyBullet: 1.88 cm, 71%), 11 min, but 5.05 cm with the 40 ms a timer-driven '
        'policy_node can add: short of the goal (90% within 2 cm) either way'),
    'position': (
        '--actuator position --kp 500 --kv 20 --timestep 0.005 (absolute targets: 0.1 of '
        "action is 0.314 rad on a +-pi joint), as 'position, bounded changes'",
        '--config arm7 reward_control_weight:=0.05 '
        "randomize_servo_bandwidth='uniform 5 20' randomize_servo_latency='uniform 0 0.04'",
        'UR5 of example-robot-data, 500k steps: 7.34 cm mean final distance, 3% within 2 cm '
        '(PyBullet: 9.63 cm, 0%), 2 min; unsafe: its targets lie up to 4.81 rad from the '
        "measured angle (99th percentile 2.25 rad; 79% beyond the 0.126 rad the UR5's "
        '3.15 rad/s allows per control step), jumps a real servo turns into a protective '
        'stop: use --position-delta'),
    'motor, velocity damping': (
        '--velocity-damping --timestep 0.02, a --home with the arm raised, --target-region '
        'X Y Z R (UR5: 0.4 0 0.3 0.3)',
        '--config arm7',
        'UR5 of example-robot-data, 5M steps: 0.32 cm mean final distance, 100% within 2 cm, '
        '7.5 min on 2 cores; on a damping the robot lacks (an assumption in the card)'),
}


def interface(opts) -> str:
    """Return the name of ``opts``' command interface, as :data:`RECIPES` keys it."""
    if opts.actuator == 'motor' and opts.velocity_damping:
        return 'motor, velocity damping'
    if opts.actuator == 'position' and opts.position_delta is not None:
        return 'position, bounded changes'
    return opts.actuator


def training_arguments(opts) -> list:
    """Return the measured recipe's ``train`` arguments for ``opts``' interface ([] if none)."""
    recipe_ = RECIPES.get(interface(opts))
    return shlex.split(recipe_[1]) if recipe_ else []


def randomization(opts) -> dict:
    """Return the recipe's ``{term: text}`` (its ``randomize_<term>`` arguments)."""
    out = {}
    for arg in training_arguments(opts):
        key, _, value = arg.replace(':=', '=', 1).partition('=')
        if key.startswith('randomize_'):
            out[key[len('randomize_'):]] = value
    return out


def recipe(opts) -> str:
    """Return the line with the measured recipe for ``opts``' command interface."""
    name = interface(opts)
    if name not in RECIPES:
        return (f'recipe: none measured yet for {name} actuators; docs/own_arm.md '
                '("Recipes that learned") lists those that were')
    flags, _, result = RECIPES[name]
    return (f'recipe measured for {name} actuators: import with {flags}; trained with the '
            f'command above: {result} (docs/own_arm.md)')


def options(args):
    """Return the :class:`~pg_node.sim.urdf_import.ImportOptions` of parsed arguments."""
    from pg_node.sim.urdf_import import ImportOptions
    opts = ImportOptions(
        tip=args.tip, base=args.base, actuator=args.actuator, kp=args.kp, kv=args.kv,
        velocity_gain=args.velocity_gain, max_acceleration=args.max_acceleration,
        effort_scale=args.effort_scale, gravity_compensation=args.gravity_compensation,
        tip_offset=tuple(args.tip_offset), package_paths=args.package_path,
        visual_meshes=not args.no_visual_meshes, contacts=args.contacts,
        timestep=args.timestep, integrator=args.integrator, armature=args.armature,
        damping=args.damping, home=args.home, position_delta=args.position_delta,
        velocity_damping=args.velocity_damping, hard_limits=args.hard_limits,
        targets=args.targets,
        target_min_height=args.target_min_height,
        target_region=tuple(args.target_region) if args.target_region else None,
        seed=args.seed, xacro_args=dict(args.xacro_arg), choose=True)
    return replace(opts, randomization=randomization(opts))


def main(argv=None) -> int:
    """Run ``python -m pg_node arm``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser().parse_args(argv)
    from pg_node.sim.urdf_import import (default_output, import_urdf, load_robot,
                                         UrdfImportError, write_model)
    opts = options(args)
    command = 'python -m pg_node arm ' + ' '.join(shlex.quote(a) for a in argv)
    warnings = []
    try:
        robot = load_robot(args.urdf, opts.xacro_args, opts.package_paths, warnings)
        out = args.output or str(Path(MODELS) / default_output(args.urdf, robot))
        result = import_urdf(args.urdf, opts, out_path=out, command=command, robot=robot)
    except UrdfImportError as exc:
        print(f'arm import: {exc}', file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:   # a number that is not one, and the like
        reason = '; '.join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f'arm import: {args.urdf}: {reason}', file=sys.stderr)
        return 1
    try:
        if not args.output:
            Path(MODELS).mkdir(exist_ok=True)
        write_model(result, out)
    except OSError as exc:
        print(f'arm import: cannot write {exc.filename or out}: {exc.strerror}',
              file=sys.stderr)
        return 1
    for text in warnings + result.warnings:
        print(f'warning: {text}', file=sys.stderr)
    for line in report(result, opts, out):
        print(line)
    return 0


def report(result, opts, out) -> list:
    """Return the lines that say what the import made and chose, and how to train it."""
    from pg_node.common.params import SIM_PARAMS
    from pg_node.sim.urdf_import import training_settings
    lines = [f'arm joints ({len(result.arm_joints)}): {", ".join(result.arm_joints)}',
             f'fixed joints ({len(result.fixed_joints)}): '
             f'{", ".join(result.fixed_joints) or "none"}']
    if result.coupled_joints:
        coupled = ', '.join(f'{name} = {offset:g} + {multiplier:g} x {leader} (within '
                            f'{result.coupling_error.get(name, 0.0):.2g} rad under random '
                            'commands)' for name, (leader, multiplier, offset)
                            in result.coupled_joints.items())
        lines.append(f'coupled joints ({len(result.coupled_joints)}, URDF <mimic>, no '
                     f'actuator): {coupled}')
    opts = result.options or opts          # as the import took them (with_defaults)
    if opts.velocity_damping:
        damping = 'velocity damping (effort / velocity limit, an assumption)'
    elif opts.damping is not None:
        damping = f'damping {opts.damping:g} N m s/rad (no velocity damping)'
    else:
        damping = "the URDF's damping (no velocity damping)"
    limits = ('hard joint limits' if opts.hard_limits
              else "MuJoCo's soft joint limits (--hard-limits for a robot's)")
    armature = f', armature {opts.armature:g} kg m^2' if opts.armature is not None else ''
    gravity = 'on' if opts.gravity_compensation else 'off'
    lines.append(f'physics: timestep {opts.timestep:g} s ({opts.integrator}), {damping}'
                 f'{armature}, gravity compensation {gravity}, '
                 f'{opts.actuator} actuators, {limits}')
    if opts.position_delta is not None:
        lines.append(f'actions: changes of at most {opts.position_delta:g} rad per control '
                     'step around the measured angle (pg_position_delta; policy_node does the '
                     'same)')
    if result.mesh_files:
        converted = (f' ({result.converted_meshes} converted to STL)'
                     if result.converted_meshes else '')
        n = len(result.mesh_files)
        lines.append(f'meshes: {n} file{"s" if n > 1 else ""}{converted} copied to '
                     f'{result.mesh_dir}; the model names them by absolute path, so that it '
                     "and a trained policy's card load from any folder (import again to "
                     'move them)')
    lines += [f'chose {line}' for line in result.choices]
    frame_skip, steps = training_settings(result.timestep)
    defaults = (SIM_PARAMS['frame_skip'].default, SIM_PARAMS['max_episode_steps'].default)
    extra = ''.join(f' {key}:={value}' for key, value, default in
                    (('frame_skip', frame_skip, defaults[0]),
                     ('max_episode_steps', steps, defaults[1])) if value != default)
    kept = f'{result.n_targets} reachable targets'
    if result.n_targets < opts.targets:
        from pg_node.sim.urdf_import import rejected_text
        kept = (f'{result.n_targets} of {opts.targets} reachable targets (the poses drawn '
                f'for the rest: {rejected_text(result.rejected)}; 50 draws a target at most)')
    lines.append(f'{kept}; wrote {out}')
    # the absolute path: the run keeps it, and play, export and policy_node find the model
    # from any folder
    model = shlex.quote(str(Path(out).resolve()))
    # the recipe's arguments as written in RECIPES, its --config first
    train = RECIPES[interface(opts)][1] if interface(opts) in RECIPES else ''
    config, rest = '', train
    if train.startswith('--config '):
        config, _, rest = train.partition(' ')[2].partition(' ')
        config = f'--config {config} '
    lines.append(f'train with: python -m pg_node train {config}'
                 f'model:={model}{extra}{" " + rest if rest else ""}  (a control step of '
                 f'{frame_skip} x {result.timestep:g} s = {frame_skip * result.timestep:g} '
                 f's, {steps}-step episodes of {steps * frame_skip * result.timestep:g} s)')
    lines.append(recipe(opts))
    return lines
