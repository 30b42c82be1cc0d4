"""
Domain randomization and fixed perturbations of an arm task (no ROS here).

A policy trained on one exact model meets a real arm whose links are heavier, whose joints
are more damped, whose motors are weaker, whose commands arrive late and whose sensors are
noisy. The *terms* below change the simulated arm in each of these ways, per arm, with
the vocabulary of mjlab's and Isaac Lab's event terms: each term draws a value from a
*distribution*, applies it to the model's nominal value with an *operation*, and is drawn
*when* it says (at startup, at every episode reset, or every N control steps).

=================  ==========  ================================================================
term               operation   what it changes (per arm; each link / joint / motor drawn alone)
=================  ==========  ================================================================
``mass``           scale       link masses, and their inertias by the same factor
``damping``        scale       arm joint damping (``dof_damping``)
``frictionloss``   scale       arm joint dry friction (``dof_frictionloss``)
``armature``       scale       arm joint armature, the motors' reflected inertia
``gear``           scale       actuator strength (``actuator_gear``): torque per unit command
``latency``        abs         whole control steps between a command and its effect
``obs_noise``      abs         std of Gaussian noise on the observed joint angles, rad
``vel_noise``      abs         std of Gaussian noise on the observed joint velocities, rad/s
``action_noise``   abs         std of Gaussian noise added to each applied command
``target_noise``   abs         std of Gaussian noise on the observed target position, m
``servo_bandwidth`` abs        each servo's tracking bandwidth, Hz: a first-order lag
``servo_latency``  abs         the servos' dead time, s (whole physics steps)
``payload``        abs         an unknown payload at the fingertip, kg: its weight, which no
                               gravity compensation knows
=================  ==========  ================================================================

A term is written as a short string, one ROS parameter each (``randomize_<term>`` of
``sim_node``; empty: off)::

    [operation] distribution a b [reset | startup | every N]
    [operation] value            [reset | startup | every N]

* ``operation``: ``scale`` (nominal x value), ``add`` (nominal + value) or ``abs`` (the
  value itself); the table's column is the default. ``latency`` and the noise terms are
  ``abs`` only.
* ``distribution``: ``uniform a b``, ``log_uniform a b`` (``0 < a``) or ``gaussian mean
  std`` (truncated at 3 std); a single number is that value always.
* when: ``reset`` (the default: a new value at each episode start), ``startup`` (once per
  arm) or ``every N`` (every N control steps of the arm, and at its first start).

Examples: ``randomize_mass: uniform 0.7 1.5``, ``randomize_latency: uniform 0 2`` (whole
steps, each equally likely), ``randomize_obs_noise: 0.01``.

Latency: the command applied at control step t is the one received at t - L; until an
episode has L commands, the arm gets zero (the control penalty is still on the commanded
action, what the policy chose). Action noise is added to the applied command, which MuJoCo
then clamps to the control range. Observation noise is drawn once per control step and
arm and enters only the observation (and ``joint_state``): the reward and the recorded
distance are the true ones. The fingertip-to-target part of the observation is what a
robot computes: the fingertip by forward kinematics of the noisy joint angles, minus the
noisy target.

Servo tracking (``servo_bandwidth``, ``servo_latency``): a position or velocity servo on a
real arm reaches its setpoint late and gradually; between the command the arm receives (after
``latency`` and ``action_noise``) and MuJoCo's ``ctrl`` it goes through a dead time of
``round(servo_latency / timestep)`` physics steps and then a first-order lag of time constant
``tau = 1 / (2 pi servo_bandwidth)``, advanced exactly at every physics step (ctrl of a unit
step after ``k`` steps: ``1 - exp(-k timestep / tau)``). The law is the same for every
interface (a position setpoint, a velocity, a torque whose current loop is slow), and its
one parameter is the -3 dB bandwidth drive makers state. Both start each episode at the
command that holds the arm where it starts, as the ``latency`` history does: zero for a
motor or a velocity servo, the start angle for a position servo (whose zero command is the
middle of the joint's range: a lag starting there would pull the arm towards it).

Payload: the weight ``payload x gravity`` pulls at the fingertip site (``qfrc_applied``,
set at every physics step from the site's position), on an arm whose gravity compensation
(``gravcomp``) knows only its own links: the gravity-compensation error of an unknown tool
or object. Its inertia is left out (what ``mass`` and ``armature`` cover).

The terms are applied by :class:`pg_node.sim.randomization.Randomizer`, inside
:class:`~pg_node.sim.arm_task.ArmTask`. Every arm draws from its own generator,
``PCG64(SeedSequence(seed + i, spawn_key=(1,)))``, apart from the task's (which draws the
episode starts): turning a term on leaves the start states and goals the same, so a
perturbed evaluation meets the very episodes of the nominal one, and lock-step training
through the graph still equals the in-process run to the bit.
"""
from dataclasses import dataclass
import math
from typing import Dict, Mapping, Optional, Sequence

