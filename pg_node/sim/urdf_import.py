"""
Turn a robot's URDF (or xacro) into an arm model that pg_node trains with (no ROS here).

MuJoCo's own URDF compiler reads the robot; :func:`import_urdf` prepares the URDF for it
(xacro expanded, meshes found and converted) and edits the compiled :class:`mujoco.MjSpec`
into pg_node's conventions (:mod:`pg_node.sim.arm_task`) in named steps (:func:`_build`:
joints, physics, actuators, scene, task, targets, custom data, checks): one actuator per
arm joint with commands in ``[-1, 1]``, a ``fingertip`` site, a mocap ``target``, reachable
goals, and a check of the model under hard commands. What each step chooses, and why:
docs/own_arm.md ("How the import chooses what it chooses"). Errors are
:class:`UrdfImportError` with a one-line message.
"""
import contextlib
from dataclasses import dataclass, field, replace
import io
import math
import os
from pathlib import Path
import re
import shutil
import tempfile
from typing import Dict, List, Mapping, Optional, Sequence, Tuple, Union
import xml.etree.ElementTree as ET
from xml.sax.saxutils import escape

import mujoco
import numpy as np
from pg_node.common.perturbations import parse_terms, TermSpec

#: mesh formats MuJoCo reads
MESH_FORMATS = ('.stl', '.obj', '.msh')
#: mesh formats converted to STL (with trimesh; COLLADA needs pycollada)
CONVERTED_FORMATS = ('.dae', '.ply', '.off', '.glb', '.gltf')
ARM_JOINT_TYPES = ('revolute', 'continuous')
FALLBACK_SPHERE = 0.02
#: the control step and episode length the defaults give (frame_skip 2 x 0.02 s, 50 steps)
CONTROL_STEP = 0.04
EPISODE_SECONDS = 2.0
#: MuJoCo's minimum body mass here (compiler boundmass): what a massless moving link weighs
BOUND_MASS = 0.001


class UrdfImportError(ValueError):
    """A URDF that cannot be turned into an arm model; the message says why, in one line."""


@dataclass
class ImportOptions:
    """What :func:`import_urdf` makes of the robot (docs/own_arm.md: the flags, the steps)."""

    tip: str
    base: Optional[str] = None
    actuator: str = 'motor'
    kp: float = 100.0
    kv: float = 10.0
    #: velocity actuators: N m s/rad, force = gain x (target speed - joint speed); None:
    #: per joint effort / velocity limit (the effort limit at an error of the whole limit)
    velocity_gain: Optional[float] = None
    effort_scale: float = 1.0
    #: rad/s^2: each arm joint's effort is capped at this times its inertia at the start
    #: pose (:func:`_cap_efforts`); None: the URDF's (with ``choose`` and motor actuators:
    #: :data:`MAX_ACCELERATION`)
    max_acceleration: Optional[float] = None
    gravity_compensation: bool = True
    tip_offset: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    package_paths: Sequence[str] = ()
    visual_meshes: bool = True
    contacts: bool = False
    #: None: :func:`with_defaults` (0.02 s; 0.002 s for undamped motors)
    timestep: Optional[float] = None
    integrator: str = 'implicitfast'
    armature: Optional[float] = None
    damping: Optional[float] = None
    #: each arm joint's damping = effort / velocity limit: an assumption, kept in the model
    velocity_damping: bool = False
    #: joint limits as hard as MuJoCo keeps stable (``solreflimit`` time constant 2 x
    #: ``timestep``, critically damped), a robot's end stop, not MuJoCo's 0.02 s spring;
    #: None: chosen (:func:`with_defaults`: on with ``choose``)
    hard_limits: Optional[bool] = False
    #: position actuators: rad per control step; the actions are changes around the
    #: measured angle (``pg_position_delta``); None: absolute targets over the range
    position_delta: Optional[float] = None
    home: Optional[Sequence[float]] = None
    targets: int = 1000
    target_min_height: Optional[float] = 0.0
    target_region: Optional[Tuple[float, float, float, float]] = None
    init_qpos_noise: float = 0.1
    init_qvel_noise: float = 0.005
    seed: int = 0
    xacro_args: Mapping[str, str] = field(default_factory=dict)
    #: the import chooses what these options leave None from the URDF (``arm import``
    #: does): the start pose, the goal region, hard limits, an armature and a finer
    #: timestep where the check needs them (docs/own_arm.md); False: the plain defaults
    choose: bool = False
    #: the training's randomization (``{term: text}``, as ``randomize_<term>``): the check
    #: runs the model with each term at both ends of its range
    randomization: Mapping[str, str] = field(default_factory=dict)


@dataclass
class ImportResult:
    """The MJCF text, the mesh files it names, and what the import did."""

    xml: str
    arm_joints: List[str]
    fixed_joints: List[str]
    warnings: List[str] = field(default_factory=list)
    n_targets: int = 0
    #: coupled joint -> (its leader, multiplier, offset): URDF ``<mimic>`` on the chain
    coupled_joints: Dict[str, Tuple[str, float, float]] = field(default_factory=dict)
    #: the folder the meshes go to (named by absolute path in ``xml``)
    mesh_dir: Optional[Path] = None
    #: file name in ``mesh_dir`` -> the file to copy, or the converted file's bytes
    mesh_files: Dict[str, Union[Path, bytes]] = field(default_factory=dict)
    converted_meshes: int = 0
    timestep: float = 0.02
    #: coupled joint -> the largest distance from its mimic seen under random commands, rad
    coupling_error: Dict[str, float] = field(default_factory=dict)
    #: the options as the import took them (:func:`with_defaults`)
    options: Optional[ImportOptions] = None
    #: what the import assumes that the URDF does not say (:func:`assumptions`)
    assumptions: List[str] = field(default_factory=list)
    #: what the import chose and why, one line each (custom text ``pg_import_choices``)
    choices: List[str] = field(default_factory=list)
    #: why fewer targets than asked were kept: reason -> how many drawn poses it removed
    rejected: Dict[str, int] = field(default_factory=dict)


#: the default physics step, and the one of a torque-driven arm without damping
TIMESTEP, UNDAMPED_TIMESTEP = 0.02, 0.002


def with_defaults(opts: ImportOptions) -> ImportOptions:
    """
    Return ``opts`` with ``timestep`` and ``hard_limits`` decided where they are None.

    :data:`UNDAMPED_TIMESTEP` for motors with no damping (neither ``damping`` nor
    ``velocity_damping``), else :data:`TIMESTEP`; hard limits on (a robot's end stops).

    >>> with_defaults(ImportOptions(tip='tool0')).timestep
    0.002
    >>> with_defaults(ImportOptions(tip='tool0', actuator='position')).timestep
    0.02
    """
    timestep = opts.timestep
    if timestep is None:
        undamped = (opts.actuator == 'motor' and not opts.velocity_damping
                    and opts.damping is None)
        timestep = UNDAMPED_TIMESTEP if undamped else TIMESTEP
    hard = True if opts.hard_limits is None else opts.hard_limits
    return replace(opts, timestep=timestep, hard_limits=hard)


def assumptions(opts: ImportOptions) -> List[str]:
    """
    Return what a model imported with ``opts`` assumes that the URDF does not say.

    One line each, kept in the model (custom text ``pg_physics_assumptions``) and in the card
    of every policy trained on it.
    """
    out = []
    if opts.velocity_damping:
        out.append('velocity_damping: each arm joint is damped by effort / velocity limit '
                   "(N m s/rad), as if the robot's controller enforced it; a robot in torque "
                   'mode does not')
    elif opts.damping is not None:
        out.append(f'damping: every arm joint is damped by {opts.damping:g} N m s/rad (arm '
                   "import --damping, not the URDF's)")
    if opts.armature is not None:
        out.append(f'armature: every arm joint has {opts.armature:g} kg m^2 of rotor inertia '
                   "(arm import --armature, or the import's choice: pg_import_choices)")
    if opts.gravity_compensation:
        out.append("gravity compensation: the robot cancels the arm's own weight (MuJoCo "
                   'gravcomp on every arm body); a payload it is not told of is not '
                   'cancelled')
    if opts.effort_scale != 1:
        out.append(f'effort: the URDF effort limits x {opts.effort_scale:g} (--effort-scale)')
    if opts.max_acceleration is not None and math.isfinite(opts.max_acceleration):
        out.append(f"effort: each arm joint's effort at most {opts.max_acceleration:g} rad/s^2 x "
                   'its inertia at the start pose (arm import --max-acceleration; '
                   'pg_import_choices names the joints it caps)')
    return out


