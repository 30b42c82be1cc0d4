r"""
What the learner spends per batch besides learning, and what rewriting metadata.yaml costs.

Feeds PROFILE.md, "What the learner spends per batch besides learning" (2026-12-01 session:
``recorder.record_batch``, TensorBoard, the metric messages into the bag, unpacking the
batch; ``metadata.yaml`` with 1 and 200 bag files). Those figures came from
``/tmp/t17/learner_cost.py`` and ``/tmp/t17/dump_cost.py``, which this replaces.

No node runs: the script calls, in ``learner_node.on_batch``'s order, the same functions on
the same objects the learner holds (``pg_node.ros.messages``, ``EpisodeStats``,
``EpisodeRecorder``, ``TensorBoardLog``, a ``progress.csv`` writer). The batches are real:
the default task (64 arms, 8-step rollouts) stepped with the initial policy's sampler and
judged by a critic, then packed into the ``Float64MultiArray`` the critic sends. Per batch,
each piece's CPU time (``time.process_time``, the whole process, the TensorBoard writer's
thread included) and wall time (``time.perf_counter``):

* unpack: ``messages.unpack_batch(*table_msg.from_msg(msg))`` (decode and checks);
* learn and the weights' message, for scale (on the path the actors wait on);
* the running episode statistics (``EpisodeStats.update``);
* ``recorder.record_batch``: step messages of the recorded arms, episode summaries, the
  bag's chunks;
* the 14 metrics into the bag (``recorder.record_metrics``);
* TensorBoard as the learner writes it today (``TensorBoardLog.write``, one event with all
  15 values) and, with ``--add-scalar``, the way it was when PROFILE.md's figure was taken
  (``SummaryWriter.add_scalar`` once per metric, 15 events; changed in 56f1df1);
* the ``progress.csv`` row;
* with ``--publish``, the 14 ``std_msgs/Float64`` metric messages published (rclpy, no
  subscriber; set ``ROS_DOMAIN_ID`` to keep off other graphs).

Then ``metadata.yaml``: a bag of the recorder's topics split into ``--files`` files, its
``metadata.yaml`` rewritten ``--meta-repeats`` times (``BagWriter.flush``; the writer does
it at most once a second and at each split). The file list grows with every split::

    AMENT_PREFIX_PATH=$PWD/.venv PYTHONPATH=$PWD .venv/bin/python bench/learner_batch_cost.py \
        [--batches 300] [--files 1,200] [--add-scalar] [--publish] [key=value ...]

Prints two markdown tables of medians. Not a test: nothing is asserted. Run nothing else
meanwhile (PROFILE.md's figures were taken at nice 19 beside a benchmark, so inflated).
"""
import argparse
import collections
import math
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


class Costs:
    """CPU and wall seconds of each named piece, one entry per call."""

    def __init__(self):
        self.on = True
        self.seen = collections.defaultdict(list)

    def __call__(self, name, fn, *args, **kwargs):
        """Call ``fn(*args, **kwargs)``, note its CPU and wall time under ``name``."""
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn(*args, **kwargs)
        if self.on:
            self.seen[name].append((time.process_time() - c0, time.perf_counter() - w0))
        return out


def batch_messages(cfg, count: int):
    """Return ``count`` batch messages as critic_node sends them, and the task's dims."""
    from pg_node.rl.critic import Critic
    from pg_node.rl.learner import Learner
    from pg_node.rl.rollout_buffer import RolloutBuffer
    from pg_node.rl.sampler import make_rng, NumpySampler
    from pg_node.rl.train_inprocess import task_of
    from pg_node.ros import messages, table_msg
    shared = cfg['/**']
    a_cfg, c_cfg, l_cfg = cfg['actor_node'], cfg['critic_node'], cfg['learner_node']
    task = task_of(cfg)
    learner = Learner(task.obs_dim, task.act_dim, {**l_cfg, **a_cfg})
    critic = Critic(task.obs_dim, c_cfg)
    sampler = NumpySampler.from_config(task.obs_dim, task.act_dim, {**l_cfg, **a_cfg})
    sampler.load(*learner.weights())
    rng = make_rng(shared['seed'])
    buf = RolloutBuffer(a_cfg['n_steps'], task.num_envs, task.obs_dim, task.act_dim)
    lo, hi = task.spec.ctrl_low, task.spec.ctrl_high
    obs = task.reset()
    ep_step, ep_id = task.episode_step.copy(), task.episode_id.copy()
    seq, out = 0, []
    try:
        for k in range(count):
            for _ in range(a_cfg['n_steps']):
                act, logp = sampler.sample(obs, rng)
                buf.add_action(obs, act, logp, ep_step, ep_id, seq)
                obs, rew, term, trunc, info = task.step(np.clip(act, lo, hi))
                buf.add_outcome(rew, term, trunc, info['final_obs'])
                ep_step, ep_id = info['episode_step'], info['episode_id']
                seq += 1
            ro = buf.finish()
            adv, ret, stats = critic.judge(ro)
            batch = messages.Batch(obs=ro.obs, act=ro.act, logp=ro.logp, adv=adv, ret=ret,
                                   rew=ro.rew, terminated=ro.terminated,
                                   truncated=ro.truncated, ep_step=ro.ep_step,
                                   episode_id=ro.episode_id, seq=ro.seq,
                                   actor=np.zeros(ro.rew.shape))
            header = {'version': k, 'n_actors': 1, 'batch_seq': k, 'n_steps': ro.n_steps,
                      'num_envs': ro.num_envs, 'value_loss': stats['value_loss'],
                      'explained_variance': stats['explained_variance']}
            out.append(table_msg.to_msg(*messages.pack_batch(batch, header)))
    finally:
        task.close()
    return out, task.obs_dim, task.act_dim, shared['model']


