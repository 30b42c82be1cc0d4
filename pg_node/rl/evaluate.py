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


def evaluate_policy(policy, model: str, n_episodes: int = 100, seed: int = 0,
                    max_episode_steps: int = 50,
                    perturbation: Optional[Mapping] = None) -> Dict[str, float]:
    """Run ``n_episodes`` episodes of ``policy.mean_action`` side by side; return statistics."""
    task = ArmTask(resolve_model(model), num_envs=n_episodes,
                   seed=seed + EVAL_SEED_OFFSET, max_episode_steps=max_episode_steps,
                   randomization=perturbation)
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
    return {'eval_return': float(np.mean(returns)), 'eval_return_std': float(np.std(returns)),
            'eval_episodes': int(n_episodes), 'eval_returns': returns.tolist(),
            'eval_final_distance': float(np.mean(final)),
            'eval_reached': float(np.mean(final <= REACHED)),
            'eval_final_distances': final.tolist()}
