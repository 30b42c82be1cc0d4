"""
A URDF written from a MuJoCo arm model, for ``robot_description`` (no ROS here).

ROS tools (``robot_state_publisher``, RViz's RobotModel, Foxglove's URDF panel) take a
robot as a URDF. The hand-written arms (``reacher2``, ``arm5_3d``, ``arm7``) have none, so
:func:`export_urdf` writes one from the model:

* **links**: the root link ``world`` (MuJoCo's world body: the scene's fixed frame), then
  one link per body of the arm (every body below a child of the world that holds an arm
  joint; the target is no part of it), named as the body. A link's frame is its body's
  orientation at zero joint angles, placed at its joint's anchor (at the body's origin for
  a body without a joint), so that the URDF joint turns about the link's origin as
  MuJoCo's hinge turns about its anchor.
* **joints**: a hinge is ``revolute`` (limited) or ``continuous``, a slide ``prismatic``,
  named as in MuJoCo (what ``sim_node``'s joint states carry); a body without a joint is
  attached ``fixed``. A body with several joints is refused (:class:`UrdfExportError`).
* the **fingertip** site as a fixed link ``fingertip`` (``fingertip_site`` if a body has
  that name), so that TF has the point the task measures.
* **visuals** from the geoms, in their colours: sphere, box and cylinder as such, a
  capsule as a cylinder and two spheres, an ellipsoid as a box around it; planes and
  meshes are left out (a URDF mesh needs a file a viewer can fetch).
* **inertials** and the joint limits (``effort`` the largest torque of the joint's
  actuator) as the model has them.

:func:`robot_description` is what ``sim_node`` publishes: the vendor's URDF, as it is,
when the model names one in its custom text ``pg_source_urdf`` (``arm import`` writes it
relative to the model's folder, :mod:`pg_node.sim.urdf_import`; an absolute path is taken
as such), else the URDF written here (hand-written arms, an arm imported from a xacro, or
the vendor's file not found: then :attr:`Description.problem` says why, in one line).

Kinematics are MuJoCo's at every joint angle: :func:`pg_node.sim.kinematics_check.
compare_kinematics` takes the result with zero deviation (``test/test_urdf_export.py``).
"""
import math
import os
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional, Tuple
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
from pg_node.sim.actuation import force_limit
from pg_node.sim.arm_task import ArmSpec

ROOT = 'world'


class UrdfExportError(ValueError):
    """A model this exporter cannot write as a URDF; the message says why, in one line."""


def rpy(rot: np.ndarray) -> Tuple[float, float, float]:
    """
    Return URDF's roll, pitch, yaw of a rotation matrix (``R = Rz(yaw) Ry(pitch) Rx(roll)``).

    >>> [round(a, 6) for a in rpy(np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]]))]
    [0.0, -0.0, 1.570796]
    """
    pitch = math.asin(-max(-1.0, min(1.0, rot[2, 0])))
    if abs(rot[2, 0]) < 1 - 1e-9:
        roll = math.atan2(rot[2, 1], rot[2, 2])
        yaw = math.atan2(rot[1, 0], rot[0, 0])
    else:                               # gimbal lock: put it all in yaw
        roll = 0.0
        yaw = math.atan2(-rot[0, 1], rot[1, 1])
    return roll, pitch, yaw


def _num(values) -> str:
    return ' '.join(f'{float(v):.9g}' for v in values)


def _origin(parent: ET.Element, pos, rot) -> None:
    ET.SubElement(parent, 'origin', xyz=_num(np.where(np.abs(pos) < 1e-12, 0.0, pos)),
                  rpy=_num(np.where(np.abs(rpy(rot)) < 1e-12, 0.0, rpy(rot))))


def _relative(frame: Tuple[np.ndarray, np.ndarray], pos, rot):
    """Return the pose ``(pos, rot)`` (world) in ``frame`` (world ``(pos, rot)``)."""
    p, r = frame
    return r.T @ (np.asarray(pos) - p), r.T @ np.asarray(rot)


def arm_bodies(model: mujoco.MjModel, spec: Optional[ArmSpec] = None) -> List[int]:
    """Return the arm's bodies in tree order: every body under a world child with an arm joint."""
    spec = spec or ArmSpec.from_model(model)
    roots = set()
    for j in spec.joint_ids:
        b = int(model.jnt_bodyid[j])
        while model.body_parentid[b] != 0:
            b = int(model.body_parentid[b])
        roots.add(b)
    out = []
    for b in range(1, model.nbody):
        top = b
        while model.body_parentid[top] != 0:
            top = int(model.body_parentid[top])
        if top in roots:
            out.append(b)
    return out


