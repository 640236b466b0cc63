"""The compiled kernels (:mod:`pan1_env.kernels`), loaded on first use, the size tuple they take, and
the named groups of the sub-step kernel's inputs.

Importing :mod:`pan1_env.kernels` imports numba (about half a second), so the modules that
``import pan1_env`` reaches get it through :func:`kernels` when they first step, not at import time.
A module-level reference, not an attribute on an env, so envs stay picklable.

The sub-step kernel (:func:`pan1_env.kernels.group_advance`) takes its arrays in named groups:
:class:`Physics`, :class:`State`, :class:`Control`, :class:`Shield`, :class:`Record` and, for
whole-arm safety, :class:`WholeArm`. The caller builds each by name (and changes a field with
``_replace``) and hands it over as a plain tuple (:func:`plain`): numba types a plain tuple of
arrays in its C dispatcher, a named one through Python (about half a microsecond a field, which a
one-arm step would feel), and the kernel names each group again on entry. Defined here, at module
level, so that numba's disk cache can refer to them and the engine can build them without numba.
"""

from __future__ import annotations

from collections import namedtuple
from types import ModuleType

__all__ = ["kernels", "kernel_sizes", "plain", "Physics", "State", "Control", "Shield", "Record", "WholeArm"]

#: the arms' parameters (rows of :class:`pan1_env.dynamics.ArmBatch`): ``lam (A, n, n)``, ``lengths (A, n)``,
#: ``base (A, 2)``, ``phi (A,)``, and ``passive`` (a passive first joint: must agree with k < n)
Physics = namedtuple("Physics", "lam lengths base phi passive")
#: the state, updated in place: ``q (A, n)``, ``v (A, k)``, and the tracker's previous v* ``v_prev (A, k)``
#: with ``has_prev (A,)`` saying whether there is one
State = namedtuple("State", "q v v_prev has_prev")
#: what a call does: ``command (A, k)`` (velocities, or torques with ``torque_mode``), the tracker gain
#: ``ke``, the sub-step ``dt`` and the number of sub-steps ``n_sub``
Control = namedtuple("Control", "command torque_mode ke dt n_sub")
#: the safety filter: ``on``, the end-effector obstacles each arm's filter sees (``centers (A, O, 2)``,
#: ``radii (A, O)``, ``mask (A, O)``), the RCBF's ``kappa``, ``epsilon``, ``margin``, and the speed bound
#: ``v_max`` of its QP
Shield = namedtuple("Shield", "on centers radii mask kappa epsilon margin v_max")
#: the outputs, per arm: ``v_star (A, k)``, ``tau`` (``(A, k)`` or ``(A, n)``), ``qd (A, n)``, ``p (A, 2)``,
#: running ``min_clear``, ``min_h``, ``qp_counts (A, 3)``, ``max_track``, and ``finite``
Record = namedtuple("Record", "v_star tau qd p min_clear min_h qp_counts max_track finite")
#: whole-arm safety (:mod:`pan1_env.kernels.capsules`): ``caps (A, C, CAPSULE_COLUMNS)``, ``start_time (A,)``,
#: ``link_radius``, ``link_bodies``, ``sensing``, ``skin``, ``joints (A, L + 1, 2)`` (out), ``n_world`` (the
#: world obstacles among the capsules), ``angles (A, 2, n)`` (in with ``carried``, out), ``carried``, ``finish``
WholeArm = namedtuple("WholeArm", "caps start_time link_radius link_bodies sensing skin joints n_world angles carried "
                                  "finish")

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


def plain(group: tuple | None) -> tuple | None:
    """A named group as the plain tuple the kernel takes (None stays None)."""
    return None if group is None else tuple(group)
