"""
Where PyBullet's reading of a URDF and pg_node's MuJoCo import of it disagree (no ROS here).

A sim-to-sim figure means something only if the two engines simulate the same robot: the
same joints in the same order, the same limits, the same masses and the same kinematics.
:func:`compare` holds an arm model made by ``arm import`` against a
:class:`pg_node.sim.pybullet_arm.PybulletArm` of the same URDF: each arm joint's limits,
each moving link's mass (by link name: MuJoCo names the bodies after the links; a link
lighter than MuJoCo's minimum mass, 0.001 kg, counts as that), and, at
``poses`` joint configurations drawn within the limits, the world position of every link
frame both have and of the fingertip. :meth:`Agreement.line` says it in one line, which
the stand-in node logs at start (docs/sim_to_sim.md).
"""
from dataclasses import dataclass, field
from typing import List

import mujoco
import numpy as np
from pg_node.sim.arm_task import ArmSpec
from pg_node.sim.urdf_import import BOUND_MASS

#: metres: link frames closer than this are the same
POSITION_TOLERANCE = 1e-3
#: relative: masses closer than this are the same
MASS_TOLERANCE = 1e-3


@dataclass
class Agreement:
    """What :func:`compare` found; ``disagreements`` is empty when the engines agree."""

    position_error: float = 0.0
    poses: int = 0
    links_compared: int = 0
    disagreements: List[str] = field(default_factory=list)

    def line(self) -> str:
        """Return the finding in one line."""
        head = (f'PyBullet and the MuJoCo model: {self.links_compared} link frames at '
                f'{self.poses} poses within {1000 * self.position_error:.3g} mm')
        if not self.disagreements:
            return head + '; joints, limits and masses agree'
        return head + '; they disagree: ' + '; '.join(self.disagreements)


def compare(model: mujoco.MjModel, arm, poses: int = 5, seed: int = 0) -> Agreement:
    """Return how the arm ``model`` and the PyBullet ``arm`` (same joints) agree."""
    spec = ArmSpec.from_model(model)
    out = Agreement(poses=poses)
    if tuple(arm.joint_names) != tuple(spec.joint_names):
        out.disagreements.append(f'joints {", ".join(arm.joint_names)} against the model\'s '
                                 f'{", ".join(spec.joint_names)}')
        return out
    for k, name in enumerate(spec.joint_names):
        if spec.joint_limited[k] != arm.limited[k]:
            out.disagreements.append(f'{name} is {"" if arm.limited[k] else "not "}limited '
                                     'in PyBullet')
        elif spec.joint_limited[k] and not np.allclose(
                spec.joint_range[k], (arm.lower[k], arm.upper[k]), atol=1e-6):
            out.disagreements.append(f'{name} limits {arm.lower[k]:.4g}..{arm.upper[k]:.4g} '
                                     f'against {spec.joint_range[k][0]:.4g}..'
                                     f'{spec.joint_range[k][1]:.4g}')
    masses = arm.masses()
    first = int(model.jnt_bodyid[spec.joint_ids[0]])
    moving = [b for b in range(model.nbody) if _below(model, b, first)]
    for b in moving:
        name = model.body(b).name
        # MuJoCo raises a lighter body to its minimum mass (urdf_import.BOUND_MASS)
        if name in masses and not np.isclose(max(masses[name], BOUND_MASS), model.body_mass[b],
                                             rtol=MASS_TOLERANCE, atol=1e-9):
            out.disagreements.append(f'link {name} weighs {masses[name]:.4g} kg in PyBullet, '
                                     f'{model.body_mass[b]:.4g} kg in MuJoCo')
    bodies = [b for b in range(1, model.nbody) if model.body(b).name in arm.links]
    out.links_compared = len(bodies) + 1
    tip_body = int(model.site_bodyid[spec.fingertip_site])
    tip_offset = model.site_pos[spec.fingertip_site]
    data = mujoco.MjData(model)
    rng = np.random.default_rng(seed)
    low, high = spec.angle_bounds()
    for _ in range(poses):
        q = rng.uniform(low, high)
        data.qpos[spec.qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        arm.set_state(q)
        for b in bodies:
            gap = np.linalg.norm(arm.link_position(model.body(b).name) - data.xpos[b])
            out.position_error = max(out.position_error, float(gap))
        tip = arm.link_position(model.body(tip_body).name, tip_offset)
        out.position_error = max(out.position_error, float(np.linalg.norm(
            tip - data.site_xpos[spec.fingertip_site])))
    if out.position_error > POSITION_TOLERANCE:
        out.disagreements.insert(0, f'link frames up to {1000 * out.position_error:.3g} mm '
                                    'apart')
    return out


def _below(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0:
        if body == ancestor:
            return True
        body = int(model.body_parentid[body])
    return False
