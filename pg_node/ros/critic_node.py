"""
critic_node: annotates rollouts with the chosen phi and fits the value function V_w.

Subscribes ``/<run>/pg_node/rollout`` (from the actors) and ``/<run>/pg_node/policy_weights``
(only the optimal baseline needs the policy); publishes ``/<run>/pg_node/batch`` (layout in
:mod:`pg_node.ros.messages`) for the learner, and ``/diagnostics``.

Which rollouts make which batch, and what a repeated one means, is decided by
:class:`pg_node.rl.critic_batching.CriticBatching`; the node drives it. In ``sync`` mode a
batch holds one rollout of each of the ``num_actors`` actors, all sampled by the same policy
version, side by side in actor-id order: batched A2C across processes, and reproducible
because the order never depends on which message came first. In ``async`` mode every
rollout is annotated and sent as it comes. A rollout seen before (an actor's
re-send) is not annotated again: the batch made from it is sent again instead (the batch or
the new weights may have been lost, and the learner answers a repeated batch by publishing
its weights again), so no single lost message stalls synchronous training. A malformed
rollout is dropped and counted.

A batch is sent as soon as phi is computed; V takes its regression step on the rollout
afterwards, in a task queued behind the batch: while the learner works when it is a process
of its own, after it when both share a process (``critic_and_learner``), off the hand-over's
path either way. The batch header's ``value_loss`` and ``explained_variance`` are V's on the
rollout before that step, and the next rollout's phi waits for the step, as in-process.

V is checkpointed to ``<run_dir>/critic`` every ``checkpoint_every`` batches and on exit, and
a restarted critic resumes from the newest valid checkpoint.
"""
from pathlib import Path

import numpy as np
from pg_node.common.params import params_for
from pg_node.rl.checkpoint import load_latest, save_checkpoint
from pg_node.rl.critic import Critic
from pg_node.rl.critic_batching import CriticBatching
from pg_node.rl.learner import make_policy
from pg_node.rl.rollout_buffer import RolloutArrays
from pg_node.rl.weights import load_flat_state
from pg_node.ros import messages
from pg_node.ros import table_msg
from pg_node.ros.diagnostics import Diagnostics, RateCounter
from pg_node.ros.parameters import declare_params
from pg_node.ros.qos import LATCHED, RELIABLE
from pg_node.ros.run_protocol import EndWithLearner, RunGuard
from pg_node.ros.runtime import run
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray
import torch


