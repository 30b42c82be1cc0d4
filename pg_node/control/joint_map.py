"""
Where a policy's joints are in a robot's joint states: one arm by plain name, or several.

A ``sensor_msgs/JointState`` names its joints in any order and may carry others; a policy's
card names the arm's joints. One arm is matched by the plain names (``joint0``), several arms
by ``arm<i>/<joint>``, as ``sim_node`` publishes them.

A controller names its joints in its ``joints`` parameter: a forward command controller
takes ``Float64MultiArray`` index ``i`` as ``joints[i]``, with no name on the wire
(ros2_controllers (jazzy ed360c97d)
forward_command_controller/src/forward_command_controller.cpp:48-52), so its order must be
the command's; a joint trajectory controller takes names in any order, but every name must
be one of its ``joints`` and all of them must be there
(joint_trajectory_controller/src/joint_trajectory_controller.cpp:1676-1685, 1702-1713).
:func:`controller_mismatch` says how the two differ.
"""
from collections import Counter
import re
from typing import List, Optional, Sequence

import numpy as np
from pg_node.common.param_schema import ConfigError

#: a joint of arm ``i`` among several
PREFIXED = re.compile(r'^arm(\d+)/(.+)$')


def arm_joint_names(joints: Sequence[str], num_arms: int, plain: bool) -> List[str]:
    """
    Return the names of ``joints`` of every arm, arm-major: plain for one arm, else prefixed.

    >>> arm_joint_names(['j0', 'j1'], 2, plain=False)
    ['arm0/j0', 'arm0/j1', 'arm1/j0', 'arm1/j1']
    """
    return list(joints) if plain else [f'arm{i}/{n}' for i in range(num_arms) for n in joints]


def joint_columns(names: Sequence[str], joints: Sequence[str], num_arms: int = 0
                  ) -> np.ndarray:
    """
    Return ``(arms, joints)`` indices into a JointState's arrays for the model's ``joints``.

    One arm with the plain names, or ``num_arms`` (0: as many as the message names) arms
    named ``arm<i>/<joint>``. Raises ConfigError naming the first model joint that is missing.

    >>> joint_columns(['wrist', 'joint1', 'joint0'], ['joint0', 'joint1']).tolist()
    [[2, 1]]
    >>> joint_columns(['arm1/joint0', 'arm0/joint0', 'arm1/x', 'arm0/x'], ['joint0', 'x'])
    array([[1, 3],
           [0, 2]])
    """
    where = {name: i for i, name in enumerate(names)}
    plain = [j for j in joints if j in where]
    if plain and num_arms <= 1:
        missing = [j for j in joints if j not in where]
        if missing:
            raise ConfigError(_missing(missing[0], joints, names))
        return np.array([[where[j] for j in joints]])
    if num_arms == 0:
        arms = {int(m.group(1)) for name in names
                if (m := PREFIXED.match(name)) and m.group(2) in joints}
        if not arms:
            raise ConfigError(_missing(joints[0], joints, names))
        num_arms = max(arms) + 1
    index = np.empty((num_arms, len(joints)), dtype=int)
    for i in range(num_arms):
        for k, j in enumerate(joints):
            col = where.get(f'arm{i}/{j}')
            if col is None:
                raise ConfigError(_missing(f'arm{i}/{j}', joints, names))
            index[i, k] = col
    return index


def _missing(joint: str, joints: Sequence[str], names: Sequence[str]) -> str:
    shown = ', '.join(list(names)[:8]) + (', ...' if len(names) > 8 else '')
    return (f"joint_states has no joint {joint!r}: the policy's arm has joints "
            f"{', '.join(joints)} (plain, or as arm<i>/<joint> for several arms); the message "
            f'names [{shown}] (remap joint_states, or give a model with these joint names)')


def controller_mismatch(commanded: Sequence[str], served: Sequence[str], controller: str,
                        ordered: bool = True) -> Optional[str]:
    """
    Return how a controller's ``joints`` (``served``) differ from the commanded ones, or None.

    ``ordered``: the order counts (a forward command controller's ``Float64MultiArray``);
    False: only the set does (a joint trajectory controller, whose messages carry names).

    >>> controller_mismatch(['a', 'b'], ['a', 'b'], '/arm_controller') is None
    True
    >>> controller_mismatch(['a', 'b'], ['b', 'a'], '/arm_controller', ordered=False) is None
    True
    >>> print(controller_mismatch(['a', 'b'], ['b', 'a'], '/c'))
    controller /c has joints [b, a], the commands are for [a, b]: the same joints in another \
order (a Float64MultiArray carries no names: element i goes to joints[i])
    >>> print(controller_mismatch(['a', 'b'], ['a', 'c'], '/c', ordered=False))
    controller /c has joints [a, c], the commands are for [a, b]: missing b; extra c
    """
    if list(commanded) == list(served):
        return None
    said = (f"controller {controller} has joints [{', '.join(served)}], the commands are "
            f"for [{', '.join(commanded)}]")
    if Counter(commanded) == Counter(served):
        if not ordered:
            return None
        return (f'{said}: the same joints in another order (a Float64MultiArray carries no '
                'names: element i goes to joints[i])')
    missing = [j for j in commanded if j not in served]
    extra = [j for j in served if j not in commanded]
    parts = ([f"missing {', '.join(missing)}"] if missing else []) + \
        ([f"extra {', '.join(extra)}"] if extra else [])
    return f"{said}: {'; '.join(parts) or 'a joint named twice'}"
