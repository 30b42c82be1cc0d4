"""
Turn a robot's URDF into an arm model that pg_node trains with (no ROS here).

MuJoCo's own URDF compiler reads the robot (links become bodies, URDF joints hinges or
slides with their limits, ``<dynamics>`` damping and friction, the effort limit as the
joint's actuator force range); this module prepares the URDF for it and then edits the
compiled :class:`mujoco.MjSpec` into pg_node's conventions (:mod:`pg_node.sim.arm_task`):

* **arm joints**: the revolute and continuous joints on the chain from ``base`` (default: the
  root link) to ``tip``. Every other moving joint (joints above the base, other branches,
  a gripper below the tip, a floating root) is fixed at its zero position (deleted from the
  model) and listed in :attr:`ImportResult.fixed_joints`.
* **actuators**, one per arm joint, with normalised commands in ``[-1, 1]`` as the shipped
  models have: ``motor`` applies ``u * effort * effort_scale`` N m (``effort`` is the URDF
  ``<limit effort>``), ``position`` drives the joint to the angle ``u`` maps to linearly
  over the joint's range (``-pi..pi`` for a continuous joint) with stiffness ``kp`` and
  damping ``kv``, its force clamped to ``effort * effort_scale``.
* ``gravity_compensation``: every body of the arm gets ``gravcomp="1"`` (MuJoCo applies the
  bodies' weight back as a passive force), as torque-controlled arms do in their firmware.
* a ``fingertip`` site at the tip link's origin plus ``tip_offset`` (in the tip's frame),
  a mocap ``target`` sphere, a floor (visual only) and a light.
* **reachable targets**: ``targets`` fingertip positions of forward kinematics at joint
  angles drawn uniformly within the limits (seeded), kept where they are at least
  ``target_min_height`` high (and within ``target_region``, a ball, when given), stored as
  the custom numeric ``pg_target_points`` (x y z per point, 0.1 mm resolution); the task
  draws each goal among them. ``pg_init_qpos`` holds the arm's start pose (``home``, else
  zero clipped into the limits).
* **meshes**: ``package://NAME/REL`` is looked up as ROS does, in ``share/NAME`` of every
  prefix of ``AMENT_PREFIX_PATH``, then in each ``package_paths`` folder (``DIR/NAME/REL``,
  or ``DIR/REL`` when ``DIR`` is the package itself), then in the URDF's folder and each of
  its parents (same two forms); ``file://`` and plain paths (relative to the URDF's folder)
  too. MuJoCo reads STL, OBJ and MSH; a visual mesh in another format (COLLADA ``.dae``)
  is dropped when the link has collision geometry, else replaced by a small sphere, a
  collision mesh in another format by a small sphere, each with a warning.
  ``visual_meshes=False`` keeps only the collision geometry (what simulation needs).
  Mesh files are referenced by paths relative to the written model.
* ``velocity_damping``: each arm joint's damping becomes ``effort / velocity limit`` (the
  URDF's ``<limit velocity>``), so that the full torque drives the joint at no more than
  its velocity limit, as the robot's controller enforces; without it a torque-driven joint
  of small inertia accelerates to tens of rad/s. Otherwise ``damping`` (if given) or the
  URDF's ``<dynamics damping>``.
* contacts are off (pg_node's reaching task has none) unless ``contacts``.

Errors are :class:`UrdfImportError` with a one-line message.
"""
from dataclasses import dataclass, field
import math
import os
from pathlib import Path
from typing import List, Optional, Sequence, Tuple
import xml.etree.ElementTree as ET

import mujoco
import numpy as np

#: mesh formats MuJoCo reads
MESH_FORMATS = ('.stl', '.obj', '.msh')
ARM_JOINT_TYPES = ('revolute', 'continuous')
FALLBACK_SPHERE = 0.02


class UrdfImportError(ValueError):
    """A URDF that cannot be turned into an arm model; the message says why, in one line."""


