"""
Which learner settings each policy update has, by the ``algo`` that chooses it, and the check.

The registry of settings, without torch: ``train`` checks a configuration with it before any
node starts (in well under a second), the learner when it is built and ``ros2 param set``
when a value changes. Each update class (:mod:`pg_node.rl.updaters`) takes its ``settings``
from here, so they are said once; a test keeps the classes' constructors and this table
equal. The parameter table (a lower layer) lists the same names as ``algo``'s choices.
"""
from typing import Any, Dict, Tuple

from pg_node.common.param_schema import ConfigError
from pg_node.common.params import LEARNER_PARAMS

_A2C = ('learning_rate', 'optimizer', 'ent_coef', 'max_grad_norm', 'normalize_advantage')
_NPG = ('ent_coef', 'normalize_advantage', 'max_kl', 'cg_iters', 'cg_damping')

#: algo -> the learner parameters its update is built from
SETTINGS: Dict[str, Tuple[str, ...]] = {
    'a2c': _A2C,
    'ppo': _A2C + ('n_epochs', 'batch_size', 'clip_range', 'target_kl'),
    'npg': _NPG,
    'trpo': _NPG + ('line_search_steps',),
}


def check_algo_setting(label: str, algo: str, key: str, value) -> None:
    """
    Raise ConfigError if ``key`` is a setting ``algo``'s update lacks, set off its default.

    A value equal to the default passes: the shipped parameter file and ``ros2 param dump``
    list every parameter, every update's settings included, and giving those back changes
    nothing. Any other value would be taken and ignored, so it is refused, naming the
    settings ``algo`` has.
    """
    has = SETTINGS[algo]
    if key in has or not any(key in s for s in SETTINGS.values()):
        return
    if value != LEARNER_PARAMS[key].default:
        raise ConfigError(f'parameter {label!r}: {value!r} is not allowed: algo {algo!r} has '
                          f'no {key}; its settings: {", ".join(has)}')


def check_settings(section: str, values: Dict[str, Any]) -> None:
    """
    Check every value of a configuration that names an ``algo`` (the learner's section).

    The label of a refused key is ``section.key`` (``key`` alone for an empty ``section``).
    Other sections pass: this is :func:`pg_node.common.config_files.load_config`'s ``check``.
    """
    if 'algo' not in values:
        return
    for key, value in values.items():
        check_algo_setting(f'{section}.{key}' if section else key, values['algo'], key, value)
