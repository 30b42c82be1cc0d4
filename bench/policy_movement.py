r"""
How far each algorithm moves the policy per update and per sample, and how well V fits.

The estimator lab measures the variance of phi (the advantage-like weight of the likelihood
ratio gradient, eqs. 5-14 of the theory notes). Every algorithm row of BENCHMARKS.md's curves
section but plain REINFORCE uses the same phi, GAE, so the lab gives them the same variance;
what sets them apart is the step each takes from its estimate. This script measures that
step in the curves section's own computation (``train_inprocess``, seed 0):

- ``KL per update``: the mean over the batch of KL(pi_old || pi_new), the policy before and
  after the update's gradient steps (the observation normaliser's own update excluded), by
  ``torch.distributions.kl_divergence`` of the diagonal Gaussians; median over the updates;
- ``updates``: updates per 100k environment steps; ``KL per 100k``: their sum per 100k steps,
  the distance the policy travels per sample;
- ``V explained``: the critic's explained variance of the returns, measured on each rollout
  before V is fitted to it (median over the second half of the run);
- ``eval``: the deterministic evaluation at the end (100 episodes), as in the curves section.

``--tenths`` adds, per row, V's explained variance (median) in each tenth of the run: how
well the critic knows the returns when an estimator that leans on V (TD residual, GAE,
value baseline) is learning from it.

Run (one at a time on a quiet machine; about 10-40 s per row at 300k steps)::

    AMENT_PREFIX_PATH=$PWD/.venv .venv/bin/python bench/policy_movement.py --steps 300000

Not a test: nothing is asserted.
"""
import argparse
from pathlib import Path
import sys

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: row -> (preset or None for the defaults, overrides), the curves section's algorithm rows
ROWS = {
    'A2C (defaults)': (None, ()),
    'plain REINFORCE': (None, ('estimator=total_return', 'normalize_advantage=false')),
    'A2C (before issue 48)': (None, ('gamma=0.9', 'vf_epochs=1')),
    'PPO': ('ppo', ()),
    'NPG': ('npg', ()),
    'TRPO': ('trpo', ()),
    'phi = td_residual': (None, ('estimator=td_residual',)),
    'phi = value_baseline': (None, ('estimator=value_baseline',)),
    'phi = gae': (None, ('estimator=gae',)),
}
#: the rows run when --rows is not given: the algorithms (the phi rows are for --tenths)
ALGORITHM_ROWS = ('A2C (defaults)', 'plain REINFORCE', 'A2C (before issue 48)',
                  'PPO', 'NPG', 'TRPO')


def measure(preset, overrides, steps: int, seed: int):
    """Train one row; return the per-update KLs, explained variances and the evaluation."""
    import torch
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import config_file
    from pg_node.rl.train_inprocess import train_inprocess
    from pg_node.rl.updaters import UPDATERS
    cfg = load_config(config_file(preset) if preset else None, [*overrides, f'seed={seed}'])
    kls, explained = [], []
    originals = {cls: cls.update for cls in UPDATERS.values()}

    def wrap(cls):
        def update(self, batch):
            with torch.no_grad():
                before = self.policy.distribution(batch.obs)
                before = torch.distributions.Normal(before.mean.clone(), before.stddev.clone())
            out = originals[cls](self, batch)
            with torch.no_grad():
                after = self.policy.distribution(batch.obs)
                kls.append(float(torch.distributions.kl_divergence(before, after)
                                 .sum(-1).mean()))
            return out
        return update

    def progress(stats):
        if 'explained_variance' in stats:
            explained.append(stats['explained_variance'])

    for cls in originals:
        cls.update = wrap(cls)
    try:
        summary = train_inprocess(cfg, steps, progress, eval_episodes=100)
    finally:
        for cls, fn in originals.items():
            cls.update = fn
    return kls, explained, summary


def main() -> int:
    """Print one table row per algorithm."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--steps', type=int, default=300_000)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--tenths', action='store_true',
                        help="also V's explained variance in each tenth of the run")
    parser.add_argument('--rows', default=','.join(ALGORITHM_ROWS),
                        help='comma-separated rows of: ' + ', '.join(ROWS))
    args = parser.parse_args()
    rows = [r.strip() for r in args.rows.split(',') if r.strip()]
    bad = [r for r in rows if r not in ROWS]
    if bad:
        parser.error(f'unknown rows {bad}; known: {", ".join(ROWS)}')
    print(f'{args.steps:,} steps, seed {args.seed}\n')
    tenths = {}
    print('| row | updates per 100k | KL per update (median) | KL per 100k steps '
          '| V explained (median, 2nd half) | eval |')
    print('|---|---|---|---|---|---|')
    for name in rows:
        preset, overrides = ROWS[name]
        kls, explained, summary = measure(preset, overrides, args.steps, args.seed)
        per = 100_000 / summary['total_steps']
        half = explained[len(explained) // 2:]
        print(f'| {name} | {len(kls) * per:.0f} | {np.median(kls):.2e} '
              f'| {np.sum(kls) * per:.3f} | {np.median(half):.3f} '
              f'| {summary["eval_return"]:.2f} |', flush=True)
        tenths[name] = [float(np.median(part)) for part in np.array_split(explained, 10)]
    if args.tenths:
        print(f'\nV explained variance (median) in each tenth of {args.steps:,} steps\n')
        print('| row | ' + ' | '.join(f'{k}/10' for k in range(1, 11)) + ' |')
        print('|---|' + '---|' * 10)
        for name, values in tenths.items():
            print(f'| {name} | ' + ' | '.join(f'{v:.2f}' for v in values) + ' |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
