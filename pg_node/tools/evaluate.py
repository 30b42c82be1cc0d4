"""``python -m pg_node eval <checkpoint>``: the deterministic return of a saved policy."""
import argparse
import json
from pathlib import Path
import sys

from pg_node.rl.checkpoint import load_latest
from pg_node.rl.evaluate import evaluate_policy
from pg_node.rl.learner import make_policy
import torch


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
