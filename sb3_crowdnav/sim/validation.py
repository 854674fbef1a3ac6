"""The checks of user input, one rule for the whole package.

``TypeError`` when a value has the wrong type (a ``str`` where a number is expected, a ``bool`` where
an int is expected, a list where a bool is expected); ``ValueError`` when it has the right type but
a wrong value (out of range, not finite, not one of the choices). Every message names the parameter
and says what is allowed, so that a caller can pass the text on to the user unchanged.

The module lives on the ground floor (``sim``, NumPy only) so that every floor above can use it.
NumPy scalars are accepted like Python's: values often come out of arrays or YAML files.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from numbers import Integral, Real
from typing import Any

import numpy as np

__all__ = [
    "check_at_most",
    "check_bool",
    "check_choice",
    "check_instance",
    "check_int",
    "check_number",
    "check_positive",
    "check_probability",
    "check_range",
    "check_share",
]


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def check_bool(name: str, value: Any) -> None:
    """``TypeError`` unless ``value`` is a bool (``0``/``1`` and ``"yes"`` are not: they are easy slips)."""
    if not _is_bool(value):
        raise TypeError(f"{name} must be a bool, got {value!r} ({type(value).__name__})")


def check_int(name: str, value: Any, minimum: int | None = None, maximum: int | None = None) -> None:
    """``TypeError`` unless ``value`` is an int (not a bool); ``ValueError`` outside ``[minimum, maximum]``."""
    if _is_bool(value) or not isinstance(value, Integral):
        raise TypeError(f"{name} must be an int, got {value!r} ({type(value).__name__})")
    if minimum is not None and value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be <= {maximum}, got {value!r}")


def _check_real(name: str, value: Any) -> None:
    # ``type(value) is float`` first: the common case skips the slower ABC check
    if type(value) is not float and (_is_bool(value) or not isinstance(value, Real)):
        raise TypeError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")


def check_number(name: str, value: Any, *, positive: bool = True, allow_zero: bool = False) -> None:
    """``TypeError`` unless ``value`` is a real number (not a bool); ``ValueError`` unless finite (and > 0, or >= 0)."""
    _check_real(name, value)
    if positive and (value < 0 or (value == 0 and not allow_zero)):
        allowed = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be {allowed}, got {value!r}")


def check_positive(name: str, value: Any, unit: str = "") -> None:
    """``TypeError`` unless ``value`` is a real number; ``ValueError`` unless finite and > 0 (``unit``: e.g. ``" [m]"``)."""
    _check_real(name, value)
    if not value > 0:
        raise ValueError(f"{name} must be > 0{unit}, got {value!r}")


def check_range(name: str, value: Any, low: float, high: float, *, low_open: bool = False,
                high_open: bool = False) -> None:
    """``TypeError`` unless ``value`` is a real number; ``ValueError`` outside the interval from ``low`` to ``high``.

    ``low_open`` / ``high_open`` exclude the end: ``check_range("gamma", g, 0, 1, low_open=True)`` is (0, 1].
    """
    _check_real(name, value)
    above = value > low if low_open else value >= low
    below = value < high if high_open else value <= high
    if not (above and below):
        interval = f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
        raise ValueError(f"{name} must be in {interval}, got {value!r}")


def check_probability(name: str, value: Any) -> None:
    """``TypeError`` unless ``value`` is a real number; ``ValueError`` outside [0, 1]."""
    check_range(name, value, 0, 1)


def check_share(name: str, value: Any) -> None:
    """``TypeError`` unless ``value`` is a bool or a float (not an int: ``1`` is a slip); ``ValueError`` for a float
    outside [0, 1]. An option that is all-or-none or a share (``robot_visible=0.5``)."""
    if _is_bool(value):
        return
    if not isinstance(value, (float, np.floating)):
        raise TypeError(f"{name} must be a bool or a float share in [0, 1], got {value!r} ({type(value).__name__})")
    check_range(name, value, 0, 1)


def check_at_most(name: str, value: Any, limit: float, unit: str = "") -> None:
    """``ValueError`` when ``value`` exceeds its sensible upper ``limit`` (the bounds table of the docs)."""
    if value > limit:
        raise ValueError(f"{name} must be <= {limit}{unit}, got {value!r}")


def check_at_least(name: str, value: Any, limit: float, unit: str = "") -> None:
    """``ValueError`` when ``value`` is below its sensible lower ``limit`` (e.g. a length whose square divides)."""
    if value < limit:
        raise ValueError(f"{name} must be >= {limit}{unit}, got {value!r}")


def check_choice(name: str, value: Any, choices: Collection[Any]) -> None:
    """``ValueError`` naming the allowed ``choices`` when ``value`` is not one of them.

    A value of another type is also a wrong value here (``reward=3`` is not one of the reward names):
    the message listing the choices is the useful one.
    """
    try:
        known = value in choices
    except TypeError:  # an unhashable value against a set
        known = False
    if not known:
        raise ValueError(f"{name} must be one of {tuple(choices)}, got {value!r}")


def check_instance(name: str, value: Any, types: type | tuple[type, ...], allowed: str) -> None:
    """``TypeError`` naming ``allowed`` (e.g. ``"a WarehouseLayout or None"``) unless ``value`` is one of ``types``."""
    if not isinstance(value, types):
        raise TypeError(f"{name} must be {allowed}, got {type(value).__name__}")
