"""Argument types the commands share: a usage error (exit 2) names what was expected."""
import argparse
import math


def positive_int(text: str) -> int:
    """Return ``text`` as an integer >= 1, or raise argparse's type error."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be >= 1, got {value}')
    return value


def positive_float(text: str) -> float:
    """Return ``text`` as a finite number > 0, or raise argparse's type error."""
    value = float(text)
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be > 0, got {text}')
    return value


def non_negative_float(text: str) -> float:
    """Return ``text`` as a finite number >= 0, or raise argparse's type error."""
    value = float(text)
    if not value >= 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def run_id_arg(text: str) -> str:
    """Return ``text`` if it can name a run (:mod:`pg_node.common.run`), else a type error."""
    from pg_node.common.run import check_run_id
    try:
        return check_run_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f'{text!r}: {exc}') from None