@dataclass
class ImportOptions:
    """What :func:`import_urdf` makes of the robot (see the module docstring)."""

    tip: str
    base: Optional[str] = None
    actuator: str = 'motor'
    kp: float = 100.0
    kv: float = 10.0
    effort_scale: float = 1.0
    gravity_compensation: bool = False
    tip_offset: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    package_paths: Sequence[str] = ()
    visual_meshes: bool = True
    contacts: bool = False
    timestep: float = 0.002
    integrator: str = 'implicitfast'
    armature: Optional[float] = None
    damping: Optional[float] = None
    velocity_damping: bool = False
    home: Optional[Sequence[float]] = None
    targets: int = 1000
    target_min_height: Optional[float] = 0.0
    target_region: Optional[Tuple[float, float, float, float]] = None
    init_qpos_noise: float = 0.1
    init_qvel_noise: float = 0.005
    seed: int = 0


@dataclass
class ImportResult:
    """The MJCF text and what the import did."""

    xml: str
    arm_joints: List[str]
    fixed_joints: List[str]
    warnings: List[str] = field(default_factory=list)
    n_targets: int = 0


def _one_line(exc: Exception) -> str:
    return '; '.join(line.strip() for line in str(exc).splitlines() if line.strip())


def _floats(text: Optional[str], n: int, default: float = 0.0) -> List[float]:
    if text is None:
        return [default] * n
    values = [float(v) for v in text.split()]
    if len(values) != n:
        raise ValueError(f'expected {n} numbers, got {text!r}')
    return values