def per_batch(cfg, msgs, obs_dim, act_dim, model, skip, tmp: Path, add_scalar, publish):
    """Run the learner's per-batch work on each message; return the Costs."""
    from pg_node.bag.recorder import EpisodeRecorder
    from pg_node.common.run_dir import RunDir
    from pg_node.rl.learner import EpisodeStats, Learner
    from pg_node.rl.logger import TAGS, TensorBoardLog
    from pg_node.ros import messages, table_msg
    from pg_node.ros.learner_node import METRICS, PROGRESS_FIELDS
    from std_msgs.msg import Float64
    l_cfg = {**cfg['learner_node'], **cfg['actor_node']}
    learner = Learner(obs_dim, act_dim, l_cfg)
    stats = EpisodeStats()
    run = RunDir(tmp)                       # laid out as the learner's run directory
    recorder = EpisodeRecorder(run.next_bag(), model, record_arms=l_cfg['record_arms'],
                               split_max_episodes=l_cfg['bag_split_episodes'])
    tensorboard = TensorBoardLog(run.tensorboard)
    writer = None
    if add_scalar:
        from torch.utils.tensorboard import SummaryWriter
        writer = SummaryWriter(str(tmp / 'tensorboard_add_scalar'), flush_secs=10)
    progress = run.progress_writer(PROGRESS_FIELDS)
    node = pubs = None
    if publish:
        import rclpy
        rclpy.init()
        node = rclpy.create_node('learner_batch_cost')
        pubs = {name: node.create_publisher(Float64, f'/learner_batch_cost/metrics/{name}', 10)
                for name in METRICS}
    cost = Costs()
    t0 = time.monotonic()
    try:
        for k, msg in enumerate(msgs):
            cost.on = k >= skip
            header, batch = cost('unpack the batch (decode, checks)', messages.unpack_batch,
                                 *table_msg.from_msg(msg), obs_dim=obs_dim, act_dim=act_dim)
            out = cost('learn (for scale)', learner.learn, batch.obs, batch.act, batch.logp,
                       batch.adv)
            cost("the weights' message (flatten, pack; for scale)",
                 lambda: table_msg.to_msg(*messages.pack_weights(
                     *learner.weights(), learner.version, learner.env_steps, 0)))
            now_ns = time.time_ns()
            cost('running episode statistics (EpisodeStats.update)', stats.update, batch.rew,
                 batch.terminated, batch.truncated, batch.episode_id, batch.actor)
            cost('recorder.record_batch', recorder.record_batch, batch, learner.version,
                 now_ns)
            metrics = {
                'episode_return': stats.mean_return(), 'episode_length': stats.mean_length(),
                'policy_loss': out['policy_loss'], 'entropy': out['entropy'],
                'approx_kl': out['approx_kl'], 'grad_norm': out['grad_norm'],
                'value_loss': header['value_loss'],
                'explained_variance': header['explained_variance'],
                'policy_version': float(learner.version),
                'env_steps': float(learner.env_steps), 'policy_lag': 0.0,
                'rejected_batches': 0.0, 'skipped_updates': float(out['skipped_updates']),
                'steps_per_second': 10_000.0}
            if pubs is not None:
                cost(f'{len(metrics)} metric messages published',
                     lambda: [pubs[n].publish(Float64(data=float(v)))
                              for n, v in metrics.items()])
            cost(f'{len(metrics)} metric messages into the bag', recorder.record_metrics,
                 metrics, now_ns)
            logged = {**metrics, 'learning_rate': learner.update.learning_rate}
            cost(f'TensorBoard, one event of {len(logged)} values (TensorBoardLog.write)',
                 tensorboard.write, logged, learner.env_steps)
            if writer is not None:
                def scalars():
                    for name, value in logged.items():
                        if math.isfinite(value):
                            tag, sign = TAGS.get(name, (f'pg_node/{name}', 1.0))
                            writer.add_scalar(tag, sign * value, learner.env_steps)
                cost(f'TensorBoard, add_scalar x {len(logged)} (before 56f1df1)', scalars)
            cost('progress.csv row', progress.write, time.monotonic() - t0, metrics)
    finally:
        recorder.close()
        tensorboard.close()
        if writer is not None:
            writer.close()
        progress.close()
        if node is not None:
            import rclpy
            node.destroy_node()
            rclpy.shutdown()
    return cost, recorder.episodes_written


