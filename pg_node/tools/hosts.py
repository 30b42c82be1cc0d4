"""
One run on many machines: the learner host announces the run, worker hosts check and follow.

``python -m pg_node train --part learner --run-id NAME ...`` runs the critic and the learner
on one host; ``train --part workers --actors 2,3 --run-id NAME ...`` runs simulator/actor
pairs on others (:mod:`pg_node.tools.train`). Over DDS cross only what crosses between
processes anyway: rollouts, batches' weights and this module's announcement; each lock-step
loop stays inside its worker host's ``sim_and_actor`` process.

The learner host's ``train`` publishes ``/<run>/pg_node/run_info``
(``diagnostic_msgs/DiagnosticStatus``, reliable, transient-local: a worker that starts later
gets it) with the run's state (``training``, then ``done``), the number of actors, and the
configuration every host must share (:func:`shared_config`: everything a simulator or an
actor reads, the run dir aside) with its SHA-256. A worker host's ``train`` waits for it
before starting anything: a run id no learner announces, or a configuration that differs
from the learner host's, is refused in one line naming the keys. It then follows it: when the
learner host says ``done`` (or ``stopped``: it was interrupted), every worker host stops its
nodes and ends by itself.
"""
import hashlib
import json
import socket
import time
from typing import Dict, List, Optional

from pg_node.common.params import SHARED
from pg_node.common.run import run_topic

#: the states the learner host announces: training, then done (learned total_steps) or
#: stopped (interrupted, failed); a worker host ends at either
TRAINING, DONE, STOPPED = 'training', 'done', 'stopped'
#: sections of the configuration a worker host must share with the learner host
WORKER_SECTIONS = (SHARED, 'sim_node', 'actor_node')
#: values that may differ from host to host: paths of files each host writes for itself
HOST_KEYS = ('run_dir', 'round_trip_log')


def shared_config(cfg: Dict[str, Dict]) -> Dict[str, Dict]:
    """
    Return what every host of a run must agree on: the simulator's and the actor's values.

    >>> from pg_node.common.config_files import load_config
    >>> a = shared_config(load_config(None, ['run_dir=/a']))
    >>> a == shared_config(load_config(None, ['run_dir=/b', 'gamma=0.5',
    ...                                       'sim_node.round_trip_log=/tmp/t.npy']))
    True
    >>> a == shared_config(load_config(None, ['num_envs=8']))
    False
    """
    return {section: {k: v for k, v in cfg[section].items() if k not in HOST_KEYS}
            for section in WORKER_SECTIONS}


def config_digest(shared: Dict[str, Dict]) -> str:
    """Return the SHA-256 of a :func:`shared_config`, from its canonical JSON."""
    return hashlib.sha256(json.dumps(shared, sort_keys=True).encode()).hexdigest()


def differences(mine: Dict[str, Dict], theirs: Dict[str, Dict]) -> List[str]:
    """
    Return ``section.key: here X, learner host Y`` for every value in which two configs differ.

    >>> differences({'/**': {'num_envs': 8, 'seed': 0}}, {'/**': {'num_envs': 64, 'seed': 0}})
    ['/**.num_envs: 8 here, 64 on the learner host']
    """
    out = []
    for section in sorted(set(mine) | set(theirs)):
        a, b = mine.get(section, {}), theirs.get(section, {})
        for key in sorted(set(a) | set(b)):
            if a.get(key) != b.get(key):
                out.append(f'{section}.{key}: {a.get(key)!r} here, {b.get(key)!r} on the '
                           'learner host')
    return out


