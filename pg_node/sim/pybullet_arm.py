"""
An arm in PyBullet, loaded from the robot's own URDF: a second physics engine (no ROS here).

pg_node trains in MuJoCo on its own conversion of the robot (:mod:`pg_node.sim.urdf_import`);
:class:`PybulletArm` reads the vendor's URDF itself with PyBullet (Bullet's Featherstone
multibody), so that a policy can be tried on an engine and a model reading pg_node had no
hand in (docs/sim_to_sim.md). What it takes from the URDF and what it decides:

* **the URDF as shipped**: links, joints, inertias (``URDF_USE_INERTIA_FROM_FILE``), limits
  and ``<dynamics damping>``; a link without ``<inertial>`` (a frame such as ``tool0``) gets
  MuJoCo's minimum mass (0.001 kg, 1e-6 kg m^2), not PyBullet's default of 1 kg and
  1 kg m^2, which hangs a kilogram on the tip (seen: the two-link fixture's fingertip
  frame); ``package://`` and ``file://`` meshes are rewritten to the files
  :func:`pg_node.sim.urdf_import.resolve_mesh` finds (as ``arm import`` finds them), a mesh
  that is not found is dropped (contacts are off: the reaching task has none). Moving joints
  that are not arm joints (a gripper, a mimic) are fixed at zero, as ``arm import`` does.
* **the base fixed** at the world origin, the root link's frame where MuJoCo puts it.
* **joints by name**: commands and states are in the order of ``joints``.
* **commands in SI**, as ros2_control's interfaces take them: ``effort`` (N m, clamped to
  the URDF's ``<limit effort>``), ``position`` (rad) and ``velocity`` (rad/s), the last two
  by PyBullet's joint motors with the effort limit as their force (and ``<limit velocity>``
  as the position motor's speed). PyBullet gives every joint a velocity motor by default;
  it is switched off (zero force) before torque control, or it would brake every joint.
* **gravity compensation** (``gravity_compensation``): the arm's weight at the current
  angles (PyBullet's inverse dynamics at zero velocity and acceleration), computed anew
  every ``compensation_period``, is added to every effort command, as a torque robot's
  firmware does; off, the command must hold the arm.
* **no extra damping**: PyBullet's default link damping (0.04) is set to zero, so the only
  damping is the URDF's.
* **the physics step**: a control period is split into equal steps (:func:`substeps`) no
  longer than :data:`MAX_TIMESTEP` nor than :meth:`PybulletArm.stable_timestep`: PyBullet
  integrates the URDF's joint damping explicitly, where MuJoCo's ``implicitfast`` does it
  implicitly, so a strongly damped light joint needs a far shorter step in PyBullet.

Errors reading the URDF are :class:`PybulletError`, one line.
"""
import contextlib
import math
import os
from pathlib import Path
import sys
import tempfile
from typing import List, Optional, Sequence, Tuple
import xml.etree.ElementTree as ET

import numpy as np
from pg_node.sim.urdf_import import BOUND_MASS, resolve_mesh, UrdfImportError

#: the longest physics step :func:`substeps` gives (PyBullet's default step, 1/240 s)
MAX_TIMESTEP = 1.0 / 240.0
MODES = ('effort', 'position', 'velocity')
#: how often gravity compensation is updated: a torque robot's firmware loop (libfranka and
#: the UR's RTDE run at 1 kHz and 500 Hz)
COMPENSATION_PERIOD = 0.001


