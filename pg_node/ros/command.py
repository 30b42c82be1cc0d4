"""
The torque command, as ros2_control's forward command controller takes it, plus a tag.

A command is a ``std_msgs/Float64MultiArray`` of ``num_envs x n_actuators``
values, arm-major. pg_node's actor adds a third dimension of size 1 whose label names the
transition it answers (``transition 1234``): the data and its shape are unchanged for any
other reader, and a lock-step simulator steps only on the command that answers its current
transition, so a second publisher on the topic cannot desynchronise training. A fourth
dimension of size 1 names the run (``run 123``: :func:`pg_node.common.run.run_token`); a
simulator drops a command of another run (one without it is of token 0, the empty run id's).
A plain command (no tags) drives a simulator in real-time mode, as a robot's controller
would.

Training's simulator and actor speak it on ``pg_node/commands``
(:data:`pg_node.common.run.COMMANDS`): ``arm_controller/commands`` is a real controller's
topic, which only ``policy_node`` publishes on.
"""
from typing import Optional

import numpy as np
from pg_node.bag.ros_types import float64_field
from pg_node.ros import table_msg
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

TAG = 'transition'
RUN_TAG = 'run'


def to_msg(act: np.ndarray, seq: Optional[int] = None, run: int = 0) -> Float64MultiArray:
    """
    Return the command for ``act`` (``(num_envs, n_actuators)``), tagged with ``seq``, ``run``.

    >>> msg = to_msg(np.zeros((2, 3)), seq=7, run=42)
    >>> [(d.label, d.size, d.stride) for d in msg.layout.dim]
    [('arm', 2, 6), ('actuator', 3, 3), ('transition 7', 1, 1), ('run 42', 1, 1)]
    >>> transition_of(msg), transition_of(to_msg(np.zeros((2, 3))))
    (7, None)
    >>> run_of(msg), run_of(to_msg(np.zeros((2, 3))))
    (42, 0)
    """
    n, a = act.shape
    msg = Float64MultiArray()
    dims = [MultiArrayDimension(label='arm', size=n, stride=n * a),
            MultiArrayDimension(label='actuator', size=a, stride=a)]
    msg.layout.dim = dims
    msg.data = float64_field(act)
    return msg if seq is None else tag(msg, seq, run)


def to_cdr(act: np.ndarray, seq: int, run: int = 0) -> bytes:
    """
    Return :func:`to_msg`'s tagged command serialised, for ``publish`` (the actor's path).

    >>> msg = table_msg.from_cdr(to_cdr(np.arange(6.0).reshape(2, 3), seq=7))
    >>> [(d.label, d.size, d.stride) for d in msg.layout.dim], transition_of(msg)
    ([('arm', 2, 6), ('actuator', 3, 3), ('transition 7', 1, 1), ('run 0', 1, 1)], 7)
    >>> msg.data.tolist()
    [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    """
    n, a = act.shape
    return table_msg.to_cdr([('arm', n, n * a), ('actuator', a, a), (f'{TAG} {int(seq)}', 1, 1),
                             (f'{RUN_TAG} {int(run)}', 1, 1)], 0, act)


def tag(msg: Float64MultiArray, seq: int, run: int = 0) -> Float64MultiArray:
    """Mark ``msg`` as run ``run``'s answer to transition ``seq`` (dimensions of size 1)."""
    msg.layout.dim.append(MultiArrayDimension(label=f'{TAG} {int(seq)}', size=1, stride=1))
    msg.layout.dim.append(MultiArrayDimension(label=f'{RUN_TAG} {int(run)}', size=1, stride=1))
    return msg


def _tag_value(msg: Float64MultiArray, tag_name: str) -> Optional[int]:
    for dim in msg.layout.dim:
        name, _, number = dim.label.partition(' ')
        if name == tag_name and number.lstrip('-').isdigit():
            return int(number)
    return None


def transition_of(msg: Float64MultiArray) -> Optional[int]:
    """Return the transition number a command answers, None for a plain command."""
    return _tag_value(msg, TAG)


def run_of(msg: Float64MultiArray) -> int:
    """Return the run token of a command: 0 (the empty run id's) when it has none."""
    value = _tag_value(msg, RUN_TAG)
    return 0 if value is None else value
