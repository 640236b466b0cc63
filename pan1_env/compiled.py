"""The compiled kernels (:mod:`pan1_env.kernels`), loaded on first use, and the size tuple they take.

Importing :mod:`pan1_env.kernels` imports numba (about half a second), so the modules that
``import pan1_env`` reaches get it through :func:`kernels` when they first step, not at import time.
A module-level reference, not an attribute on an env, so envs stay picklable.
"""

from __future__ import annotations

from types import ModuleType

__all__ = ["kernels", "kernel_sizes"]

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
