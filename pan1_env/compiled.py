"""The compiled kernels (:mod:`pan1_env.kernels`), loaded on first use, and the size tuples and filter
settings the sub-step kernel takes (its argument groups: :mod:`pan1_env.kernel_groups`).

Importing :mod:`pan1_env.kernels` imports numba (about half a second), so the modules that
``import pan1_env`` reaches get it through :func:`kernels` when they first step, not at import time.
A module-level reference, not an attribute on an env, so envs stay picklable.
"""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

from .kernel_groups import FilterSettings

if TYPE_CHECKING:
    from .safety import FilterParams

__all__ = ["kernels", "kernel_sizes", "kernel_filter"]

_KERNELS: ModuleType | None = None


def kernels() -> ModuleType:
    """The :mod:`pan1_env.kernels` module (imported on the first call)."""
    global _KERNELS
    if _KERNELS is None:
        from . import kernels as module

        _KERNELS = module
    return _KERNELS


def kernel_sizes(n: int, k: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The first two arguments of :func:`pan1_env.kernels.group_advance` for arms of ``n`` links and
    ``k`` actuated joints: ``(0,) * n, (0,) * k``. Numba types a tuple by its length, so these hand
    the kernel n and k as compile-time constants."""
    return (0,) * n, (0,) * k


def kernel_filter(params: FilterParams, max_torque: float = float("inf")) -> FilterSettings:
    """The filter's settings as the sub-step kernel takes them, its ``rcbf`` group, with the actuated joints'
    torque bound (N·m) that the torque-mode filter keeps (the engine's ``max_torque``; inf: none)."""
    return FilterSettings(kappa=params.kappa, epsilon=params.epsilon, margin=params.margin,
                          distance=params.barrier == "distance", decay=params.decay, by_rate=params.by_rate,
                          lookahead=params.lookahead, fault_margin=params.fault_margin, tau_max=float(max_torque))
