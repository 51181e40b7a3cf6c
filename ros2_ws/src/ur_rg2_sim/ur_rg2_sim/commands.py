"""Validation of joint commands and parameter values. Plain Python, no ROS."""

from collections import Counter
from collections.abc import Iterable, Sequence
import math


class CommandError(ValueError):
    """A command or parameter value is rejected; the message says why."""


def joint_targets(names: Sequence[str], positions: Sequence[float],
                  known: Iterable[str]) -> dict[str, float]:
    """Return ``{name: position}`` for a JointState-like command, or raise CommandError.

    The whole command is rejected if any part is malformed, so that a bad message never
    moves some joints and not others.
    """
    known = tuple(known)
    if not names:
        raise CommandError('no joint names')
    if len(names) != len(positions):
        raise CommandError(f'{len(names)} joint names but {len(positions)} positions')
    unknown = [name for name in names if name not in known]
    if unknown:
        raise CommandError(
            f"unknown joint {', '.join(map(repr, unknown))} (arm joints: {', '.join(known)})")
    # Counted once (a message of 100,000 names made a count per name take minutes).
    repeated = sorted(name for name, count in Counter(names).items() if count > 1)
    if repeated:
        raise CommandError(f"joint {', '.join(map(repr, repeated))} given more than once")
    for name, position in zip(names, positions):
        if not math.isfinite(position):
            raise CommandError(f'{name} position is {position}, not a finite number')
    return {name: float(position) for name, position in zip(names, positions)}


def finite_vector(name: str, value: Sequence[float], length: int) -> tuple[float, ...]:
    """Return ``value`` as a tuple if it has ``length`` finite numbers, else raise."""
    if len(value) != length:
        raise CommandError(f'{name} needs {length} numbers, got {len(value)}')
    if not all(math.isfinite(v) for v in value):
        raise CommandError(f'{name} must be finite numbers, got {list(value)}')
    return tuple(float(v) for v in value)


def in_range(name: str, value: float, low: float, high: float) -> float:
    """Return ``value`` if ``low <= value <= high`` (and finite), else raise CommandError."""
    if not (math.isfinite(value) and low <= value <= high):
        raise CommandError(f'{name} must be between {low:g} and {high:g}, got {value}')
    return value
