"""Checks of scalar settings (a config field, an option value): each returns the value or raises one
ValueError naming the setting and what was expected ("levels: expected an integer >= 1, got 0").

Used by the configurations' `__post_init__` across research/ (tracking, flow, radiometry).
"""

from __future__ import annotations

import math

import numpy as np


def _is_number(value) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))


def integer(name: str, value, low: int = 0) -> int:
    """An integer >= low (a bool or a float such as 1.0 is refused)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
    return int(value)


def number(name: str, value, low: float = -math.inf, high: float = math.inf, *, low_open: bool = False) -> float:
    """A finite number in [low, high] (or (low, high] with low_open)."""
    ok = _is_number(value) and math.isfinite(float(value))
    if ok:
        v = float(value)
        ok = (v > low if low_open else v >= low) and v <= high
    if not ok:
        lo = "(" if low_open else "["
        if math.isinf(high):
            want = f"a finite number {'>' if low_open else '>='} {low:g}"
        else:
            want = f"a finite number in {lo}{low:g}, {high:g}]"
        raise ValueError(f"{name}: expected {want}, got {value!r}")
    return float(value)


def probability(name: str, value) -> float:
    """A finite number in [0, 1] (a score, an IoU or a 1 - IoU threshold, a fraction)."""
    return number(name, value, 0.0, 1.0)


def flag(name: str, value) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected True or False, got {value!r}")
    return bool(value)
