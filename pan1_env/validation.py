"""Checks of numbers at the package's boundaries, with one clear message each.

Every constructor argument, option and wrapper parameter goes through these, so a bad value gets
a ``ValueError`` naming the argument and the value instead of a failure deep inside numpy. numpy
scalars are accepted; booleans and strings are not numbers.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numpy as np

__all__ = ["real", "positive_int", "whole_ratio", "float_array"]


def real(name: str, value: Any, *, positive: bool = False, non_negative: bool = False,
         allow_inf: bool = False) -> float:
    """``value`` as a float, checked to be a finite (or, with ``allow_inf``, infinite) real number."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name} must be a number, got {value!r}")
    out = float(value)
    if math.isnan(out) or (math.isinf(out) and not allow_inf):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if positive and not out > 0:
        raise ValueError(f"{name} must be positive, got {value!r}")
    if non_negative and not out >= 0:
        raise ValueError(f"{name} must be non-negative, got {value!r}")
    return out


def positive_int(name: str, value: Any, *, minimum: int = 1) -> int:
    """``value`` as an int ≥ ``minimum`` (whole numbers only; numpy integers accepted)."""
    if isinstance(value, bool) or not isinstance(value, Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer ≥ {minimum}, got {value!r}")
    return int(value)


def whole_ratio(name: str, big: float, small_name: str, small: float) -> int:
    """``big / small`` as a whole number ≥ 1 (e.g. physics sub-steps per control step)."""
    ratio = big / small
    if not math.isfinite(ratio) or ratio > 1e6:
        raise ValueError(f"{name}={big} / {small_name}={small} = {ratio:.3g} sub-steps is too many (at most 1e6)")
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
        raise ValueError(f"{name}={big} must be a whole multiple of {small_name}={small}")
    return int(round(ratio))


def float_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float array of ``shape`` (e.g. an action), or a ``ValueError`` naming ``name``,
    the expected shape and what was received (a dict, a string, a ragged list, … or the wrong shape).

    Only the conversion and the shape are checked; NaN and inf pass (the callers report them).
    """
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        text = repr(value)
        if len(text) > 80:
            text = text[:77] + "..."
        raise ValueError(f"{name} must be an array of numbers of shape {shape}, got {type(value).__name__} "
                         f"{text}") from None
    if out.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {out.shape}")
    return out