OPERATIONS = ('scale', 'add', 'abs')
DISTRIBUTIONS = ('uniform', 'log_uniform', 'gaussian')
#: the model terms whose value must stay > 0 (the others >= 0)
POSITIVE = ('mass', 'gear')
#: the most control steps a command may be late
MAX_LATENCY = 10
#: the longest servo dead time, s
MAX_SERVO_LATENCY = 1.0
#: the spawn key of the randomization generators (the task's own have none)
STREAM = 1


@dataclass(frozen=True)
class Term:
    """What one term changes: a model field, the command path or the observation."""

    kind: str           # 'model', 'latency', 'noise', 'servo' or 'payload'
    default_op: str
    unit: str
    description: str


TERMS: Dict[str, Term] = {
    'mass': Term('model', 'scale', 'kg', 'link masses, and inertias by the same factor'),
    'damping': Term('model', 'scale', 'N m s/rad', 'arm joint damping'),
    'frictionloss': Term('model', 'scale', 'N m', 'arm joint dry friction'),
    'armature': Term('model', 'scale', 'kg m^2', "arm joint armature (the motors' inertia)"),
    'gear': Term('model', 'scale', '', 'actuator strength (gear: torque per unit command)'),
    'latency': Term('latency', 'abs', 'steps', 'control steps between a command and its '
                                               'effect'),
    'obs_noise': Term('noise', 'abs', 'rad', 'std of the noise on observed joint angles'),
    'vel_noise': Term('noise', 'abs', 'rad/s', 'std of the noise on observed joint '
                                               'velocities'),
    'action_noise': Term('noise', 'abs', '', 'std of the noise added to applied commands'),
    'target_noise': Term('noise', 'abs', 'm', 'std of the noise on the observed target'),
    'servo_bandwidth': Term('servo', 'abs', 'Hz', "each servo's tracking bandwidth (a "
                                                  'first-order lag, tau = 1 / (2 pi f))'),
    'servo_latency': Term('servo', 'abs', 's', "the servos' dead time (whole physics steps)"),
    'payload': Term('payload', 'abs', 'kg', 'an unknown payload at the fingertip: its weight, '
                                            'which no gravity compensation knows'),
}

#: ``--perturb`` names: ``<term>_<operation>`` or these aliases
ALIASES = {'latency_steps': 'latency'}


class BadTerm(ValueError):
    """A term, range or perturbation that cannot be used; the message says why in one line."""


@dataclass(frozen=True)
class TermSpec:
    """One configured term: how its values are drawn and applied, and when."""

    term: str
    operation: str
    distribution: str
    a: float
    b: float
    when: str = 'reset'
    every: int = 0

    @property
    def bounds(self):
        """Return the smallest and largest value a draw can take."""
        if self.distribution == 'gaussian':
            return self.a - 3 * self.b, self.a + 3 * self.b
        return self.a, self.b

    def text(self) -> str:
        """Return the spec in the parameter's syntax (what :func:`parse_term` reads)."""
        when = f'every {self.every}' if self.when == 'every' else self.when
        if self.distribution == 'uniform' and self.a == self.b:
            return f'{self.operation} {self.a:g} {when}'
        return f'{self.operation} {self.distribution} {self.a:g} {self.b:g} {when}'


