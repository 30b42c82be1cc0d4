"""
What a parameter is: its default, meaning and allowed values, and the check of a given value.

A :class:`Param` is one row of the node tables (:mod:`pg_node.common.params`); its
:meth:`Param.check` refuses a value of the wrong type or out of range with a
:class:`ConfigError` whose message names the key, the value and what is allowed. The checks
some parameters add (``validate``) that are no one else's live here too.
"""
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any, Callable, List, Optional, Sequence


class ConfigError(ValueError):
    """A parameter file or override that cannot be used; the message says why."""


@dataclass(frozen=True)
class Param:
    """One parameter: its default (whose type is the parameter's type) and its limits."""

    default: Any
    description: str
    choices: Optional[Sequence[Any]] = None
    low: Optional[float] = None
    high: Optional[float] = None
    low_inclusive: bool = True
    #: extra check: called with the value, raises ValueError/OSError with the reason
    validate: Optional[Callable[[Any], Any]] = None
    #: True: may change while the node runs (``ros2 param set``); False: read-only
    live: bool = False
    #: a str parameter that also takes a bare number (YAML ``0.01``, ``key:=2``) as its text
    numbers_as_text: bool = False

    def allowed(self) -> str:
        """Describe the allowed values in words."""
        kind = type(self.default).__name__
        if isinstance(self.default, list):
            kind = 'non-empty list of positive integers'
        if self.choices is not None:
            return 'one of ' + ', '.join(repr(c) for c in self.choices)
        if self.low is not None or self.high is not None:
            lo = '' if self.low is None else (
                f'{self.low} <= ' if self.low_inclusive else f'{self.low} < ')
            hi = '' if self.high is None else f' <= {self.high}'
            return f'{_article(kind)} {kind} with {lo}value{hi}'
        return f'{_article(kind)} {kind}'

    def check(self, key: str, value):
        """Return ``value`` converted to the parameter's type, or raise ConfigError."""
        want = type(self.default)
        bad = ConfigError(f'parameter {key!r}: {value!r} is not allowed; '
                          f'expected {self.allowed()}')
        if want is bool:
            if not isinstance(value, bool):
                raise bad
        elif want is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise bad
        elif want is float:
            if isinstance(value, str):
                # YAML 1.1 reads 3e-4 (no dot) as a string; accept any float literal.
                try:
                    value = float(value)
                except ValueError:
                    raise bad from None
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad
            value = float(value)
            if not math.isfinite(value):
                raise bad
        elif want is str:
            if (self.numbers_as_text and isinstance(value, (int, float))
                    and not isinstance(value, bool)):
                value = repr(value)
            if not isinstance(value, str):
                raise bad
        elif want is list:
            if not isinstance(value, (list, tuple)):
                raise bad
            if not value:
                # a ROS 2 parameter cannot hold an empty list: it has no type, and the node
                # that declares it fails (ParameterUninitializedException)
                raise ConfigError(f'parameter {key!r}: [] is not allowed; expected '
                                  f'{self.allowed()} (a ROS 2 parameter cannot hold an empty '
                                  'list)')
            for v in value:
                if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                    raise ConfigError(f'parameter {key!r}: {list(value)!r} is not allowed: '
                                      f'{v!r} is not a positive integer; expected '
                                      f'{self.allowed()}')
            value = list(value)
        if self.choices is not None and value not in self.choices:
            raise bad
        if self.low is not None and (value < self.low or (value == self.low
                                                          and not self.low_inclusive)):
            raise bad
        if self.high is not None and value > self.high:
            raise bad
        if self.validate is not None:
            try:
                self.validate(value)
            except (ValueError, OSError) as exc:
                raise ConfigError(f'parameter {key!r}: {value!r} is not allowed: {exc}') from None
        return value


def _article(word: str) -> str:
    return 'an' if word[0] in 'aeiou' else 'a'


#: a float's limits when only values above 0 are allowed
POSITIVE = {'low': 0.0, 'low_inclusive': False}


def writable_file(path: str) -> None:
    """Refuse a file name whose directory does not exist (the file is written at the end)."""
    if path and not Path(path).expanduser().parent.is_dir():
        raise ValueError(f'no directory {str(Path(path).expanduser().parent)!r} to write it in')


def arm_indices(text: str) -> List[int]:
    """
    Return the arm indices in ``text`` (``'0, 3'``; empty: none); ValueError if not.

    >>> arm_indices('0, 3'), arm_indices('')
    ([0, 3], [])
    """
    try:
        arms = [int(a) for a in text.replace(',', ' ').split()]
    except ValueError:
        raise ValueError(f'{text!r} is not arm indices separated by commas') from None
    if any(a < 0 for a in arms):
        raise ValueError(f'{text!r}: an arm index is 0 or more')
    return arms
