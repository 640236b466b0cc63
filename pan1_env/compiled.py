"""The compiled kernels (:mod:`pan1_env.kernels`), loaded on first use, the size tuple they take, and
the named whole-arm argument of the sub-step kernel.

Importing :mod:`pan1_env.kernels` imports numba (about half a second), so the modules that
``import pan1_env`` reaches get it through :func:`kernels` when they first step, not at import time.
A module-level reference, not an attribute on an env, so envs stay picklable.

The sub-step kernel's whole-arm argument is built by name (:class:`WholeArm`, a field changed with
``_replace``) and handed over as a plain tuple (:func:`plain`): numba types a plain tuple of arrays in
its C dispatcher, a named one through Python (about half a microsecond a field).
"""

from __future__ import annotations

from collections import namedtuple
from types import ModuleType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .safety import FilterParams

__all__ = ["kernels", "kernel_sizes", "kernel_filter", "plain", "WholeArm"]

#: the sub-step kernel's ``whole`` argument for whole-arm safety (:mod:`pan1_env.kernels.capsules`), in its
#: order: ``caps (A, C, CAPSULE_COLUMNS)``, ``start_time (A,)``, ``link_radius``, ``link_bodies``, ``sensing``,
#: ``gate`` (the smooth activation's width past ``sensing``; 0: a hard range), ``skin``, ``joints (A, L + 1, 2)``
#: (out), ``n_world`` (the world obstacles among the capsules), ``angles (A, 2, n)`` (in with ``carried``, out),
#: ``carried``, ``finish``
WholeArm = namedtuple("WholeArm", "caps start_time link_radius link_bodies sensing gate skin joints n_world angles "
                                  "carried finish")

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


def kernel_filter(params: FilterParams, max_torque: float = float("inf")) -> tuple:
    """The filter's settings as the sub-step kernel takes them, its ``rcbf`` argument, in this order: κ, ε,
    the margin, the distance barrier (else the squared one), λ of ε(h̃), whether the whole-arm last
    resort measures violation by the barrier's rate (:attr:`pan1_env.safety.FilterParams.fallback`), how far
    ahead (s) they keep moving obstacles out (:attr:`~pan1_env.safety.FilterParams.lookahead`), whether they
    keep the fault margin (:attr:`~pan1_env.safety.FilterParams.fault_margin`), and the actuated joints' torque
    bound (N·m) that the torque-mode filter keeps (the engine's ``max_torque``; inf: none)."""
    return (params.kappa, params.epsilon, params.margin, params.barrier == "distance", params.decay, params.by_rate,
            params.lookahead, params.fault_margin, float(max_torque))


def plain(group: tuple | None) -> tuple | None:
    """A named argument as the plain tuple the kernel takes (None stays None)."""
    return None if group is None else tuple(group)
