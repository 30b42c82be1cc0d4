"""
actor_node: samples torques from the Gaussian policy for every arm and gathers rollouts.

Subscribes ``pg_node/transition`` (from ``sim_node``) and ``/<run>/pg_node/policy_weights``
(from ``learner_node``, latched); publishes ``pg_node/commands`` (one command per new
transition, ``num_envs x n_actuators`` values, arm-major, clipped to the control range) and,
every ``n_steps`` control steps, the rollout on ``/<run>/pg_node/rollout`` tagged with the policy
version that sampled it (layout in :mod:`pg_node.ros.messages`).

Every decision of the protocol (when it may act, what a repeated or skipped transition
means, when a rollout goes again) is :class:`pg_node.rl.actor_sync.ActorSync`'s; the node
drives it. It acts only once it holds the learner's weights. In ``sync`` mode, after sending
rollout k sampled by version v it waits for version v + 1 before acting again: exact
on-policy A2C (the simulator, in lock-step, waits with it). If no new weights come within
``rollout_resend_timeout`` seconds (plus the time the rollout takes on a slow link:
:func:`pg_node.rl.actor_sync.resend_timeout`) it sends the rollout again (the critic drops
duplicates), so a lost message or a restarted critic cannot deadlock the graph. In
``async`` mode it keeps sampling with the newest weights it has.

A transition re-sent by the simulator (same ``seq``: it had no command for a second) gets the
command already sent for it once more, the same torques: the first was lost, as it is when a
restarted simulator sends its first transition before its command subscription has heard of
this publisher (the transition is latched, the command is not). A re-send that comes before
the answer (the actor waits for weights) is answered once. A transition that skips a number
(a restarted simulator, a world reset) discards the partial rollout, whose last command's
outcome is unknown.

A lock-step simulator that steps its arms in ``G`` groups (``lock_step_groups``) sends each
group's transitions on their own (:mod:`pg_node.ros.transition`); the actor answers each
group with a command for its arms, in the order they come, keeps one buffer per group and
sends the rollout of all arms once every group has its ``n_steps``: the critic and learner
see the same rollouts as with one group. A group that finishes first waits for the others
(and in sync mode for the next weights) before acting again.
"""
import time

import numpy as np
from pg_node.common.params import params_for
from pg_node.common.paths import resolve_model
from pg_node.common.run import COMMANDS
from pg_node.rl.actor_sync import ActorSync, resend_timeout, Step
from pg_node.rl.rollout_buffer import concat_arms, RolloutBuffer
from pg_node.rl.sampler import make_rng, NumpySampler
from pg_node.ros import command
from pg_node.ros import messages
from pg_node.ros import table_msg
from pg_node.ros import transition
from pg_node.ros.diagnostics import Diagnostics, RateCounter
from pg_node.ros.parameters import declare_params
from pg_node.ros.qos import LATCHED, RELIABLE
from pg_node.ros.run_protocol import EndWithLearner, RunGuard
from pg_node.ros.runtime import run
from pg_node.sim.arm_task import arm_groups, ArmSpec
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64MultiArray