def training_settings(timestep: float) -> Tuple[int, int]:
    """
    Return ``(frame_skip, max_episode_steps)`` that make a 0.04 s control step, 2 s episodes.

    >>> training_settings(0.02), training_settings(0.002), training_settings(0.01)
    ((2, 50), (20, 50), (4, 50))
    """
    frame_skip = max(1, round(CONTROL_STEP / timestep))
    return frame_skip, max(1, round(EPISODE_SECONDS / (frame_skip * timestep)))


def _one_line(exc: Exception) -> str:
    return '; '.join(line.strip() for line in str(exc).splitlines() if line.strip())


def _check_robot(root: ET.Element, path: Path) -> ET.Element:
    if root.tag != 'robot':
        raise UrdfImportError(f'{path} is not a URDF file: its root element is <{root.tag}>, '
                              'not <robot>')
    if root.find('link') is None:
        raise UrdfImportError(f'{path} is not a URDF file: it has no <link>')
    return root


def is_xacro(path) -> bool:
    """Return whether ``path`` names a xacro file (``.xacro``, e.g. ``robot.urdf.xacro``)."""
    return str(path).lower().endswith('.xacro')


def read_urdf(path) -> ET.Element:
    """Return the ``<robot>`` element of the URDF at ``path``, or raise UrdfImportError."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except OSError as exc:
        raise UrdfImportError(f'cannot read {path}: {exc.strerror}') from None
    except ET.ParseError as exc:
        raise UrdfImportError(f'{path} is not a URDF file: not valid XML ({exc})') from None
    return _check_robot(root, path)


def expand_xacro(path, args: Mapping[str, str] = None, package_paths: Sequence[str] = (),
                 warnings: Optional[List[str]] = None) -> str:
    """
    Return the URDF text of the xacro file at ``path`` with ``args`` (``name -> value``).

    ``$(find NAME)`` names the first folder of :func:`package_dirs` that exists. What xacro
    prints (deprecations and the like) is appended to ``warnings``.
    """
    path = Path(path)
    if not path.is_file():
        raise UrdfImportError(f'cannot read {path}: No such file or directory')
    try:
        import xacro
        import xacro.substitution_args as substitution
    except ImportError:
        raise UrdfImportError(f'{path} is a xacro file and the xacro package is not '
                              f'installed: pip install xacro, or expand it first: xacro '
                              f'{path} > robot.urdf') from None
    original = substitution._eval_find

    def find(package):
        for folder in package_dirs(package, path.parent, package_paths):
            if folder.is_dir():
                return str(folder)
        raise UrdfImportError(f'$(find {package}): package {package!r} not found; looked in: '
                              + ', '.join(str(p) for p in package_dirs(
                                  package, path.parent, package_paths)))

    said = io.StringIO()
    substitution._eval_find = find
    try:
        with contextlib.redirect_stderr(said):
            doc = xacro.process_file(str(path.resolve()), mappings=dict(args or {}))
        text = doc.toxml()
    except UrdfImportError:
        raise
    except Exception as exc:  # noqa: B902 - xacro raises XacroException, ExpatError, NameError...
        reason = _one_line(exc) or type(exc).__name__
        undefined = re.search(r'Undefined substitution argument (\S+)', reason)
        if undefined:
            reason += f' (give it: --xacro-arg {undefined[1].rstrip(";")}:=VALUE)'
        raise UrdfImportError(f'xacro cannot expand {path}: {reason}') from None
    finally:
        substitution._eval_find = original
    if warnings is not None:
        warnings.extend(f'xacro: {line.strip()}' for line in said.getvalue().splitlines()
                        if line.strip())
    return text


def load_robot(path, xacro_args: Mapping[str, str] = None, package_paths: Sequence[str] = (),
               warnings: Optional[List[str]] = None) -> ET.Element:
    """Return the ``<robot>`` of a URDF, or of a xacro file expanded; UrdfImportError else."""
    path = Path(path)
    if not is_xacro(path):
        if xacro_args:
            raise UrdfImportError(f'--xacro-arg is for .xacro files; {path} is not one')
        return read_urdf(path)
    text = expand_xacro(path, xacro_args, package_paths, warnings)
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfImportError(f'{path} expands to invalid XML ({exc})') from None
    return _check_robot(root, path)


def ament_prefixes() -> List[Path]:
    """Return the prefixes of ``AMENT_PREFIX_PATH``, in order."""
    return [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]


def package_dirs(package: str, urdf_dir: Path, package_paths: Sequence[str] = ()
                 ) -> List[Path]:
    """Return the folders package ``package`` may be, in the order they are tried."""
    out = [prefix / 'share' / package for prefix in ament_prefixes()]
    for folder in [Path(p) for p in package_paths] + [urdf_dir, *urdf_dir.parents]:
        out.append(folder / package)
        if folder.name == package:
            out.append(folder)
    return list(dict.fromkeys(out))


def mesh_candidates(uri: str, urdf_dir: Path, package_paths: Sequence[str] = ()) -> List[Path]:
    """Return the files a mesh URI may name, in the order they are tried."""
    if uri.startswith('package://'):
        package, _, rel = uri[len('package://'):].partition('/')
        return [folder / rel for folder in package_dirs(package, urdf_dir, package_paths)]
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


def convert_mesh(source: Path) -> Tuple[bytes, List[str]]:
    """
    Return a binary STL of the mesh file ``source`` (COLLADA, PLY, ...) and notes on it.

    Every triangle of the file, with its node transforms, becomes one mesh; a COLLADA
    ``<unit meter>`` scales it to metres (as rviz does). Raises ValueError when the file
    cannot be read or holds no triangles, ImportError without trimesh (or pycollada).
    """
    import trimesh
    if source.suffix.lower() == '.dae':
        import collada  # noqa: F401 - trimesh reads COLLADA through pycollada
    notes = []
    try:
        mesh = trimesh.load(str(source), force='mesh')
    except Exception as exc:  # noqa: B902 - trimesh and pycollada raise many kinds
        raise ValueError(_one_line(exc) or type(exc).__name__) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError('it holds no triangles')
    if source.suffix.lower() == '.dae':
        unit, up = _collada_asset(source)
        if unit != 1.0:
            mesh.apply_scale(unit)
        if up not in ('Z_UP', None):
            notes.append(f'its up axis is {up}, which is not applied (URDF tools differ on '
                         'it): check the link in a render')
    return mesh.export(file_type='stl'), notes


def _collada_asset(path: Path) -> Tuple[float, Optional[str]]:
    """Return a COLLADA file's ``<unit meter>`` (1 when absent) and ``<up_axis>``."""
    unit, up = 1.0, None
    try:
        for _, elem in ET.iterparse(path):
            tag = elem.tag.rpartition('}')[2]
            if tag == 'unit' and elem.get('meter'):
                unit = float(elem.get('meter'))
            elif tag == 'up_axis':
                up = (elem.text or '').strip()
            elif tag == 'asset':
                break
    except (ET.ParseError, ValueError):
        pass
    return unit, up


class _Meshes:
    """The mesh files of one import: what MuJoCo compiles from, what is copied where."""

    def __init__(self, scratch: Path):
        self.scratch = scratch        # converted files, while the import compiles
        self.compiled = {}            # source -> the path MuJoCo reads
        self.names = {}               # the path MuJoCo reads -> file name in the mesh folder
        self.files = {}               # file name -> source path or converted bytes
        self.converted = 0

    def _name(self, stem: str, suffix: str) -> str:
        name, k = stem + suffix, 1
        while name in self.files:
            k += 1
            name = f'{stem}_{k}{suffix}'
        return name

    def add(self, source: Path, what: str, warnings: List[str]) -> Path:
        """Return the file MuJoCo reads for ``source``; convert it when MuJoCo cannot."""
        if source in self.compiled:
            return self.compiled[source]
        if source.suffix.lower() in MESH_FORMATS:
            name = self._name(source.stem, source.suffix.lower())
            self.files[name] = path = source
        else:
            data, notes = convert_mesh(source)
            name = self._name(source.stem, '.stl')
            self.files[name] = data
            path = self.scratch / name
            path.write_bytes(data)
            self.converted += 1
            warnings.extend(f'{what}: {note}' for note in notes)
        self.compiled[source] = path
        self.names[str(path)] = name
        return path


def _chain(robot: ET.Element, base: Optional[str], tip: str):
    """Return ``(base, root, chain joint names, every joint by name)``; check the links."""
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
    chain = [j.get('name') for j in reversed(path) if j.get('type') in ARM_JOINT_TYPES]
    if not chain:
        raise UrdfImportError(f'no revolute joint between {base!r} and {tip!r}')
    return base, root, chain, joints


