"""
Whether a robot's description (URDF) has the kinematics of a policy's arm model (no ROS).

``policy_node`` asks this on configure when ``/robot_description`` is published (as
``robot_state_publisher`` does): a policy trained on another arm than the one it drives
computes its observation's fingertip from the wrong forward kinematics. The URDF is
compiled by MuJoCo with its geometry removed (meshes are not needed and often not found);
then, at a few joint configurations drawn within the limits, each arm joint's anchor
(relative to the first joint's) and axis are compared between the two models. This covers
the chain up to the last joint; the fingertip's offset beyond it is not in a URDF.

The tolerance is ``policy_node``'s ``kinematics_tolerance`` parameter: a calibrated arm's
description (``ur_calibration``'s, for a UR) differs from the nominal one by millimetres to
centimetres, and the refusal gives the deviation measured, so a user can judge it.
"""
from typing import Optional, Sequence
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
from pg_node.sim.arm_task import ArmSpec

#: metres and unit-vector components: anchors and axes that differ less are the same (the
#: default of ``kinematics_tolerance``)
TOLERANCE = 1e-3
CONFIGURATIONS = 5


def _urdf_model(urdf: str) -> mujoco.MjModel:
    root = ET.fromstring(urdf)
    for link in root.iter('link'):
        for tag in ('visual', 'collision'):
            for element in link.findall(tag):
                link.remove(element)
    for element in root.findall('mujoco'):
        root.remove(element)
    compiler = ET.SubElement(ET.SubElement(root, 'mujoco'), 'compiler')
    compiler.attrib.update(balanceinertia='true', boundmass='0.001', boundinertia='1e-6',
                           discardvisual='true', fusestatic='false')
    return mujoco.MjModel.from_xml_string(ET.tostring(root, encoding='unicode'))


def _pose(model: mujoco.MjModel, joints: Sequence[str], q: np.ndarray):
    data = mujoco.MjData(model)
    for name, value in zip(joints, q):
        data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
    mujoco.mj_kinematics(model, data)
    ids = [model.joint(name).id for name in joints]
    anchors = data.xanchor[ids] - data.xanchor[ids[0]]
    return anchors, data.xaxis[ids]


def compare_kinematics(model: mujoco.MjModel, urdf: str, seed: int = 0,
                       tolerance: float = TOLERANCE) -> Optional[str]:
    """
    Return how ``urdf`` differs from the arm ``model`` on its arm joints (one line), or None.

    ``tolerance``: in metres for the joints' anchors, and in unit-vector components for
    their axes. A refusal names the largest deviation found and the tolerance.
    """
    spec = ArmSpec.from_model(model)
    joints = list(spec.joint_names)
    try:
        other = _urdf_model(urdf)
    except (ET.ParseError, ValueError) as exc:
        return f'robot_description does not compile: {" ".join(str(exc).split())[:200]}'
    names = {other.joint(i).name for i in range(other.njnt)}
    missing = [j for j in joints if j not in names]
    if missing:
        return (f'robot_description has no joint {", ".join(missing)} '
                f'(it has {", ".join(sorted(names)[:8])})')
    for j in joints:
        if model.jnt_type[model.joint(j).id] != other.jnt_type[other.joint(j).id]:
            return f'joint {j} is of another type in robot_description'
    rng = np.random.default_rng(seed)
    low, high = spec.angle_bounds()
    worst_gap = worst_turn = (0.0, None, None)
    for _ in range(CONFIGURATIONS):
        q = rng.uniform(low, high)
        a, b = _pose(model, joints, q), _pose(other, joints, q)
        for k, j in enumerate(joints):
            gap = float(np.linalg.norm(a[0][k] - b[0][k]))
            turn = float(np.linalg.norm(a[1][k] - b[1][k]))
            if gap > worst_gap[0]:
                worst_gap = (gap, j, q)
            if turn > worst_turn[0]:
                worst_turn = (turn, j, (a[1][k], b[1][k]))
    gap, j, q = worst_gap
    if gap > tolerance:
        return (f"joint {j} is {1000 * gap:.1f} mm away from where the policy's model has it "
                f'(relative to {joints[0]}, at angles {np.round(q, 2).tolist()}; '
                f'kinematics_tolerance {1000 * tolerance:g} mm)')
    turn, j, axes = worst_turn
    if turn > tolerance:
        ours, theirs = axes
        return (f'joint {j} turns about {np.round(theirs, 3).tolist()} in robot_description, '
                f"about {np.round(ours, 3).tolist()} in the policy's model (a difference of "
                f'{turn:.3g}; kinematics_tolerance {tolerance:g})')
    return None
