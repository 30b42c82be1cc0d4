"""
``python -m pg_node arm import ROBOT.urdf --tip LINK``: your robot's URDF as a pg_node arm.

Writes an MJCF (``-o``, default ``<robot>.xml`` in the current folder) that ``model:=FILE``
trains with; see :mod:`pg_node.sim.urdf_import` for what it holds. It prints which joints
became arm joints and which were fixed, and every warning (meshes MuJoCo cannot read).
A bad input ends in one line on stderr and exit status 1 (2 for a usage error).
"""
import argparse
import shlex
import sys

from pg_node.tools.args import positive_float, positive_int


def _height(text: str):
    return None if text.lower() == 'none' else float(text)


def parser() -> argparse.ArgumentParser:
    """Return the command line parser of ``python -m pg_node arm``."""
    top = argparse.ArgumentParser(prog='python -m pg_node arm',
                                  description="Make pg_node arm models from a robot's URDF.")
    sub = top.add_subparsers(dest='action', required=True)
    p = sub.add_parser('import', help='write an MJCF arm model from a URDF',
                       description='Write an MJCF arm model (fingertip site, mocap target, '
                                   'one actuator per arm joint, reachable targets) from a '
                                   "URDF, through MuJoCo's URDF compiler.")
    p.add_argument('urdf', help='the robot description (.urdf; expand a .xacro first)')
    p.add_argument('--tip', required=True, help='link whose origin is the fingertip')
    p.add_argument('--base', help='link the arm starts at (default: the root link); joints '
                                  'above it are fixed')
    p.add_argument('-o', '--output', help='MJCF file to write (default: <robot name>.xml)')
    p.add_argument('--actuator', choices=('motor', 'position'), default='motor',
                   help='motor: torque u * effort; position: target angle mapped from u over '
                        'the joint range (default: %(default)s)')
    p.add_argument('--kp', type=positive_float, default=100.0,
                   help='position actuators: stiffness in N m/rad (default: %(default)s)')
    p.add_argument('--kv', type=positive_float, default=10.0,
                   help='position actuators: damping in N m s/rad (default: %(default)s)')
    p.add_argument('--effort-scale', type=positive_float, default=1.0,
                   help='multiplies every URDF effort limit (default: %(default)s)')
    p.add_argument('--gravity-compensation', action='store_true',
                   help="compensate the arm's weight (MuJoCo gravcomp), as torque-controlled "
                        'arms do in firmware')
    p.add_argument('--tip-offset', type=float, nargs=3, metavar=('X', 'Y', 'Z'),
                   default=(0.0, 0.0, 0.0), help="fingertip in the tip link's frame, m")
    p.add_argument('--package-path', action='append', default=[], metavar='DIR',
                   help='folder holding ROS packages (or a package) for package:// meshes, '
                        'tried after the ament index; repeatable')
    p.add_argument('--no-visual-meshes', action='store_true',
                   help='keep only the collision geometry')
    p.add_argument('--contacts', action='store_true',
                   help='keep collision contacts (default: off, as in the shipped arms)')
    p.add_argument('--timestep', type=positive_float, default=0.002,
                   help='physics step in s (default: %(default)s)')
    p.add_argument('--integrator', choices=('euler', 'rk4', 'implicit', 'implicitfast'),
                   default='implicitfast', help='default: %(default)s')
    p.add_argument('--armature', type=float, help='rotor inertia added to every arm joint')
    p.add_argument('--damping', type=float,
                   help='damping of every arm joint (default: the URDF <dynamics>)')
    p.add_argument('--velocity-damping', action='store_true',
                   help='damping of each arm joint = effort / URDF velocity limit, so that '
                        'full torque moves it at most at its velocity limit')
    p.add_argument('--home', type=float, nargs='+', metavar='Q',
                   help='start pose, one angle per arm joint (default: 0 clipped to limits)')
    p.add_argument('--targets', type=positive_int, default=1000,
                   help='reachable target points to store (default: %(default)s)')
    p.add_argument('--target-min-height', type=_height, default=0.0, metavar='Z',
                   help="lowest target z in m, or 'none' (default: %(default)s)")
    p.add_argument('--target-region', type=float, nargs=4, metavar=('X', 'Y', 'Z', 'R'),
                   help='keep only targets within R m of (X, Y, Z)')
    p.add_argument('--seed', type=int, default=0,
                   help='seed of the target sampling (default: %(default)s)')
    return top


def options(args):
    """Return the :class:`~pg_node.sim.urdf_import.ImportOptions` of parsed arguments."""
    from pg_node.sim.urdf_import import ImportOptions
    return ImportOptions(
        tip=args.tip, base=args.base, actuator=args.actuator, kp=args.kp, kv=args.kv,
        effort_scale=args.effort_scale, gravity_compensation=args.gravity_compensation,
        tip_offset=tuple(args.tip_offset), package_paths=args.package_path,
        visual_meshes=not args.no_visual_meshes, contacts=args.contacts,
        timestep=args.timestep, integrator=args.integrator, armature=args.armature,
        damping=args.damping, velocity_damping=args.velocity_damping, home=args.home,
        targets=args.targets,
        target_min_height=args.target_min_height,
        target_region=tuple(args.target_region) if args.target_region else None,
        seed=args.seed)


def main(argv=None) -> int:
    """Run ``python -m pg_node arm``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser().parse_args(argv)
    from pathlib import Path
    from pg_node.sim.urdf_import import import_urdf, UrdfImportError
    opts = options(args)
    out = args.output
    if out is None:
        from pg_node.sim.urdf_import import read_urdf
        try:
            out = (read_urdf(args.urdf).get('name') or Path(args.urdf).stem) + '.xml'
        except UrdfImportError as exc:
            print(f'arm import: {exc}', file=sys.stderr)
            return 1
    command = 'python -m pg_node arm ' + ' '.join(shlex.quote(a) for a in argv)
    try:
        result = import_urdf(args.urdf, opts, out_path=out, command=command)
    except UrdfImportError as exc:
        print(f'arm import: {exc}', file=sys.stderr)
        return 1
    except (ValueError, OSError) as exc:   # a number that is not one, and the like
        reason = '; '.join(line.strip() for line in str(exc).splitlines() if line.strip())
        print(f'arm import: {args.urdf}: {reason}', file=sys.stderr)
        return 1
    try:
        Path(out).write_text(result.xml)
    except OSError as exc:
        print(f'arm import: cannot write {out}: {exc.strerror}', file=sys.stderr)
        return 1
    for text in result.warnings:
        print(f'warning: {text}', file=sys.stderr)
    print(f'arm joints ({len(result.arm_joints)}): {", ".join(result.arm_joints)}')
    print(f'fixed joints ({len(result.fixed_joints)}): '
          f'{", ".join(result.fixed_joints) or "none"}')
    print(f'{result.n_targets} reachable targets; wrote {out} (train with model:={out})')
    return 0