def _couplings(chain: List[str], joints: Dict[str, ET.Element]):
    """
    Split the chain's joints into actuated ones and coupled ones (a ``<mimic>`` of an arm joint).

    Returns ``(actuated, {coupled: (leader, multiplier, offset)})``; a mimic whose leader
    is not on the chain (so not moving) is neither, and gets fixed.
    """
    mimics = {}
    for name in chain:
        mimic = joints[name].find('mimic')
        if mimic is not None:
            mimics[name] = (mimic.get('joint'), float(mimic.get('multiplier', 1.0)),
                            float(mimic.get('offset', 0.0)))
    actuated = [name for name in chain if name not in mimics]
    coupled = {}
    grew = True
    while grew:   # a mimic of a mimic of an arm joint is coupled too
        grew = False
        for name, (leader, *_) in mimics.items():
            if name not in coupled and (leader in actuated or leader in coupled):
                coupled[name] = mimics[name]
                grew = True
    if not actuated:
        raise UrdfImportError(f'every revolute joint on the chain mimics another: '
                              f'{", ".join(chain)}')
    return actuated, {name: coupled[name] for name in chain if name in coupled}


def _prepare_meshes(robot: ET.Element, urdf_dir: Path, opts: ImportOptions,
                    warnings: List[str], meshes: _Meshes):
    """Resolve every mesh, convert what MuJoCo cannot read; drop or replace what fails."""
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
                what = f'link {name!r}: {kind} mesh {uri!r}'
                reason = None
                if suffix in MESH_FORMATS + CONVERTED_FORMATS:
                    source = resolve_mesh(uri, urdf_dir, opts.package_paths)
                    try:
                        mesh.set('filename', str(meshes.add(source, what, warnings)))
                        continue
                    except ImportError as exc:
                        reason = (f'is {suffix}, and converting it needs {exc.name} (pip '
                                  'install trimesh pycollada)')
                    except ValueError as exc:
                        reason = f'cannot be converted ({exc})'
                else:
                    reason = f'is {suffix or "no known format"}, which MuJoCo cannot read'
                geometry = elem.find('geometry')
                if kind == 'visual' and collisions:
                    link.remove(elem)
                    warnings.append(f'{what} {reason}; showing the collision geometry instead')
                else:
                    geometry.remove(mesh)
                    ET.SubElement(geometry, 'sphere', radius=str(FALLBACK_SPHERE))
                    warnings.append(f'{what} {reason}; a sphere of radius {FALLBACK_SPHERE} m '
                                    'stands in')


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        raise UrdfImportError(f'MuJoCo cannot compile the robot: {_one_line(exc)}') from None


def _principal_moments(link: ET.Element) -> Optional[np.ndarray]:
    """Return the sorted principal moments of a link's URDF inertia, or None without one."""
    inertia = link.find('inertial/inertia')
    if inertia is None:
        return None
    v = {k: float(inertia.get(k, 0.0)) for k in ('ixx', 'iyy', 'izz', 'ixy', 'ixz', 'iyz')}
    tensor = np.array([[v['ixx'], v['ixy'], v['ixz']], [v['ixy'], v['iyy'], v['iyz']],
                       [v['ixz'], v['iyz'], v['izz']]])
    return np.linalg.eigvalsh(tensor)


def _parse(robot: ET.Element, urdf_path: Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_string(ET.tostring(robot, encoding='unicode'))
    except ValueError as exc:
        raise UrdfImportError(f'MuJoCo cannot read the URDF {urdf_path}: '
                              f'{_one_line(exc)}') from None


def _load_spec(robot: ET.Element, urdf_path: Path, warnings: List[str]):
    """
    Return ``(spec, model)`` of the prepared URDF; balance the inertias MuJoCo rejects.

    A link whose inertia breaks ``A + B >= C`` is balanced (MuJoCo's ``balanceinertia``
    sets its principal moments to their mean) and named in a warning; one that is not
    positive definite is refused in one line.
    """
    spec = _parse(robot, urdf_path)
    try:
        return spec, spec.compile()
    except ValueError as exc:
        text = _one_line(exc)
    found = re.search(r"Element name '([^']*)'", text)
    link = next((link for link in robot.findall('link')
                 if found and link.get('name') == found.group(1)), None)
    if 'positive eigenvalues' in text and link is not None:
        moments = _principal_moments(link)
        raise UrdfImportError(
            f'link {link.get("name")!r}: its <inertia> is not positive definite (principal '
            f'moments {_fmt(moments, 4)} kg m^2): no body has such an inertia and MuJoCo '
            'cannot balance it; fix the URDF')
    if 'balanceinertia' not in text:
        raise UrdfImportError(f'MuJoCo cannot compile the robot: {text}')
    robot.find('mujoco/compiler').set('balanceinertia', 'true')
    spec = _parse(robot, urdf_path)
    model = _compile(spec)
    for link in robot.findall('link'):
        moments = _principal_moments(link)
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, link.get('name'))
        now = np.sort(model.body_inertia[body])
        if (moments is None or body < 0 or moments[0] <= 0 or np.allclose(now, moments, rtol=1e-6)
                or np.ptp(now) > 1e-9 * now.max()):
            continue
        warnings.append(f'link {link.get("name")!r}: MuJoCo rejects its inertia (principal '
                        f'moments {_fmt(moments, 4)} kg m^2 break A + B >= C); balanced to '
                        f'{now[0]:.4g} each (balanceinertia): fix the URDF for the real '
                        'values')
    return spec, model


def _links_below(joints: Dict[str, ET.Element], link: str) -> List[str]:
    """Return ``link`` and every link below it."""
    children = {}
    for j in joints.values():
        children.setdefault(j.find('parent').get('link'), []).append(j.find('child').get('link'))
    out, todo = [], [link]
    while todo:
        out.append(todo.pop())
        todo.extend(children.get(out[-1], []))
    return out


def _mass_warnings(robot: ET.Element, model: mujoco.MjModel, joints: Dict[str, ET.Element],
                   moved: List[str]) -> List[str]:
    """Warn of moving links without mass or inertial, and of joints that move no mass."""
    links = {link.get('name'): link for link in robot.findall('link')}
    first = joints[moved[0]].find('child').get('link')
    from_geometry, zero, mass = [], [], {}
    for name in _links_below(joints, first):
        link = links[name]
        inertial = link.find('inertial')
        geometry = bool(link.findall('collision') or link.findall('visual'))
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if inertial is None:
            mass[name] = float(model.body_mass[body]) if body >= 0 and link.findall(
                'collision') else 0.0
            if mass[name] > BOUND_MASS:
                from_geometry.append(f'{name} ({mass[name]:.3g} kg)')
                continue
        else:
            element = inertial.find('mass')
            mass[name] = float(element.get('value', 0.0)) if element is not None else 0.0
        if mass[name] <= 0 and geometry:
            zero.append(name)
    out = []
    if from_geometry:
        out.append('links without an <inertial>, so MuJoCo weighed their collision geometry '
                   f'at 1000 kg/m^3: {", ".join(from_geometry)}; give them the real mass '
                   'and inertia')
    if zero:
        out.append(f'links with geometry but no mass: {", ".join(zero)}; each weighs '
                   f"{BOUND_MASS} kg (MuJoCo's minimum): right for a marker, wrong for a part")
    for name in moved:
        group = _links_below(joints, joints[name].find('child').get('link'))
        if not any(mass.get(link, 0.0) > 0 for link in group):
            out.append(f'joint {name!r} moves no mass (links {", ".join(group)}): at '
                       f"{BOUND_MASS} kg each (MuJoCo's minimum) it spins up at any torque; "
                       'give them <inertial> elements')
    return out


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


def _fmt(values, digits: int = 6) -> str:
    return ' '.join(f'{v:.{digits}g}' for v in np.asarray(values, dtype=float).ravel())


def default_output(urdf_path, robot: ET.Element) -> str:
    """Return the model file ``arm import`` writes by default: ``<robot name>.xml``."""
    stem = Path(urdf_path).name.split('.')[0]
    return (robot.get('name') or stem) + '.xml'


