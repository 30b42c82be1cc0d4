r"""
Benchmark: whether longer training brings config/dr.yaml within 1.5x on a heavier reacher2.

Trains the ``dr`` preset in process (``train_inprocess``: the graph's computation, bit for
bit) for each ``--steps`` value with one seed, then evaluates the deterministic policy on
100 episodes of the nominal arm and of single perturbations (armature x1.5 and x2, latency
3 steps, strength x0.6, damping x3), and prints per perturbation the return, the mean final
distance in cm, the share within 2 cm and the ratio of the final distance to the nominal::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/bench_dr_length.py \
        --steps 1000000 3000000 [--seed 0]

Used for issue 30's note of 2026-12-04 (1M and 3M, seed 0). Not a test; nothing asserted.
"""
import argparse
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

PERTURBATIONS = (None, 'armature_scale=1.5', 'armature_scale=2', 'latency_steps=3',
                 'gear_scale=0.6', 'damping_scale=3')


def main() -> int:
    """Train for each step count, evaluate, print a table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, nargs='+', default=[1_000_000, 3_000_000])
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import config_file
    from pg_node.common.perturbations import parse_perturbation
    from pg_node.rl.evaluate import evaluate_policy
    from pg_node.rl.train_inprocess import train_inprocess
    print('| steps | perturbation | return | final distance (cm) | within 2 cm | x nominal |')
    print('|---:|---|---:|---:|---:|---:|')
    for steps in args.steps:
        cfg = load_config(config_file('dr'), [f'seed={args.seed}'])
        policy = train_inprocess(cfg, steps, eval_episodes=1)['learner'].policy
        nominal = None
        for key in PERTURBATIONS:
            terms = {} if key is None else parse_perturbation([key])
            res = evaluate_policy(policy, cfg['/**']['model'], 100, 0, perturbation=terms)
            cm = 100 * res['eval_final_distance']
            nominal = cm if key is None else nominal
            print(f"| {steps:,} | {key or 'nominal'} | {res['eval_return']:.3f} | {cm:.2f} | "
                  f"{100 * res['eval_reached']:.0f}% | {cm / nominal:.2f} |", flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
