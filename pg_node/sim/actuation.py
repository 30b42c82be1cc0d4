"""
An arm model's actuators as :mod:`pg_node.control.interfaces` takes them: read from MuJoCo.

:func:`actuators` reads each actuator's gain, biases, gear, control range and its joint's
range out of an ``MjModel`` into a plain :class:`pg_node.control.interfaces.Actuators`
record, and says which actuators follow MuJoCo's affine law (fixed gain, no activation
dynamics, a joint transmission); the command interfaces, their units and maps live there.
It reads too what the guards take their defaults from: each joint's damping, the largest
joint torque its actuator may apply, and its largest inertia (:func:`joint_inertia`).
"""
from typing import Callable, Optional, Sequence

import mujoco
import numpy as np
from pg_node.control.interfaces import Actuators


def actuators(model: mujoco.MjModel) -> Actuators:
    """Return the actuators of ``model`` (a pg_node arm model) as a plain record."""
    gain = model.actuator_gainprm[:, 0].copy()
    gear = model.actuator_gear[:, 0].copy()
    on_joint = model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT
    joint = np.where(on_joint, model.actuator_trnid[:, 0], 0)    # (another transmission: none)
    ctrl_low, ctrl_high = ctrl_range(model)
    limited = model.jnt_limited[joint].astype(bool) & on_joint
    rng = model.jnt_range[joint]
    affine = ((model.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE)
              & (model.actuator_gaintype == mujoco.mjtGain.mjGAIN_FIXED)
              & on_joint & (gain != 0) & (gear != 0))
    return Actuators(
        names=tuple(model.actuator(i).name for i in range(model.nu)),
        joints=tuple(model.joint(int(j)).name if on else '' for j, on in zip(joint, on_joint)),
        gain=gain,
        b0=model.actuator_biasprm[:, 0].copy(), b1=model.actuator_biasprm[:, 1].copy(),
        b2=model.actuator_biasprm[:, 2].copy(), gear=gear, ctrl_low=ctrl_low,
        ctrl_high=ctrl_high, joint_low=np.where(limited, rng[:, 0], -np.inf),
        joint_high=np.where(limited, rng[:, 1], np.inf), affine=affine,
        damping=np.where(on_joint, model.dof_damping[model.jnt_dofadr[joint]], 0.0),
        force_limit=force_limit(model, joint, on_joint),
        inertia=np.where(on_joint, joint_inertia(model)[model.jnt_dofadr[joint]], np.inf))


def force_limit(model: mujoco.MjModel, joint: np.ndarray, on_joint: np.ndarray) -> np.ndarray:
    """
    Return the largest joint torque each actuator may apply (N m), infinite where unlimited.

    The tighter of the actuator's ``forcerange`` (times its gear) and the joint's
    ``actuatorfrcrange``; a motor's control range bounds it further (the guards take that
    from the record's maps, not from here).
    """
    gear = np.abs(model.actuator_gear[:, 0])
    by_actuator = np.where(model.actuator_forcelimited.astype(bool),
                           np.abs(model.actuator_forcerange).max(axis=1) * gear, np.inf)
    frc = model.jnt_actfrcrange[joint]
    by_joint = np.where(model.jnt_actfrclimited[joint].astype(bool) & on_joint,
                        np.abs(frc).max(axis=1), np.inf)
    return np.minimum(by_actuator, by_joint)


#: poses, besides the reference pose, over which :func:`joint_inertia` takes the largest
POSES = 32


def joint_inertia(model: mujoco.MjModel) -> np.ndarray:
    """
    Return each degree of freedom's largest inertia (kg m^2, armature included).

    The diagonal of the joint-space inertia matrix depends on the pose (a shoulder carries
    an outstretched arm's inertia, not a folded one's): the largest over the reference pose
    and :data:`POSES` poses drawn, with a fixed seed, within the joint ranges (+-pi where
    unlimited). Deterministic, and an upper bound in practice: a braking distance computed
    with it is the longer one.
    """
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    low = np.where(model.jnt_limited.astype(bool), model.jnt_range[:, 0], -np.pi)
    high = np.where(model.jnt_limited.astype(bool), model.jnt_range[:, 1], np.pi)
    hinge = np.isin(model.jnt_type, (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE))
    largest = np.zeros(model.nv)
    for k in range(POSES + 1):
        data.qpos[:] = model.qpos0
        if k:
            for j in np.flatnonzero(hinge):
                data.qpos[model.jnt_qposadr[j]] = rng.uniform(low[j], high[j])
        mujoco.mj_forward(model, data)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        diag = np.diag(full)
        largest = np.maximum(largest, diag)
    return largest


