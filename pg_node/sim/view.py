"""
How pg_node looks at an arm: a camera that frames it, and an OpenGL that works headless.

Used by the Gymnasium environment's ``render()`` and by ``python -m pg_node render``.
"""
import os

import mujoco


def framing_camera(model: mujoco.MjModel, target_dim: int) -> mujoco.MjvCamera:
    """
    Return a free camera that frames the arm from its base.

    A planar arm (targets in 2-D) is seen from straight above, close enough that its reach
    fills the picture; a 3-D arm from above and the side, far enough for its whole extent.
    """
    camera = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, camera)
    extent = max(float(model.stat.extent), 0.1)
    if target_dim > 2:
        camera.lookat[:] = [0.0, 0.0, 0.3 * extent]     # above the base, mid-reach
        camera.distance, camera.elevation = 1.8 * extent, -30.0
    else:
        camera.lookat[:] = [0.0, 0.0, 0.0]
        camera.distance, camera.elevation = 0.75, -90.0
    camera.azimuth = 90.0
    return camera


def use_headless_gl() -> str:
    """
    Make MuJoCo's renderer use OSMesa where nobody chose a backend and there is no display.

    MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when it is imported (GLFW when unset,
    which needs a display). Called before the first ``mujoco.Renderer`` of a process, this
    swaps in the OSMesa context (Debian ``libosmesa6``) when ``MUJOCO_GL`` is unset and
    neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` is; an explicit ``MUJOCO_GL`` always wins.
    Returns the backend in use. OSMesa is loaded only by the process that renders: with it
    loaded, torch's optimisers have crashed here, so training processes never call this.
    """
    chosen = os.environ.get('MUJOCO_GL', '').strip().lower()
    if chosen or os.environ.get('DISPLAY') or os.environ.get('WAYLAND_DISPLAY'):
        return chosen or 'glfw'
    from mujoco.osmesa import GLContext
    from mujoco.rendering.classic import gl_context
    gl_context.GLContext = GLContext
    return 'osmesa'


def draw_pose(renderer, camera, model, data, spec, angles, goal):
    """
    Return the picture (``(H, W, 3)`` uint8) of the arm at joint ``angles`` reaching ``goal``.

    The goal is drawn once more as a larger translucent sphere, so that it shows at any
    resolution. ``spec`` is the model's :class:`pg_node.sim.arm_task.ArmSpec`.
    """
    import numpy as np
    mujoco.mj_resetData(model, data)
    data.qpos[spec.qpos_adr] = angles
    if spec.target_mocap >= 0:
        data.mocap_pos[spec.target_mocap][:len(goal)] = goal
    else:
        data.qpos[spec.target_qpos_adr] = goal
    mujoco.mj_forward(model, data)
    renderer.update_scene(data, camera)
    scene = renderer.scene
    if scene.ngeom < scene.maxgeom:
        mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE,
                            np.array([0.02, 0.0, 0.0]), data.xpos[spec.target_body].copy(),
                            np.eye(3).ravel(), np.array([0.9, 0.2, 0.2, 0.5], dtype=np.float32))
        scene.ngeom += 1
    return renderer.render()
