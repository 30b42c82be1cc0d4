"""
What the nodes of one training run share besides the data: its topics, token, end.

The run's topics and token, the learner's state, and the end of the run.

Several runs may share a ROS domain (docs/many_runs.md): every shared topic lives under the
run's namespace (:mod:`pg_node.common.run`) and every message carries the run's token, so a
message of another run is dropped and counted (:class:`RunGuard`). The learner publishes its
state (training, then done) latched, and nodes started one by one end with it
(:class:`EndWithLearner`).
"""
import os

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from pg_node.common.paths import SUPERVISOR_ENV
from pg_node.common.run import run_token, run_topic
from pg_node.ros.qos import LATCHED
from rclpy.node import Node

#: run topic where each simulator publishes its arms' drawn randomization terms, for the bag
RANDOMIZATION = 'randomization'


class RunGuard:
    """
    The run a node belongs to (:mod:`pg_node.common.run`): its shared topics, and a check.

    :meth:`foreign` drops a message that carries another run's token: it is counted
    (``dropped``, the node's ``foreign_messages`` in ``/diagnostics``) and logged once per
    topic and token, naming both runs, so a stray publisher shows in the log without
    flooding it.
    """

    def __init__(self, node: Node, run_id: str):
        self.node = node
        self.run_id = run_id
        self.token = run_token(run_id)
        self.dropped = 0
        self._told = set()

    def topic(self, name: str) -> str:
        """Return the absolute name of the run's shared topic ``name``."""
        return run_topic(self.run_id, name)

    def foreign(self, token: int, topic: str) -> bool:
        """Return whether a message of ``token`` on ``topic`` is another run's (and count it)."""
        if token == self.token:
            return False
        self.dropped += 1
        if (topic, token) not in self._told:
            self._told.add((topic, token))
            self.node.get_logger().warning(
                f'dropped a message on {topic} of another run (run token {token}; this run, '
                f'{self.run_id!r}, has {self.token}): not learned from or acted on; counted '
                'in /diagnostics as foreign_messages, not logged again for this sender')
        return True


#: the learner's state, ``/<run>/pg_node/learner_state`` (latched): training, then done
LEARNER_STATE = 'learner_state'
TRAINING, DONE = 'training', 'done'


def learner_state_msg(run: 'RunGuard', state: str, version: int,
                      env_steps: int) -> DiagnosticStatus:
    """Return the learner's state as a ``DiagnosticStatus`` carrying the run's token."""
    status = DiagnosticStatus(name='learner_node', hardware_id=run.run_id, message=state)
    status.values = [KeyValue(key=k, value=str(v)) for k, v in (
        ('state', state), ('run_token', run.token), ('policy_version', version),
        ('env_steps', env_steps))]
    return status


def supervised() -> bool:
    """Return whether ``python -m pg_node train`` started this process (and ends it)."""
    return os.environ.get(SUPERVISOR_ENV, '').strip() == str(os.getppid())


class EndWithLearner:
    """
    Ends a node of a run when the run's learner says it has finished.

    Under ``train`` or ``ros2 launch`` the whole graph is stopped when the learner exits;
    nodes started one by one (``ros2 run``) have no one to stop them, and an actor would
    re-send its last rollout every few seconds for ever. So a node not started by ``train``
    follows ``/<run>/pg_node/learner_state`` (latched, so a node that starts after the
    learner still hears it) and, at ``done``, says so and sets its ``exit_code`` to 0, which
    ends its process (:func:`run`) the way the learner's own exit does. A state of another
    run is dropped and counted (:class:`RunGuard`).
    """

    def __init__(self, node: Node, run: 'RunGuard'):
        self.node = node
        self.run = run
        self.topic = run.topic(LEARNER_STATE)
        node.exit_code = None
        if not supervised():
            node.create_subscription(DiagnosticStatus, self.topic, self.on_state, LATCHED)

    def on_state(self, msg: DiagnosticStatus):
        """At the run's learner's ``done``: say so and end the node."""
        values = {kv.key: kv.value for kv in msg.values}
        try:
            token = int(values.get('run_token', ''))
        except ValueError:
            return
        if self.run.foreign(token, self.topic) or values.get('state') != DONE:
            return
        if self.node.exit_code is None:
            self.node.get_logger().info(
                f"the learner has finished ({values.get('env_steps')} steps, policy version "
                f"{values.get('policy_version')}): stopping")
            self.node.exit_code = 0
