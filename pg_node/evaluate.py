"""
Evaluate a policy's deterministic mean action: ``python -m pg_node eval <checkpoint>``.

Every arm runs one full episode with ``u = mu(s)``; the report is the mean and standard
deviation of the episode returns (the metric Gymnasium and SB3 report for Reacher).
"""
import argparse
import json
from pathlib import Path
import sys
from typing import Dict

import numpy as np
from pg_node.arm_task import ArmTask
from pg_node.paths import resolve_model
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


def main(argv=None) -> int:
    """Run ``python -m pg_node eval``."""
    parser = argparse.ArgumentParser(prog='python -m pg_node eval',
                                     description='Evaluate a saved policy checkpoint.')
    parser.add_argument('checkpoint', help='a ckpt_*.pt file, or a directory of them '
                                           '(the newest valid one is used)')
    parser.add_argument('--episodes', type=int, default=100, help='default: %(default)s')
    parser.add_argument('--seed', type=int, default=0, help='default: %(default)s')
    parser.add_argument('--model', help='arm model (default: the one it was trained on)')
    parser.add_argument('--json', action='store_true', help='print JSON')
    args = parser.parse_args(argv)
    from pg_node.checkpoint import load_latest
    from pg_node.learner import make_policy
    path = Path(args.checkpoint)
    if path.is_dir():
        state, problems = load_latest(path)
        for p in problems:
            print(p, file=sys.stderr)
        if state is None:
            print(f'no readable checkpoint in {path}', file=sys.stderr)
            return 1
    else:
        try:
            state = torch.load(path, map_location='cpu', weights_only=False)
        except Exception as exc:  # noqa: B902 - report any unreadable file clearly
            print(f'cannot read checkpoint {path}: {exc}', file=sys.stderr)
            return 1
    cfg = state['config']
    policy = make_policy(state['obs_dim'], state['act_dim'], cfg)
    policy.load_state_dict(state['policy'])
    res = evaluate_policy(policy, args.model or cfg['model'], args.episodes, args.seed)
    res['policy_version'] = int(state['version'])
    del res['eval_returns']
    if args.json:
        print(json.dumps(res))
    else:
        print(f"policy version {res['policy_version']}: return {res['eval_return']:.2f} "
              f"+/- {res['eval_return_std']:.2f} over {args.episodes} episodes")
    return 0