def import_urdf(urdf_path, opts: ImportOptions, out_path=None, command: str = '',
                robot: Optional[ET.Element] = None) -> ImportResult:
    """
    Return the MJCF of the arm in ``urdf_path`` (docs/own_arm.md says what it holds).

    ``out_path`` (default: ``<robot name>.xml`` beside the URDF) is where the model will be
    written: its meshes go to ``<model>_meshes/`` beside it (:func:`write_model` writes
    both). ``command``, the command line that made the model, is kept as the custom text
    ``pg_import_command`` (an XML comment at the top says so). ``robot``: the URDF's
    ``<robot>`` already read (it is changed), else read from ``urdf_path``.
    """
    urdf_path = Path(urdf_path).resolve() if Path(urdf_path).exists() else Path(urdf_path)
    warnings: List[str] = []
    if robot is None:
        robot = load_robot(urdf_path, opts.xacro_args, opts.package_paths, warnings)
    urdf_dir = urdf_path.parent
    out = Path(out_path).resolve() if out_path else urdf_dir / default_output(urdf_path, robot)
    base, _, chain, joints = _chain(robot, opts.base, opts.tip)
    arm, coupled = _couplings(chain, joints)
    parts = _Robot(urdf=robot, path=urdf_path, base=base, arm=arm, coupled=coupled,
                   joints=joints, warnings=warnings)
    _check_options(parts, opts)
    # a floating or planar joint (a mobile base) is fixed like every other non-arm joint;
    # MuJoCo would refuse a free joint below the URDF's root body anyway
    for j in robot.findall('joint'):
        if j.get('type') in ('floating', 'planar'):
            j.set('type', 'fixed')
            parts.fixed.append(j.get('name'))
    with tempfile.TemporaryDirectory(prefix='pg_node_meshes_') as scratch:
        meshes = _Meshes(Path(scratch))
        _prepare_meshes(robot, urdf_dir, opts, warnings, meshes)
        source = (None if is_xacro(urdf_path) or not urdf_path.is_file()
                  else Path(os.path.relpath(urdf_path, out.parent)).as_posix())
        xml, task, lag, parts, opts = _stable_build(parts, opts, command=command,
                                                    source=source)
    mesh_dir = out.parent / f'{out.stem}_meshes'
    xml = _finish_xml(xml, meshes, mesh_dir, urdf_name=urdf_path.name, command=command)
    return ImportResult(xml=xml, arm_joints=arm, fixed_joints=parts.fixed,
                        warnings=parts.warnings, n_targets=len(task.points),
                        coupled_joints=coupled, mesh_dir=mesh_dir if meshes.files else None,
                        mesh_files=meshes.files, converted_meshes=meshes.converted,
                        timestep=opts.timestep, coupling_error=lag, options=opts,
                        assumptions=assumptions(opts), choices=task.choices,
                        rejected=task.rejected)


@dataclass
class _Robot:
    """
    The robot as the build's steps pass it on: the URDF, its arm, what the steps decide.

    :func:`import_urdf` fills the fields up to ``warnings``; :func:`_mujoco_spec` and
    :func:`_joints` add the joints they fix, and :func:`_joints` the efforts and ranges
    that :func:`_actuators` maps commands over.
    """

    #: the URDF's ``<robot>``, its meshes prepared for MuJoCo's URDF compiler
    urdf: ET.Element
    #: the file it came from (for messages)
    path: Path
    #: the link the arm starts at
    base: str
    #: the actuated joints, in chain order
    arm: List[str]
    #: coupled joint -> (its leader, multiplier, offset): URDF ``<mimic>`` on the chain
    coupled: Dict[str, Tuple[str, float, float]]
    #: every URDF joint by name
    joints: Dict[str, ET.Element]
    warnings: List[str]
    fixed: List[str] = field(default_factory=list)
    #: N m per arm and coupled joint: the URDF's effort limit x ``effort_scale``
    efforts: Dict[str, float] = field(default_factory=dict)
    #: per arm joint (low, high), rad; -pi..pi for a joint without limits
    ranges: Optional[np.ndarray] = None
    #: MuJoCo's first reading of the robot, every joint and contact in it (:func:`_task`'s
    #: kinematics and self-collisions)
    model: Optional[mujoco.MjModel] = None


@dataclass
class _Task:
    """The reaching task the model holds: the start pose and where the goals are."""

    home: np.ndarray
    #: goals within this ball (x, y, z, radius; m), or anywhere the fingertip reaches
    region: Optional[Tuple[float, float, float, float]]
    #: goals at least this high (m), or at any height
    min_height: Optional[float]
    #: the goals, one fingertip position (x y z) a row
    points: Optional[np.ndarray] = None
    #: goals in self-collision are drawn again (with a region the import chose)
    no_self_collision: bool = False
    #: what the import chose and why, one line each (``pg_import_choices``)
    choices: List[str] = field(default_factory=list)
    #: reason -> how many drawn poses it removed from the goals
    rejected: Dict[str, int] = field(default_factory=dict)


def _check_options(robot: _Robot, opts: ImportOptions) -> None:
    """Refuse options that do not fit each other or the robot, in one line."""
    if opts.actuator not in ('motor', 'position', 'velocity'):
        raise UrdfImportError(f'unknown actuator {opts.actuator!r}; use motor, position or '
                              'velocity')
    if opts.actuator == 'velocity':
        slow = [name for name in robot.arm if _velocity_limit(robot.joints[name]) <= 0]
        if slow:
            raise UrdfImportError('--actuator velocity needs a <limit velocity> on every arm '
                                  f'joint; {", ".join(slow)} has none')
    if opts.position_delta is not None and (opts.actuator != 'position'
                                            or not opts.position_delta > 0):
        raise UrdfImportError('--position-delta needs --actuator position and a positive '
                              f'angle in rad, got {opts.position_delta:g} with --actuator '
                              f'{opts.actuator}')
    if opts.home is not None and len(opts.home) != len(robot.arm):
        raise UrdfImportError(f'--home needs {len(robot.arm)} angles (the arm joints '
                              f'{", ".join(robot.arm)}), got {len(opts.home)}')


def _stable_build(robot: _Robot, given: ImportOptions, *, command: str = '',
                  source: Optional[str] = None):
    """
    Return :func:`_build`'s model with physics the check keeps finite, and what it used.

    Returns ``(xml, task, lag, robot, options)``. The options as given first; while the
    model diverges under the check (:func:`diverges`) and ``choose`` leaves them open, an
    armature of :data:`ARMATURES` (the smallest that holds: the motors' rotor inertia, which
    the URDF does not give), then the timestep halved down to :data:`FINEST_TIMESTEP`. None
    holding is refused with the reason; without ``choose`` the divergence is a warning.
    """
    tried = []
    for opts, physics in _physics_candidates(given):
        attempt = replace(robot, warnings=list(robot.warnings), fixed=list(robot.fixed),
                          efforts={})
        xml, task, lag, reason = _build(attempt, opts, physics, command=command,
                                        source=source)
        if reason is None or not given.choose:
            if reason is not None:
                attempt.warnings.append(reason)
            return xml, task, lag, attempt, opts
        tried.append(f'armature {opts.armature or 0:g} kg m^2, timestep {opts.timestep:g} s')
    raise UrdfImportError(f'{reason}; tried {"; ".join(tried)}: give the motors\' real rotor '
                          'inertia (--armature), a smaller --timestep, or --velocity-damping')


#: a joint faster than this (rad/s) under the check's commands has diverged: the vendor
#: arms MuJoCo keeps stable reach 160-650 rad/s under bang-bang torques at their URDF
#: efforts (0.002 s), those that diverge 10^3-10^7 (docs/own_arm.md)
DIVERGED_SPEED = 1000.0
#: the armatures (kg m^2, every arm joint) the import tries, smallest first, while the
#: model diverges; a 7-joint arm's motors reflect 0.1-1 kg m^2 through their gears
ARMATURES = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5)
#: the finest timestep the import tries (s)
FINEST_TIMESTEP = 0.0005


