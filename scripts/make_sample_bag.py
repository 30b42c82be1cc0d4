"""
Make ``bags/sample/``: training metrics and a few episodes of a trained policy on reacher2.

Trains in-process (:func:`pg_node.rl.train_inprocess.train_inprocess`, the same classes the
nodes wrap) while an :class:`pg_node.bag.recorder.EpisodeRecorder` records the training
metrics on ``/pg_node/metrics/*`` at their real wall times; then runs the trained policy's
deterministic action on ``--arms`` arms for ``--episodes`` episodes each, in batches of
``--batch-steps`` steps annotated by the trained critic, and records them (joint states,
targets, commands, rewards, episode summaries) paced at simulated real time.

Usage (from the repository root)::

    python scripts/make_sample_bag.py [--total-steps N] [--out bags/sample] [key=value ...]
"""
import argparse
import json
from pathlib import Path
import shutil
import sys
import time

import numpy as np
from pg_node.bag.recorder import EpisodeRecorder
from pg_node.common.config_files import load_config
from pg_node.common.paths import resolve_model
from pg_node.rl.rollout_buffer import RolloutBuffer
from pg_node.rl.train_inprocess import train_inprocess
from pg_node.ros.messages import Batch
from pg_node.sim.arm_task import ArmTask

EVAL_SEED_OFFSET = 20_000


def record_episodes(rec, policy, critic, model, arms, episodes, batch_steps, seed, version,
                    max_episode_steps=50):
    """Run ``policy``'s mean action on ``arms`` arms and record ``episodes`` each."""
    task = ArmTask(resolve_model(model), num_envs=arms, seed=seed,
                   max_episode_steps=max_episode_steps)
    lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
    buf = RolloutBuffer(batch_steps, arms, task.obs_dim, task.act_dim)
    obs = task.reset()
    seq = 0
    returns = []
    t_wall = time.time_ns()
    total = episodes * max_episode_steps
    try:
        while seq < total:
            for _ in range(min(batch_steps, total - seq)):
                act, logp = policy.act_numpy(obs, deterministic=True)
                buf.add_action(obs, act, logp, task.episode_step, task.episode_id, seq)
                obs, rew, term, trunc, info = task.step(np.clip(act, lo, hi))
                buf.add_outcome(rew, term, trunc, info['final_obs'])
                returns += info['episode_return'][~np.isnan(info['episode_return'])].tolist()
                seq += 1
            if buf.pos < buf.n_steps:  # a last, shorter batch
                T = buf.pos
                for name in ('obs', 'act', 'logp', 'rew', 'terminated', 'truncated',
                             'final_obs', 'ep_step', 'episode_id', 'seq'):
                    setattr(buf, name, getattr(buf, name)[:T])
                buf.n_steps = T
            ro = buf.finish()
            adv, ret, _ = critic.annotate(ro, policy)
            batch = Batch(obs=ro.obs, act=ro.act, logp=ro.logp, adv=adv, ret=ret, rew=ro.rew,
                          terminated=ro.terminated, truncated=ro.truncated,
                          ep_step=ro.ep_step, episode_id=ro.episode_id, seq=ro.seq,
                          actor=np.zeros_like(ro.seq))
            # paced at simulated real time: replay at rate 1 shows the arm at its real speed
            t_wall += int(round(ro.rew.shape[0] * task.dt * 1e9))
            rec.record_batch(batch, version, t_wall)
    finally:
        task.close()
    return returns, t_wall


def main(argv=None) -> int:
    """Train, record, print what was made."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('overrides', nargs='*', help='key=value parameter overrides')
    parser.add_argument('--total-steps', type=int, default=600_000)
    parser.add_argument('--out', type=Path, default=Path('bags/sample'))
    parser.add_argument('--arms', type=int, default=4)
    parser.add_argument('--episodes', type=int, default=3, help='episodes per arm')
    parser.add_argument('--batch-steps', type=int, default=20)
    args = parser.parse_args(argv)
    cfg = load_config(None, args.overrides)
    shared = cfg['/**']
    if args.out.exists():
        shutil.rmtree(args.out)
    rec = EpisodeRecorder(args.out, shared['model'], record_arms=args.arms,
                          split_max_episodes=0, split_max_bytes=0)
    t_start = time.time()

    def on_update(m):
        metrics = dict(m)
        metrics['steps_per_second'] = m['env_steps'] / max(m['wall_seconds'], 1e-9)
        rec.record_metrics(metrics, time.time_ns())

    try:
        summary = train_inprocess(cfg, args.total_steps, on_update)
        learner, critic = summary['learner'], summary['critic']
        returns, t_end = record_episodes(
            rec, learner.policy, critic, shared['model'], args.arms, args.episodes,
            args.batch_steps, shared['seed'] + EVAL_SEED_OFFSET, learner.version)
        rec.record_metrics({'eval_return': summary['eval_return'],
                            'eval_return_std': summary['eval_return_std']}, t_end)
    finally:
        rec.close()
    size = sum(f.stat().st_size for f in args.out.iterdir())
    report = {'total_steps': summary['total_steps'],
              'train_wall_seconds': round(summary['wall_seconds'], 1),
              'policy_version': summary['policy_version'],
              'eval_return_100_episodes': round(summary['eval_return'], 3),
              'eval_return_std': round(summary['eval_return_std'], 3),
              'recorded_episodes': rec.episodes_written,
              'recorded_mean_return': round(float(np.mean(returns)), 3),
              'bag_bytes': size, 'seconds': round(time.time() - t_start, 1)}
    print(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