def parse_actors(text: str, num_actors: int) -> List[int]:
    """
    Return the actor ids of ``--actors`` (``2,3`` or ``0-3``), or raise ValueError saying why.

    >>> parse_actors('2,3', 4), parse_actors('0-2', 3)
    ([2, 3], [0, 1, 2])
    >>> parse_actors('1,5', 4)
    Traceback (most recent call last):
    ...
    ValueError: --actors 1,5: actor 5 is out of range; this run has actors 0..3 (num_actors=4)
    """
    ids = []
    for part in text.split(','):
        lo, _, hi = part.strip().partition('-')
        if not lo.isdigit() or (hi and not hi.isdigit()):
            raise ValueError(f'--actors {text}: expected actor ids like 2,3 or 0-3')
        ids += list(range(int(lo), int(hi or lo) + 1))
    for i in ids:
        if i >= num_actors:
            raise ValueError(f'--actors {text}: actor {i} is out of range; this run has '
                             f'actors 0..{num_actors - 1} (num_actors={num_actors})')
    if len(set(ids)) != len(ids) or not ids:
        raise ValueError(f'--actors {text}: each actor id once, at least one')
    return sorted(ids)


class _Node:
    """An rclpy node of its own context, spun by the supervisor's loop (no thread)."""

    def __init__(self, name: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context,
                                      start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin(self, seconds: float = 0.0):
        """Handle what has arrived, waiting at most ``seconds``."""
        end = time.monotonic() + seconds
        while True:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, end - time.monotonic())))
            if time.monotonic() >= end:
                return

    def close(self):
        """Leave the graph."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def _status(values: Dict[str, str], run_id: str):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    status = DiagnosticStatus(name=f'pg_node run {run_id}', hardware_id=socket.gethostname(),
                              message=values['state'])
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    return status


def _latched():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Announcer(_Node):
    """The learner host's side: publishes the run's state and configuration (latched)."""

    def __init__(self, cfg: Dict[str, Dict]):
        """Announce the run of ``cfg`` as training."""
        super().__init__('pg_node_run_info')
        from diagnostic_msgs.msg import DiagnosticStatus
        self.run_id = cfg[SHARED]['run_id']
        shared = shared_config(cfg)
        self.values = {'state': TRAINING, 'num_actors': cfg[SHARED]['num_actors'],
                       'config_sha256': config_digest(shared),
                       'config': json.dumps(shared, sort_keys=True)}
        self.pub = self.node.create_publisher(DiagnosticStatus,
                                              run_topic(self.run_id, 'run_info'), _latched())
        self.pub.publish(_status(self.values, self.run_id))

    def finish(self, state: str, linger: float = 10.0):
        """
        Announce the end: ``done`` (``state``, the supervisor's, is 'done') or ``stopped``.

        Waits until the worker hosts' subscriptions are gone, ``linger`` s at most, so that
        each gets the news before this process leaves the graph.
        """
        self.values['state'] = DONE if state == 'done' else STOPPED
        self.pub.publish(_status(self.values, self.run_id))
        end = time.monotonic() + linger
        while time.monotonic() < end and self.pub.get_subscription_count():
            self.spin(0.1)


class Follower(_Node):
    """A worker host's side: reads the learner host's announcement of the run."""

    def __init__(self, run_id: str):
        """Subscribe to the announcement of run ``run_id``."""
        super().__init__('pg_node_worker_host')
        from diagnostic_msgs.msg import DiagnosticStatus
        self.run_id = run_id
        self.info: Optional[Dict[str, str]] = None
        self.node.create_subscription(DiagnosticStatus, run_topic(run_id, 'run_info'),
                                      self._on_info, _latched())

    def _on_info(self, status):
        self.info = {kv.key: kv.value for kv in status.values}

    def wait(self, timeout: float) -> Optional[Dict[str, str]]:
        """Return the announcement, waiting up to ``timeout`` s for the first one."""
        end = time.monotonic() + timeout
        while self.info is None and time.monotonic() < end:
            self.spin(0.1)
        return self.info

    def check(self, cfg: Dict[str, Dict]) -> Optional[str]:
        """Return why this host cannot join (configurations differ), or None."""
        theirs = json.loads(self.info['config'])
        wrong = differences(shared_config(cfg), theirs)
        if wrong:
            return ("this host's configuration differs from the learner host's: "
                    + '; '.join(wrong))
        return None

    def done(self) -> bool:
        """Return whether the learner host has announced the end of the run."""
        self.spin()
        return self.info is not None and self.info.get('state') != TRAINING
