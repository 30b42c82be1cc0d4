"""
What drawing arm 0's scene into the training bag costs the learner (``record_scene_period``).

Run from the repository root:

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/bench_bag_scene.py

Batches of a real :class:`pg_node.sim.arm_task.ArmTask` (random actions, ``--arms`` arms,
``--steps`` steps each) are made first; then :class:`pg_node.bag.recorder.EpisodeRecorder`
records them (``record_arms`` 4, zstd) with each ``scene_period`` in turn, the log clock
advancing as a training at ``--rate`` environment steps per second would move it. Each row
is the best of ``--repeat`` runs, the rows interleaved run by run (a shared machine's load
drifts). ``off`` is the bag as before; ``trail only`` draws once (period 1e9 s): the cost
of moving arm 0's kinematics and trail every step; the others add the messages.
Columns: CPU ms per batch, us per recorded step of arm 0, bag MB.
"""
import argparse
from pathlib import Path
import shutil
import tempfile
import time

import numpy as np
from pg_node.bag.recorder import EpisodeRecorder
from pg_node.common.paths import resolve_model
from pg_node.ros.messages import Batch
from pg_node.ros.scene_msg import scene_markers
from pg_node.sim.arm_task import ArmTask


def batches(model, arms, steps, count, seed=0):
    """Return ``count`` Batches of ``steps`` steps of ``arms`` arms of one actor."""
    task = ArmTask(model, num_envs=arms, seed=seed)
    rng = np.random.default_rng(seed)
    obs, seq, out = task.reset(), 0, []
    for _ in range(count):
        cols = {k: [] for k in ('obs', 'act', 'rew', 'terminated', 'truncated', 'ep_step',
                                'episode_id', 'seq', 'actor')}
        for _ in range(steps):
            act = rng.normal(0.0, 1.0, (arms, task.act_dim))
            ep_step, ep_id = task.episode_step.copy(), task.episode_id.copy()
            before = obs
            obs, rew, term, trunc, _ = task.step(np.clip(act, task.spec.ctrl_low,
                                                         task.spec.ctrl_high))
            for k, v in (('obs', before), ('act', act), ('rew', rew), ('terminated', term),
                         ('truncated', trunc), ('ep_step', ep_step), ('episode_id', ep_id),
                         ('seq', np.full(arms, seq)), ('actor', np.zeros(arms, int))):
                cols[k].append(v)
            seq += 1
        arrays = {k: np.stack(v) for k, v in cols.items()}
        shape = arrays['rew'].shape
        out.append(Batch(logp=np.zeros(shape), adv=np.zeros(shape), ret=np.zeros(shape),
                         **arrays))
    task.close()
    return out


def record(tmp: Path, model, data, period, rate):
    """Record ``data`` with ``period``; return (CPU s, bag bytes)."""
    bag = tmp / 'bag'
    if bag.exists():
        shutil.rmtree(bag)
    rec = EpisodeRecorder(bag, model, record_arms=4, split_max_episodes=0,
                          draw_scene=scene_markers if period else None, scene_period=period)
    t_wall, step_ns = 1_700_000_000_000_000_000, 0
    cpu = time.process_time()
    for batch in data:
        n = np.asarray(batch.rew).size
        step_ns += int(n / rate * 1e9)
        rec.record_batch(batch, 0, t_wall + step_ns)
    rec.close()
    cpu = time.process_time() - cpu
    return cpu, sum(p.stat().st_size for p in bag.glob('*.mcap'))


def main():
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--model', default='reacher2')
    parser.add_argument('--arms', type=int, default=64)
    parser.add_argument('--steps', type=int, default=64)
    parser.add_argument('--batches', type=int, default=40)
    parser.add_argument('--rate', type=float, default=9000.0,
                        help='environment steps per second of the training (log clock)')
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args()
    model = str(resolve_model(args.model))
    data = batches(model, args.arms, args.steps, args.batches)
    rows = {'off': 0.0, 'trail only': 1e9, 'period 1 s': 1.0, 'period 0.25 s': 0.25}
    best = dict.fromkeys(rows)
    tmp = Path(tempfile.mkdtemp(prefix='bench_bag_scene_'))
    try:
        for _ in range(args.repeat):
            for name, period in rows.items():
                got = record(tmp, model, data, period, args.rate)
                if best[name] is None or got[0] < best[name][0]:
                    best[name] = got
    finally:
        shutil.rmtree(tmp)
    seconds = args.batches * args.arms * args.steps / args.rate
    print(f'{args.model}: {args.batches} batches of {args.arms} arms x {args.steps} steps '
          f'({seconds:.0f} s of training at {args.rate:g} steps/s), record_arms 4, best of '
          f'{args.repeat}')
    print('| scene | CPU ms / batch | us / step of arm 0 | bag MB |')
    print('|---|---|---|---|')
    for name, (cpu, size) in best.items():
        print(f'| {name} | {1e3 * cpu / args.batches:.2f} | '
              f'{1e6 * cpu / (args.batches * args.steps):.1f} | {size / 1e6:.2f} |')


if __name__ == '__main__':
    main()