def _number(term: str, word: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise BadTerm(f'{term}: {word!r} is not a number') from None
    if not math.isfinite(value):
        raise BadTerm(f'{term}: {word!r} is not a finite number')
    return value


def parse_term(term: str, text: str) -> Optional[TermSpec]:
    """
    Read one term's string (module docstring); return None for an empty one.

    >>> parse_term('mass', 'uniform 0.7 1.5').text()
    'scale uniform 0.7 1.5 reset'
    >>> parse_term('latency', '2 startup').text()
    'abs 2 startup'
    >>> parse_term('mass', 'uniform 1.5 0.7')
    Traceback (most recent call last):
    ...
    pg_node.common.perturbations.BadTerm: mass: the range 1.5 0.7 is empty (need a <= b)
    """
    if term not in TERMS:
        raise BadTerm(f'unknown term {term!r}; the terms are: {", ".join(TERMS)}')
    words = str(text).split()
    if not words:
        return None
    info = TERMS[term]
    op = info.default_op
    if words[0] in OPERATIONS:
        op = words.pop(0)
        if info.kind != 'model' and op != 'abs':
            raise BadTerm(f'{term}: only abs applies (it is a value of its own, not a change '
                          f'of a model value); got {op!r}')
    when, every = 'reset', 0
    if words and words[-1] in ('reset', 'startup'):
        when = words.pop()
    elif len(words) >= 2 and words[-2] == 'every':
        every_word = words[-1]
        words = words[:-2]
        if not every_word.isdigit() or int(every_word) < 1:
            raise BadTerm(f'{term}: every {every_word!r}: need a whole number of control '
                          'steps >= 1')
        when, every = 'every', int(every_word)
    if not words:
        raise BadTerm(f'{term}: no value in {text!r}')
    if words[0] in DISTRIBUTIONS:
        dist = words.pop(0)
        if len(words) != 2:
            raise BadTerm(f'{term}: {dist} needs two numbers, got {" ".join(words) or "none"} '
                          f'in {text!r}')
        a, b = (_number(term, w) for w in words)
    elif len(words) == 1:
        dist = 'uniform'
        a = b = _number(term, words[0])
    else:
        raise BadTerm(f'{term}: cannot read {text!r}; write [operation] distribution a b '
                      f'[reset|startup|every N] with a distribution of '
                      f'{", ".join(DISTRIBUTIONS)}, or one value')
    if dist == 'gaussian':
        if b < 0:
            raise BadTerm(f'{term}: gaussian {a:g} {b:g}: the std must be >= 0')
    elif a > b:
        raise BadTerm(f'{term}: the range {a:g} {b:g} is empty (need a <= b)')
    if dist == 'log_uniform' and a <= 0:
        raise BadTerm(f'{term}: log_uniform {a:g} {b:g} needs 0 < a')
    spec = TermSpec(term, op, dist, a, b, when, every)
    _check_bounds(spec)
    return spec


def _check_bounds(spec: TermSpec):
    """Refuse a spec that can draw a value no arm can take."""
    lo, hi = spec.bounds
    kind = TERMS[spec.term].kind
    name = f'{spec.term} {spec.text()}'
    if kind == 'latency':
        if lo < 0 or hi > MAX_LATENCY:
            raise BadTerm(f'{name}: latency must stay within 0..{MAX_LATENCY} control steps '
                          f'(it can draw {lo:g}..{hi:g})')
        if spec.distribution == 'uniform' and (lo != int(lo) or hi != int(hi)):
            raise BadTerm(f'{name}: latency is whole control steps; give whole numbers')
    elif kind == 'noise':
        if lo < 0:
            raise BadTerm(f'{name}: a noise std must be >= 0 (it can draw {lo:g})')
    elif spec.term == 'servo_bandwidth':
        if lo <= 0:
            raise BadTerm(f'{name}: a servo bandwidth must stay > 0 Hz (it can draw {lo:g})')
    elif spec.term == 'servo_latency':
        if lo < 0 or hi > MAX_SERVO_LATENCY:
            raise BadTerm(f'{name}: the servo latency must stay within 0..'
                          f'{MAX_SERVO_LATENCY:g} s (it can draw {lo:g}..{hi:g})')
    elif kind == 'payload':
        if lo < 0:
            raise BadTerm(f'{name}: a payload must be >= 0 kg (it can draw {lo:g})')
    elif spec.operation == 'scale' and lo <= 0 and spec.term in POSITIVE:
        raise BadTerm(f'{name}: a {spec.term} scale must stay > 0 (it can draw {lo:g})')
    elif spec.operation == 'scale' and lo < 0:
        raise BadTerm(f'{name}: a {spec.term} scale must stay >= 0 (it can draw {lo:g})')
    elif spec.operation == 'abs' and (lo < 0 or (lo <= 0 and spec.term in POSITIVE)):
        sign = '> 0' if spec.term in POSITIVE else '>= 0'
        raise BadTerm(f'{name}: {spec.term} must stay {sign} (it can draw {lo:g})')


def parse_terms(specs: Mapping[str, object]) -> Dict[str, TermSpec]:
    """Read ``{term: text or TermSpec}``; return the terms that are on."""
    out = {}
    for term, text in specs.items():
        spec = text if isinstance(text, TermSpec) else parse_term(term, text)
        if spec is not None:
            out[term] = spec
    return out


PARAM_PREFIX = 'randomize_'


def from_params(params: Mapping[str, object]) -> Dict[str, str]:
    """Return ``{term: text}`` from ``sim_node``'s ``randomize_<term>`` parameters."""
    return {t: str(params.get(PARAM_PREFIX + t, '') or '') for t in TERMS}


def parse_perturbation(items: Sequence[str]) -> Dict[str, TermSpec]:
    """
    Read ``KEY=VALUE`` perturbations (``mass_scale=1.3 latency_steps=2 obs_noise=0.02``).

    A key is a term with its default operation (``obs_noise``), ``<term>_<operation>``
    (``mass_scale``, ``damping_add``) or an alias (``latency_steps``); the value is fixed,
    the same for every arm and link, from the start.

    >>> sorted((k, v.text()) for k, v in parse_perturbation(['mass_scale=1.3']).items())
    [('mass', 'scale 1.3 startup')]
    """
    out = {}
    for item in items:
        key, sep, value = str(item).partition('=')
        key = key.strip()
        if not sep or not key:
            raise BadTerm(f'--perturb {item!r}: write KEY=VALUE, e.g. mass_scale=1.3')
        term, op = ALIASES.get(key, key), None
        if term not in TERMS:
            base, _, suffix = key.rpartition('_')
            if suffix in OPERATIONS and base in TERMS:
                term, op = base, suffix
            else:
                keys = ([f'{t}_{o}' for t in TERMS for o in OPERATIONS
                         if TERMS[t].kind == 'model']
                        + [t for t in TERMS if TERMS[t].kind != 'model'])
                raise BadTerm(f'--perturb {key!r}: unknown key; known: {", ".join(keys)}, '
                              'latency_steps')
        if term in out:
            raise BadTerm(f'--perturb: {term} given twice')
        text = f'{op or TERMS[term].default_op} {value.strip()} startup'
        if len(value.split()) != 1:
            raise BadTerm(f'--perturb {item!r}: the value must be one number')
        try:
            out[term] = parse_term(term, text)
        except BadTerm as exc:
            raise BadTerm(f'--perturb {item}: {exc}') from None
    return out
