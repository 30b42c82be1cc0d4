"""
learner_node: applies the A2C (or PPO) update, publishes weights, logs, checkpoints.

Subscribes ``/<run>/pg_node/batch`` (from ``critic_node``); publishes
``/<run>/pg_node/policy_weights`` (reliable, transient-local, depth 1: a late or restarted
actor gets the newest), one ``std_msgs/Float64`` topic per training metric under
``/<run>/pg_node/metrics/`` (``episode_return``,
``episode_length``, ``policy_loss``, ``value_loss``, ``entropy``, ``explained_variance``,
``approx_kl``, ``grad_norm``, ``steps_per_second``, ``policy_version``, ``env_steps``,
``policy_lag``, ``rejected_batches``, ``skipped_updates``), each episode summary on
``/<run>/pg_node/episode`` as the bag gets it (the bag's own topics are ``/pg_node/...``),
its state on ``/<run>/pg_node/learner_state`` (latched ``DiagnosticStatus``: ``training``,
then ``done``; nodes started one by one end at ``done``,
:class:`pg_node.ros.run_protocol.EndWithLearner`), and ``/diagnostics``. ``<run>``: the
``run_id`` parameter (:mod:`pg_node.common.run`); the
empty one drops the prefix.

Each accepted batch is one update and one new policy version; which batch is accepted is
:class:`pg_node.rl.learner_gate.LearnerGate`'s decision. A batch received again (the
same version and number: the critic re-sends when the actor's rollout comes again) is not
learned from twice; the weights are published again instead, in case they were lost. In
``sync`` mode a batch sampled by any version other than the current one is refused and
counted (on-policy A2C); in ``async`` mode batches up to ``max_policy_lag`` versions old
are learned from and the lag is reported. A malformed batch (layout, non-finite or absurd
values) is dropped, counted (``dropped_batches``) and warned about at most once a second.
When an actor's transition numbers start again (its simulator restarted), the episodes its
arms had open are written to the bag as cut short (``sim_restarts_seen`` counts this).

Everything the run makes goes under ``run_dir``: ``checkpoints/`` (atomic, the newest valid
one resumed on restart), ``bag/`` (the episodes learned from, see
:mod:`pg_node.bag.recorder`), ``progress.csv`` (one row per update, its ``wall_seconds``
going on across a resume) and ``tensorboard/`` (the same metrics as event files, see
:mod:`pg_node.rl.logger`). When
``total_steps`` environment steps are learned the learner writes a final checkpoint,
closes the bag and, with ``exit_when_done``, exits with code 0.
"""
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from pg_node.bag.recorder import EPISODE_QOS, EpisodeRecorder
from pg_node.common.param_schema import ConfigError
from pg_node.common.params import params_for
from pg_node.common.paths import resolve_model
from pg_node.common.run_dir import RunDir
from pg_node.rl.learner import EpisodeStats, Learner
from pg_node.rl.learner_gate import LearnerGate, Verdict
from pg_node.rl.logger import TensorBoardLog
from pg_node.rl.update_settings import check_algo_setting
from pg_node.ros import messages
from pg_node.ros import table_msg
from pg_node.ros.diagnostics import Diagnostics, RateCounter
from pg_node.ros.parameters import declare_params
from pg_node.ros.qos import LATCHED, RELIABLE
from pg_node.ros.run_protocol import (DONE, LEARNER_STATE, learner_state_msg, RANDOMIZATION,
                                      RunGuard, TRAINING)
from pg_node.ros.runtime import run
from pg_node.ros.scene_msg import scene_markers
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from std_msgs.msg import Float64, Float64MultiArray
import torch

METRICS = ('episode_return', 'episode_length', 'policy_loss', 'value_loss', 'entropy',
           'explained_variance', 'approx_kl', 'grad_norm', 'steps_per_second',
           'policy_version', 'env_steps', 'policy_lag', 'rejected_batches', 'skipped_updates')
PROGRESS_FIELDS = ('wall_seconds',) + METRICS
#: seconds without a batch after which the learner says it waits (a batch takes milliseconds)
GAP_WARNING = 3.0
#: seconds a finished learner waits for the nodes that follow it to hear that it is done
DONE_LINGER = 5.0


