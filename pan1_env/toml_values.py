"""Reading a scenario file's values: numbers, angles, vectors and tables, each checked where it is read, and the
filter's settings of the ``[safety]`` table (:mod:`pan1_env.scenario`). Every problem is a :class:`ScenarioError`
naming the file, the key and what is wrong."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from .safety import BARRIERS, FALLBACKS

__all__ = ["ScenarioError", "MAX_MAGNITUDE", "FILTER_KEYS", "as_float", "as_angle", "number", "vector", "table",
           "known_keys", "filter_settings"]

MAX_MAGNITUDE = 1e9  # every number in a scenario file must satisfy |x| ≤ MAX_MAGNITUDE
#: the ``[safety]`` keys of the filter's choices (:func:`filter_settings`)
FILTER_KEYS = ("barrier", "decay", "gate", "fallback", "lookahead", "fault_margin")

_ANGLE = re.compile(
    r"^\s*(?P<sign>[+-])?\s*(?P<num>\d+(?:\.\d*)?|\.\d+)?\s*\*?\s*(?P<pi>pi|π)?"
    r"\s*(?:/\s*(?P<den>\d+(?:\.\d*)?))?\s*$"
)


class ScenarioError(ValueError):
    """An invalid scenario: the message names the source, the key and the problem."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source, self.key, self.problem = source, key, problem
        super().__init__(f"{source}: {key}: {problem}")


def as_float(value: int | float, src: str, key: str) -> float:
    """A TOML number as a float within ±MAX_MAGNITUDE (TOML integers can be arbitrarily large)."""
    if isinstance(value, int) and abs(value) > MAX_MAGNITUDE:
        raise ScenarioError(src, key, f"an integer of {len(str(abs(value)))} digits is out of range: numbers "
                            f"must lie within ±{MAX_MAGNITUDE:g}")
    out = float(value)
    if math.isfinite(out) and abs(out) > MAX_MAGNITUDE:
        raise ScenarioError(src, key, f"{out:g} is out of range: numbers must lie within ±{MAX_MAGNITUDE:g}")
    return out


def as_angle(value: Any, src: str, key: str) -> float:
    if isinstance(value, bool):
        raise ScenarioError(src, key, f"expected an angle, got {value!r}")
    if isinstance(value, (int, float)):
        out = as_float(value, src, key)
    elif isinstance(value, str):
        m = _ANGLE.match(value)
        if not m or not (m.group("num") or m.group("pi")):
            raise ScenarioError(src, key, f"cannot read angle {value!r}; write e.g. 0.5 or '-3*pi/4'")
        out = as_float(float(m.group("num") or 1.0), src, key) * (math.pi if m.group("pi") else 1.0)
        if m.group("den"):
            den = as_float(float(m.group("den")), src, key)
            if den == 0:
                raise ScenarioError(src, key, f"division by zero in angle {value!r}")
            out /= den
        if m.group("sign") == "-":
            out = -out
    else:
        raise ScenarioError(src, key, f"expected an angle (number or string like 'pi/3'), got {value!r}")
    if not math.isfinite(out):
        raise ScenarioError(src, key, f"angle must be finite, got {value!r}")
    return out


def number(table: Mapping[str, Any], key: str, src: str, prefix: str, *, positive: bool = True,
            default: float | None = None, infinite: bool = False) -> float:
    full = f"{prefix}.{key}"
    if key not in table:
        if default is None:
            raise ScenarioError(src, full, "missing")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(src, full, f"expected a number, got {value!r}")
    value = as_float(value, src, full)
    if not math.isfinite(value) and not (infinite and value == math.inf):
        raise ScenarioError(src, full, f"must be {'a number or inf' if infinite else 'finite'}, got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(src, full, f"must be positive, got {value!r}")
    if not positive and value < 0:
        raise ScenarioError(src, full, f"must be non-negative, got {value!r}")
    return value


def vector(value: Any, src: str, key: str, size: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ScenarioError(src, key, f"expected a non-empty list of numbers, got {value!r}")
    if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in value):
        raise ScenarioError(src, key, f"expected a list of numbers, got {value!r}")
    arr = np.array([as_float(x, src, key) for x in value], dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(src, key, f"values must be finite, got {value!r}")
    if size is not None and arr.size != size:
        raise ScenarioError(src, key, f"expected {size} numbers, got {arr.size}")
    return arr


def table(data: Mapping[str, Any], key: str, src: str, allowed: set[str],
           required: bool = True) -> dict[str, Any]:
    if key not in data:
        if required:
            raise ScenarioError(src, key, "missing table")
        return {}
    return known_keys(data[key], key, src, allowed)


def known_keys(table: Any, key: str, src: str, allowed: set[str]) -> dict[str, Any]:
    """``table`` checked to be a TOML table whose keys are all in ``allowed``."""
    if not isinstance(table, dict):
        raise ScenarioError(src, key, f"expected a table, got {type(table).__name__}")
    unknown = set(table) - allowed
    if unknown:
        raise ScenarioError(src, f"{key}.{sorted(unknown)[0]}", f"unknown key; allowed keys are {sorted(allowed)}")
    return table


def filter_settings(saf: Mapping[str, Any], src: str) -> dict[str, Any]:
    """The filter's choices in the ``[safety]`` table ``saf`` (:data:`FILTER_KEYS`), as the keyword arguments
    ``barrier``, ``decay``, ``gate``, ``fallback``, ``lookahead`` and ``fault_margin`` of
    :class:`pan1_env.safety.FilterParams` (a scenario's ``filter``)."""
    barrier = saf.get("barrier", "squared")
    if barrier not in BARRIERS:
        raise ScenarioError(src, "safety.barrier", f"unknown barrier {barrier!r}; allowed values are "
                            + ", ".join(f'"{b}"' for b in BARRIERS))
    fallback = saf.get("fallback", "command")
    if fallback not in FALLBACKS:
        raise ScenarioError(src, "safety.fallback", f"unknown fallback {fallback!r}; allowed values are "
                            + ", ".join(f'"{f}"' for f in FALLBACKS))
    fault_margin = saf.get("fault_margin", False)
    if not isinstance(fault_margin, bool):
        raise ScenarioError(src, "safety.fault_margin", f"expected true or false, got {fault_margin!r}")
    return {"barrier": barrier,
            "decay": number(saf, "decay", src, "safety", positive=False, default=0.0),
            "gate": number(saf, "gate", src, "safety", positive=False, default=0.0),
            "fallback": fallback,
            "lookahead": number(saf, "lookahead", src, "safety", positive=False, default=0.0, infinite=True),
            "fault_margin": fault_margin}
