r"""
Where an in-process training spends its time: per control step and per rollout, medians.

Feeds PROFILE.md, "Where the graph's time goes that in-process does not spend" (the
paragraph "In one process": ``ArmTask.step`` and the numpy sample per control step; V's
judge, V's fit, the A2C update and the hand-over of the weights per rollout). Those figures
were taken by ``/tmp/rec/ip_parts.py``, which this replaces.

Runs ``pg_node.rl.train_inprocess`` (the default parameters, or a preset and overrides)
with a few of its calls wrapped from outside with ``time.perf_counter``; nothing in
``pg_node`` changes, and the training does the same arithmetic as without the wrappers
(about 1 us each per call). Per control step: ``ArmTask.step`` and ``NumpySampler.sample``
(one call per group of arms, summed over the step). Per rollout: ``Critic.judge`` (V of
every state, phi), ``Critic.fit`` (V's regression step), ``Learner.learn`` (the update),
and the weights into the sampler (``Learner.weights`` plus ``NumpySampler.load``), then the
whole rollout (one callback to the next) and what the pieces leave of it (the buffer,
clipping, bookkeeping). The first ``--skip`` rollouts (start-up) and the evaluation at the
end are left out::

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/inprocess_parts.py \
        200000 [key=value ...] [--config arm7] [--skip 50]

Prints one markdown row per piece: calls counted, median and p90 in ms. Not a test:
nothing is asserted. Run nothing else meanwhile; the machine's drift shows in the
totals more than in the shares.
"""
import argparse
import collections
from pathlib import Path
import statistics
import sys
import time

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

#: (class path, method, piece, per): the calls wrapped; ``per`` is 'step' or 'rollout'
WRAPPED = (
    ('pg_node.sim.arm_task.ArmTask', 'step', 'ArmTask.step', 'step'),
    ('pg_node.rl.sampler.NumpySampler', 'sample', 'numpy sample', 'step'),
    ('pg_node.rl.critic.Critic', 'judge', "V's judge (Critic.judge)", 'rollout'),
    ('pg_node.rl.critic.Critic', 'fit', "V's fit (Critic.fit)", 'rollout'),
    ('pg_node.rl.learner.Learner', 'learn', 'A2C update (Learner.learn)', 'rollout'),
    ('pg_node.rl.learner.Learner', 'weights', 'weights to the sampler', 'rollout'),
    ('pg_node.rl.sampler.NumpySampler', 'load', 'weights to the sampler', 'rollout'),
)


class Probe:
    """Seconds spent in each wrapped piece, keyed by control step or rollout."""

    def __init__(self):
        self.on = True
        self.step = 0              # control steps begun
        self.rollout = 0           # rollouts finished (callbacks seen)
        self.spent = collections.defaultdict(lambda: collections.defaultdict(float))
        self.rollout_end = []      # perf_counter at each callback
        self.undo = []

    def wrap(self, where: str, method: str, piece: str, per: str):
        """Replace ``where.method`` by a timed call; remember how to undo it."""
        module, _, name = where.rpartition('.')
        cls = getattr(__import__(module, fromlist=[name]), name)
        orig = getattr(cls, method)
        probe = self

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return orig(*args, **kwargs)
            finally:
                if probe.on:
                    key = probe.step if per == 'step' else probe.rollout
                    probe.spent[piece][key] += time.perf_counter() - t0
                    if method == 'step':
                        probe.step += 1

        setattr(cls, method, timed)
        self.undo.append((cls, method, orig))

    def restore(self):
        """Put the original methods back."""
        for cls, method, orig in reversed(self.undo):
            setattr(cls, method, orig)
        self.undo = []


def stats_ms(values):
    """Return ``(n, median ms, p90 ms)`` of seconds."""
    values = sorted(values)
    if not values:
        return 0, float('nan'), float('nan')
    return (len(values), 1e3 * statistics.median(values),
            1e3 * values[min(len(values) - 1, int(0.9 * len(values)))])