def _visuals(link: ET.Element, model, data, geoms, frame, materials: Dict[tuple, str]):
    for g in geoms:
        kind, size = model.geom_type[g], model.geom_size[g]
        pos, rot = _relative(frame, data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3))
        rgba = tuple(float(c) for c in model.geom_rgba[g])
        shapes = []                              # (offset along the geom's z, element)
        if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            shapes.append((0.0, ET.Element('sphere', radius=_num([size[0]]))))
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            shapes.append((0.0, ET.Element('box', size=_num(2 * size))))
        elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            shapes.append((0.0, ET.Element('box', size=_num(2 * size))))
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            shapes.append((0.0, ET.Element('cylinder', radius=_num([size[0]]),
                                           length=_num([2 * size[1]]))))
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            shapes.append((0.0, ET.Element('cylinder', radius=_num([size[0]]),
                                           length=_num([2 * size[1]]))))
            for end in (-size[1], size[1]):
                shapes.append((end, ET.Element('sphere', radius=_num([size[0]]))))
        for along, shape in shapes:
            visual = ET.SubElement(link, 'visual')
            _origin(visual, pos + rot[:, 2] * along, rot)
            ET.SubElement(visual, 'geometry').append(shape)
            name = materials.setdefault(rgba, f'rgba{len(materials)}')
            ET.SubElement(visual, 'material', name=name)


def _inertial(link: ET.Element, model, data, b: int, frame) -> None:
    if model.body_mass[b] <= 0:
        return
    inertial = ET.SubElement(link, 'inertial')
    _origin(inertial, *_relative(frame, data.xipos[b], data.ximat[b].reshape(3, 3)))
    ET.SubElement(inertial, 'mass', value=_num([model.body_mass[b]]))
    i = model.body_inertia[b]
    ET.SubElement(inertial, 'inertia', ixx=_num([i[0]]), iyy=_num([i[1]]), izz=_num([i[2]]),
                  ixy='0', ixz='0', iyz='0')


def export_urdf(model: mujoco.MjModel, name: Optional[str] = None) -> str:
    """Return the URDF text of the arm in ``model`` (see the module docstring)."""
    spec = ArmSpec.from_model(model)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)              # qpos 0: every joint at zero
    robot = ET.Element('robot', name=name or model.names[:model.names.index(b'\0')].decode()
                       or 'arm')
    materials: Dict[tuple, str] = {}
    links: Dict[int, ET.Element] = {}
    frames: Dict[int, Tuple[np.ndarray, np.ndarray]] = {0: (np.zeros(3), np.eye(3))}
    names = {0: ROOT}
    ET.SubElement(robot, 'link', name=ROOT)
    on_joint = model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT
    effort = dict(zip(model.actuator_trnid[:, 0][on_joint].tolist(),
                      force_limit(model, model.actuator_trnid[:, 0], on_joint)[on_joint]))
    gear = {int(j): abs(model.actuator_gear[a, 0]) * np.abs(model.actuator_ctrlrange[a]).max()
            for a, j in enumerate(model.actuator_trnid[:, 0]) if on_joint[a]}
    for b in arm_bodies(model, spec):
        body = model.body(b)
        names[b] = body.name or f'body{b}'
        parent = int(model.body_parentid[b])
        rot = data.xmat[b].reshape(3, 3)
        n_joints = int(model.body_jntnum[b])
        if n_joints > 1:
            raise UrdfExportError(f'body {names[b]!r} has {n_joints} joints: a URDF link '
                                  'moves on one')
        j = int(model.body_jntadr[b]) if n_joints else -1
        origin = data.xanchor[j] if j >= 0 else data.xpos[b]
        frames[b] = (origin.copy(), rot.copy())
        link = links[b] = ET.SubElement(robot, 'link', name=names[b])
        _inertial(link, model, data, b, frames[b])
        _visuals(link, model, data, np.flatnonzero(model.geom_bodyid == b), frames[b],
                 materials)
        kind = 'fixed'
        if j >= 0:
            jt = model.jnt_type[j]
            if jt == mujoco.mjtJoint.mjJNT_HINGE:
                kind = 'revolute' if model.jnt_limited[j] else 'continuous'
            elif jt == mujoco.mjtJoint.mjJNT_SLIDE:
                kind = 'prismatic'
            else:
                raise UrdfExportError(f'joint {model.joint(j).name!r} is a ball or free joint: '
                                      'no URDF joint has its motion')
            if kind == 'prismatic' and not model.jnt_limited[j]:
                raise UrdfExportError(f'slide joint {model.joint(j).name!r} is unlimited')
        joint = ET.SubElement(robot, 'joint', type=kind,
                              name=model.joint(j).name if j >= 0 else f'{names[b]}_fixed')
        _origin(joint, *_relative(frames[parent], *frames[b]))
        ET.SubElement(joint, 'parent', link=names[parent])
        ET.SubElement(joint, 'child', link=names[b])
        if j >= 0:
            ET.SubElement(joint, 'axis', xyz=_num(rot.T @ data.xaxis[j]))
            limit = {'effort': _num([min(effort.get(j, math.inf), gear.get(j, 0.0))]),
                     'velocity': '0'}
            if model.jnt_limited[j]:
                limit.update(lower=_num([model.jnt_range[j, 0]]),
                             upper=_num([model.jnt_range[j, 1]]))
            ET.SubElement(joint, 'limit', **limit)
    if spec.fingertip_site >= 0:
        site = spec.fingertip_site
        b = int(model.site_bodyid[site])
        tip = 'fingertip' if 'fingertip' not in names.values() else 'fingertip_site'
        ET.SubElement(robot, 'link', name=tip)
        joint = ET.SubElement(robot, 'joint', type='fixed', name=f'{tip}_fixed')
        _origin(joint, *_relative(frames[b], data.site_xpos[site],
                                  data.site_xmat[site].reshape(3, 3)))
        ET.SubElement(joint, 'parent', link=names[b])
        ET.SubElement(joint, 'child', link=tip)
    for rgba, mat in materials.items():
        material = ET.Element('material', name=mat)
        ET.SubElement(material, 'color', rgba=_num(rgba))
        robot.insert(0, material)
    ET.indent(robot)
    return ('<?xml version="1.0"?>\n<!-- written by pg_node.sim.urdf_export from the MuJoCo '
            'model; kinematics equal to it -->\n' + ET.tostring(robot, encoding='unicode')
            + '\n')


