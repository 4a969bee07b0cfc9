"""Argument checks shared by the zoo's constructors: a finite number in range, a whole number in range.

Standard library only, so that :mod:`floaff_zoo.sim` (no Lightning, no torch) may use it as the models and
DataModules do. Each caller passes the error type its own users catch (``DataConfigError``,
``MisconfigurationException``, ``ValueError``); the message names the argument (and its owner) and shows the value.

A bool is refused wherever a number is asked for: ``True`` is an int to Python, never a size or a weight here.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

__all__ = ["check_flag", "check_integer", "check_number", "check_numbers", "is_number", "shown"]


def is_number(value: object) -> bool:
    """Whether ``value`` is a real number (numpy's included) that is not a bool: None or a text fails the
    comparisons with a TypeError naming no argument."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def shown(value: object) -> str:
    """``value`` as a message shows it: a number as printed (``nan``, ``-1`` for numpy's scalars too), anything else
    as its repr (a text in quotes)."""
    return str(value) if is_number(value) else repr(value)


def _finite(value: numbers.Real) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an int too large for a float: every later float() of it fails
        return False


def _message(owner: str, name: str, what: str, none_means: str | None, note: str, value: object) -> str:
    alt = f" or null ({none_means})" if none_means is not None else ""
    extra = f" ({note})" if note else ""
    return f"{owner + ': ' if owner else ''}{name} must be {what}{alt}{extra}, got {shown(value)}"


def check_number(
    name: str,
    value: object,
    low: float = 0.0,
    high: float = math.inf,
    strict: bool = False,
    owner: str = "",
    error: type[Exception] = ValueError,
    none_means: str | None = None,
    note: str = "",
) -> None:
    """Refuse a ``value`` that is not a finite number in [low, high] ((low, high] when ``strict``).

    Args:
        name: the argument's name in the message (``data.max_yaw_deg``, ``crop_radius``).
        low, high: the bounds; an infinite one is not checked (nor written in the message).
        strict: ``value`` must exceed ``low`` (a size or a radius) rather than reach it (a weight).
        owner: who takes the argument (``CFARModule``), written first; "" for none.
        error: the exception type raised, called with the message.
        none_means: None is accepted, and the message says what it stands for.
        note: a word added after the bounds (``0 = no smoothing``).
    Raises:
        error: ``"{owner}: {name} must be a finite number > 0 (note), got {value}"``.
    """
    if value is None and none_means is not None:
        return
    if not (is_number(value) and _finite(value) and (value > low if strict else value >= low) and value <= high):
        bounds = [f"{'>' if strict else '>='} {low:g}"] * _finite(low) + [f"<= {high:g}"] * _finite(high)
        what = " ".join(["a finite number", " and ".join(bounds)]).rstrip()
        raise error(_message(owner, name, what, none_means, note, value))


def check_numbers(
    values: Mapping[str, object],
    low: float = 0.0,
    high: float = math.inf,
    strict: bool = False,
    owner: str = "",
    error: type[Exception] = ValueError,
) -> None:
    """:func:`check_number` on each of ``values`` ({name: value}), in order: the first one out of range is named."""
    for name, value in values.items():
        check_number(name, value, low, high, strict, owner, error)


def check_integer(
    name: str,
    value: object,
    minimum: int = 0,
    maximum: int | None = None,
    owner: str = "",
    error: type[Exception] = ValueError,
    none_means: str | None = None,
) -> None:
    """Refuse a ``value`` that is not an integer (Python's or numpy's, not a bool, not a float such as 2.0) in
    [minimum, maximum]; arguments as for :func:`check_number`.

    Raises:
        error: ``"{owner}: {name} must be an integer >= 1, got {value}"``.
    """
    if value is None and none_means is not None:
        return
    integer = isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if not (integer and minimum <= value and (maximum is None or value <= maximum)):
        what = f"an integer >= {minimum}" + (f" and <= {maximum}" if maximum is not None else "")
        raise error(_message(owner, name, what, none_means, "", value))


def is_flag(value: object) -> bool:
    """Whether ``value`` is a bool, Python's or numpy's (recognised by its type without importing numpy)."""
    kind = type(value)
    return isinstance(value, bool) or (kind.__module__ == "numpy" and kind.__name__ in ("bool_", "bool"))


def check_flag(name: str, value: object, owner: str = "", error: type[Exception] = ValueError) -> None:
    """Refuse a ``value`` that is not a bool: the text "false" from a hand-written config is true, 0 or 1 no flag;
    arguments as for :func:`check_number`.

    Raises:
        error: ``"{owner}: {name} must be true or false, got {value!r}"``.
    """
    if not is_flag(value):
        raise error(f"{owner + ': ' if owner else ''}{name} must be true or false, got {value!r}")