class ActorNode(Node):
    """Samples the policy for all arms of one simulator and gathers rollouts."""

    def __init__(self):
        super().__init__('actor_node')
        self.cfg = declare_params(self, params_for('actor_node'))
        model = resolve_model(self.cfg['model'])
        import mujoco
        self.spec = ArmSpec.from_model(mujoco.MjModel.from_xml_path(str(model)))
        self.act_dim = len(self.spec.ctrl_low)
        self.obs_dim = self.spec.obs_layout.size
        self.policy = NumpySampler.from_config(self.obs_dim, self.act_dim, self.cfg)
        self.rng = make_rng(self.cfg['seed'] + 7919 * self.cfg['actor_id'])
        self.protocol = ActorSync(self.cfg['sync_mode'] == 'sync')
        self.set_groups(1)
        self.last_rollout = None
        self.counters = {'commands': 0, 'commands_resent': 0, 'rollouts': 0,
                         'rollouts_resent': 0, 'rollouts_discarded': 0, 'transitions_dropped': 0,
                         'transitions_repeated': 0, 'weights_dropped': 0,
                         'weights_received': 0, 'policy_lag': 0}
        self.steps = RateCounter()
        self.run = RunGuard(self, self.cfg['run_id'])
        self.end_with_learner = EndWithLearner(self, self.run)   # ros2 run: end with it
        self.pub_cmd = self.create_publisher(Float64MultiArray, COMMANDS, 10)
        self.pub_rollout = self.create_publisher(Float64MultiArray, self.run.topic('rollout'),
                                                 RELIABLE)
        # one transition of each group of arms may wait here (depth 1 with one group: a
        # real-time simulator's newest transition replaces one not yet answered)
        self.sub_transition = self.create_subscription(
            Float64MultiArray, 'pg_node/transition', self.on_transition,
            QoSProfile(depth=self.cfg['lock_step_groups'], reliability=LATCHED.reliability,
                       durability=LATCHED.durability),
            raw=True)
        self.create_subscription(Float64MultiArray, self.run.topic('policy_weights'),
                                 self.on_weights, LATCHED)
        self.diag = Diagnostics(self, f'actor_node {self.cfg["actor_id"]}',
                                f'{self.cfg["num_envs"]} arms')
        self.create_timer(1.0, self.on_tick)
        self.get_logger().info(
            f'actor {self.cfg["actor_id"]}: {self.cfg["num_envs"]} arms, {self.cfg["sync_mode"]}'
            f' mode, rollouts of {self.cfg["n_steps"]} steps; waiting for policy weights')

    # --- inputs ---------------------------------------------------------------------------

    def on_weights(self, msg: Float64MultiArray):
        """Load a new policy version; in sync mode, resume acting when it is the awaited one."""
        try:
            header, layout, vec = messages.unpack_weights(*table_msg.from_msg(msg))
            if self.run.foreign(header['run'], self.run.topic('policy_weights')):
                return
            self.policy.load(layout, vec)
        except ValueError as exc:
            self.counters['weights_dropped'] += 1
            self.get_logger().warning(f'dropped policy weights: {exc}',
                                      throttle_duration_sec=1.0)
            return
        held = self.protocol.version
        if self.protocol.on_weights(header['version']):
            self.get_logger().warning(
                f'policy version went back from {held} to {header["version"]} '
                '(learner restarted): discarding the partial rollout')
            self.discard_partial()
        self.counters['weights_received'] += 1
        self.act_pending()

    def on_transition(self, msg):
        """
        Record the outcome of the last command and answer the new observation.

        ``msg``: the subscription's serialised bytes (``raw=True``, decoded straight into
        numpy by :func:`pg_node.ros.transition.from_cdr`) or a ``Float64MultiArray``.
        """
        try:
            tr = (transition.from_cdr(msg) if isinstance(msg, bytes)
                  else transition.from_msg(msg))
            if self.run.foreign(tr.run, 'pg_node/transition'):
                return
            if tr.obs.shape[1] != self.obs_dim:
                raise ValueError(f'observations of size {tr.obs.shape[1]}, expected '
                                 f'{self.obs_dim}')
            if tr.groups != len(self.groups):
                self.set_groups(tr.groups)
            g = tr.seq % tr.groups
            if tr.arms != self.groups[g]:
                n = self.cfg['num_envs']
                raise ValueError(
                    f'arms {tr.arms.start}..{tr.arms.stop - 1} are not group {g} of '
                    f'{tr.groups} of {n} arms (the simulator has another num_envs?)')
        except ValueError as exc:
            self.counters['transitions_dropped'] += 1
            self.get_logger().warning(f'dropped a transition: {exc}', throttle_duration_sec=1.0)
            return
        buf = self.bufs[g]
        step, previous = self.protocol.on_transition(g, tr.seq, answered=buf.pending,
                                                     waiting=g in self.pending,
                                                     partial=buf.pos + buf.pending > 0)
        if step.repeated:
            self.counters['transitions_repeated'] += 1
        if step is Step.REPEAT_ANSWERED:
            self.pub_cmd.publish(self.last_cmd[g])
            self.counters['commands_resent'] += 1
            self.get_logger().info(f'transition {tr.seq} came again: sending its command '
                                   'again', throttle_duration_sec=1.0)
            return
        if step is Step.REPEAT_WAITING:
            return
        if step is Step.SKIPPED:
            self.get_logger().warning(
                f'transition {tr.seq} after {previous}: discarding the partial rollout')
            self.discard_partial()
        if buf.pending:
            buf.add_outcome(tr.reward, tr.terminated, tr.truncated, tr.final_obs)
            if all(b.full for b in self.bufs):
                self.send_rollout()
        self.pending[g] = tr
        self.act_pending()

    # --- acting ---------------------------------------------------------------------------

    def set_groups(self, groups: int):
        """Expect the simulator's arms in ``groups`` groups: one buffer each, all empty."""
        groups_of = arm_groups(self.cfg['num_envs'], groups)     # ValueError: too many
        if hasattr(self, 'bufs'):
            self.discard_partial()
        self.groups = groups_of
        self.bufs = [RolloutBuffer(self.cfg['n_steps'], arms.stop - arms.start, self.obs_dim,
                                   self.act_dim) for arms in self.groups]
        self.protocol.set_groups(groups)
        self.last_cmd = [None] * groups        # each group's last serialised command
        self.pending = {}                      # group -> transition not answered yet

    def discard_partial(self):
        """Drop the partial rollout of every group (its commands' outcomes are unknown)."""
        if any(b.pos + b.pending for b in self.bufs):
            self.counters['rollouts_discarded'] += 1
        for b in self.bufs:
            b.reset()
        self.protocol.discard()

    def act_pending(self):
        """
        Answer the waiting transitions in the order they came, as far as allowed.

        Not before the first weights, nor in sync mode before the awaited version; a group
        whose buffer is full waits until every group's is and the rollout is sent.
        """
        if not self.protocol.may_act:
            return
        for g in [g for g in self.pending if not self.bufs[g].full]:
            self.act(g, self.pending.pop(g))

    def act(self, g: int, tr: transition.Transition):
        """Sample and send the command for ``tr``'s observations (group ``g``)."""
        if not any(b.pos or b.pending for b in self.bufs):
            self.protocol.start_rollout()      # the first command of a rollout
        act, logp = self.policy.sample(tr.obs, self.rng)
        cmd = np.clip(act, self.spec.ctrl_low, self.spec.ctrl_high)
        # the simulator waits for the command: send it first, then keep the step
        self.last_cmd[g] = command.to_cdr(cmd, tr.seq, self.run.token)
        self.pub_cmd.publish(self.last_cmd[g])
        self.bufs[g].add_action(tr.obs, act, logp, tr.episode_step, tr.episode_id, tr.seq)
        self.counters['commands'] += 1
        self.steps.add(tr.num_envs)

    def send_rollout(self):
        """Publish the full rollout; in sync mode, wait for the next policy version."""
        ro = concat_arms([b.finish() for b in self.bufs])
        tag = self.protocol.seal_rollout()
        self.last_rollout = table_msg.to_msg(*messages.pack_rollout(
            ro, tag.version, self.cfg['actor_id'], tag.seq, self.run.token))
        self.pub_rollout.publish(self.last_rollout)
        self.protocol.sent(time.monotonic())
        self.counters['rollouts'] += 1
        self.counters['policy_lag'] = tag.lag

    def on_tick(self):
        """Re-send a rollout the learner never answered; publish diagnostics."""
        timeout = resend_timeout(self.cfg['rollout_resend_timeout'],
                                 len(self.last_rollout.data) if self.last_rollout else 0)
        if self.protocol.resend_due(time.monotonic(), timeout):
            self.get_logger().warning(
                f'no policy version {self.protocol.wait_for} after {timeout:g} s: sending the '
                'rollout again')
            self.pub_rollout.publish(self.last_rollout)
            self.protocol.sent(time.monotonic())
            self.counters['rollouts_resent'] += 1
        self.diag.publish({**self.counters, 'foreign_messages': self.run.dropped,
                           'run_id': self.run.run_id, 'policy_version': self.protocol.version,
                           'waiting_for': self.protocol.waiting(),
                           'steps_per_second': round(self.steps.rate(), 1)},
                          message=f'policy version {self.protocol.version}')


def main(args=None):
    """Run actor_node until Ctrl-C or an external shutdown."""
    return run(ActorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