def _physics_candidates(given: ImportOptions):
    """Yield ``(options, the lines saying what was chosen)``, in the order they are tried."""
    opts = with_defaults(given)
    if not given.choose:
        yield opts, []
        return
    if given.max_acceleration is None and given.actuator == 'motor':   # a full command is a
        opts = replace(opts, max_acceleration=MAX_ACCELERATION)          # full torque
    said = []
    if given.hard_limits is None:
        said.append('hard limits: every limited arm joint stops as hard as MuJoCo keeps '
                    "stable (solreflimit 2 x the timestep), as the robot's end stops and "
                    "PyBullet's limits do (--no-hard-limits: MuJoCo's 0.02 s spring)")
    step = ('timestep: {t:g} s, {why}; control step {c:g} s (frame_skip {k}), the '
            "recipe's, 2 s episodes")
    why = ('motors without damping need the finer step'
           if opts.timestep == UNDAMPED_TIMESTEP else 'the default')
    frame_skip = training_settings(opts.timestep)[0]
    timed = [step.format(t=opts.timestep, why=why, c=frame_skip * opts.timestep,
                         k=frame_skip)] if given.timestep is None else []
    yield opts, said + timed
    armatures = ARMATURES if given.armature is None else ()
    for armature in armatures:
        yield replace(opts, armature=armature), said + timed + [
            f'armature: {armature:g} kg m^2 on every arm joint, the smallest of '
            f"{_fmt(ARMATURES)} with which 2 s of full commands under the training's "
            "randomization stay finite (the motors' rotor inertia, which the URDF does "
            'not give; --armature sets it)']
    if given.timestep is None:
        last = replace(opts, armature=armatures[-1]) if armatures else opts
        timestep = opts.timestep / 2
        while timestep >= FINEST_TIMESTEP - 1e-12:
            frame_skip = training_settings(timestep)[0]
            yield replace(last, timestep=timestep), said + [
                step.format(t=timestep, why='the finest that kept full commands finite',
                            c=frame_skip * timestep, k=frame_skip)] + (
                [f'armature: {last.armature:g} kg m^2 on every arm joint'] if armatures
                else [])
            timestep /= 2


def _build(robot: _Robot, opts: ImportOptions, physics: Sequence[str] = (), *,
           command: str = '', source: Optional[str] = None):
    """
    Return the model's MJCF, its task, each coupled joint's lag (rad) and why it diverges.

    MuJoCo compiles three times: to read the robot (:func:`_mujoco_spec`), to place the
    goals (:func:`_targets`: the fingertip's forward kinematics), and once the model is
    complete, for the checks. ``command`` and ``source`` (the vendor's URDF relative to the
    model's folder) become custom texts, ``physics`` (what was chosen) with the task's
    choices ``pg_import_choices``. The reason is None when the model holds.
    """
    spec, model = _mujoco_spec(robot)
    _joints(spec, model, robot, opts)
    task = _task(robot, opts)
    capped = _cap_efforts(spec, robot, task, opts)
    task.choices = task.choices + ([capped] if capped else []) + list(physics)
    _physics(spec, robot, opts)
    _actuators(spec, robot, opts)
    _scene(spec, opts)
    _targets(spec, robot, task, opts)
    _custom(spec, task, opts, command=command, source=source)
    xml = spec.to_xml()
    lag, reason = _checks(_compile(spec), xml, robot, task, opts)
    return xml, task, lag, reason


def _mujoco_spec(robot: _Robot) -> Tuple[mujoco.MjSpec, mujoco.MjModel]:
    """
    Return the spec MuJoCo's URDF compiler makes of the robot, and its model.

    The model is MuJoCo's reading of the URDF: the inertias it balances, the masses it
    gives links without one (warned of here), the joint limits (:func:`_joints`).
    """
    for old in robot.urdf.findall('mujoco'):
        robot.urdf.remove(old)
    ext = ET.Element('mujoco')
    # visuals were dropped when unwanted (_prepare_meshes): MuJoCo's discardvisual would also
    # drop the collision geoms once their contacts are off
    ET.SubElement(ext, 'compiler', fusestatic='false', strippath='false',
                  discardvisual='false', boundmass=str(BOUND_MASS), boundinertia='1e-06')
    robot.urdf.insert(0, ext)
    spec, model = _load_spec(robot.urdf, robot.path, robot.warnings)
    robot.model = model
    robot.warnings.extend(_mass_warnings(robot.urdf, model, robot.joints,
                                         robot.arm + list(robot.coupled)))
    return spec, model


def _joints(spec: mujoco.MjSpec, model: mujoco.MjModel, robot: _Robot,
            opts: ImportOptions) -> None:
    """
    Keep the chain's joints, fix every other; set each kept joint's effort and damping.

    A fixed joint is deleted (its link welded at the joint's zero) with the joint equalities
    (URDF ``<mimic>``) that name it. The arm joints' ranges are read from ``model``, the
    robot as first compiled: nothing here changes a limit.
    """
    keep = set(robot.arm) | set(robot.coupled)
    others = [j.name for j in spec.joints if j.name not in keep]
    for eq in list(spec.equalities):
        if eq.type == mujoco.mjtEq.mjEQ_JOINT and {eq.name1, eq.name2} & set(others):
            spec.delete(eq)
    for name in others:
        spec.delete(spec.joint(name))
    robot.fixed += others
    for name in [*robot.arm, *robot.coupled]:
        joint = spec.joint(name)
        effort = _effort(robot.joints[name], robot.warnings) * opts.effort_scale
        robot.efforts[name] = effort
        if name in robot.arm:
            joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            joint.actfrcrange = [-effort, effort]
        # a coupled joint is damped too: undamped, MuJoCo's soft equality lets it oscillate
        # and, at 0.02 s, blow up
        if opts.armature is not None:
            joint.armature = opts.armature
        if opts.damping is not None:
            joint.damping = [opts.damping, 0.0, 0.0]
        if opts.hard_limits:   # critically damped, as stiff as MuJoCo keeps stable
            joint.solref_limit = [2 * opts.timestep, 1.0]
        if opts.velocity_damping:   # full torque holds the joint at its velocity limit
            velocity = _velocity_limit(robot.joints[name])
            if velocity > 0:
                joint.damping = [effort / velocity, 0.0, 0.0]
            else:
                robot.warnings.append(f'joint {name!r} has no velocity limit; its damping '
                                      'stays')
    ranges = []
    for name in robot.arm:
        j = model.joint(name)
        limited = bool(model.jnt_limited[j.id])
        ranges.append(model.jnt_range[j.id].copy() if limited
                      else np.array([-math.pi, math.pi]))
    robot.ranges = np.array(ranges)


#: ``ImportOptions.integrator`` -> MuJoCo's
INTEGRATORS = {'euler': mujoco.mjtIntegrator.mjINT_EULER,
               'rk4': mujoco.mjtIntegrator.mjINT_RK4,
               'implicit': mujoco.mjtIntegrator.mjINT_IMPLICIT,
               'implicitfast': mujoco.mjtIntegrator.mjINT_IMPLICITFAST}


def _physics(spec: mujoco.MjSpec, robot: _Robot, opts: ImportOptions) -> None:
    """Set the step and integrator, the arm's gravity compensation, contacts off."""
    spec.option.timestep = opts.timestep
    spec.option.integrator = INTEGRATORS[opts.integrator]
    if opts.gravity_compensation:
        for body in _subtree(spec, robot.base):
            body.gravcomp = 1.0
    if not opts.contacts:   # pg_node's reaching task touches nothing
        for geom in spec.geoms:
            geom.contype = 0
            geom.conaffinity = 0


def _actuators(spec: mujoco.MjSpec, robot: _Robot, opts: ImportOptions) -> None:
    """Add one actuator per arm joint, its command normalised to ``[-1, 1]``."""
    for name, (lo, hi) in zip(robot.arm, robot.ranges):
        effort = robot.efforts[name]
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = [-1.0, 1.0]
        if opts.actuator == 'motor':
            act.gear[0] = effort
        elif opts.actuator == 'velocity':
            # MuJoCo's <velocity>: force = kv (vmax u - qdot), clamped to the effort limit
            vmax = _velocity_limit(robot.joints[name])
            kv = opts.velocity_gain or effort / vmax
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm[0] = kv * vmax
            act.biasprm[:3] = [0.0, 0.0, -kv]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-effort, effort]
        else:
            # force = kp * (mid + half * u - q) - kv * qdot, clamped to the effort limit
            mid, half = (lo + hi) / 2, (hi - lo) / 2
            act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.gainprm[0] = opts.kp * half
            act.biasprm[:3] = [opts.kp * mid, -opts.kp, -opts.kv]
            act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.forcerange = [-effort, effort]


def _scene(spec: mujoco.MjSpec, opts: ImportOptions) -> None:
    """Add the ``fingertip`` site, a light and a floor (visual unless ``contacts``)."""
    spec.body(opts.tip).add_site(name='fingertip', pos=list(opts.tip_offset),
                                 size=[0.01, 0, 0], rgba=[0.0, 0.8, 0.6, 1.0])
    world = spec.worldbody
    world.add_light(name='top', pos=[0, 0, 3], dir=[0, 0, -1], diffuse=[0.7, 0.7, 0.7])
    world.add_geom(name='ground', type=mujoco.mjtGeom.mjGEOM_PLANE, size=[2, 2, 0.1],
                   rgba=[0.9, 0.9, 0.9, 1], contype=1 if opts.contacts else 0,
                   conaffinity=1 if opts.contacts else 0)