def read_urdf(path) -> ET.Element:
    """Return the ``<robot>`` element of the URDF at ``path``, or raise UrdfImportError."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise UrdfImportError(f'cannot read {path}: {exc.strerror}') from None
    except ET.ParseError as exc:
        raise UrdfImportError(f'{path} is not a URDF file: not valid XML ({exc})') from None
    if root.tag != 'robot':
        raise UrdfImportError(f'{path} is not a URDF file: its root element is <{root.tag}>, '
                              'not <robot>')
    if root.find('link') is None:
        raise UrdfImportError(f'{path} is not a URDF file: it has no <link>')
    return root


def ament_prefixes() -> List[Path]:
    """Return the prefixes of ``AMENT_PREFIX_PATH``, in order."""
    return [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]


def mesh_candidates(uri: str, urdf_dir: Path, package_paths: Sequence[str] = ()) -> List[Path]:
    """Return the files a mesh URI may name, in the order they are tried."""
    if uri.startswith('package://'):
        package, _, rel = uri[len('package://'):].partition('/')
        out = [prefix / 'share' / package / rel for prefix in ament_prefixes()]
        folders = [Path(p) for p in package_paths]
        folders += [urdf_dir, *urdf_dir.parents]
        for folder in folders:
            out.append(folder / package / rel)
            if folder.name == package:
                out.append(folder / rel)
        return out
    if uri.startswith('file://'):
        return [Path(uri[len('file://'):])]
    path = Path(uri)
    return [path if path.is_absolute() else urdf_dir / path]


def resolve_mesh(uri: str, urdf_dir: Path, package_paths: Sequence[str] = ()) -> Path:
    """Return the existing file a mesh URI names, or raise UrdfImportError saying where."""
    candidates = mesh_candidates(uri, urdf_dir, package_paths)
    for path in candidates:
        if path.is_file():
            return path.resolve()
    where = ', '.join(dict.fromkeys(str(p.parent) for p in candidates)) or 'nowhere'
    raise UrdfImportError(f'mesh {uri!r} not found; looked in: {where}')


def _chain(robot: ET.Element, base: Optional[str], tip: str):
    """Return ``(base, root, arm joint names, every joint by name)``; check the links."""
    links = [link.get('name') for link in robot.findall('link')]
    joints = {j.get('name'): j for j in robot.findall('joint')}
    parent_of = {}
    for j in joints.values():
        parent, child = j.find('parent'), j.find('child')
        if parent is None or child is None:
            raise UrdfImportError(f'joint {j.get("name")!r} lacks a <parent> or <child> link')
        for end, link in (('parent', parent.get('link')), ('child', child.get('link'))):
            if link not in links:   # else it looked like a second root link
                known = ', '.join(links[:12]) + (', ...' if len(links) > 12 else '')
                raise UrdfImportError(f'joint {j.get("name")!r} names {end} link {link!r}, '
                                      f'which the URDF does not define (links: {known})')
        if j.get('type') in ('revolute', 'prismatic') and j.find('limit') is None:
            # ROS's own URDF parser (urdfdom) refuses the file for this: the joint's range
            # would silently be a full turn here
            raise UrdfImportError(f'{j.get("type")} joint {j.get("name")!r} has no <limit>: '
                                  'a URDF must give one (lower, upper, effort, velocity), as '
                                  "ROS's URDF parser requires")
        parent_of[child.get('link')] = (parent.get('link'), j)
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise UrdfImportError(f'the URDF must have one root link, it has {len(roots)}: '
                              f'{", ".join(roots[:5])}')
    root = roots[0]
    for name, what in ((tip, '--tip'), (base, '--base')):
        if name is not None and name not in links:
            known = ', '.join(links[:12]) + (', ...' if len(links) > 12 else '')
            raise UrdfImportError(f'unknown link {name!r} ({what}); the links are: {known}')
    base = base or root
    path, link = [], tip
    while link != base:
        if link not in parent_of:
            raise UrdfImportError(f'link {base!r} (--base) is not above {tip!r} (--tip) in the '
                                  "robot's tree")
        link, joint = parent_of[link]
        path.append(joint)
    arm = [j.get('name') for j in reversed(path) if j.get('type') in ARM_JOINT_TYPES]
    if not arm:
        raise UrdfImportError(f'no revolute joint between {base!r} and {tip!r}')
    return base, root, arm, joints


def _prepare_meshes(robot: ET.Element, urdf_dir: Path, opts: ImportOptions,
                    warnings: List[str]):
    """Resolve every mesh to an absolute path; drop or replace what MuJoCo cannot read."""
    for link in robot.findall('link'):
        name = link.get('name')
        collisions = link.findall('collision')
        for kind in ('visual', 'collision'):
            for elem in link.findall(kind):
                mesh = elem.find('geometry/mesh')
                if kind == 'visual' and not opts.visual_meshes:
                    link.remove(elem)
                    continue
                if mesh is None:
                    continue
                uri = mesh.get('filename', '')
                suffix = Path(uri).suffix.lower()
                if suffix not in MESH_FORMATS:
                    geometry = elem.find('geometry')
                    what = f'link {name!r}: {kind} mesh {uri!r} is {suffix or "no known format"}'
                    if kind == 'visual' and collisions:
                        link.remove(elem)
                        warnings.append(f'{what}, which MuJoCo cannot read; showing the '
                                        'collision geometry instead')
                    else:
                        geometry.remove(mesh)
                        ET.SubElement(geometry, 'sphere', radius=str(FALLBACK_SPHERE))
                        warnings.append(f'{what}, which MuJoCo cannot read; a sphere of '
                                        f'radius {FALLBACK_SPHERE} m stands in')
                    continue
                mesh.set('filename', str(resolve_mesh(uri, urdf_dir, opts.package_paths)))


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        raise UrdfImportError(f'MuJoCo cannot compile the robot: {_one_line(exc)}') from None


def _subtree(spec: mujoco.MjSpec, name: str) -> List:
    """Return the body ``name`` and every body below it."""
    out, todo = [], [spec.body(name)]
    while todo:
        body = todo.pop()
        out.append(body)
        todo.extend(body.bodies)
    return out


def _effort(joint: ET.Element, warnings: List[str]) -> float:
    limit = joint.find('limit')
    given = limit.get('effort') if limit is not None else None
    effort = float(given) if given is not None else 0.0
    if given is None:
        warnings.append(f'joint {joint.get("name")!r} has no effort limit; using 1 N m')
        effort = 1.0
    elif not effort > 0:
        warnings.append(f'joint {joint.get("name")!r} has effort limit {given}, which cannot '
                        'move it; using 1 N m (scale it with --effort-scale)')
        effort = 1.0
    return effort


def _fmt(values) -> str:
    return ' '.join(f'{v:g}' for v in np.asarray(values, dtype=float).ravel())


def import_urdf(urdf_path, opts: ImportOptions, out_path=None, command: str = ''
                ) -> ImportResult:
    """
    Return the MJCF of the arm in ``urdf_path`` (see the module docstring).

    ``out_path`` (default: beside the URDF) is where the model will be written: mesh paths
    are made relative to its folder. ``command``, the command line that made the model, is
    kept as the custom text ``pg_import_command`` (an XML comment at the top says so).
    """
    urdf_path = Path(urdf_path).resolve() if Path(urdf_path).exists() else Path(urdf_path)
    robot = read_urdf(urdf_path)
    urdf_dir = urdf_path.parent
    warnings: List[str] = []
    base, root, arm, joints = _chain(robot, opts.base, opts.tip)
    if opts.actuator not in ('motor', 'position'):
        raise UrdfImportError(f'unknown actuator {opts.actuator!r}; use motor or position')
    if opts.home is not None and len(opts.home) != len(arm):
        raise UrdfImportError(f'--home needs {len(arm)} angles (the arm joints '
                              f'{", ".join(arm)}), got {len(opts.home)}')
    _prepare_meshes(robot, urdf_dir, opts, warnings)
    # a floating or planar joint (a mobile base) is fixed like every other non-arm joint;
    # MuJoCo would refuse a free joint below the URDF's root body anyway
    fixed = []
    for j in robot.findall('joint'):
        if j.get('type') in ('floating', 'planar'):
            j.set('type', 'fixed')
            fixed.append(j.get('name'))
    for old in robot.findall('mujoco'):
        robot.remove(old)
    ext = ET.Element('mujoco')
    # visuals were dropped above when unwanted: MuJoCo's discardvisual would also drop the
    # collision geoms once their contacts are off
    ET.SubElement(ext, 'compiler', fusestatic='false', strippath='false',
                  discardvisual='false', boundmass='0.001', boundinertia='1e-06')
    robot.insert(0, ext)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(robot, encoding='unicode'))
    except ValueError as exc:
        raise UrdfImportError(f'MuJoCo cannot read the URDF {urdf_path}: '
                              f'{_one_line(exc)}') from None
    _compile(spec)

    # joints: the chain's revolute joints stay, every other moving joint is fixed
    others = [j.name for j in spec.joints if j.name not in arm]
    for eq in list(spec.equalities):   # URDF <mimic> becomes a joint equality
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and {eq.name1, eq.name2} & set(others):
            spec.delete(eq)
    for name in others:
        spec.delete(spec.joint(name))
    fixed += others
    spec.option.timestep = opts.timestep
    spec.option.integrator = {'euler': mujoco.mjtIntegrator.mjINT_EULER,
                              'rk4': mujoco.mjtIntegrator.mjINT_RK4,
                              'implicit': mujoco.mjtIntegrator.mjINT_IMPLICIT,
                              'implicitfast': mujoco.mjtIntegrator.mjINT_IMPLICITFAST
                              }[opts.integrator]
    efforts = {}
    for name in arm:
        joint = spec.joint(name)
        effort = _effort(joints[name], warnings) * opts.effort_scale
        efforts[name] = effort
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
        joint.actfrcrange = [-effort, effort]
        if opts.armature is not None:
            joint.armature = opts.armature
        if opts.damping is not None:
            joint.damping = [opts.damping, 0.0, 0.0]
        if opts.velocity_damping:
            limit = joints[name].find('limit')
            velocity = float(limit.get('velocity', 0)) if limit is not None else 0.0
            if velocity > 0:
                joint.damping = [effort / velocity, 0.0, 0.0]
            else:
                warnings.append(f'joint {name!r} has no velocity limit; its damping stays')
    moving = _subtree(spec, base)
    if opts.gravity_compensation:
        for body in moving:
            body.gravcomp = 1.0
    if not opts.contacts:
        for geom in spec.geoms:
            geom.contype = 0
            geom.conaffinity = 0

    model = _compile(spec)
    limited, ranges = [], []
    for name in arm:
        j = model.joint(name)
        lim = bool(model.jnt_limited[j.id])
        limited.append(lim)
        ranges.append(model.jnt_range[j.id].copy() if lim else np.array([-math.pi, math.pi]))
    ranges = np.array(ranges)

    # actuators, normalised commands in [-1, 1]
    for name, (lo, hi) in zip(arm, ranges):
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-1.0, 1.0]
        if opts.actuator == 'motor':
            act.gear[0] = efforts[name]
        else:
            # force = kp * (mid + half * u - q) - kv * qdot, clamped to the effort limit
            mid, half = (lo + hi) / 2, (hi - lo) / 2
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm[0] = opts.kp * half
            act.biasprm[:3] = [opts.kp * mid, -opts.kp, -opts.kv]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-efforts[name], efforts[name]]

    tip_body = spec.body(opts.tip)
    tip_body.add_site(name='fingertip', pos=list(opts.tip_offset), size=[0.01, 0, 0],
                      rgba=[0.0, 0.8, 0.6, 1.0])
    world = spec.worldbody
    world.add_light(name='top', pos=[0, 0, 3], dir=[0, 0, -1], diffuse=[0.7, 0.7, 0.7])
    world.add_geom(name='ground', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1],
                   rgba=[0.9, 0.9, 0.9, 1], contype=1 if opts.contacts else 0,
                   conaffinity=1 if opts.contacts else 0)

    # start pose, then the reachable targets from forward kinematics
    if opts.home is not None:
        home = np.array(opts.home, dtype=float)
        if np.any(home < ranges[:, 0]) or np.any(home > ranges[:, 1]):
            raise UrdfImportError(f'--home {_fmt(home)} is outside the joint limits')
    else:
        home = np.clip(0.0, ranges[:, 0], ranges[:, 1])
    model = _compile(spec)
    points = _reachable_points(model, arm, ranges, opts)
    if len(points) == 0:
        raise UrdfImportError('no reachable target is left after the height/region filter')
    target = world.add_body(name='target', mocap=True, pos=list(points[0]))
    target.add_geom(name='target', type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.02, 0, 0],
                    rgba=[0.9, 0.2, 0.2, 1], contype=0, conaffinity=0)
    for name, data in (('pg_init_qpos', home),
                       ('pg_init_qpos_noise', [opts.init_qpos_noise]),
                       ('pg_init_qvel_noise', [opts.init_qvel_noise]),
                       ('pg_target_points', points.ravel())):
        spec.add_numeric(name=name, data=list(np.asarray(data, dtype=float)))
    if command:
        spec.add_text(name='pg_import_command', data=command)
    _compile(spec)

    out_dir = Path(out_path).resolve().parent if out_path else urdf_dir
    xml = spec.to_xml()
    for mesh in spec.meshes:   # relative to the written model (MuJoCo's rule for file=)
        if os.path.isabs(mesh.file):
            xml = xml.replace(f'file="{mesh.file}"',
                              f'file="{os.path.relpath(mesh.file, out_dir)}"')
    if command:
        xml = ('<!--\n  Written by python -m pg_node arm import from ' + urdf_path.name
               + '; the exact command is the\n  custom text pg_import_command below. Do not '
               'edit: change the URDF or the options\n  and import again.\n-->\n' + xml)
    return ImportResult(xml=xml, arm_joints=arm, fixed_joints=fixed, warnings=warnings,
                        n_targets=len(points))


def _reachable_points(model: mujoco.MjModel, arm: List[str], ranges: np.ndarray,
                      opts: ImportOptions) -> np.ndarray:
    """Return fingertip positions at uniform joint angles within the limits, filtered."""
    rng = np.random.default_rng(opts.seed)
    data = mujoco.MjData(model)
    site = model.site('fingertip').id
    adr = [model.joint(name).qposadr[0] for name in arm]
    keep = []
    tries = 0
    while len(keep) < opts.targets and tries < 50 * opts.targets:
        tries += 1
        data.qpos[adr] = rng.uniform(ranges[:, 0], ranges[:, 1])
        mujoco.mj_kinematics(model, data)
        p = data.site_xpos[site].copy()
        if opts.target_min_height is not None and p[2] < opts.target_min_height:
            continue
        if opts.target_region is not None:
            center, radius = np.array(opts.target_region[:3]), opts.target_region[3]
            if np.linalg.norm(p - center) > radius:
                continue
        keep.append(p)
    return np.round(np.array(keep).reshape(-1, 3), 4)