class CriticNode(Node):
    """Turns rollouts into advantage-annotated batches."""

    def __init__(self):
        super().__init__('critic_node')
        torch.set_num_threads(1)
        self.cfg = declare_params(self, {**params_for('critic_node'),
                                         **{k: v for k, v in params_for('actor_node').items()
                                            if k in ('log_std_init', 'state_dependent_std')}},
                                  self.on_parameter)
        self.critic = None
        self.policy = None
        self.policy_weights = None
        self.ckpt_dir = Path(self.cfg['run_dir']) / 'critic'
        self.batches = 0
        self.batching = CriticBatching(self.cfg['sync_mode'] == 'sync', self.cfg['num_actors'])
        self.counters = {'rollouts': 0, 'rollouts_dropped': 0, 'duplicates': 0,
                         'batches': 0, 'batches_resent': 0, 'stale_groups_dropped': 0}
        self.steps = RateCounter()
        self.last_stats = {}
        self.pending_fit = None            # (obs, returns) of the batch V has not learned yet
        self.run = RunGuard(self, self.cfg['run_id'])
        self.end_with_learner = EndWithLearner(self, self.run)   # ros2 run: end with it
        self.pub_batch = self.create_publisher(Float64MultiArray, self.run.topic('batch'),
                                               RELIABLE)
        self.create_subscription(Float64MultiArray, self.run.topic('rollout'), self.on_rollout,
                                 RELIABLE)
        if self.cfg['estimator'] == 'optimal_baseline':
            self.create_subscription(Float64MultiArray, self.run.topic('policy_weights'),
                                     self.on_weights, LATCHED)
        self.diag = Diagnostics(self, 'critic_node', self.cfg['estimator'])
        self.create_timer(1.0, self.on_tick)
        self.get_logger().info(f'critic: phi = {self.cfg["estimator"]}, gamma '
                               f'{self.cfg["gamma"]}, lambda {self.cfg["gae_lambda"]}, '
                               f'{self.cfg["num_actors"]} actor(s), {self.cfg["sync_mode"]}')

    def on_parameter(self, name: str, value) -> None:
        """Apply a live parameter to V's update (the critic is built at the first rollout)."""
        if self.critic is not None:
            self.critic.configure(name, value)

    def _ensure_critic(self, obs_dim: int):
        if self.critic is not None:
            return
        self.critic = Critic(obs_dim, self.cfg)
        state, problems = load_latest(self.ckpt_dir)
        for p in problems:
            self.get_logger().warning(p)
        if state is not None:
            self.critic.load(state)
            self.batches = int(state['version'])
            self.get_logger().info(f'resumed V from {self.ckpt_dir} (batch {self.batches})')

    def on_weights(self, msg: Float64MultiArray):
        """Keep the newest policy (for the optimal baseline's score norms)."""
        try:
            header, layout, vec = messages.unpack_weights(*table_msg.from_msg(msg))
        except ValueError as exc:
            self.get_logger().warning(f'dropped policy weights: {exc}', throttle_duration_sec=1.0)
            return
        if self.run.foreign(header['run'], self.run.topic('policy_weights')):
            return
        self.policy_weights = (layout, vec)
        if self.policy is not None:
            load_flat_state(self.policy, layout, vec)

    def on_rollout(self, msg: Float64MultiArray):
        """Check a rollout, drop duplicates, and annotate once its group is complete."""
        try:
            header, ro = messages.unpack_rollout(*table_msg.from_msg(msg))
            if self.run.foreign(header['run'], self.run.topic('rollout')):
                return
            if self.critic is not None and ro.obs.shape[-1] != self.critic.value_fn.obs_dim:
                raise ValueError(f'observations of size {ro.obs.shape[-1]}, expected '
                                 f'{self.critic.value_fn.obs_dim}')
        except ValueError as exc:
            self.counters['rollouts_dropped'] += 1
            self.get_logger().warning(f'dropped a rollout: {exc}', throttle_duration_sec=1.0)
            return
        step = self.batching.on_rollout(header['actor_id'], header['rollout_seq'],
                                        header['version'], ro)
        if step.duplicate:
            self.counters['duplicates'] += 1
            if step.resend is not None:
                self.pub_batch.publish(step.resend)
                self.counters['batches_resent'] += 1
            return
        self.counters['rollouts'] += 1
        self.counters['stale_groups_dropped'] += step.stale
        self._ensure_critic(ro.obs.shape[-1])
        if step.parts:
            self.annotate(step.version, step.parts)

    def annotate(self, version: int, parts):
        """Concatenate rollouts along the arm axis, compute phi, send the batch, fit V."""
        self.finish_fit()                  # phi of this rollout needs V after the last step
        ros = [ro for _, ro in parts]
        ro = RolloutArrays(**{k: np.concatenate([getattr(r, k) for r in ros], axis=1)
                              for k in ros[0].as_dict()})
        actor = np.concatenate([np.full(r.rew.shape, a) for a, r in parts], axis=1)
        policy = None
        if self.cfg['estimator'] == 'optimal_baseline':
            if self.policy_weights is None:
                self.get_logger().warning('no policy weights yet for the optimal baseline')
                return
            if self.policy is None:
                self.policy = make_policy(ro.obs.shape[-1], ro.act.shape[-1], self.cfg)
                load_flat_state(self.policy, *self.policy_weights)
            policy = self.policy
        adv, ret, stats = self.critic.judge(ro, policy)
        batch = messages.Batch(obs=ro.obs, act=ro.act, logp=ro.logp, adv=adv, ret=ret,
                               rew=ro.rew, terminated=ro.terminated, truncated=ro.truncated,
                               ep_step=ro.ep_step, episode_id=ro.episode_id, seq=ro.seq,
                               actor=actor)
        header = {'version': version, 'n_actors': len(parts), 'batch_seq': self.batches,
                  'n_steps': ro.n_steps, 'num_envs': ro.num_envs,
                  'value_loss': stats['value_loss'],
                  'explained_variance': stats['explained_variance'], 'run': self.run.token}
        msg = table_msg.to_msg(*messages.pack_batch(batch, header))
        self.pub_batch.publish(msg)
        # V learns from the rollout only after the learner and then the actors are served
        # (phi above was computed with V before its step, as in-process): a task queued
        # now runs after the batch's delivery to a learner in this process
        # (critic_and_learner), and at once when the learner is a process of its own
        self.pending_fit = (ro.obs, ret)
        self.schedule(self.finish_fit)
        self.batching.sent(version, msg)
        self.batches += 1
        self.counters['batches'] += 1
        self.steps.add(ro.rew.size)

    def schedule(self, work) -> None:
        """Queue ``work`` on this node's executor (run it now when there is none)."""
        executor = self.executor
        if executor is None:
            work()
        else:
            executor.create_task(work)

    def finish_fit(self):
        """Take V's regression step on the newest batch's rollout, if not taken yet."""
        if self.pending_fit is None:
            return
        obs, ret = self.pending_fit
        self.pending_fit = None
        self.last_stats = self.critic.fit(obs, ret)
        if self.batches % self.cfg['checkpoint_every'] == 0:
            self.save()

    def save(self):
        """Write an atomic checkpoint of V (after its pending step)."""
        self.finish_fit()
        if self.critic is not None:
            save_checkpoint(self.ckpt_dir, self.batches, self.critic.state())

    def on_tick(self):
        """Publish diagnostics."""
        self.diag.publish({**self.counters, 'foreign_messages': self.run.dropped,
                           'run_id': self.run.run_id,
                           'steps_per_second': round(self.steps.rate(), 1),
                           **{k: round(v, 4) for k, v in self.last_stats.items()}},
                          message=f'{self.batches} batches')


def main(args=None):
    """Run critic_node until Ctrl-C or an external shutdown."""
    return run(CriticNode, args, cleanup=lambda node: node.save())


if __name__ == '__main__':
    raise SystemExit(main())