def inertia_at(model: mujoco.MjModel, joint_names: Sequence[str]
               ) -> Callable[[np.ndarray], np.ndarray]:
    """
    Return a function: angles ``(arms, len(joint_names))`` to each actuator's inertia there.

    The inertia an actuator's torque meets at that pose with the other joints free to move,
    ``1 / (M^-1)_ii`` of the joint-space inertia matrix ``M`` (armature included; the other
    joints of the model at their reference angles), at most the record's largest
    (:func:`joint_inertia`): what the braking guard sizes a torque that changes the joint's
    speed by a given amount in one tick with
    (:meth:`pg_node.control.guards.CommandGuard.joint_limits`). Infinite for an actuator
    without a joint of its own.

    >>> from pg_node.common.paths import resolve_model
    >>> m = mujoco.MjModel.from_xml_path(str(resolve_model('arm7')))
    >>> names = [m.joint(j).name for j in range(7)]
    >>> folded = [[0, -0.8, 2.0, -2.1, 2.8, 2.4, 1.9]]
    >>> at = inertia_at(m, names)(np.array(folded))[0]
    >>> bool(at[0] < actuators(m).inertia[0] / 5)     # the shoulder, 5+ times lighter
    True
    """
    largest = actuators(model).inertia
    inverse = _inverse_mass_at(model, joint_names)
    on_joint = model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT
    dof = model.jnt_dofadr[np.where(on_joint, model.actuator_trnid[:, 0], 0)]

    def at(q: np.ndarray) -> np.ndarray:
        diagonal = np.diagonal(inverse(q), axis1=1, axis2=2)[:, dof]
        return np.minimum(np.where(on_joint, 1.0 / diagonal, np.inf), largest)
    return at


def _inverse_mass_at(model: mujoco.MjModel, joint_names: Sequence[str]
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """
    Return a function: angles ``(arms, len(joint_names))`` to ``M^-1`` ``(arms, nv, nv)``.

    ``M`` the joint-space inertia matrix at each pose (armature included), the model's other
    joints at their reference angles: what :func:`inertia_at` and :func:`mass_matrix_at`
    read their inertias from.
    """
    data = mujoco.MjData(model)
    adr = np.array([model.joint(n).qposadr[0] for n in joint_names])
    full = np.zeros((model.nv, model.nv))

    def at(q: np.ndarray) -> np.ndarray:
        out = np.empty((len(q), model.nv, model.nv))
        for i, angles in enumerate(q):
            data.qpos[:] = model.qpos0
            data.qpos[adr] = angles
            mujoco.mj_fwdPosition(model, data)
            mujoco.mj_fullM(model, data, full)
            out[i] = np.linalg.inv(full)
        return out
    return at


def ctrl_range(model: mujoco.MjModel):
    """Return each actuator's control range ``(low, high)``, infinite where unlimited."""
    limited = model.actuator_ctrllimited.astype(bool)
    return (np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf),
            np.where(limited, model.actuator_ctrlrange[:, 1], np.inf))


def mass_matrix_at(model: mujoco.MjModel, joint_names: Sequence[str]
                   ) -> Optional[Callable[[np.ndarray], np.ndarray]]:
    """
    Return a function: angles ``(arms, len(joint_names))`` to the actuated joints' inertia.

    The ``(arms, nu, nu)`` matrix ``((M^-1)_aa)^-1`` of the joint-space inertia matrix ``M``
    (armature included) over the actuators' joints ``a``: the inertia the actuators' torques
    meet together at that pose, the other joints free to move (with none, the block of
    ``M``). The effort hold brakes with it (:meth:`pg_node.control.guards.CommandGuard.hold`):
    ``tau = -M_a qdot / (BRAKE_TICKS T)`` takes the same share of every joint's speed off per
    tick, however the joints are coupled. None where an actuator has no joint of its own.

    >>> from pg_node.common.paths import resolve_model
    >>> m = mujoco.MjModel.from_xml_path(str(resolve_model('arm7')))
    >>> names = [m.joint(j).name for j in range(7)]
    >>> ready = mass_matrix_at(m, names)(np.array([[0, -0.785, 0, -2.356, 0, 1.571, 0.785]]))
    >>> ready.shape, bool(np.allclose(ready, np.swapaxes(ready, 1, 2)))
    ((1, 7, 7), True)
    """
    if not np.all(model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT):
        return None
    inverse = _inverse_mass_at(model, joint_names)
    dof = model.jnt_dofadr[model.actuator_trnid[:, 0]]

    def at(q: np.ndarray) -> np.ndarray:
        return np.linalg.inv(inverse(q)[:, dof][:, :, dof])
    return at