class LearnerNode(Node):
    """Owns the policy: learns from batches and hands out new versions."""

    def __init__(self):
        super().__init__('learner_node')
        torch.set_num_threads(1)
        self.cfg = declare_params(self, {**params_for('learner_node'),
                                         **params_for('actor_node')},
                                  lambda name, value: self.learner.configure(name, value))
        self.add_on_set_parameters_callback(self.refuse_other_updates_settings)
        import mujoco
        from pg_node.sim.arm_task import ArmSpec
        model_path = resolve_model(self.cfg['model'])
        spec = ArmSpec.from_model(mujoco.MjModel.from_xml_path(str(model_path)))
        obs_dim = spec.obs_layout.size
        self.run_dir = RunDir(self.cfg['run_dir']).make()
        self.learner = Learner(obs_dim, len(spec.ctrl_low), self.cfg)
        state, problems = self.learner.resume(self.run_dir.checkpoints)
        for p in problems:
            self.get_logger().warning(p)
        if state is not None:
            self.get_logger().info(f'resumed policy version {self.learner.version} '
                                   f'({self.learner.env_steps} steps) from checkpoints')
        self.stats = EpisodeStats()
        self.steps = RateCounter()
        self.counters = {'batches': 0, 'rejected_batches': 0, 'dropped_batches': 0,
                         'repeated_batches': 0, 'skipped_updates': 0, 'sim_restarts_seen': 0,
                         'gaps': 0}
        self.gate = LearnerGate(self.cfg['sync_mode'] == 'sync', self.cfg['max_policy_lag'])
        self.last_batch_time = None            # time.monotonic() of the newest batch learned
        self.gap_reported = False
        self.last_seq = {}                     # actor -> last transition number learned
        # progress.csv's clock goes on across a resume: the checkpoint keeps its reading
        self.t0 = time.monotonic() - (state or {}).get('wall_seconds', 0.0)
        self.last_metrics = {}
        self.done = False
        self.exit_code = None              # set when done: runtime.run then stops
        bag_dir = self.run_dir.next_bag()   # a restarted learner: a new bag beside the old
        self.run = RunGuard(self, self.cfg['run_id'])
        self.pub_episode = self.create_publisher(DiagnosticStatus, self.run.topic('episode'),
                                                 EPISODE_QOS)
        self.recorder = EpisodeRecorder(bag_dir, model_path, record_arms=self.cfg['record_arms'],
                                        split_max_episodes=self.cfg['bag_split_episodes'],
                                        on_summary=self.pub_episode.publish,
                                        draw_scene=scene_markers,
                                        scene_period=self.cfg['record_scene_period'],
                                        frame_skip=self.bag_frame_skip())
        self.recorder_t = time.time_ns()
        self.tensorboard = TensorBoardLog(self.run_dir.tensorboard)
        self.progress = self.run_dir.progress_writer(PROGRESS_FIELDS)
        self.pub_weights = self.create_publisher(Float64MultiArray,
                                                 self.run.topic('policy_weights'), LATCHED)
        self.pub_metrics = {name: self.create_publisher(Float64, self.run.topic(f'metrics/{name}'),
                                                        10)
                            for name in METRICS}
        self.create_subscription(Float64MultiArray, self.run.topic('batch'), self.on_batch,
                                 RELIABLE)
        self.create_subscription(Float64MultiArray, self.run.topic(RANDOMIZATION),
                                 self.on_randomization, 100)
        self.diag = Diagnostics(self, 'learner_node', self.cfg['algo'])
        self.pub_state = self.create_publisher(DiagnosticStatus, self.run.topic(LEARNER_STATE),
                                               LATCHED)
        self.pub_state.publish(learner_state_msg(self.run, TRAINING, self.learner.version,
                                                 self.learner.env_steps))
        self.create_timer(1.0, self.on_tick)
        self.publish_weights()
        self.get_logger().info(
            f'learner: {self.cfg["algo"]}, version {self.learner.version}, '
            f'{self.learner.env_steps}/{self.cfg["total_steps"]} steps, '
            f'run dir {self.run_dir.path}')

    def bag_frame_skip(self) -> int:
        """
        Return the simulator's ``frame_skip`` for the bag's clock: the run's ``params.yaml``.

        The bag's stamps, ``/clock`` and ``pg_node.dt`` are simulated time (timestep x
        frame_skip per step); an arm imported at 0.002 s trains at 20. Without a run file
        (a launch by hand): sim_node's default.
        """
        from pg_node.rl.trained_policy import run_frame_skip
        return run_frame_skip(self.run_dir.path)

    def refuse_other_updates_settings(self, params) -> SetParametersResult:
        """Refuse (``ros2 param set``) a setting the update lacks, naming the ones it has."""
        for p in params:
            try:
                check_algo_setting(f'{self.get_name()}.{p.name}', self.cfg['algo'], p.name,
                                   p.value)
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def publish_weights(self):
        """Publish the current policy (latched)."""
        layout, vec = self.learner.weights()
        self.pub_weights.publish(table_msg.to_msg(*messages.pack_weights(
            layout, vec, self.learner.version, self.learner.env_steps, self.run.token)))

    def on_randomization(self, msg: Float64MultiArray):
        """Write a simulator's drawn randomization terms to the bag, as they came."""
        if self.done or not msg.data or msg.layout.data_offset < 1:
            return
        if self.run.foreign(int(msg.data[0]), self.run.topic(RANDOMIZATION)):
            return
        self.recorder.record_randomization(msg, time.time_ns())

    def on_batch(self, msg: Float64MultiArray):
        """Learn from a batch of the right version; publish, log and checkpoint."""
        if self.done:
            return
        try:
            header, batch = messages.unpack_batch(*table_msg.from_msg(msg),
                                                  obs_dim=self.learner.policy.obs_dim,
                                                  act_dim=self.learner.policy.act_dim)
        except ValueError as exc:
            self.counters['dropped_batches'] += 1
            self.get_logger().warning(f'dropped a batch: {exc}', throttle_duration_sec=1.0)
            return
        if self.run.foreign(header['run'], self.run.topic('batch')):
            return
        verdict = self.gate.on_batch(header['version'], header['batch_seq'],
                                     self.learner.version)
        if verdict is Verdict.REPEAT:
            # the critic sent a batch again: our weights were probably lost on the way
            self.counters['repeated_batches'] += 1
            self.publish_weights()
            return
        if verdict is Verdict.REFUSE:
            self.counters['rejected_batches'] += 1
            self.get_logger().warning(
                f'refused a batch of policy version {header["version"]}: the policy is at '
                f'{self.learner.version} ({self.cfg["sync_mode"]} mode, lag allowed '
                f'{self.gate.max_lag})', throttle_duration_sec=1.0)
            return
        lag = self.learner.version - header['version']
        self.note_batch_after_gap()
        stats = self.learner.learn(batch.obs, batch.act, batch.logp, batch.adv)
        self.gate.learned(self.learner.version)
        self.counters['batches'] += 1
        self.counters['skipped_updates'] += int(stats['skipped_updates'])
        self.steps.add(batch.rew.size)
        self.publish_weights()
        now_ns = time.time_ns()
        self.check_sim_restarts(batch, now_ns)
        self.stats.update(batch.rew, batch.terminated, batch.truncated, batch.episode_id,
                          batch.actor)
        self.recorder.record_batch(batch, header['version'], now_ns)
        metrics = {
            'episode_return': self.stats.mean_return(),
            'episode_length': self.stats.mean_length(),
            'policy_loss': stats['policy_loss'], 'entropy': stats['entropy'],
            'approx_kl': stats['approx_kl'], 'grad_norm': stats['grad_norm'],
            'value_loss': header['value_loss'],
            'explained_variance': header['explained_variance'],
            'policy_version': float(self.learner.version),
            'env_steps': float(self.learner.env_steps),
            'policy_lag': float(lag),
            'rejected_batches': float(self.counters['rejected_batches']),
            'skipped_updates': float(self.counters['skipped_updates']),
            'steps_per_second': self.last_metrics.get('steps_per_second', float('nan')),
        }
        for name, value in metrics.items():
            self.pub_metrics[name].publish(Float64(data=float(value)))
        self.recorder.record_metrics(metrics, now_ns)
        self.tensorboard.write({**metrics, 'learning_rate': self.learner.update.learning_rate},
                               self.learner.env_steps)
        self.progress.write(self.wall_seconds(), metrics)
        self.last_metrics.update(metrics)
        if self.learner.version % self.cfg['checkpoint_every'] == 0:
            self.save()
        if self.learner.env_steps >= self.cfg['total_steps']:
            self.finish()

    def check_sim_restarts(self, batch, now_ns: int):
        """
        Notice a restarted simulator: its transition numbers (``seq``) start again at 0.

        The episodes its arms had open were cut short: they are written to the bag as such,
        dropped from the running returns, and the episode ids seen before are forgotten
        (the new simulator numbers its episodes from 0 again). The actor never mixes two
        simulator lives in one rollout (it discards a partial rollout when ``seq`` jumps).
        """
        for a in np.unique(batch.actor[0]):
            cols = batch.actor[0] == a
            first, last = int(batch.seq[0, cols].min()), int(batch.seq[-1, cols].max())
            prev = self.last_seq.get(int(a))
            if prev is not None and first <= prev:
                self.counters['sim_restarts_seen'] += 1
                n = self.recorder.cut_short_actor(int(a), now_ns, self.learner.version)
                self.stats.forget_actor(int(a))
                self.get_logger().warning(
                    f'the simulator of actor {int(a)} restarted (transition {first} after '
                    f'{prev}): {n} open episodes marked cut short')
            self.last_seq[int(a)] = last

    def wall_seconds(self) -> float:
        """Return the training time of this run so far, resumed sessions included."""
        return time.monotonic() - self.t0

    def save(self):
        """Write an atomic checkpoint of the current version."""
        self.learner.save(self.run_dir.checkpoints, {'wall_seconds': self.wall_seconds()})
        self.progress.flush()
        self.tensorboard.flush()

    def finish(self):
        """Write the final checkpoint, close the bag, and stop if asked to."""
        self.done = True
        self.save()
        self.recorder.close()
        self.get_logger().info(f'done: {self.learner.env_steps} steps, policy version '
                               f'{self.learner.version}')
        self.pub_state.publish(learner_state_msg(self.run, DONE, self.learner.version,
                                                 self.learner.env_steps))
        if self.cfg['exit_when_done']:
            if self.pub_state.get_subscription_count():
                # nodes started one by one end at this news (EndWithLearner): stay until
                # they have it, as their subscriptions go, DONE_LINGER s at most
                self.linger_until = time.monotonic() + DONE_LINGER
                self.create_timer(0.1, self.linger)
            else:
                self.exit_code = 0         # runtime.run stops the process after this callback

    def linger(self):
        """End the process once the nodes that follow the learner's state are gone."""
        if (not self.pub_state.get_subscription_count()
                or time.monotonic() >= self.linger_until):
            self.exit_code = 0

    def close(self):
        """Save and close everything (on exit, Ctrl-C or SIGTERM)."""
        if not self.done:
            self.save()
        self.recorder.close()
        self.progress.close()
        self.tensorboard.close()

    def note_batch_after_gap(self):
        """Say that batches come again after a gap that :meth:`watch_gap` reported."""
        now = time.monotonic()
        if self.gap_reported:
            self.get_logger().info(
                f'a batch again after {now - self.last_batch_time:.1f} s without one (policy '
                f'version {self.learner.version}, repeated batches so far '
                f"{self.counters['repeated_batches']}): training goes on")
            self.gap_reported = False
        self.last_batch_time = now

    def watch_gap(self):
        """
        Say once when no batch came for a while: a worker host unreachable, a node restarting.

        The actors re-send their rollouts and the critic its batches, so a gap heals by
        itself; the log says when it began and (:meth:`note_batch_after_gap`) when it ended.
        """
        if self.last_batch_time is None or self.done or self.gap_reported:
            return
        waited = time.monotonic() - self.last_batch_time
        if waited >= GAP_WARNING:
            self.gap_reported = True
            self.counters['gaps'] += 1
            self.get_logger().warning(
                f'no batch for {waited:.1f} s at policy version {self.learner.version}: '
                'waiting for the actors (a lost link to a worker host, or a node restarting, '
                'heals by itself: rollouts and batches are sent again)')

    def on_tick(self):
        """Publish steps per second and diagnostics."""
        self.watch_gap()
        rate = self.steps.rate()
        self.last_metrics['steps_per_second'] = rate
        self.pub_metrics['steps_per_second'].publish(Float64(data=rate))
        self.progress.flush()
        self.diag.publish({**self.counters, 'foreign_messages': self.run.dropped,
                           'run_id': self.run.run_id, 'policy_version': self.learner.version,
                           'env_steps': self.learner.env_steps,
                           'steps_per_second': round(rate, 1)},
                          message=f'version {self.learner.version}, '
                                  f'{self.learner.env_steps} steps')


def main(args=None):
    """Run learner_node until done, Ctrl-C or an external shutdown."""
    return run(LearnerNode, args, cleanup=lambda node: node.close())


if __name__ == '__main__':
    raise SystemExit(main())
