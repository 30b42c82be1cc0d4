"""
What a robot's settings say against the physics a policy was trained on (numpy-free, no ROS).

A policy's card records its training physics (``physics``:
:func:`pg_node.sim.training_physics.training_physics`): who carried the arm's weight, the
control period, the damping the import assumed. ``policy_node``'s parameters describe the
robot it drives. Where the two disagree the policy meets an arm it never learned, which no
guard catches: a policy trained with the weight compensated sags on a robot that does not
compensate, one trained at 25 Hz overshoots when commanded at 100 Hz, one that leaned on
an assumed velocity damping overshoots on a torque-mode robot that has none. These are
warnings, not refusals: the user may know better (a stand-in, a slower test), and says so
by reading the one line configure logs.
"""
from typing import List, Mapping

#: ``policy_node``'s ``gravity_compensation`` values and what each says about the robot
GRAVITY_COMPENSATION = {
    '': 'not stated (not compared with the card)',
    'robot': "the robot's driver cancels the arm's weight (a Franka's torque interface)",
    'policy': "nothing cancels the arm's weight: the commands must carry it",
}
#: the relative difference of control period that counts as a contradiction
PERIOD_TOLERANCE = 0.01


def contradictions(physics: Mapping, params: Mapping) -> List[str]:
    """
    Return each way ``params`` (``policy_node``'s) contradict a card's ``physics``.

    * ``control_rate`` (non-zero) whose period differs from the card's ``control_period``
      by more than :data:`PERIOD_TOLERANCE`;
    * ``gravity_compensation`` (stated) other than the card's (``robot`` or ``policy``);
    * ``command_interface`` effort for a policy whose model assumed a velocity damping
      (``arm import --velocity-damping``), which a robot in torque mode lacks.

    A card without ``physics`` (written before issue 46) contradicts nothing.

    >>> physics = {'control_period': 0.04, 'gravity_compensation': 'robot',
    ...            'assumptions': ['velocity_damping: each arm joint is damped by ...']}
    >>> contradictions(physics, {'control_rate': 25.0, 'gravity_compensation': 'robot',
    ...                          'command_interface': 'position'})
    []
    >>> for line in contradictions(physics, {'control_rate': 100.0, 'command_interface':
    ...                                      'effort', 'gravity_compensation': 'policy'}):
    ...     print(line.split(', the policy was ')[0])
    control_rate 100 Hz
    gravity_compensation policy
    command_interface effort
    """
    if not physics:
        return []
    out = []
    period = physics.get('control_period')
    rate = float(params.get('control_rate') or 0.0)
    if period and rate and abs(rate * period - 1.0) > PERIOD_TOLERANCE:
        out.append(f'control_rate {rate:g} Hz, the policy was trained at {1 / period:g} Hz '
                   f'(control period {period:g} s)')
    stated, trained = params.get('gravity_compensation') or '', physics.get(
        'gravity_compensation')
    if stated and trained in ('robot', 'policy', 'partial') and stated != trained:
        by = {'robot': 'the robot compensating gravity',
              'policy': 'no gravity compensation (its commands carried the weight)',
              'partial': "gravity compensated for part of the arm's links"}[trained]
        out.append(f'gravity_compensation {stated}, the policy was trained with {by}')
    assumed = [a for a in physics.get('assumptions') or () if a.startswith('velocity_damping')]
    if params.get('command_interface') == 'effort' and assumed:
        out.append('command_interface effort, the policy was trained with a velocity damping '
                   '(effort / velocity limit) that a robot in torque mode lacks')
    return out


def warning(physics: Mapping, params: Mapping) -> str:
    """Return the one line configure logs for the contradictions ('' when there are none)."""
    found = contradictions(physics, params)
    if not found:
        return ''
    return ("the parameters contradict the policy card's physics: " + '; '.join(found)
            + ' (docs/deploy.md#the-training-physics)')