WRITTEN = 'written from the MuJoCo model'


class Description(NamedTuple):
    """A ``robot_description``: the URDF, where it came from, and why not the vendor's."""

    urdf: str
    #: the vendor's file, or :data:`WRITTEN`
    origin: str
    #: why the file the model names was not taken ('' if it was, or none is named)
    problem: str = ''


def source_urdf(model: mujoco.MjModel, model_path=None) -> Optional[Path]:
    """
    Return the file the model's custom text ``pg_source_urdf`` names, or None.

    A relative path is relative to the folder of ``model_path`` (the MJCF file), where
    ``arm import`` wrote it from; without ``model_path`` it is returned as it is.
    """
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, 'pg_source_urdf')
    if i < 0:
        return None
    adr, size = model.text_adr[i], model.text_size[i]
    path = Path(bytes(model.text_data[adr:adr + size - 1]).decode())
    if not path.is_absolute() and model_path is not None:
        path = Path(os.path.normpath(Path(model_path).resolve().parent / path))
    return path


def robot_description(model: mujoco.MjModel, model_path=None) -> Description:
    """
    Return the vendor's URDF of an imported arm, else one written (:func:`export_urdf`).

    The vendor's file is the one the model names (``pg_source_urdf``, relative to the
    folder of ``model_path``); if it cannot be read (the model moved without it, or a copy
    of the model's text elsewhere), the URDF is written and ``problem`` says so.
    """
    path = source_urdf(model, model_path)
    if path is None:
        return Description(export_urdf(model), WRITTEN)
    if not path.is_absolute():
        problem = f'pg_source_urdf {path} is relative and the model file is not known'
    else:
        try:
            return Description(path.read_text(encoding='utf-8'), str(path))
        except (OSError, UnicodeDecodeError) as exc:
            problem = (f"the model's vendor URDF (pg_source_urdf) {path} cannot be read: "
                       f'{getattr(exc, "strerror", None) or exc}')
    return Description(export_urdf(model), WRITTEN, problem)


def main(argv=None) -> int:
    """Print the ``robot_description`` of a model (shipped name or MJCF path), as sim_node's."""
    import sys
    from pg_node.common.paths import resolve_model
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or args[0].startswith('-'):
        print('usage: python -m pg_node.sim.urdf_export MODEL > arm.urdf  (MODEL: reacher2, '
              'arm5_3d, arm7 or an MJCF path): the URDF sim_node publishes as robot_description',
              file=sys.stderr)
        return 2
    try:
        path = str(resolve_model(args[0]))
        description = robot_description(mujoco.MjModel.from_xml_path(path), path)
        if description.problem:
            print(f'urdf_export: {description.problem}; written from the model instead',
                  file=sys.stderr)
        print(description.urdf, end='')
    except (ValueError, OSError) as exc:
        print(f'urdf_export: {" ".join(str(exc).split())}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
