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
#: A UR's servoj thread ignores a target that needs more than this speed, rad/s, from the last
#: target or else from the measured angles within one robot cycle (Universal_Robots_Client_
#: Library c5d1e26 resources/external_control.urscript:96 JOINT_IGNORE_SPEED; the check,
#: targetWithinLimits, :143-170, a strict ``>``; applied at :199 and :207)
URCL_JOINT_IGNORE_SPEED = 20.0
#: a UR e-Series' robot cycle, s (get_steptime() at 500 Hz, external_control.urscript:5)
UR_E_STEPTIME = 0.002
#: the bound policy_node keeps a UR's targets within (``max_position_delta``): 0.9 of the
#: 0.04 rad URCL takes, since a change of exactly 0.04 rad computed as ``q + 0.04`` is
#: 0.04 + 1e-17 rad and is ignored (test_position_delta)
UR_POSITION_DELTA = 0.036


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


def urcl_accepts(target: np.ndarray, last_target: np.ndarray, measured: np.ndarray,
                 steptime: float = UR_E_STEPTIME) -> bool:
    """
    Return whether a UR's servoj thread takes ``target`` (rad per joint) rather than ignore it.

    As external_control.urscript:199-210 decides: within reach of the last target it took
    (``last_target``) at :data:`URCL_JOINT_IGNORE_SPEED` in one ``steptime``, or else of the
    measured angles.

    >>> urcl_accepts(np.array([0.039]), np.zeros(1), np.zeros(1))
    True
    >>> urcl_accepts(np.array([0.05]), np.zeros(1), np.array([0.02]))
    True
    >>> urcl_accepts(np.array([0.05]), np.zeros(1), np.zeros(1))
    False
    """
    def within(start):
        speed = np.abs(np.asarray(target) - np.asarray(start)) / steptime
        return bool(np.all(speed <= URCL_JOINT_IGNORE_SPEED))
    return within(last_target) or within(measured)


def bound_change(target: np.ndarray, q: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """
    Return ``target`` moved to within ``bound`` (rad, per joint; inf: no bound) of ``q``.

    >>> bound_change(np.array([1.0, -1.0, 0.05]), np.zeros(3), np.array([0.1, 0.2, np.inf]))
    array([ 0.1 , -0.2 ,  0.05])
    """
    return np.clip(target, q - bound, q + bound)
