"""
Position targets relative to the measured angle: a bounded change per control step.

A position policy with absolute targets maps its action over the whole joint range (an
action of 0.1 is 0.63 rad on a +-2 pi joint: a jump a real servo turns into a protective
stop). With a **position delta** ``d`` (rad per control step, per joint) the action ``a`` in
``[-1, 1]`` is instead a change around the measured angle ``q``::

    target = clip(q + clip(a, -1, 1) * d, joint_low, joint_high)

so that no command lies further than ``d`` from where the joint is. The arm model carries
``d`` as the custom numeric ``pg_position_delta`` (``arm import --position-delta``; one
value, or one per arm joint), the simulator turns the policy's actions into targets this
way at every control step (:class:`pg_node.sim.arm_task.ArmTask`), the card records it
(``command_interfaces.position.max_position_delta``) and ``policy_node`` does the same with
the measured joint states. A model without it keeps absolute targets, as before.

Pure numpy: the simulator, ``policy_node`` and the tests share this one copy.
"""
from typing import Optional

import numpy as np

#: the custom numeric of an arm model that holds the delta (rad per control step)
MODEL_NUMERIC = 'pg_position_delta'


def deltas(value, joints: int) -> Optional[np.ndarray]:
    """
    Return the per-joint delta of ``value`` (one number or one per joint), or None if unset.

    ``None``, an empty value or all zeros: no delta (absolute targets).

    >>> deltas([0.1], 2), deltas(None, 2), deltas([0.1, 0.2], 2)
    (array([0.1, 0.1]), None, array([0.1, 0.2]))
    """
    if value is None:
        return None
    d = np.atleast_1d(np.asarray(value, dtype=float))
    if d.size == 0 or not np.any(d):
        return None
    if d.size == 1:
        d = np.full(joints, float(d[0]))
    if d.shape != (joints,) or np.any(d < 0) or not np.all(np.isfinite(d)):
        raise ValueError(f'{MODEL_NUMERIC} needs one positive number or one per arm joint '
                         f'({joints}), got {list(np.atleast_1d(value))}')
    return d


def targets(action: np.ndarray, q: np.ndarray, delta: np.ndarray, low: np.ndarray,
            high: np.ndarray) -> np.ndarray:
    """
    Return the target angles (rad) of relative actions ``action`` at measured angles ``q``.

    ``action``, ``q``: ``(..., joints)``; ``delta``, ``low``, ``high``: per joint. A
    non-finite action stays non-finite (the guards then hold).

    >>> targets(np.array([[1.0, -0.5, 3.0]]), np.array([[0.0, 1.0, 2.9]]),
    ...         np.array([0.1, 0.2, 0.2]), np.full(3, -3.0), np.full(3, 3.0))
    array([[0.1, 0.9, 3. ]])
    """
    a = np.asarray(action, dtype=float)
    with np.errstate(invalid='ignore'):
        return np.clip(np.asarray(q, dtype=float) + np.clip(a, -1.0, 1.0) * delta, low, high)


def bound_change(target: np.ndarray, q: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """
    Return ``target`` moved to within ``bound`` (rad, per joint; inf: no bound) of ``q``.

    >>> bound_change(np.array([1.0, -1.0, 0.05]), np.zeros(3), np.array([0.1, 0.2, np.inf]))
    array([ 0.1 , -0.2 ,  0.05])
    """
    return np.clip(target, q - bound, q + bound)
