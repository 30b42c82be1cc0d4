"""
What a viewer draws of a few simulated arms: their links, goals and fingertip trails (no ROS).

ROS viewers draw a robot from TF, which pg_node cannot publish without ``tf2_msgs`` (not on
PyPI). This module gives instead every shape to draw at its **world pose** in one fixed
frame, for ``sim_node``'s ``pg_node/scene`` (:mod:`pg_node.ros.scene_msg` makes the
``MarkerArray``) and ``python -m pg_node view``:

* **links**: each geom of the arm's bodies (:func:`pg_node.sim.urdf_export.arm_bodies`, as
  ``robot_description`` has them) at its pose in the MuJoCo data: a sphere, box or cylinder
  as such, an ellipsoid as a scaled sphere, a capsule as a cylinder and two end spheres, a
  mesh as the box around it; in the geom's colour;
* the **goal** (the target body's position) and the **fingertip** (the fingertip site), as
  spheres;
* the fingertip's **trail**: its last ``trail_length`` positions in the current episode
  (:meth:`Scene.record`, called each control step while someone watches).

Arm ``i`` is drawn shifted by ``offsets[i]`` (``sim_node``'s grid: its frame ``arm<i>`` is
the fixed frame shifted so). Sizes follow ROS markers: ``scale`` is a sphere's or box's full
extent, a cylinder's diameter (x, y) and height (z, along the pose's z axis).
"""
from collections import deque
from dataclasses import dataclass
from typing import Dict, List, Sequence

import mujoco
import numpy as np
from pg_node.sim.arm_task import ArmSpec
from pg_node.sim.urdf_export import arm_bodies

SPHERE, BOX, CYLINDER = 'sphere', 'box', 'cylinder'
GOAL_RGBA = (0.9, 0.2, 0.2, 1.0)
TIP_RGBA = (0.0, 0.8, 0.6, 1.0)
TRAIL_RGBA = (1.0, 0.6, 0.0, 0.8)
#: m: the goal's and fingertip's sphere diameter, the trail's line width
GOAL_SIZE, TIP_SIZE, TRAIL_WIDTH = 0.03, 0.025, 0.005


@dataclass
class Shapes:
    """Shapes of one kind, one row each: world position, orientation (w x y z), size."""

    kind: str
    pos: np.ndarray      # (n, 3)
    quat: np.ndarray     # (n, 4)
    scale: np.ndarray    # (n, 3)
    rgba: np.ndarray     # (n, 4)


@dataclass
class ArmView:
    """One arm's scene: its link shapes by kind, goal, fingertip and trail (world frame)."""

    arm: int
    links: List[Shapes]
    goal: np.ndarray
    tip: np.ndarray
    trail: np.ndarray    # (k, 3), oldest first


def mat_to_quat(mats: np.ndarray) -> np.ndarray:
    """
    Return unit quaternions ``(n, 4)`` (w x y z) of rotation matrices ``(n, 9)`` or ``(n, 3, 3)``.

    >>> mat_to_quat(np.eye(3)[None]).round(6).tolist()
    [[1.0, 0.0, 0.0, 0.0]]
    """
    mats = np.asarray(mats, dtype=np.float64).reshape(-1, 9)
    out = np.empty((len(mats), 4))
    for k, m in enumerate(mats):
        mujoco.mju_mat2Quat(out[k], m)
    return out


class Scene:
    """The shapes of ``arms`` of a task's model; :meth:`views` reads them from MuJoCo data."""

    def __init__(self, model: mujoco.MjModel, arms: Sequence[int], offsets: np.ndarray,
                 trail_length: int = 50):
        """Pick the arm's geoms and their sizes out of ``model`` once."""
        self.spec = ArmSpec.from_model(model)
        self.arms = list(arms)
        self.offsets = np.asarray(offsets, dtype=np.float64)
        self.trails: Dict[int, deque] = {i: deque(maxlen=max(trail_length, 1))
                                         for i in self.arms}
        self.trail_length = trail_length
        bodies = set(arm_bodies(model, self.spec))
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] in bodies
                 and model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE]
        # (kind, geom ids, local offset along the geom's z, local rotation, scale)
        self.parts = []
        by_kind: Dict[tuple, list] = {}
        for g in geoms:
            t, size = model.geom_type[g], model.geom_size[g]
            z0 = np.zeros(3)
            if t == mujoco.mjtGeom.mjGEOM_SPHERE:
                items = [(SPHERE, z0, np.full(3, 2 * size[0]))]
            elif t == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
                items = [(SPHERE, z0, 2 * size)]
            elif t == mujoco.mjtGeom.mjGEOM_BOX:
                items = [(BOX, z0, 2 * size)]
            elif t == mujoco.mjtGeom.mjGEOM_CYLINDER:
                items = [(CYLINDER, z0, np.array([2 * size[0], 2 * size[0], 2 * size[1]]))]
            elif t == mujoco.mjtGeom.mjGEOM_CAPSULE:
                ball = np.full(3, 2 * size[0])
                items = [(CYLINDER, z0, np.array([2 * size[0], 2 * size[0], 2 * size[1]])),
                         (SPHERE, np.array([0, 0, -size[1]]), ball),
                         (SPHERE, np.array([0, 0, size[1]]), ball)]
            else:                          # a mesh (or other): the box around it
                aabb = model.geom_aabb[g]
                items = [(BOX, aabb[:3].copy(), 2 * aabb[3:])]
            for kind, local, scale in items:
                by_kind.setdefault(kind, []).append((g, local, scale, model.geom_rgba[g]))
        for kind, rows in by_kind.items():
            self.parts.append((kind, np.array([r[0] for r in rows], dtype=int),
                               np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
                               np.array([r[3] for r in rows], dtype=np.float64)))

    def record(self, datas: Sequence[mujoco.MjData], episode_step: np.ndarray) -> None:
        """Add each shown arm's fingertip to its trail; an episode's first step starts anew."""
        site = self.spec.fingertip_site
        for i, trail in self.trails.items():
            if episode_step[i] == 0:
                trail.clear()
            trail.append(datas[i].site_xpos[site] + self.offsets[i])

    def views(self, datas: Sequence[mujoco.MjData]) -> List[ArmView]:
        """Return each shown arm's shapes at the poses in ``datas`` (one MjData per arm)."""
        out = []
        for i in self.arms:
            d, shift = datas[i], self.offsets[i]
            links = []
            for kind, ids, local, scale, rgba in self.parts:
                mats = d.geom_xmat[ids].reshape(-1, 3, 3)
                pos = d.geom_xpos[ids] + np.einsum('nij,nj->ni', mats, local) + shift
                links.append(Shapes(kind, pos, mat_to_quat(mats), scale, rgba))
            tip = d.site_xpos[self.spec.fingertip_site] + shift
            trail = (np.array(self.trails[i]) if self.trail_length and self.trails[i]
                     else np.empty((0, 3)))
            out.append(ArmView(i, links, d.xpos[self.spec.target_body] + shift, tip, trail))
        return out
