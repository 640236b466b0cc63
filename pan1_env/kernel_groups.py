"""The sub-step kernel's arguments, declared once as named groups.

:func:`pan1_env.kernels.group_advance` takes, after its two size tuples (:func:`pan1_env.compiled.kernel_sizes`),
one tuple per group below, in the order of :data:`KERNEL_GROUPS`. Each group's fields are listed here and
nowhere else: the engine builds a group by name, :func:`plain` turns it into the plain tuple numba gets
(numba types a plain tuple of arrays in its C dispatcher, a named one through Python, about half a
microsecond a field), and the kernel names it again on entry (``ArmState(*state)``), so that no code
depends on a field's position. A group changes with ``_replace``.

No numba here: the engine and the kernels both import this module, and ``import pan1_env`` stays fast.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["ArmModel", "ArmState", "Stepped", "Command", "EndEffectorObstacles", "FilterSettings", "FILTER_OFF",
           "Stepping", "StepOutputs", "WholeArm", "KERNEL_GROUPS", "plain"]


class ArmModel(NamedTuple):
    """Each arm's constants (leading axis A, the arms of one kind in every copy): ``lam (A, n, n)``,
    ``lengths (A, n)``, ``base (A, 2)``, ``phi (A,)`` (:class:`pan1_env.dynamics.ArmBatch`), ``damping (A,)``
    (b of the first joint: a PAn−1 arm's, or a full arm's once it has lost its first actuator), and
    ``passive``, whether the first joint is passive (k = n − 1)."""
    lam: np.ndarray
    lengths: np.ndarray
    base: np.ndarray
    phi: np.ndarray
    damping: np.ndarray
    passive: bool


class ArmState(NamedTuple):
    """Each arm's state, advanced in place: ``q (A, n)``, ``v (A, k)`` the actuated velocities, ``momentum (A,)``
    a PAn−1 arm's passive momentum p₁ (docs/MODEL.md §7), and the tracker's memory: ``v_prev (A, k)`` the last
    v*, ``has_prev (A,)`` whether it is set."""
    q: np.ndarray
    v: np.ndarray
    momentum: np.ndarray
    v_prev: np.ndarray
    has_prev: np.ndarray


class Stepped(NamedTuple):
    """Which arms a call advances, and when: ``rows (R,)`` int64 distinct arm indices, ``window (A, 2)`` int64,
    the sub-steps ``window[i, 0] ≤ s < window[i, 1]`` in which arm i moves (a fault stops a full arm there
    and starts its passive twin)."""
    rows: np.ndarray
    window: np.ndarray


class Command(NamedTuple):
    """The held command: ``command (A, k)`` desired velocities, or torques with ``torque_mode``; ``filter_on``,
    whether the safety filter acts."""
    command: np.ndarray
    torque_mode: bool
    filter_on: bool


class EndEffectorObstacles(NamedTuple):
    """The obstacles the end-effector filter keeps each arm's end-effector from: ``centers (A, O, 2)``,
    ``radii (A, O)``, ``mask (A, O)``; empty (O = 0) with whole-arm safety, whose obstacles are capsules."""
    centers: np.ndarray
    radii: np.ndarray
    mask: np.ndarray


class FilterSettings(NamedTuple):
    """The filter's settings (:class:`pan1_env.safety.FilterParams` as the kernel takes them:
    :func:`pan1_env.compiled.kernel_filter`): κ, ε, the margin, ``distance`` (the distance barrier, else the
    squared one), λ ``decay`` of ε(h̃), ``by_rate`` (the whole-arm last resort's measure), ``lookahead`` (s),
    ``fault_margin``, and ``tau_max`` (N·m; inf: torque mode's filter is unbounded)."""
    kappa: float
    epsilon: float
    margin: float
    distance: bool
    decay: float
    by_rate: bool
    lookahead: float
    fault_margin: bool
    tau_max: float


#: the filter's settings with the filter off (``filter_on`` False): the kernel reads none of them
FILTER_OFF = FilterSettings(kappa=1.0, epsilon=1.0, margin=0.0, distance=False, decay=0.0, by_rate=False,
                            lookahead=0.0, fault_margin=False, tau_max=float("inf"))


class Stepping(NamedTuple):
    """How a call steps: ``ke`` the tracker's gain K_e, ``dt`` the physics sub-step (s), ``n_sub`` the number of
    sub-steps, ``v_max`` the actuated speed bound the filter keeps (inf: none)."""
    ke: float
    dt: float
    n_sub: int
    v_max: float


class StepOutputs(NamedTuple):
    """What a call writes per arm: ``v_star (A, k)`` and ``tau`` (``(A, k)``, or full ``(A, n)`` rows whose
    passive entry is left alone) of the last sub-step, ``qd (A, n)`` the joint velocities and ``p (A, 2)`` the
    end-effector at the final state; running over calls: ``min_clear (A,)`` the smallest clearance,
    ``min_h (A,)`` the smallest filtered barrier, ``qp_counts (A, 3)`` the QP statuses' sub-steps,
    ``max_track (A,)`` the largest tracking error, ``finite (A,)`` whether the state stayed finite."""
    v_star: np.ndarray
    tau: np.ndarray
    qd: np.ndarray
    p: np.ndarray
    min_clear: np.ndarray
    min_h: np.ndarray
    qp_counts: np.ndarray
    max_track: np.ndarray
    finite: np.ndarray


class WholeArm(NamedTuple):
    """Whole-arm safety (:mod:`pan1_env.kernels.capsules`), None for the paper's end-effector filter:
    ``caps (A, C, CAPSULE_COLUMNS)`` each arm's capsules, ``start_time (A,)`` the call's first sub-step's time,
    ``link_radius``, ``link_bodies`` (every link, else the end-effector only), ``sensing`` (m, the rows'
    range), ``gate`` (the smooth activation's width past it; 0: a hard range), ``skin``, ``joints (A, L + 1, 2)``
    (out), ``n_world`` (the world obstacles among the capsules), ``angles (A, 2, n)`` (the link angles' cosines
    and sines: out, and in with ``carried``), ``carried`` and ``finish`` (whether the call computes the joint
    velocities and end-effectors)."""
    caps: np.ndarray
    start_time: np.ndarray
    link_radius: float
    link_bodies: bool
    sensing: float
    gate: float
    skin: float
    joints: np.ndarray
    n_world: int
    angles: np.ndarray
    carried: bool
    finish: bool


#: the kernel's groups after its size tuples, in its order; ``whole`` is a :class:`WholeArm` or None
KERNEL_GROUPS = (ArmModel, ArmState, Stepped, Command, EndEffectorObstacles, FilterSettings, Stepping, StepOutputs)


def plain(group: tuple | None) -> tuple | None:
    """A named group as the plain tuple the kernel takes (None stays None)."""
    return None if group is None else tuple(group)
