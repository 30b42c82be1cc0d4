"""
An arm model's actuators as :mod:`pg_node.control.interfaces` takes them: read from MuJoCo.

:func:`actuators` reads each actuator's gain, biases, gear, control range and its joint's
range out of an ``MjModel`` into a plain :class:`pg_node.control.interfaces.Actuators`
record, and says which actuators follow MuJoCo's affine law (fixed gain, no activation
dynamics, a joint transmission); the command interfaces, their units and maps live there.
"""
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
        joint_high=np.where(limited, rng[:, 1], np.inf), affine=affine)


def ctrl_range(model: mujoco.MjModel):
    """Return each actuator's control range ``(low, high)``, infinite where unlimited."""
    limited = model.actuator_ctrllimited.astype(bool)
    return (np.where(limited, model.actuator_ctrlrange[:, 0], -np.inf),
            np.where(limited, model.actuator_ctrlrange[:, 1], np.inf))
