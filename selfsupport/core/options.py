"""Allowed ranges of method settings, written as intervals next to the settings themselves.

A dataclass field carries ``metadata={"range": "(0, 1)"}`` (open/closed ends as in
mathematics, ``inf`` for no bound); :func:`check_range` refuses a value outside it with one
line that names the setting, the value and the interval::

    >>> check_range("shrink", 0.5, "(0, 1)")
    >>> check_range("shrink", 2.0, "(0, 1)")
    Traceback (most recent call last):
    ...
    selfsupport.core.errors.InputError: option shrink=2 is out of range: it must lie in (0, 1)
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

from selfsupport.core.errors import InputError

__all__ = ["parse_interval", "in_interval", "check_range", "check_options"]


def parse_interval(spec: str) -> tuple[float, float, bool, bool]:
    """``"(0, 1]"`` -> ``(lo, hi, lo_closed, hi_closed)``."""
    s = spec.strip()
    if len(s) < 5 or s[0] not in "([" or s[-1] not in ")]" or "," not in s:
        raise ValueError(f"bad interval {spec!r}; write e.g. '(0, 1)' or '[1, inf)'")
    lo, hi = (float(t) for t in s[1:-1].split(","))
    return lo, hi, s[0] == "[", s[-1] == "]"


def in_interval(value: float, spec: str) -> bool:
    """Whether ``value`` lies in the interval ``spec`` (NaN lies in none).

    >>> in_interval(1.0, "(0, 1]"), in_interval(0.0, "(0, 1]"), in_interval(float("nan"), "(-inf, inf)")
    (True, False, False)
    """
    lo, hi, lo_c, hi_c = parse_interval(spec)
    return (value >= lo if lo_c else value > lo) and (value <= hi if hi_c else value < hi)


def check_range(name: str, value: Any, spec: str | None) -> None:
    """Raise :class:`InputError` when ``value`` is not finite or lies outside the interval ``spec``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if math.isnan(value) or (spec is None and math.isinf(value)):
        raise InputError(f"option {name}={value!r} is not a finite number; give a finite value")
    if spec is None:
        return  # (an infinity passes only an interval closed at inf, e.g. "[0, inf]")
    if not in_interval(value, spec):
        raise InputError(f"option {name}={value:g} is out of range: it must lie in {spec}")


def check_options(cls: type, options: Mapping[str, Any]) -> None:
    """:func:`check_range` of every ``options`` item against ``cls``'s field metadata ``"range"``
    (unknown names are left to the method, which lists the known ones)."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for name, value in options.items():
        if name in fields:
            check_range(name, value, fields[name].metadata.get("range"))
