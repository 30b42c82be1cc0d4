"""
Evaluate a policy's deterministic mean action on the simulated arm.

Every arm runs one full episode with ``u = mu(s)``; the report is the mean and standard
deviation of the episode returns (the metric Gymnasium and SB3 report for Reacher), the
mean fingertip-to-target distance at the episode's end and the share of episodes that end
within :data:`REACHED` of the target. ``perturbation`` (terms of
:mod:`pg_node.common.perturbations`, e.g. from ``--perturb mass_scale=1.3``) evaluates on
an arm that is not the model; the episodes' starts and goals stay the same, so runs and
perturbations are compared on the very same episodes.
"""
from typing import Dict, Mapping, Optional

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask
import torch

EVAL_SEED_OFFSET = 10_000
#: an episode "reaches" its target when it ends this close to it (m)
REACHED = 0.02


def metrics(returns: np.ndarray, final: np.ndarray) -> dict:
    """Return the evaluation's summary of per-episode returns and final distances (m)."""
    return {'eval_return': float(np.mean(returns)), 'eval_return_std': float(np.std(returns)),
            'eval_episodes': len(returns), 'eval_returns': returns.tolist(),
            'eval_final_distance': float(np.mean(final)),
            'eval_reached': float(np.mean(final <= REACHED)),
            'eval_final_distances': final.tolist()}


def evaluate_policy(policy, model: str, n_episodes: int = 100, seed: int = 0,
                    max_episode_steps: int = 50,
                    perturbation: Optional[Mapping] = None,
                    frame_skip: int = 2, position_delta=None) -> Dict[str, float]:
    """
    Run ``n_episodes`` episodes of ``policy.mean_action`` side by side; return statistics.

    ``position_delta``: the run's (its card's ``max_position_delta``), for a model without
    its own ``pg_position_delta`` (:func:`pg_node.sim.arm_task.with_position_delta`).
    """
    task = ArmTask(resolve_model(model), num_envs=n_episodes,
                   seed=seed + EVAL_SEED_OFFSET, max_episode_steps=max_episode_steps,
                   randomization=perturbation, frame_skip=frame_skip,
                   position_delta=position_delta)
    try:
        obs = task.reset()
        returns = np.full(n_episodes, np.nan)
        final = np.full(n_episodes, np.nan)
        lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
        with torch.no_grad():
            for _ in range(max_episode_steps):
                act = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
                obs, _, _, _, info = task.step(np.clip(act.astype(np.float64), lo, hi))
                first = ~np.isnan(info['episode_return']) & np.isnan(returns)
                returns[first] = info['episode_return'][first]
                final[first] = info['distance'][first]
    finally:
        task.close()
    return metrics(returns, final)


def evaluate_in_pybullet(policy, model: str, urdf, n_episodes: int = 100, seed: int = 0,
                         max_episode_steps: int = 50, frame_skip: int = 2,
                         gravity_compensation: Optional[bool] = None,
                         package_paths=(), max_timestep: Optional[float] = None,
                         position_delta=None, payload: float = 0.0) -> Dict[str, float]:
    """
    Run :func:`evaluate_policy`'s episodes with the arm in PyBullet, read from ``urdf``.

    The starts and goals are drawn by the MuJoCo task exactly as :func:`evaluate_policy`
    draws them (same seeds); each episode then runs in a
    :class:`pg_node.sim.pybullet_arm.PybulletArm` of the robot's URDF, lock-step: the
    observation is rebuilt from PyBullet's joint angles and velocities with the model's
    forward kinematics (:class:`pg_node.sim.observation.ObservationBuilder`, as
    ``policy_node`` builds it on a robot), ``u = mu(s)`` clipped to the control range is
    turned into N m (motor actuators), rad (position servos) or rad/s (velocity servos) by
    the model's actuators
    (:mod:`pg_node.control.interfaces`) and held for a control period of ``frame_skip`` x
    the model's timestep. The reward and the distance are the task's, with the fingertip
    where PyBullet puts it (the tip link's frame plus the model's fingertip offset).
    A policy of relative position targets (the model's ``pg_position_delta`` or the run's
    ``position_delta``) commands ``q + u d`` around PyBullet's angles, as ``policy_node`` does.
    ``gravity_compensation``: None follows the model (its links' ``gravcomp``).
    ``payload``: kg hung at the fingertip that the compensation does not know, as MuJoCo's
    ``payload`` term (:meth:`pg_node.sim.pybullet_arm.PybulletArm.set_payload`).
    The result also holds ``pybullet_timestep`` and ``pybullet_warnings``.
    """
    from pg_node.control.interfaces import check, INTERFACES
    from pg_node.sim.actuation import actuators
    from pg_node.sim.observation import ObservationBuilder
    from pg_node.sim.pybullet_arm import PybulletArm
    from pg_node.sim.training_physics import gravity_compensation as who_compensates
    from pg_node.control.position_delta import targets
    task = ArmTask(resolve_model(model), num_envs=n_episodes, seed=seed + EVAL_SEED_OFFSET,
                   max_episode_steps=max_episode_steps, frame_skip=frame_skip,
                   position_delta=position_delta)
    task.reset()
    q0, qd0, _ = task.joint_state()
    goals = task.target_pos()
    task.close()
    m, s = task.model, task.spec
    act = actuators(m)
    # the interface of the actuators' kind (velocity servos were run as position ones)
    interface = next((name for name in INTERFACES if check(act, name) is None), 'position')
    why = check(act, interface)
    if why:
        raise ValueError(why)
    to_si = INTERFACES[interface].to_si
    delta = task.position_delta
    reach = INTERFACES['position'].si_range(act) if delta is not None else None
    if gravity_compensation is None:
        gravity_compensation = who_compensates(m, s.link_bodies) == 'robot'
    tip_link = m.body(int(m.site_bodyid[s.fingertip_site])).name
    tip_offset = m.site_pos[s.fingertip_site].copy()
    obs_of = ObservationBuilder(m)
    arm = PybulletArm(urdf, s.joint_names, control_period=task.dt, max_timestep=max_timestep,
                      gravity_compensation=gravity_compensation, package_paths=package_paths)
    if payload:
        arm.set_payload(tip_link, tip_offset, payload)
    returns, final = np.empty(n_episodes), np.empty(n_episodes)
    lo, hi = s.ctrl_low, s.ctrl_high
    try:
        with torch.no_grad():
            for i in range(n_episodes):
                arm.set_state(q0[i], qd0[i])
                ret = 0.0
                for _ in range(max_episode_steps):
                    q, qd, _ = arm.state()
                    obs = obs_of(q[None], qd[None], goals[i][None])
                    u = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
                    u = u[0].astype(np.float64)
                    arm.step(to_si(act, np.clip(u, lo, hi)) if delta is None
                             else targets(u, q, delta, *reach), mode=interface)
                    dist = float(np.linalg.norm(arm.link_position(tip_link, tip_offset)
                                                - goals[i]))
                    # the task's reward: the unclipped action in the penalty (ArmTask.step)
                    ret += -task.reward_dist_weight * dist \
                        - task.reward_control_weight * float(np.square(u).sum())
                returns[i], final[i] = ret, dist
        timestep, warnings = arm.timestep, list(arm.warnings)
    finally:
        arm.close()
    return dict(metrics(returns, final), pybullet_timestep=timestep,
                pybullet_warnings=warnings)