def metadata_cost(model, files: int, repeats: int, tmp: Path):
    """Return CPU and wall seconds of each of ``repeats`` metadata.yaml rewrites."""
    from pg_node.bag.recorder import EpisodeRecorder
    from pg_node.ros.learner_node import METRICS
    recorder = EpisodeRecorder(tmp / f'bag_{files}', model, split_max_episodes=0,
                               split_max_bytes=0)
    metrics = dict.fromkeys(METRICS, 1.0)
    try:
        for k in range(files):
            if k:
                recorder.writer.split()
            recorder.record_metrics(metrics, 1_000_000 * (k + 1))
        assert recorder.writer.file_index == files - 1
        cost = Costs()
        for _ in range(repeats):
            cost('metadata.yaml', recorder.writer.flush, metadata=True)
        return cost.seen['metadata.yaml']
    finally:
        recorder.close()


def main(argv=None) -> int:
    """Measure; print the two tables."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('overrides', nargs='*', help='key=value, as train takes them')
    parser.add_argument('--batches', type=int, default=300, help='batches timed')
    parser.add_argument('--skip', type=int, default=20, help='batches before the timing')
    parser.add_argument('--files', default='1,200', help='bag files for metadata.yaml')
    parser.add_argument('--meta-repeats', type=int, default=20)
    parser.add_argument('--add-scalar', action='store_true',
                        help='also time TensorBoard the old way, add_scalar per metric')
    parser.add_argument('--publish', action='store_true',
                        help='also time publishing the metric messages (rclpy)')
    args = parser.parse_intermixed_args(argv)
    from pg_node.common.config_files import load_config
    import torch
    torch.set_num_threads(1)                        # as the nodes and train_inprocess
    cfg = load_config(None, args.overrides)
    t0 = time.perf_counter()
    msgs, obs_dim, act_dim, model = batch_messages(cfg, args.skip + args.batches)
    made = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        cost, episodes = per_batch(cfg, msgs, obs_dim, act_dim, model, args.skip, Path(tmp),
                                   args.add_scalar, args.publish)
        meta = {f: metadata_cost(model, f, args.meta_repeats, Path(tmp))
                for f in (int(x) for x in args.files.split(','))}
    shared = cfg['/**']
    print(f"learner's work per batch: {args.batches} batches of {shared['num_envs']} arms x "
          f"{cfg['actor_node']['n_steps']} steps after {args.skip} (made in {made:.0f} s), "
          f'{episodes} episode summaries written, '
          f"record_arms={cfg['learner_node']['record_arms']}; medians")
    print()
    print('| piece, per batch | CPU ms | wall ms |')
    print('|---|---|---|')
    for name, seen in cost.seen.items():
        cpu, wall = zip(*seen)
        print(f'| {name} | {1e3 * statistics.median(cpu):.3f} | '
              f'{1e3 * statistics.median(wall):.3f} |')
    print()
    print(f'| metadata.yaml rewritten, {args.meta_repeats} times | CPU ms | wall ms |')
    print('|---|---|---|')
    for files, seen in meta.items():
        cpu, wall = zip(*seen)
        plural = 's' if files > 1 else ''
        print(f'| {files} bag file{plural} | '
              f'{1e3 * statistics.median(cpu):.3f} | {1e3 * statistics.median(wall):.3f} |')
    return 0


if __name__ == '__main__':
    sys.exit(main())
