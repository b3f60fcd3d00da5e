"""Ranges of the estimators' parameters and the checks that refuse values outside them.

The service's request models (``service/kinds.py``) mirror these ranges, so a job is refused
at submission with the same bounds the library applies to a direct call (CLI, scripts).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import fields
from typing import Any, Final, TypeVar

from .errors import InputError

MIN_FPS: Final[float] = 1.0
"""Lowest frame rate accepted, Hz (below it the slip and smoothing filters are meaningless)."""

MAX_FPS: Final[float] = 10_000.0
"""Highest frame rate accepted, Hz (above any motion-capture system's)."""

WEIGHT_MAX: Final[float] = 1e6
"""Largest ``w_s`` / ``w_l`` of ``estimate_skeleton`` (the defaults are 0.01)."""

CONTACT_OPTION_RANGES: Final[dict[str, tuple[float, float, bool]]] = {
    "smoothing_s": (0.0, 1.0, False),
    "sigma_acc": (0.0, 100.0, True),
    "relative_sigma_acc": (0.0, 10.0, False),
    "swing_weight": (0.0, 10.0, False),
    "residual_cap": (0.0, 1000.0, True),
    "swing_cost": (0.0, 1000.0, False),
    "flight_cost": (0.0, 1000.0, False),
    "switch_cost": (0.0, 1000.0, False),
    "sigma_relative_speed": (0.0, 10.0, True),
    "height_tolerance": (0.0, 1.0, False),
    "sigma_height": (0.0, 1.0, True),
    "floor_tolerance": (0.0, 1.0, False),
    "floor_ramp_s": (0.0, 10.0, False),
    "lever_arm_prior_m": (0.0, 1.0, False),
    "clip_g": (0.0, 1000.0, True),
}
"""Range ``(low, high, low excluded)`` of each numeric ``translation.ContactOptions`` field, in its
units; the service's ``ContactOptionsIn`` mirrors it."""

HACHAJ_WINDOW_RANGE: Final[tuple[int, int]] = (1, 10_000)
"""Accepted ``window`` of ``hachaj2018``, samples."""

HACHAJ_EPS_RANGE: Final[tuple[float, float]] = (0.0, 1.0)
"""Accepted ``eps`` of ``hachaj2018``, metres (above the low end, at most the high end)."""

Options = TypeVar("Options")


def options_of(method: str, table: Mapping[str, type[Options]],
               values: Mapping[str, Any]) -> Options:
    """The options of ``method`` from keyword values, checked by the options class.

    Parameters
    ----------
    method : str
        A key of ``table``.
    table : mapping of str to dataclass type
        Each method's frozen options dataclass (an estimator's ``METHOD_OPTIONS``).
    values : mapping of str to object
        Field values of ``table[method]``; missing fields take their defaults.

    Returns
    -------
    object
        ``table[method](**values)``.

    Raises
    ------
    InputError
        Unknown method (``field="method"``), an option the method does not take (``field``
        names the first, the message lists the method's options) or a value the class
        refuses.
    """
    if method not in table:
        raise InputError(f"unknown method {method!r}; use {', '.join(table)}", field="method")
    cls = table[method]
    names = sorted(f.name for f in fields(cls))  # type: ignore[arg-type]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InputError(f"unknown option(s) for {method}: {', '.join(unknown)}; "
                         f"options: {', '.join(names)}", field=unknown[0])
    return cls(**values)


def resolved_options(method: str, table: Mapping[str, type[Options]], options: Options | None,
                     values: Mapping[str, Any]) -> Options:
    """``options`` when given (then no keyword ``values``), else :func:`options_of`.

    Raises
    ------
    InputError
        Both an options object and keywords, an object of another method's class
        (``field="options"``), or what :func:`options_of` raises.
    """
    if options is None:
        return options_of(method, table, values)
    if values:
        raise InputError("give the method's options either as an options object or as "
                         f"keywords, not both (got {', '.join(sorted(values))} too)",
                         field=sorted(values)[0])
    if method not in table:
        raise InputError(f"unknown method {method!r}; use {', '.join(table)}", field="method")
    expected = table[method]
    if not isinstance(options, expected):
        raise InputError(f"options of {method} must be a {expected.__name__}, got "
                         f"{type(options).__name__}", field="options")
    return options


def check_fps(fps: float, field: str = "fps") -> float:
    """Refuse a frame rate outside ``[MIN_FPS, MAX_FPS]``.

    Parameters
    ----------
    fps : float
        Frame rate, Hz.
    field : str
        The parameter's name in the error.

    Returns
    -------
    float
        ``fps``.

    Raises
    ------
    InputError
        Not a finite number in range (e.g. ``5e-324``, which overflows the slip basis).
    """
    return check_number(fps, field, low=MIN_FPS, high=MAX_FPS, unit=" Hz")


def check_number(value: object, field: str, *, low: float | None = None,
                 high: float | None = None, low_open: bool = False, unit: str = "") -> float:
    """A finite real number within ``[low, high]`` (``(low, high]`` with ``low_open``).

    Parameters
    ----------
    value : object
        The caller's value; a bool or a string is refused.
    field : str
        The parameter's name in the error.
    low, high : float, optional
        Bounds; None: unbounded on that side.
    low_open : bool
        Exclude ``low`` itself (a strictly positive quantity: ``low=0, low_open=True``).
    unit : str
        Appended to the bounds in the message (e.g. ``" Hz"``).

    Returns
    -------
    float

    Raises
    ------
    InputError
        ``field`` names the parameter; the message says the range and the value got.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{field} must be a number, got {value!r}", field=field)
    number = float(value)
    below = low is not None and (number <= low if low_open else number < low)
    above = high is not None and number > high
    if not math.isfinite(number) or below or above:
        raise InputError(f"{field} must be a finite number {_range(low, high, low_open, unit)}"
                         f", got {value!r}", field=field)
    return number


def check_integer(value: object, field: str, *, low: int, high: int) -> int:
    """An integer within ``[low, high]``; a float with a fraction (2.5) or a bool is refused.

    Raises
    ------
    InputError
        ``field`` names the parameter; the message says the range and the value got.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise InputError(f"{field} must be an integer from {low} to {high}, got {value!r}",
                             field=field)
    number = int(value)
    if not low <= number <= high:
        raise InputError(f"{field} must be an integer from {low} to {high}, got {value!r}",
                         field=field)
    return number


def _range(low: float | None, high: float | None, low_open: bool, unit: str) -> str:
    parts = []
    if low is not None:
        parts.append(f"{'above' if low_open else 'of at least'} {low:g}{unit}")
    if high is not None:
        parts.append(f"at most {high:g}{unit}")
    return " and ".join(parts)