@contextlib.contextmanager
def _quiet():
    """Silence what Bullet's C code prints on stdout (build time, importer warnings)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, 'w') as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class PybulletError(ValueError):
    """A URDF or a command PyBullet cannot take; the message says why, in one line."""


def substeps(control_period: float, max_timestep: float = MAX_TIMESTEP) -> Tuple[int, float]:
    """
    Return ``(n, timestep)``: ``n`` equal physics steps of at most ``max_timestep`` a period.

    >>> substeps(0.04)
    (10, 0.004)
    >>> substeps(0.002)
    (1, 0.002)
    """
    n = max(1, math.ceil(control_period / max_timestep - 1e-9))
    return n, control_period / n


def prepare_urdf(urdf_path, joints: Sequence[str], package_paths: Sequence[str] = ()
                 ) -> Tuple[str, List[str]]:
    """
    Return the URDF text PyBullet loads, and warnings: meshes resolved, other joints fixed.

    Raises :class:`PybulletError` if the file does not parse or lacks one of ``joints``.
    """
    path = Path(urdf_path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise PybulletError(f'{path}: {" ".join(str(exc).split())}') from None
    warnings = []
    by_name = {j.get('name'): j for j in root.iter('joint') if j.get('name')}
    missing = [j for j in joints if j not in by_name]
    if missing:
        raise PybulletError(f'{path.name} has no joint {", ".join(missing)}')
    for name, joint in by_name.items():
        if name not in joints and joint.get('type') not in ('fixed', None):
            joint.set('type', 'fixed')
            for tag in ('mimic', 'limit'):
                for element in joint.findall(tag):
                    joint.remove(element)
    massless = []
    for link in root.iter('link'):
        if link.find('inertial') is None:
            massless.append(link.get('name'))
            inertial = ET.SubElement(link, 'inertial')
            ET.SubElement(inertial, 'mass', value=str(BOUND_MASS))
            ET.SubElement(inertial, 'inertia', ixx='1e-6', iyy='1e-6', izz='1e-6', ixy='0',
                          ixz='0', iyz='0')
        for tag in ('visual', 'collision'):
            for element in link.findall(tag):
                mesh = element.find('geometry/mesh')
                if mesh is None:
                    continue
                try:
                    mesh.set('filename', str(resolve_mesh(mesh.get('filename', ''),
                                                          path.resolve().parent, package_paths)))
                except UrdfImportError as exc:
                    warnings.append(f'link {link.get("name")!r}: {exc}; its {tag} is dropped')
                    link.remove(element)
    if massless:
        warnings.append(f'links without <inertial> ({", ".join(massless)}) get '
                        f'{BOUND_MASS:g} kg, as in MuJoCo, not the 1 kg PyBullet gives them')
    return ET.tostring(root, encoding='unicode'), warnings


class PybulletArm:
    """One arm of ``joints`` from ``urdf_path`` in a PyBullet world of its own (DIRECT)."""

    def __init__(self, urdf_path, joints: Sequence[str], control_period: float,
                 max_timestep: Optional[float] = None, gravity_compensation: bool = False,
                 gravity=(0.0, 0.0, -9.81), package_paths: Sequence[str] = (),
                 compensation_period: float = COMPENSATION_PERIOD):
        """
        Load the URDF (see the module docstring); raise PybulletError if it cannot.

        :meth:`step` advances ``control_period`` s in equal physics steps no longer than
        ``max_timestep`` (None: :data:`MAX_TIMESTEP` or :meth:`stable_timestep`, the shorter).
        ``compensation_period``: how often the gravity torque is computed anew (s).
        """
        with _quiet():
            import pybullet
            from pybullet_utils.bullet_client import BulletClient
        self.pb = pybullet
        self.joint_names = tuple(joints)
        self.gravity_compensation = bool(gravity_compensation)
        self.gravity = tuple(float(g) for g in gravity)
        self.payload = None             # (link, offset, kg): set_payload
        text, self.warnings = prepare_urdf(urdf_path, self.joint_names, package_paths)
        with _quiet():
            self.client = BulletClient(connection_mode=pybullet.DIRECT)
        c = self.client
        c.setGravity(*gravity)
        # a file beside none: mesh paths are absolute now
        with tempfile.NamedTemporaryFile('w', suffix='.urdf') as f:
            f.write(text)
            f.flush()
            try:
                with _quiet():
                    self.body = c.loadURDF(f.name, useFixedBase=True,
                                           flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
            except pybullet.error as exc:
                c.disconnect()
                raise PybulletError(f'PyBullet cannot load {Path(urdf_path).name}: '
                                    f'{exc}') from None
        index = {}
        for j in range(c.getNumJoints(self.body)):
            info = c.getJointInfo(self.body, j)
            index[info[1].decode()] = info
            c.changeDynamics(self.body, j, linearDamping=0.0, angularDamping=0.0)
        c.changeDynamics(self.body, -1, linearDamping=0.0, angularDamping=0.0)
        self.links = {info[12].decode(): j for j, info in
                      ((info[0], info) for info in index.values())}
        infos = [index[name] for name in self.joint_names]
        for info in infos:
            if info[2] != pybullet.JOINT_REVOLUTE:
                raise PybulletError(f'joint {info[1].decode()} is not revolute or continuous '
                                    'in PyBullet')
        self.ids = [int(info[0]) for info in infos]
        #: every moving joint is an arm joint (the others were fixed): PyBullet's dof order
        self.dof_ids = [j for j in range(c.getNumJoints(self.body))
                        if c.getJointInfo(self.body, j)[2] != pybullet.JOINT_FIXED]
        self._dof_index = [self.dof_ids.index(j) for j in self.ids]
        self.damping = np.array([info[6] for info in infos])
        self.friction = np.array([info[7] for info in infos])
        low, high = np.array([info[8] for info in infos]), np.array([info[9] for info in infos])
        limited = high > low    # PyBullet reads a continuous joint as 0..-1
        self.limited = limited
        self.lower = np.where(limited, low, -np.inf)
        self.upper = np.where(limited, high, np.inf)
        self.effort_limit = np.array([info[10] if info[10] > 0 else np.inf for info in infos])
        self.velocity_limit = np.array([info[11] if info[11] > 0 else np.inf for info in infos])
        n = len(self.ids)
        # PyBullet's default velocity motors (force 0 switches them off: free joints)
        c.setJointMotorControlArray(self.body, self.ids, pybullet.VELOCITY_CONTROL,
                                    targetVelocities=[0.0] * n, forces=[0.0] * n)
        self.applied = np.zeros(n)
        if max_timestep is None:
            max_timestep = min(MAX_TIMESTEP, self.stable_timestep(np.zeros(n)))
        self.control_period = float(control_period)
        self.substeps, self.timestep = substeps(self.control_period, max_timestep)
        c.setTimeStep(self.timestep)
        self._compensate_every = max(1, int(round(compensation_period / self.timestep)))

    def stable_timestep(self, q) -> float:
        """
        Return the longest physics step that keeps the URDF's joint damping stable at ``q``.

        PyBullet applies joint damping explicitly: a step ``dt`` longer than ``2 / lambda``,
        ``lambda`` the largest eigenvalue of ``M(q)^-1 B`` (mass matrix, damping), makes the
        damped velocity overshoot and grow (seen: the two-link fixture, 1 N m s/rad on
        1.3e-4 kg m^2, flipping between +-100 rad/s at 1e-4 s). The step returned is half
        that bound; infinite without damping.
        """
        if not np.any(self.damping > 0):
            return math.inf
        states = self.client.getJointStates(self.body, self.dof_ids)
        full = [s[0] for s in states]
        for k, value in zip(self._dof_index, q):
            full[k] = float(value)
        mass = np.array(self.client.calculateMassMatrix(self.body, full))
        mass = mass[np.ix_(self._dof_index, self._dof_index)]
        lam = np.max(np.real(np.linalg.eigvals(np.linalg.solve(mass, np.diag(self.damping)))))
        return 1.0 / lam

    def close(self):
        """Disconnect from the physics server."""
        if self.client is not None:
            self.client.disconnect()
            self.client = None

    def masses(self) -> dict:
        """Return every link's mass (kg) by link name, the base's under its own name."""
        c = self.client
        base = c.getBodyInfo(self.body)[0].decode()
        out = {base: float(c.getDynamicsInfo(self.body, -1)[0])}
        for name, j in self.links.items():
            out[name] = float(c.getDynamicsInfo(self.body, j)[0])
        return out

    def set_state(self, q, qdot=None):
        """Put the arm joints at angles ``q`` (rad) and velocities ``qdot`` (rad/s)."""
        qdot = np.zeros(len(self.ids)) if qdot is None else qdot
        for j, a, v in zip(self.ids, q, qdot):
            self.client.resetJointState(self.body, j, float(a), float(v))
        self.applied[:] = 0.0

    def state(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return ``(position, velocity, effort)`` of the arm joints (rad, rad/s, N m)."""
        states = self.client.getJointStates(self.body, self.ids)
        return (np.array([s[0] for s in states]), np.array([s[1] for s in states]),
                self.applied.copy())

    def gravity_torque(self) -> np.ndarray:
        """Return the torque that holds the arm still where it is (N m), by inverse dynamics."""
        states = self.client.getJointStates(self.body, self.dof_ids)
        q = [s[0] for s in states]
        zero = [0.0] * len(q)
        tau = self.client.calculateInverseDynamics(self.body, q, zero, zero)
        return np.asarray(tau)[self._dof_index]

    def step(self, command, mode: str = 'effort', periods: int = 1):
        """
        Hold ``command`` (one value per arm joint, SI units of ``mode``) ``periods`` periods.

        ``effort``: N m, plus the arm's weight under gravity compensation, clamped to the
        effort limits and applied anew at every step (PyBullet clears applied torques).
        ``position`` / ``velocity``: targets of PyBullet's joint motors, their force the
        effort limit (a position target is clamped into the joint's limits).
        """
        if mode not in MODES:
            raise PybulletError(f'unknown mode {mode!r}; use one of {", ".join(MODES)}')
        cmd = np.asarray(command, dtype=float)
        if cmd.shape != (len(self.ids),) or not np.all(np.isfinite(cmd)):
            raise PybulletError(f'a command needs {len(self.ids)} finite values')
        c, pb = self.client, self.pb
        force = np.where(np.isfinite(self.effort_limit), self.effort_limit, 1e6)
        if mode == 'position':
            target = np.clip(cmd, self.lower, self.upper)
            for j, a, f, v in zip(self.ids, target, force, self.velocity_limit):
                c.setJointMotorControl2(self.body, j, pb.POSITION_CONTROL, targetPosition=a,
                                        force=f, maxVelocity=v if np.isfinite(v) else 1e6)
        elif mode == 'velocity':
            c.setJointMotorControlArray(self.body, self.ids, pb.VELOCITY_CONTROL,
                                        targetVelocities=cmd.tolist(), forces=force.tolist())
        weight = np.zeros(len(self.ids))
        for k in range(int(periods) * self.substeps):
            if self.payload is not None:
                self._pull_payload()
            if mode == 'effort':
                if self.gravity_compensation and k % self._compensate_every == 0:
                    weight = self.gravity_torque()
                self.applied = np.clip(cmd + weight, -self.effort_limit, self.effort_limit)
                c.setJointMotorControlArray(self.body, self.ids, pb.TORQUE_CONTROL,
                                            forces=self.applied.tolist())
            c.stepSimulation()
        if mode != 'effort':
            states = c.getJointStates(self.body, self.ids)
            self.applied = np.array([s[3] for s in states])

    def set_payload(self, link: str, offset, kg: float) -> None:
        """
        Hang ``kg`` at the point ``offset`` of ``link`` that the arm's own model lacks.

        Its weight pulls there at every physics step as an external force, so
        :meth:`gravity_torque` (the URDF's masses) does not know it: the gravity
        compensation's error that ``randomize_payload`` trains for (and MuJoCo's
        ``--perturb payload``, :mod:`pg_node.common.perturbations`). 0 kg removes it.
        """
        if link not in self.links:
            raise PybulletError(f'the URDF has no moving link {link!r} to hang a payload on')
        if not np.isfinite(kg) or kg < 0:
            raise PybulletError(f'a payload is a mass in kg >= 0, not {kg!r}')
        self.payload = (link, np.asarray(offset, dtype=float), float(kg)) if kg else None

    def _pull_payload(self):
        link, offset, kg = self.payload
        force = (kg * np.asarray(self.gravity)).tolist()
        self.client.applyExternalForce(self.body, self.links[link], force,
                                       self.link_position(link, offset).tolist(),
                                       self.pb.WORLD_FRAME)

    def link_position(self, link: str, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Return the world position (m) of a point ``offset`` in link ``link``'s URDF frame."""
        c = self.client
        if link in self.links:
            state = c.getLinkState(self.body, self.links[link], computeForwardKinematics=True)
            pos, orn = state[4], state[5]
        elif link == c.getBodyInfo(self.body)[0].decode():
            pos, orn = c.getBasePositionAndOrientation(self.body)
        else:
            raise PybulletError(f'the URDF has no link {link!r}')
        rot = np.array(c.getMatrixFromQuaternion(orn)).reshape(3, 3)
        return np.asarray(pos) + rot @ np.asarray(offset, dtype=float)


def urdf_of(model_text: Optional[str]) -> Optional[str]:
    """Return the URDF path in a ``pg_import_command`` text (``arm import URDF ...``), or None."""
    if not model_text:
        return None
    import shlex
    words = shlex.split(model_text)
    if 'import' not in words:
        return None
    rest = words[words.index('import') + 1:]
    return next((w for w in rest if not w.startswith('-')), None)


def robot_urdf(model, name: str, given: Optional[str] = None) -> str:
    """
    Return the URDF PyBullet loads for ``model``: ``given``, or the one it was imported from.

    ``name`` names the model in messages. Raises PybulletError, in one line, where there is
    none: the model was not made by ``arm import`` and no URDF was given, or the file is not
    there.
    """
    urdf = given or model_urdf(model)
    if not urdf:
        raise PybulletError(f'{name} was not made by arm import; give the URDF')
    if not Path(urdf).is_file():
        raise PybulletError(f'no URDF {urdf}' + ('' if given else ' (give the URDF)'))
    return str(urdf)


def model_urdf(model) -> Optional[str]:
    """Return the URDF an ``arm import`` model (``mujoco.MjModel``) was made from, or None."""
    import mujoco
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, 'pg_import_command')
    if i < 0:
        return None
    adr, size = model.text_adr[i], model.text_size[i]
    return urdf_of(bytes(model.text_data[adr:adr + size - 1]).decode())