def _task(robot: _Robot, opts: ImportOptions) -> _Task:
    """
    Return the task: the start pose and the goals' area, as given or chosen.

    ``home`` given is checked against the limits. Without ``choose``: zero within the
    limits, goals anywhere above ``target_min_height``. With it, what is not given is
    chosen from the robot (:func:`_choose_home`, :func:`_choose_region`), each with the
    reason in ``choices``.
    """
    ranges = robot.ranges
    task = _Task(home=None, region=opts.target_region, min_height=opts.target_min_height)
    kin = _Kinematics(robot, opts) if opts.choose else None
    reach = kin.reach(np.random.default_rng(opts.seed)) if kin is not None else None
    if opts.home is not None:
        home = np.array(opts.home, dtype=float)
        if np.any(home < ranges[:, 0]) or np.any(home > ranges[:, 1]):
            raise UrdfImportError(f'--home {_fmt(home)} is outside the joint limits')
    elif kin is not None:
        home, why = _choose_home(kin, reach, opts.seed)
        task.choices.append(f'home: {_fmt(home, 4)} ({why}; --home sets it)')
    else:   # zero, clipped into the limits with room for the start's noise (a Kinova's
        # zero is below three of its limits: on them, the noise started it beyond)
        margin = np.minimum(opts.init_qpos_noise, (ranges[:, 1] - ranges[:, 0]) / 2)
        home = np.clip(0.0, ranges[:, 0] + margin, ranges[:, 1] - margin)
    task.home = home
    if kin is not None and opts.target_region is None:
        task.region, why = _choose_region(kin, home, reach)
        task.no_self_collision = True
        task.choices.append(f'goal region: {_fmt(task.region, 3)} (x y z r, m: {why}; '
                            '--target-region sets it)')
    return task


#: rad/s^2 a full command may give a joint at the start pose (:func:`_cap_efforts`): the
#: Panda's URDF efforts give 30-1800, the UR5's 47-1630 (both learned with them);
#: pybullet_data's iiwa, 300 N m on every joint, 105-27000 (its 0.3 kg last link)
MAX_ACCELERATION = 2000.0


def _cap_efforts(spec: mujoco.MjSpec, robot: _Robot, task: _Task,
                 opts: ImportOptions) -> str:
    """
    Cap each arm joint's effort at ``max_acceleration`` x its inertia at the start pose.

    The inertia is the joint-space mass matrix's diagonal at ``task.home`` (what the joint
    moves, armature included). A URDF that gives a light wrist the shoulder's torque makes
    a full command, and an exploring policy's noise, whip it round; the cap is what a
    policy then commands at most on the robot. Returns the line that says what was capped
    ('' if nothing).
    """
    if opts.max_acceleration is None or not math.isfinite(opts.max_acceleration):
        return ''
    model, data = robot.model, mujoco.MjData(robot.model)
    kin = _Kinematics(robot, opts)
    kin.tip(task.home)
    data.qpos[:] = kin.data.qpos
    mujoco.mj_fwdPosition(model, data)
    inertia = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, inertia)
    capped = []
    for name, dof in zip(robot.arm, kin.dofs):
        cap = opts.max_acceleration * (inertia[dof, dof] + (opts.armature or 0.0))
        urdf = robot.efforts[name]
        if cap < urdf:
            cap = float(f'{cap:.3g}')
            robot.efforts[name] = cap
            spec.joint(name).actfrcrange = [-cap, cap]
            capped.append(f'{name} {cap:g} (URDF {urdf:g})')
    if not capped:
        return ''
    return (f"efforts: capped at {opts.max_acceleration:g} rad/s^2 x each joint's inertia at "
            f'the start pose, N m: {", ".join(capped)}: a full command no longer whips the '
            'light links, and the policy commands no more than this on the robot '
            "(--max-acceleration sets the rate, inf keeps the URDF's)")


#: the start poses tried, drawn in the middle half of every joint's range
HOME_CANDIDATES = 1000
#: the goal region's radius over the arm's reach (the Panda's and the UR5's tuned 0.3 m)
REGION_SHARE = 0.35
#: the start pose's fingertip at least this share of the reach above the base, and as far
#: out from it: goals above a table, in front of the robot
HOME_HEIGHT_SHARE, HOME_OUT_SHARE = 0.2, 0.3
#: a contact deeper than this (m) between links that no joint joins is a self-collision
#: (collision meshes are convex hulls and primitives that overlap where the links do not:
#: the Panda of pg_node's URDF by 7 mm at its ready pose)
COLLISION_DEPTH = 0.01


class _Kinematics:
    """The fingertip, its Jacobian and self-collisions at given arm angles (first model)."""

    def __init__(self, robot: _Robot, opts: ImportOptions):
        model = self.model = robot.model
        self.data = mujoco.MjData(model)
        self.ranges, self.coupled = robot.ranges, robot.coupled
        self.adr = {name: model.joint(name).qposadr[0] for name in [*robot.arm, *robot.coupled]}
        self.arm = robot.arm
        self.dofs = [model.joint(name).dofadr[0] for name in robot.arm]
        self.body = model.body(opts.tip).id
        self.offset = np.array(opts.tip_offset, dtype=float)
        self.base = model.body(robot.base).id
        weld = model.body_weldid
        # bodies that no joint parts move together; a joint's two sides touch at the joint
        self.group = weld
        self.parent_group = weld[model.body_parentid[weld]]
        self.shoulder = model.jnt_bodyid[model.joint(robot.arm[0]).id]

    def tip(self, q) -> np.ndarray:
        """Return the fingertip at arm angles ``q`` (coupled joints on their mimic)."""
        data = self.data
        _set_pose(data, self.adr, self.arm, self.coupled, q)
        mujoco.mj_kinematics(self.model, data)
        return data.xpos[self.body] + data.xmat[self.body].reshape(3, 3) @ self.offset

    def collides(self) -> bool:
        """Return whether two links no joint joins overlap at the angles of :meth:`tip`."""
        model, data = self.model, self.data
        mujoco.mj_collision(model, data)
        for contact in data.contact[:data.ncon]:
            if contact.dist > -COLLISION_DEPTH:
                continue
            a, b = (self.group[model.geom_bodyid[g]] for g in (contact.geom1, contact.geom2))
            if a != b and self.parent_group[a] != b and self.parent_group[b] != a:
                return True
        return False

    def manipulability(self) -> float:
        """
        Return the fingertip's manipulability at :meth:`tip`'s angles.

        The product of the position Jacobian's singular values, as many as it can have
        (3; 2 for a planar arm): zero at a singularity.
        """
        model, data = self.model, self.data
        mujoco.mj_comPos(model, data)
        jacp = np.zeros((3, model.nv))
        point = data.xpos[self.body] + data.xmat[self.body].reshape(3, 3) @ self.offset
        mujoco.mj_jac(model, data, jacp, None, point, self.body)
        values = np.linalg.svd(jacp[:, self.dofs], compute_uv=False)
        return float(np.prod(values[:min(3, len(self.dofs))]))

    def origin(self) -> np.ndarray:
        """Return the base link's and the first arm joint's body's positions (at any angles)."""
        return self.data.xpos[self.base].copy(), self.data.xpos[self.shoulder].copy()

    def reach(self, rng: np.random.Generator, draws: int = 300) -> float:
        """Return the farthest the fingertip gets from the first arm joint's body (m)."""
        lo, hi = self.ranges.T
        out = 0.0
        for q in rng.uniform(lo, hi, (draws, len(self.arm))):
            tip = self.tip(q)
            out = max(out, float(np.linalg.norm(tip - self.data.xpos[self.shoulder])))
        return out


