"""
``python -m pg_node eval <run dir or checkpoint>``: the deterministic return of a saved policy.

Takes a run directory (its ``checkpoints/``), a directory of policy checkpoints (the newest
valid one is used) or one ``ckpt_*.pt`` file. A directory of the critic's checkpoints
(``<run>/critic``), a ``--model`` whose observation or action size differs from the one the
policy was trained on, and an unreadable file are refused in one line.
"""
import argparse
import json
import sys

from pg_node.rl.evaluate import evaluate_policy
from pg_node.rl.learner import make_policy
from pg_node.rl.trained_policy import find_checkpoint, PolicySourceError
from pg_node.tools.args import positive_int


def main(argv=None) -> int:
    """Run ``python -m pg_node eval``."""
    parser = argparse.ArgumentParser(prog='python -m pg_node eval',
                                     description='Evaluate a saved policy checkpoint.')
    parser.add_argument('checkpoint', help='a run directory, its checkpoints/ (the newest '
                                           'valid one is used) or a ckpt_*.pt file')
    parser.add_argument('--episodes', type=positive_int, default=100,
                        help='default: %(default)s')
    parser.add_argument('--seed', type=int, default=0, help='default: %(default)s')
    parser.add_argument('--model', help='arm model (default: the one it was trained on)')
    parser.add_argument('--json', action='store_true', help='print JSON')
    args = parser.parse_args(argv)
    try:
        state, _ = find_checkpoint(args.checkpoint)
    except PolicySourceError as exc:
        print(f'eval: {exc}', file=sys.stderr)
        return 1
    cfg = state['config']
    model = args.model or cfg['model']
    from pg_node.common.paths import resolve_model
    from pg_node.sim.arm_task import ArmTask
    try:
        task = ArmTask(resolve_model(model), num_envs=1)
    except (ValueError, OSError) as exc:
        print(f'eval: --model {model}: {exc}', file=sys.stderr)
        return 2
    sizes = (task.obs_dim, task.act_dim)
    task.close()
    if sizes != (state['obs_dim'], state['act_dim']):
        print(f'eval: --model {model} has {sizes[0]} observations and {sizes[1]} actions; the '
              f'policy was trained on {cfg["model"]} with {state["obs_dim"]} and '
              f'{state["act_dim"]}', file=sys.stderr)
        return 2
    policy = make_policy(state['obs_dim'], state['act_dim'], cfg)
    policy.load_state_dict(state['policy'])
    res = evaluate_policy(policy, model, args.episodes, args.seed)
    res['policy_version'] = int(state['version'])
    del res['eval_returns']
    if args.json:
        print(json.dumps(res))
    else:
        print(f"policy version {res['policy_version']}: return {res['eval_return']:.2f} "
              f"+/- {res['eval_return_std']:.2f} over {args.episodes} episodes")
    return 0
