"""Checks of numbers at the package's boundaries, with one clear message each.

Every constructor argument, option and wrapper parameter goes through these, so a bad value gets
a ``ValueError`` naming the argument and the value instead of a failure deep inside numpy. numpy
scalars are accepted; booleans and strings are not numbers.
"""

from __future__ import annotations

import difflib
import functools
import importlib
import inspect
import math
import types
from collections.abc import Callable, Iterable
from numbers import Integral, Real
from typing import Any, ParamSpec, TypeVar

import numpy as np

__all__ = ["real", "positive_int", "whole_ratio", "float_array", "hints_unknown_keywords", "forwards_keywords",
           "forwarded_signature", "refuse_unknown", "UnknownArgumentError"]

_P = ParamSpec("_P")
_R = TypeVar("_R")
_F = TypeVar("_F", bound=Callable[..., Any])


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


# ------------------------------------------------------------------ constructor keywords
class UnknownArgumentError(TypeError, ValueError):
    """An unknown keyword: a ``TypeError`` as Python's own, and a ``ValueError`` so that the CLI, which reports bad
    input (``ValueError``) in one line, reports it too."""


def _refuse_unknown(owner: str, kwargs: Iterable[str], known: Iterable[str], listed: list[str]) -> None:
    """TypeError for the first keyword not in ``known``, with difflib's closest match ("did you mean")."""
    known = set(known)
    for key in kwargs:
        if key not in known:
            hint = difflib.get_close_matches(key, listed, n=1)
            raise UnknownArgumentError(f"{owner} got an unknown argument {key!r}"
                            + (f"; did you mean {hint[0]!r}?" if hint else "")
                            + f" Arguments: {', '.join(listed)}")


def refuse_unknown(owner: str, keys: Iterable[str], known: Iterable[str], *,
                   error: type[Exception] = ValueError) -> None:
    """``error`` for the first of ``keys`` (options of a dict, keywords) not in ``known``, naming the
    closest known one ("did you mean") and listing them all."""
    listed = list(known)
    if error is TypeError:
        _refuse_unknown(owner, keys, listed, listed)
        return
    for key in keys:
        if key not in listed:
            hint = difflib.get_close_matches(str(key), listed, n=1)
            raise error(f"{owner}: unknown option {key!r}" + (f"; did you mean {hint[0]!r}?" if hint else ".")
                        + f" Options: {', '.join(sorted(listed))}")


def _names(sig: inspect.Signature) -> list[str]:
    return [p.name for p in sig.parameters.values()
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.name != "self"]


def hints_unknown_keywords(init: Callable[_P, _R]) -> Callable[_P, _R]:
    """Decorator for a constructor with explicit arguments: an unknown keyword raises ``TypeError``
    naming the closest argument ("did you mean 'control_dt'?") instead of Python's bare message.
    The signature seen by ``inspect.signature`` and ``help()`` is the constructor's own."""
    names = _names(inspect.signature(init))
    owner = init.__qualname__.split(".")[0]

    @functools.wraps(init)
    def checked(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        _refuse_unknown(owner, kwargs, names, names)
        return init(*args, **kwargs)

    return checked


def forwarded_signature(func: Callable[..., Any], target: Any, exclude: Iterable[str] = ()) -> inspect.Signature:
    """``func``'s signature with its ``**kwargs`` replaced by ``target``'s keyword-only arguments
    (a class: its constructor's) less ``exclude`` and those ``func`` names itself."""
    own = inspect.signature(func)
    params = [p for p in own.parameters.values() if p.kind is not p.VAR_KEYWORD]
    taken = {p.name for p in params} | set(exclude)
    theirs = inspect.signature(target.__init__ if isinstance(target, type) else target)
    params += [p for p in theirs.parameters.values() if p.kind is p.KEYWORD_ONLY and p.name not in taken]
    return own.replace(parameters=params)


class _Forwarding:
    """A constructor that passes ``**kwargs`` on to ``target``; see :func:`forwards_keywords`."""

    def __init__(self, func: Callable[..., Any], target: str, exclude: tuple[str, ...]) -> None:
        functools.update_wrapper(self, func)
        self._func, self._target, self._exclude = func, target, exclude
        self._owner: type | None = None
        self._signature: inspect.Signature | None = None  # worked out on first use: the target is imported then

    def __set_name__(self, owner: type, name: str) -> None:
        self._owner = owner

    def __reduce__(self) -> tuple[Any, tuple[Any, ...]]:
        return getattr, (self._owner, self._func.__name__)  # pickled by reference, like a plain function

    @property
    def __signature__(self) -> inspect.Signature:
        if self._signature is None:
            module, _, name = self._target.partition(":")
            target = getattr(importlib.import_module(module), name)
            self._signature = forwarded_signature(self._func, target, self._exclude)
        return self._signature

    def __get__(self, instance: Any, owner: type | None = None) -> Any:
        return self if instance is None else types.MethodType(self, instance)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        names = _names(self.__signature__)
        _refuse_unknown(self.__qualname__.split(".")[0], kwargs, [*names, *self._exclude], names)
        return self._func(*args, **kwargs)


def forwards_keywords(target: str, *, exclude: Iterable[str] = ()) -> Callable[[_F], _F]:
    """Decorator for a constructor ``f(self, ..., **kwargs)`` that passes ``kwargs`` on to ``target``
    (``"module:Class"``, imported on first use so that importing the decorated module stays light).

    ``inspect.signature``, ``help()`` and notebooks then show ``f``'s own arguments followed by the
    target's keyword-only ones less ``exclude`` (which ``f`` refuses itself): the list of arguments
    and their defaults is kept once, in the target's signature. An unknown keyword raises
    ``TypeError`` with a "did you mean" hint naming ``f``'s class.
    """
    return lambda func: _Forwarding(func, target, tuple(exclude))  # type: ignore[return-value]