def main(argv=None) -> int:
    """Train with the probe on; print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('steps', type=float, help='environment steps (2e5 works)')
    parser.add_argument('overrides', nargs='*', help='key=value, as train takes them')
    parser.add_argument('--config', help='a preset name or parameter file (default: defaults)')
    parser.add_argument('--skip', type=int, default=50,
                        help='rollouts left out at the start (at least 1: the first holds '
                             'the initial weights load)')
    args = parser.parse_intermixed_args(argv)
    from pg_node.common.config_files import load_config
    from pg_node.common.paths import config_file
    from pg_node.rl.train_inprocess import train_inprocess
    cfg = load_config(config_file(args.config) if args.config else None, args.overrides)
    total = int(args.steps)
    skip = max(1, args.skip)
    probe = Probe()
    for entry in WRAPPED:
        probe.wrap(*entry)

    def callback(info):
        probe.rollout_end.append(time.perf_counter())
        probe.rollout += 1
        if info['env_steps'] >= total:
            probe.on = False           # the evaluation that follows steps its own ArmTask

    try:
        summary = train_inprocess(cfg, total, callback=callback, eval_episodes=1)
    finally:
        probe.restore()
    n_steps = cfg['actor_node']['n_steps']
    first_step = skip * n_steps        # control steps of the rollouts left out
    ends = probe.rollout_end
    kept = range(skip, len(ends))
    if len(kept) < 2:
        print(f'only {len(ends)} rollouts: give more steps or a smaller --skip')
        return 1
    rows = []

    def per_step(piece):
        return [s for k, s in probe.spent[piece].items() if k >= first_step]

    def per_rollout(piece):
        return [probe.spent[piece].get(k, 0.0) for k in kept]

    rows.append(('ArmTask.step', 'control step', per_step('ArmTask.step')))
    rows.append(('numpy sample (every group of arms)', 'control step',
                 per_step('numpy sample')))
    sample = probe.spent['numpy sample']
    rows.append(('both', 'control step', [s + sample.get(k, 0.0) for k, s
                                          in probe.spent['ArmTask.step'].items()
                                          if k >= first_step]))
    pieces = ["V's judge (Critic.judge)", "V's fit (Critic.fit)", 'A2C update (Learner.learn)',
              'weights to the sampler']
    for piece in pieces:
        rows.append((piece, 'rollout', per_rollout(piece)))
    together = [sum(probe.spent[p].get(k, 0.0) for p in pieces) for k in kept]
    rows.append(('the four together', 'rollout', together))
    whole = [ends[k] - ends[k - 1] for k in kept]
    rows.append((f'the whole rollout ({n_steps} control steps and the four)', 'rollout', whole))
    in_steps = [sum(probe.spent[p].get(s, 0.0)
                    for p in ('ArmTask.step', 'numpy sample')
                    for s in range(k * n_steps, (k + 1) * n_steps)) for k in kept]
    rows.append(('the rest (buffer, clipping, bookkeeping)', 'rollout',
                 [w - t - s for w, t, s in zip(whole, together, in_steps)]))
    shared = cfg['/**']
    print(f"in-process training, {summary['total_steps']:,} steps, "
          f"{shared['num_envs']} arms, {n_steps}-step rollouts, "
          f"{shared['lock_step_groups']} group(s): {summary['steps_per_second']:,.0f} "
          f'steps/s over the run, {len(kept)} rollouts after the first {skip} '
          f'({n_steps * shared["num_envs"] * len(kept) / sum(whole):,.0f} steps/s in them)')
    print()
    print('| piece | per | n | median ms | p90 ms |')
    print('|---|---|---|---|---|')
    for piece, per, values in rows:
        n, med, p90 = stats_ms(values)
        print(f'| {piece} | {per} | {n:,} | {med:.3f} | {p90:.3f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