def _choose_home(kin: _Kinematics, reach: float, seed: int) -> Tuple[np.ndarray, str]:
    """
    Return a start pose away from the limits and singularities, and why it was chosen.

    Among :data:`HOME_CANDIDATES` poses drawn in the middle half of every joint's range
    (a quarter of the range from each limit), those without self-collision whose fingertip
    is above the base by :data:`HOME_HEIGHT_SHARE` of the reach and out from it by
    :data:`HOME_OUT_SHARE`; the one of most manipulability (farthest from a singularity).
    Each condition no pose meets is dropped, and the reason says so.
    """
    rng = np.random.default_rng(seed)
    lo, hi = kin.ranges.T
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    poses = mid + rng.uniform(-0.5, 0.5, (HOME_CANDIDATES, len(lo))) * half
    rows = []
    for q in poses:
        tip = kin.tip(q)
        base, shoulder = kin.origin()
        rows.append((not kin.collides(), tip[2] - base[2] >= HOME_HEIGHT_SHARE * reach,
                     np.linalg.norm((tip - shoulder)[:2]) >= HOME_OUT_SHARE * reach,
                     kin.manipulability()))
    free, high, out, score = (np.array(col) for col in zip(*rows))
    for keep, which in (
            (free & high & out, 'without self-collision, the fingertip above the base and '
                                'out in front'),
            (free & high, 'without self-collision, the fingertip above the base (none also '
                          'out in front)'),
            (free, 'without self-collision (none with the fingertip above the base)'),
            (np.ones(len(poses), bool), '(every one in self-collision)')):
        if keep.any():
            break
    best = int(np.argmax(np.where(keep, score, -1.0)))
    why = (f'the one farthest from a singularity (manipulability {score[best]:.3g}) of the '
           f'{int(keep.sum())} of {HOME_CANDIDATES} poses in the middle half of every range '
           f'{which}; reach {reach:.2f} m')
    return np.round(poses[best], 4), why


def _choose_region(kin: _Kinematics, home: np.ndarray, reach: float
                   ) -> Tuple[Tuple[float, ...], str]:
    """Return a goal ball around the start pose's fingertip, and why that one."""
    center = np.round(kin.tip(home), 3)
    radius = round(REGION_SHARE * reach, 3)
    return (*center.tolist(), radius), (f'a ball of {REGION_SHARE:g} x the reach '
                                        f"{reach:.2f} m around the start pose's fingertip; "
                                        'goals in self-collision drawn again')


def _targets(spec: mujoco.MjSpec, robot: _Robot, task: _Task, opts: ImportOptions) -> None:
    """Draw the goals (``task.points``) and add the mocap ``target`` at the first."""
    # compiled here for the fingertip's forward kinematics; the target's place, and so
    # the complete model, waits for the goals
    kin = _Kinematics(robot, opts) if task.no_self_collision else None
    points, task.rejected = _reachable_points(_compile(spec), robot, task, count=opts.targets,
                                              seed=opts.seed, kin=kin)
    if len(points) == 0:
        raise UrdfImportError('no reachable target is left: ' + rejected_text(task.rejected))
    task.points = points
    target = spec.worldbody.add_body(name='target', mocap=True, pos=list(points[0]))
    target.add_geom(name='target', type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.02, 0, 0],
                    rgba=[0.9, 0.2, 0.2, 1], contype=0, conaffinity=0)


def rejected_text(rejected: Mapping[str, int]) -> str:
    """Return why drawn poses gave no goal, e.g. ``'699 below the base plane, 3 ...'``."""
    return ', '.join(f'{n} {why}' for why, n in rejected.items() if n) or 'none rejected'


def _custom(spec: mujoco.MjSpec, task: _Task, opts: ImportOptions, *, command: str,
            source: Optional[str]) -> None:
    """Add the task's numbers (``pg_init_qpos``, ...) and the texts that say where it came from."""
    for name, data in (('pg_init_qpos', task.home),
                       ('pg_init_qpos_noise', [opts.init_qpos_noise]),
                       ('pg_init_qvel_noise', [opts.init_qvel_noise]),
                       ('pg_target_points', task.points.ravel()),
                       *((('pg_position_delta', [opts.position_delta]),)
                         if opts.position_delta is not None else ())):
        spec.add_numeric(name=name, data=list(np.asarray(data, dtype=float)))
    if command:
        spec.add_text(name='pg_import_command', data=command)
    if source:
        spec.add_text(name='pg_source_urdf', data=source)
    if task.choices:
        spec.add_text(name='pg_import_choices', data='\n'.join(task.choices))
    said = assumptions(opts)
    if said:
        spec.add_text(name='pg_physics_assumptions', data='\n'.join(said))


def _checks(model: mujoco.MjModel, xml: str, robot: _Robot, task: _Task,
            opts: ImportOptions) -> Tuple[Dict[str, float], Optional[str]]:
    """
    Warn of what 2 s of hard commands show; return the lags and why the model diverges.

    The reason is None when it does not.

    With ``choose`` or a training randomization, the divergence is :func:`diverges`' (the
    training's task and randomization); else MuJoCo's unstable steps
    (:func:`unstable_steps`), as before issue 55. Velocity servos that chatter past their
    limits, and coupled joints that stray from their ``<mimic>`` (MuJoCo's joint equality
    is soft) are each said in one warning.
    """
    arm, home = robot.arm, task.home
    if opts.choose or opts.randomization:
        reason = diverges(xml, robot, opts)
    else:
        unstable = unstable_steps(model, arm, home, opts)
        times = 'once' if unstable == 1 else f'{unstable} times'
        reason = (f'MuJoCo found the simulation unstable {times} in 2 s of full-torque '
                  f"commands at timestep {opts.timestep:g} s: give the motors' rotor "
                  'inertia (--armature), a smaller --timestep, or --velocity-damping (a '
                  'damping a robot in torque mode lacks)') if unstable else None
    if opts.actuator == 'velocity':
        limits = np.array([_velocity_limit(robot.joints[name]) for name in arm])
        fast = _overspeed(model, arm, home, opts, limits)
        if fast:
            robot.warnings.append(f'velocity servos: under 2 s of full commands {fast} faster '
                                  'than 3 times its velocity limit: the clamped servo force '
                                  "chatters on light links; give the motors' rotor inertia "
                                  '(--armature), a smaller --timestep or a smaller '
                                  '--velocity-gain')
    lag = _coupling_error(model, arm, robot.coupled, home, opts)
    for name, error in lag.items():
        if error > 0.05:
            robot.warnings.append(f'coupled joint {name!r} is up to {error:.2g} rad off its '
                                  "<mimic> under random commands: MuJoCo's joint equality is "
                                  'soft; a smaller --timestep or an --armature tightens it')
    return lag, reason


def randomization_ends(randomization: Mapping[str, str]) -> Dict[str, Dict[str, TermSpec]]:
    """
    Return the training's randomization with every term fixed at its low, then high end.

    ``{'nominal': {}, 'low': {...}, 'high': {...}}``; without terms only the nominal arm.

    >>> ends = randomization_ends({'damping': 'abs uniform 0 0.1'})
    >>> [(k, {t: v.text() for t, v in terms.items()}) for k, terms in ends.items()]
    ... # doctest: +NORMALIZE_WHITESPACE
    [('nominal', {}), ('low', {'damping': 'abs 0 startup'}),
     ('high', {'damping': 'abs 0.1 startup'})]
    """
    terms = parse_terms(randomization)
    out = {'nominal': {}}
    if terms:
        for end, label in ((0, 'low'), (1, 'high')):
            out[label] = {name: replace(term, distribution='uniform', a=term.bounds[end],
                                        b=term.bounds[end], when='startup')
                          for name, term in terms.items()}
    return out


def diverges(xml: str, robot: _Robot, opts: ImportOptions) -> Optional[str]:
    """
    Return why the model diverges under the training it is printed with, or None.

    The training's task (:class:`~pg_node.sim.arm_task.ArmTask` at the recipe's frame_skip,
    4 arms, two 2 s episodes from the start pose and its noise) under bang-bang commands
    (-1 or 1 per actuator every control step, the worst an exploring policy commands), on
    the nominal arm and with every term of ``opts.randomization`` at each end of its
    range: a joint faster than :data:`DIVERGED_SPEED`, or not finite, has diverged.
    """
    from pg_node.sim.arm_task import ArmTask
    frame_skip, steps = training_settings(opts.timestep)
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda text: None)   # said in the one reason
    try:
        with tempfile.TemporaryDirectory(prefix='pg_node_check_') as folder:
            path = Path(folder) / 'check.xml'
            path.write_text(xml)
            for label, terms in randomization_ends(opts.randomization).items():
                task = ArmTask(path, num_envs=4, seed=opts.seed, frame_skip=frame_skip,
                               max_episode_steps=steps, num_threads=1, randomization=terms)
                task.reset()
                rng = np.random.default_rng(opts.seed)
                worst = np.zeros(task.n_joints)
                for step in range(2 * steps):
                    task.step(rng.choice([-1.0, 1.0], (task.num_envs, task.act_dim)))
                    for data in task.datas:
                        speed = np.abs(data.qvel[task.spec.dof_adr])
                        worst = np.maximum(worst, np.nan_to_num(speed, nan=np.inf))
                    if worst.max() > DIVERGED_SPEED:
                        task.close()
                        joint = robot.arm[int(np.argmax(worst))]
                        where = ('the nominal arm' if label == 'nominal' else
                                 f'the randomization at its {label} ends ('
                                 + ', '.join(f'{t} {v.text().rsplit(" ", 1)[0]}'
                                             for t, v in terms.items()) + ')')
                        return (f"MuJoCo diverges under the training's commands: joint "
                                f'{joint!r} passes {DIVERGED_SPEED:g} rad/s within '
                                f'{step + 1} control steps of bang-bang commands on {where}, '
                                f'timestep {opts.timestep:g} s, frame_skip {frame_skip}, '
                                f'armature {opts.armature or 0:g} kg m^2')
                task.close()
    finally:
        mujoco.set_mju_user_warning(previous)
    return None


