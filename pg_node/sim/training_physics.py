"""
The physics a policy was trained on, as its card records it (no ROS here).

A policy learns the arm it meets in training: who carries the arm's weight, how its joints
are damped, how heavy its rotors are, how often it is commanded, what its commands mean and
how far the randomization moved all that. A robot that differs in one of these gets a
policy tuned for another arm, so the card says each (:func:`training_physics`), and
``policy_node`` compares what its parameters say about the robot with it
(:func:`pg_node.control.physics_check.contradictions`).

What the arm model does not say by itself, the importer's choices (a velocity damping the
robot is assumed to enforce, a rotor inertia given on the command line), is read from the
model's custom text ``pg_physics_assumptions`` (:func:`pg_node.sim.urdf_import.assumptions`
writes it, one line each).
"""
from typing import Dict, List, Mapping

import mujoco
import numpy as np

#: the custom text of an arm model that holds what its import assumed, one line each
ASSUMPTIONS_TEXT = 'pg_physics_assumptions'


def model_assumptions(model: mujoco.MjModel) -> List[str]:
    """Return the lines of the model's ``pg_physics_assumptions`` text (none: ``[]``)."""
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXT, ASSUMPTIONS_TEXT)
    if i < 0:
        return []
    adr, size = model.text_adr[i], model.text_size[i]
    text = bytes(model.text_data[adr:adr + size - 1]).decode()
    return [line.strip() for line in text.splitlines() if line.strip()]


def gravity_compensation(model: mujoco.MjModel, links) -> str:
    """
    Return who carries the weight of the arm's ``links`` (body ids) in this model.

    ``robot``: every link has ``gravcomp`` 1 (MuJoCo cancels its weight, as a torque robot's
    driver does, so a zero command holds the arm); ``policy``: none has (the commands must
    hold the arm up); ``partial`` otherwise; ``none needed`` without gravity.
    """
    if not np.any(model.opt.gravity):
        return 'none needed'
    links = np.asarray(links, dtype=int)
    share = model.body_gravcomp[links]
    if np.all(share == 1):
        return 'robot'
    if np.all(share == 0):
        return 'policy'
    return 'partial'


def training_physics(model: mujoco.MjModel, spec, frame_skip: int, interfaces: List[str],
                     randomization: Mapping[str, str]) -> Dict:
    """
    Return the card's ``physics``: what the policy was trained on, per arm joint in order.

    ``spec`` is the model's :class:`~pg_node.sim.arm_task.ArmSpec`; ``interfaces`` the
    command interfaces its actuators take (the card's ``command_interfaces``);
    ``randomization`` the run's ``randomize_<term>`` texts (the empty ones are left out).
    """
    dofs = np.asarray(spec.dof_adr, dtype=int)
    integrators = {int(v): k.lower() for k, v in (
        ('Euler', mujoco.mjtIntegrator.mjINT_EULER), ('RK4', mujoco.mjtIntegrator.mjINT_RK4),
        ('implicit', mujoco.mjtIntegrator.mjINT_IMPLICIT),
        ('implicitfast', mujoco.mjtIntegrator.mjINT_IMPLICITFAST))}
    return {
        'interfaces': list(interfaces),
        'gravity_compensation': gravity_compensation(model, spec.link_bodies),
        'gravity': [float(g) for g in model.opt.gravity],
        'damping': [float(v) for v in model.dof_damping[dofs]],
        'frictionloss': [float(v) for v in model.dof_frictionloss[dofs]],
        'armature': [float(v) for v in model.dof_armature[dofs]],
        'timestep': float(model.opt.timestep),
        'frame_skip': int(frame_skip),
        'control_period': float(model.opt.timestep * frame_skip),
        'integrator': integrators.get(int(model.opt.integrator), str(model.opt.integrator)),
        'assumptions': model_assumptions(model),
        'randomization': {term: str(text) for term, text in randomization.items()
                          if str(text or '').strip()},
    }
