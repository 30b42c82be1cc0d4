"""
A run's identity on the ROS network: its id, its namespace, its topics and its token.

Several trainings share one lab network (one ``ROS_DOMAIN_ID``) without mixing because each
has a **run id**, a ROS name token (``exp1``, ``run_20261203_081652``):

* its nodes live in the namespace ``/<run_id>`` (a simulator/actor pair of several in
  ``/<run_id>/arm<i>``), so ``ros2 node list`` and ``ros2 param set /<run_id>/learner_node``
  name one run's nodes;
* the topics the run's nodes share are ``/<run_id>/pg_node/<name>`` (:func:`run_topic`):
  ``rollout``, ``batch``, ``policy_weights``, ``episode``, ``metrics/<metric>``; a node's
  own topics (``joint_states``, ``target``, ``pg_node/transition``, ``pg_node/commands``)
  are relative to its namespace;
* every message of the run's wire formats carries the run's **token**, a 32-bit checksum of
  the id (:func:`run_token`), and every node drops (and counts, and logs once) a message
  whose token is another's: a stray publisher that found the topic is still not learned
  from or acted on.

The empty run id is the root namespace (``/pg_node/rollout``...): what nodes started one by
one with ``ros2 run`` and no ``run_id`` use. ``python -m pg_node train`` and the launch file
always give one.

Training's command topic is ``pg_node/commands``: never ``arm_controller/commands``, the
topic of a real ros2_control controller, which only ``policy_node`` speaks (deployment).
"""
import os
import re
from typing import Optional
import zlib

#: a run id: a ROS name token (letters, digits, underscores, a letter first), or empty
RUN_ID = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)?$')
#: longest run id: DDS topic names stay well under their 256-character limit
MAX_RUN_ID = 64
#: the node-relative topic on which the actor answers the simulator (never a controller's)
COMMANDS = 'pg_node/commands'
#: the topic of a real arm's forward command controller: only policy_node publishes on it
CONTROLLER_COMMANDS = 'arm_controller/commands'
#: the topic of a real arm's joint trajectory controller: only policy_node publishes on it
CONTROLLER_TRAJECTORY = 'arm_controller/joint_trajectory'


def check_run_id(run_id: str) -> str:
    """
    Return ``run_id`` if it can name a run, else raise ValueError saying why.

    >>> check_run_id('exp_1')
    'exp_1'
    >>> check_run_id('1exp')
    Traceback (most recent call last):
    ...
    ValueError: a run id is letters, digits and underscores, starting with a letter
    """
    if not RUN_ID.match(run_id):
        raise ValueError('a run id is letters, digits and underscores, starting with a letter')
    if len(run_id) > MAX_RUN_ID:
        raise ValueError(f'a run id has at most {MAX_RUN_ID} characters')
    return run_id


def run_namespace(run_id: str) -> str:
    """
    Return the namespace of a run's nodes: ``/<run_id>``, or ``/`` for the empty id.

    >>> run_namespace('exp1'), run_namespace('')
    ('/exp1', '/')
    """
    return f'/{run_id}' if run_id else '/'


def pair_namespace(run_id: str, actor_id: int, num_actors: Optional[int]) -> str:
    """
    Return the namespace of a run's simulator/actor pair: the run's, or ``arm<i>`` under it.

    ``num_actors`` None: one pair of several, whose count is not known where it starts.

    >>> pair_namespace('exp1', 0, 1), pair_namespace('exp1', 1, 2), pair_namespace('', 0, 2)
    ('/exp1', '/exp1/arm1', '/arm0')
    """
    if num_actors == 1:
        return run_namespace(run_id)
    return f'{run_namespace(run_id).rstrip("/")}/arm{actor_id}'


def placed_namespace(run_id: str, namespace: str) -> str:
    """
    Return the namespace of a pair placed by hand: ``namespace`` under the run's, or absolute.

    >>> placed_namespace('exp1', 'arm1'), placed_namespace('exp1', '/arm1')
    ('/exp1/arm1', '/arm1')
    >>> placed_namespace('exp1', ''), placed_namespace('', ''), placed_namespace('', 'arm1')
    ('/exp1', '/', '/arm1')
    """
    if namespace.startswith('/'):
        return namespace
    return f'{run_namespace(run_id).rstrip("/")}/{namespace.strip("/")}'.rstrip('/') or '/'


def run_topic(run_id: str, name: str) -> str:
    """
    Return the absolute name of a topic the run's nodes share.

    >>> run_topic('exp1', 'rollout'), run_topic('', 'metrics/entropy')
    ('/exp1/pg_node/rollout', '/pg_node/metrics/entropy')
    """
    return f'{run_namespace(run_id).rstrip("/")}/pg_node/{name}'


def run_of_topic(topic: str, name: str):
    """
    Return the run id whose ``name`` topic ``topic`` is, or None if it is none's.

    >>> run_of_topic('/exp1/pg_node/episode', 'episode')
    'exp1'
    >>> run_of_topic('/pg_node/episode', 'episode')
    ''
    >>> run_of_topic('/a/b/pg_node/episode', 'episode') is None
    True
    """
    suffix = f'/pg_node/{name}'
    if not topic.endswith(suffix):
        return None
    run_id = topic[:-len(suffix)].lstrip('/')
    return run_id if RUN_ID.match(run_id) and run_id.count('/') == 0 else None


def run_label(run_id: str) -> str:
    """
    Return how tools name a run to a user: its id, or ``(no run id)`` for the empty one.

    >>> run_label('exp1'), run_label('')
    ('exp1', '(no run id)')
    """
    return run_id or '(no run id)'


def run_token(run_id: str) -> int:
    """
    Return the run's token: the CRC-32 of its id, exact in a float64 header.

    >>> run_token(''), run_token('exp1') == run_token('exp1'), run_token('a') != run_token('b')
    (0, True, True)
    """
    return zlib.crc32(run_id.encode())


def run_id_for_dir(run_dir: str) -> str:
    """
    Return a run id made from a run directory's name (what ``train`` uses by default).

    >>> run_id_for_dir('runs/20261203-081652'), run_id_for_dir('/tmp/my run.v2/')
    ('run_20261203_081652', 'my_run_v2')
    """
    name = re.sub(r'[^A-Za-z0-9_]', '_', os.path.basename(os.path.normpath(run_dir)))
    if not name or not name[0].isalpha():
        name = 'run_' + name
    return name[:MAX_RUN_ID]