def _finish_xml(xml: str, meshes: _Meshes, mesh_dir: Path, *, urdf_name: str,
                command: str) -> str:
    """Return ``xml`` naming its meshes by absolute path in ``mesh_dir``, with its header."""
    for compiled, name in meshes.names.items():   # absolute paths: load from anywhere
        xml = xml.replace(f'file="{escape(compiled, {chr(34): "&quot;"})}"',
                          f'file="{escape(str(mesh_dir / name), {chr(34): "&quot;"})}"')
    if command:
        note = (f'  Its meshes are in {mesh_dir.name}/ beside it, named by absolute path:\n'
                '  import again to move them.\n' if meshes.files else '')
        xml = ('<!--\n  Written by python -m pg_node arm import from ' + urdf_name
               + '; the exact command is the\n  custom text pg_import_command below. Do not '
               'edit: change the URDF or the options\n  and import again.\n' + note + '-->\n'
               + xml)
    return xml


def _overspeed(model: mujoco.MjModel, arm: List[str], home: np.ndarray, opts: ImportOptions,
               limits: np.ndarray) -> str:
    """Return the arm joints that bang-bang commands drive past 3x their limit ('' if none)."""
    frame_skip, steps = training_settings(opts.timestep)
    data = mujoco.MjData(model)
    data.qpos[[model.joint(name).qposadr[0] for name in arm]] = home
    dofs = [model.joint(name).dofadr[0] for name in arm]
    rng = np.random.default_rng(opts.seed)
    worst = np.zeros(len(arm))
    for _ in range(steps):
        data.ctrl[:] = rng.choice([-1.0, 1.0], model.nu)
        mujoco.mj_step(model, data, nstep=frame_skip)
        worst = np.maximum(worst, np.nan_to_num(np.abs(data.qvel[dofs]), nan=np.inf))
    return ', '.join(f'{name} ({w:.3g} rad/s)' for name, w, v in zip(arm, worst, limits)
                     if w > 3 * v)


def _velocity_limit(joint: ET.Element) -> float:
    """Return a URDF joint's ``<limit velocity>`` in rad/s (0 when it has none)."""
    limit = joint.find('limit')
    return float(limit.get('velocity', 0)) if limit is not None else 0.0


def unstable_steps(model: mujoco.MjModel, arm: List[str], home: np.ndarray,
                   opts: ImportOptions) -> int:
    """
    Return how often MuJoCo reset the arm as unstable under 2 s of full-torque commands.

    From the start pose, a command of -1 or 1 per actuator drawn at every control step (the
    frame_skip of :func:`training_settings`), the worst an exploring policy commands;
    MuJoCo counts ``mjWARN_BADQACC`` when it resets a diverged simulation.
    """
    frame_skip, steps = training_settings(opts.timestep)
    data = mujoco.MjData(model)
    data.qpos[[model.joint(name).qposadr[0] for name in arm]] = home
    rng = np.random.default_rng(opts.seed)
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(lambda text: None)   # counted here, said in one warning
    try:
        for _ in range(steps):
            data.ctrl[:] = rng.choice([-1.0, 1.0], model.nu)
            mujoco.mj_step(model, data, nstep=frame_skip)
    finally:
        mujoco.set_mju_user_warning(previous)
    return int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)


def _coupling_error(model: mujoco.MjModel, arm: List[str],
                    coupled: Mapping[str, Tuple[str, float, float]], home: np.ndarray,
                    opts: ImportOptions) -> Dict[str, float]:
    """
    Return how far each coupled joint gets from its mimic (rad) under random commands.

    2 s from the start pose, a uniform random command every control step (the frame_skip
    of :func:`training_settings`): MuJoCo's joint equality is soft, so a coupled joint
    lags its leader when the arm accelerates hard.
    """
    if not coupled:
        return {}
    frame_skip, steps = training_settings(opts.timestep)
    data = mujoco.MjData(model)
    adr = {name: model.joint(name).qposadr[0] for name in [*arm, *coupled]}
    _set_pose(data, adr, arm, coupled, home)
    rng = np.random.default_rng(opts.seed)
    worst = dict.fromkeys(coupled, 0.0)
    for _ in range(steps):
        data.ctrl[:] = rng.uniform(-1.0, 1.0, model.nu)
        mujoco.mj_step(model, data, nstep=frame_skip)
        for name, (leader, multiplier, offset) in coupled.items():
            error = abs(data.qpos[adr[name]] - offset - multiplier * data.qpos[adr[leader]])
            worst[name] = max(worst[name], float(error) if np.isfinite(error) else math.inf)
    return worst


def write_model(result: ImportResult, out_path) -> None:
    """Write the model to ``out_path`` and its meshes to ``result.mesh_dir`` (OSError)."""
    if result.mesh_files:
        result.mesh_dir.mkdir(exist_ok=True)   # not its parents: the model's folder must exist
        for name, data in result.mesh_files.items():
            dest = result.mesh_dir / name
            if isinstance(data, bytes):
                dest.write_bytes(data)
            elif not (dest.exists() and dest.samefile(data)):
                shutil.copyfile(data, dest)
    Path(out_path).write_text(result.xml)


def _set_pose(data: mujoco.MjData, qpos: Mapping[str, int], arm: Sequence[str],
              coupled: Mapping[str, Tuple[str, float, float]], q) -> None:
    """
    Set the arm joints of ``data`` to the angles ``q`` and each coupled joint on its mimic.

    ``qpos``: each arm and coupled joint's address in ``qpos``; ``coupled``: joint ->
    (leader, multiplier, offset), in chain order, so that a mimic of a mimic settles in as
    many passes as there are coupled joints.
    """
    for name, value in zip(arm, q):
        data.qpos[qpos[name]] = value
    for _ in coupled:
        for name, (leader, multiplier, offset) in coupled.items():
            data.qpos[qpos[name]] = offset + multiplier * data.qpos[qpos[leader]]


def _reachable_points(model: mujoco.MjModel, robot: _Robot, task: _Task, *, count: int,
                      seed: int, kin: Optional[_Kinematics] = None):
    """
    Return up to ``count`` goals, fingertip positions at uniform angles within the limits.

    Coupled joints follow their mimic; a point below ``task.min_height``, outside
    ``task.region`` or (with ``kin``) at a pose in self-collision is drawn again (at most
    50 draws a goal). Rounded to 0.1 mm. Returns ``(points, {reason: poses it removed})``.
    """
    arm, coupled, ranges = robot.arm, robot.coupled, robot.ranges
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(model)
    site = model.site('fingertip').id
    qpos = {name: model.joint(name).qposadr[0] for name in [*arm, *coupled]}
    keep = []
    tries = 0
    low = ('below the base plane' if task.min_height == 0
           else f'below z = {task.min_height:g} m')
    rejected = {low: 0, 'outside the goal region': 0, 'in self-collision': 0}
    while len(keep) < count and tries < 50 * count:
        tries += 1
        q = rng.uniform(ranges[:, 0], ranges[:, 1])
        _set_pose(data, qpos, arm, coupled, q)
        mujoco.mj_kinematics(model, data)
        p = data.site_xpos[site].copy()
        if task.min_height is not None and p[2] < task.min_height:
            rejected[low] += 1
            continue
        if task.region is not None:
            center, radius = np.array(task.region[:3]), task.region[3]
            if np.linalg.norm(p - center) > radius:
                rejected['outside the goal region'] += 1
                continue
        if kin is not None:
            kin.tip(q)
            if kin.collides():
                rejected['in self-collision'] += 1
                continue
        keep.append(p)
    return np.round(np.array(keep).reshape(-1, 3), 4), rejected
