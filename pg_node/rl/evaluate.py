"""
Evaluate a policy's deterministic mean action on the simulated arm.

Every arm runs one full episode with ``u = mu(s)``; the report is the mean and standard
deviation of the episode returns (the metric Gymnasium and SB3 report for Reacher).
"""
from typing import Dict

import numpy as np
from pg_node.common.paths import resolve_model
from pg_node.sim.arm_task import ArmTask
import torch

EVAL_SEED_OFFSET = 10_000


def evaluate_policy(policy, model: str, n_episodes: int = 100, seed: int = 0,
                    max_episode_steps: int = 50) -> Dict[str, float]:
    """Run ``n_episodes`` episodes of ``policy.mean_action`` side by side; return statistics."""
    task = ArmTask(resolve_model(model), num_envs=n_episodes,
                   seed=seed + EVAL_SEED_OFFSET, max_episode_steps=max_episode_steps)
    try:
        obs = task.reset()
        returns = np.full(n_episodes, np.nan)
        lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
        with torch.no_grad():
            for _ in range(max_episode_steps):
                act = policy.mean_action(torch.as_tensor(obs, dtype=torch.float32)).numpy()
                obs, _, _, _, info = task.step(np.clip(act.astype(np.float64), lo, hi))
                first = ~np.isnan(info['episode_return']) & np.isnan(returns)
                returns[first] = info['episode_return'][first]
    finally:
        task.close()
    return {'eval_return': float(np.mean(returns)), 'eval_return_std': float(np.std(returns)),
            'eval_episodes': int(n_episodes), 'eval_returns': returns.tolist()}
