"""
Reading a configuration: a ROS 2 parameter file and ``key=value`` overrides, checked.

:func:`load_config` reads ``config/pg_node.yaml`` (or a preset, or a file of one's own),
applies the command line's overrides, checks every value against the node tables
(:mod:`pg_node.common.params`) and fills in the defaults; a key, section or value that cannot
be used is refused with a :class:`~pg_node.common.param_schema.ConfigError` that says why
(and which name was probably meant).
"""
import difflib
import re
import shlex
from typing import Any, Callable, Dict, Optional, Sequence

from pg_node.common.param_schema import ConfigError
from pg_node.common.params import params_for, SCHEMA, SHARED, SHARED_PARAMS
import yaml


_OVERRIDE = re.compile(r'([^=:]+)(:?=)(.*)', re.S)


def check_unquoted(overrides: Sequence[str]) -> None:
    """
    Raise ConfigError for a word after ``key=value`` that is no override: unquoted spaces.

    >>> try:
    ...     check_unquoted(['randomize_latency=uniform', '0', '2', 'seed=1'])
    ... except ConfigError as exc:
    ...     print(str(exc).split(': ')[-1])
    'randomize_latency=uniform 0 2'
    """
    texts = list(overrides)
    for i, text in enumerate(texts):
        if i == 0 or _OVERRIDE.fullmatch(text) is not None:
            continue
        if _OVERRIDE.fullmatch(texts[i - 1]) is None:
            return                  # a bare word first: parse_override says what is wrong
        end = i
        while end < len(texts) and _OVERRIDE.fullmatch(texts[end]) is None:
            end += 1
        whole = shlex.quote(' '.join(texts[i - 1:end]))
        raise ConfigError(f'override {text!r} looks like the rest of an override with spaces: '
                          f'quote it: {whole}')


def parse_override(text: str):
    """
    Split ``key=value`` or ``key:=value`` (value parsed as YAML: ``3``, ``0.5``, ``[64, 64]``).

    ``:=`` is how ROS users write a value (``-p key:=value``, launch arguments), so it is
    taken too.

    >>> parse_override('model:=my_arm.xml'), parse_override('actor_node.n_steps=16')
    (('model', 'my_arm.xml'), ('actor_node.n_steps', 16))
    """
    match = _OVERRIDE.fullmatch(text)
    if match is None:
        raise ConfigError(f'override {text!r} is not of the form key=value (or key:=value)')
    key, raw = match.group(1), match.group(3)
    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f'override {text!r}: value is not valid YAML ({exc})') from None
    return key.strip(), value


def _did_you_mean(key: str, known) -> str:
    """
    Return ``" (did you mean 'x'?)"`` for the known names closest to ``key``, or nothing.

    >>> _did_you_mean('learning_rte', ['learning_rate', 'gamma'])
    " (did you mean 'learning_rate'?)"
    """
    close = difflib.get_close_matches(key, list(known), n=3, cutoff=0.7)
    return f' (did you mean {" or ".join(repr(c) for c in close)}?)' if close else ''


#: a rule of a layer above this one, called with each section's name and checked values
SectionCheck = Callable[[str, Dict[str, Any]], None]


def load_config(path=None, overrides: Sequence[str] = (), extra_sections=None,
                check: Optional[SectionCheck] = None) -> Dict[str, Dict[str, Any]]:
    """
    Read a parameter file, apply ``key=value`` overrides, validate, fill in defaults.

    Returns ``{section: {key: value}}`` for ``'/**'``, every node in :data:`SCHEMA` and every
    node in ``extra_sections`` (a map of node name to its own table, e.g. ``sim_node``'s).
    A node's value comes from its own section, else from ``/**`` if it is a shared key, else
    from the default; a node of :data:`SCHEMA` also receives every shared key. An override
    ``key=value`` goes to ``/**`` for a shared key, else to every node that has the key;
    ``node.key=value`` sets it in one node only.

    ``check``, if given, is called with each section's name and values once they passed the
    table: a rule this layer cannot know (:func:`pg_node.rl.updaters.check_settings`, which
    refuses a setting the chosen update lacks) raises its ConfigError there.
    """
    extra = dict(extra_sections or {})
    tables = {SHARED: SHARED_PARAMS}
    tables.update({name: params_for(name) for name in SCHEMA})
    tables.update(extra)
    given = {name: {} for name in tables}
    check_unquoted(overrides)
    if path is not None:
        for name, params in read_sections(path).items():
            if name not in tables:
                raise ConfigError(f'unknown section {name!r} in {path}; known: '
                                  f'{", ".join(tables)}')
            given[name].update(params)
    for text in overrides:
        key, value = parse_override(text)
        if '.' in key:
            name, _, key = key.partition('.')
            if name not in tables:
                raise ConfigError(f'override {text!r}: unknown node {name!r}; known: '
                                  f'{", ".join(tables)}')
            given[name][key] = value
        elif key in SHARED_PARAMS:
            given[SHARED][key] = value
        else:
            homes = [n for n, t in tables.items() if key in t]
            if not homes:
                known = sorted(set().union(*tables.values()))
                raise ConfigError(f'override {text!r}: unknown parameter {key!r}'
                                  f'{_did_you_mean(key, known)}; known: {", ".join(known)} '
                                  '(node.key=value sets one node only)')
            for name in homes:
                given[name][key] = value
    out = {}
    for name, table in tables.items():
        for key in given[name]:
            if key not in table:
                raise ConfigError(f'unknown parameter {key!r} in section {name!r}'
                                  f'{_did_you_mean(key, table)}; allowed: {", ".join(table)}')
        values = {}
        for key, param in table.items():
            if key in given[name]:
                value = given[name][key]
            elif key in SHARED_PARAMS and key in given[SHARED]:
                value = given[SHARED][key]
            elif key in SHARED_PARAMS:
                value = SHARED_PARAMS[key].default
            else:
                value = param.default
            label = key if name == SHARED else f'{name}.{key}'
            values[key] = param.check(label, value)
        if check is not None:
            check(name, values)
        out[name] = values
    return out


def read_sections(path) -> Dict[str, Dict[str, Any]]:
    """Return ``{section: ros__parameters}`` of a ROS 2 parameter file, checking its shape."""
    try:
        with open(path) as f:
            raw = yaml.safe_load(f) or {}
    except OSError as exc:
        raise ConfigError(f'cannot read config file {path}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ConfigError(f'config file {path} is not valid YAML: {exc}') from None
    if not isinstance(raw, dict):
        raise ConfigError(f'config file {path} must map node names to sections')
    out = {}
    for name, section in raw.items():
        params = section.get('ros__parameters') if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(f'section {name!r} in {path} must hold a ros__parameters: map')
        out[node_key(str(name))] = params
    return out


def node_key(name: str) -> str:
    """
    Return the section a parameter-file key addresses: ``/**/sim_node`` and ``sim_node``.

    ``/**`` stays itself; ``/**/x``, ``/x`` and ``x`` all mean node ``x`` (pg_node's files use
    ``/**/x``, which reaches node ``x`` in any namespace).
    """
    if name == SHARED:
        return name
    for prefix in ('/**/', '/'):
        if name.startswith(prefix):
            return name[len(prefix):]
    return name
