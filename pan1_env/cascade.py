"""The cascaded (reduced-order) model of a PAn−1 arm and its integrators (docs/MODEL.md §2–3).

For a PAn−1 arm started from rest the passive momentum Σ_α M_1α q̇_α stays zero (Lemma 1), so
the passive velocity is a function of the active ones and the arm becomes the cascade

    q̇ = g0(q) v,                  g0 = [−M_1a / M_11 ; I_{n−1}]
    v̇ = f1(q, v) + g1(q) τ_a,     g1 = M_comb⁻¹,  f1 = −M_comb⁻¹ H_comb

with ``v = q̇_a`` the active-joint velocities, ``M_comb = M_aa − M_au M_ua / M_uu`` (a Schur
complement) and ``H_comb = H_a − M_au H_u / M_uu`` where ``H = C(q, q̇) q̇`` at ``q̇ = g0 v``.
A fully actuated arm is the case ``g0 = I``, ``M_comb = M``, ``H_comb = C q̇``.

The module also owns the full-order model ``M q̈ + C q̇ = τ − b q̇₁ e₁`` and fixed-step RK4
integrators of both, so that the cascade can be checked against the full dynamics.

After a fault in motion, or with damping b > 0, p₁ is not zero: the reduced model then carries p₁ as
a third state (docs/MODEL.md §7),

    q̇ = g0(q) v + e₁ p₁ / M_11,    v̇ = M_comb⁻¹ (τ_a − H_comb),    ṗ₁ = −b q̇₁

with H evaluated at that q̇ and ``H_comb = H_a − M_au (H_u + b q̇₁) / M_uu``
(:func:`momentum_cascade_rhs`, :func:`momentum_cascade_rk4_step`).

Functions accept an :class:`~pan1_env.dynamics.ArmParams` or :class:`~pan1_env.dynamics.ArmBatch`
and arrays with an optional leading batch axis, like :mod:`pan1_env.dynamics`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .dynamics import (
    Arm,
    angle_differences,
    checked_joints,
    damping_torque,
    forward_dynamics,
    in_joint_coordinates,
    jacobian,
    link_angles,
    mass_matrix,
)

__all__ = [
    "CascadeTerms",
    "cascade_terms",
    "passive_velocity_map",
    "joint_velocity",
    "reduced_jacobian",
    "passive_momentum",
    "passive_momentum_rate",
    "rk4_step",
    "reduced_state",
    "end_effector_drift",
    "momentum_cascade_rhs",
    "momentum_cascade_rk4_step",
    "f1",
    "g1",
    "cascade_rhs",
    "cascade_rk4_step",
    "full_order_rhs",
    "full_order_rk4_step",
    "full_torque",
]


class CascadeTerms(NamedTuple):
    """Everything the controller and the integrator need at one state (q, v)."""

    g0: np.ndarray  # (..., n, k)   q̇ = g0 v
    M_comb: np.ndarray  # (..., k, k)
    H_comb: np.ndarray  # (..., k)
    qd: np.ndarray  # (..., n)      = g0 v
    M: np.ndarray  # (..., n, n)   the full mass matrix


def _g0_from_mass(M: np.ndarray, passive: bool) -> np.ndarray:
    n = M.shape[-1]
    if not passive:
        return np.broadcast_to(np.eye(n), M.shape).copy()
    g0 = np.zeros(M.shape[:-1] + (n - 1,))
    g0[..., 0, :] = -M[..., 0, 1:] / M[..., 0, 0:1]
    g0[..., 1:, :] = np.eye(n - 1)
    return g0


def passive_velocity_map(arm: Arm, q: np.ndarray) -> np.ndarray:
    """g0(q): maps the actuated velocities v to q̇ (``(n, n−1)`` for a PA arm, ``I_n`` otherwise)."""
    return _g0_from_mass(mass_matrix(arm, q), arm.passive_first_joint)


def _as_active(arm: Arm, v: np.ndarray, lead: tuple[int, ...]) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    k = arm.n_actuated
    if v.shape != lead + (k,):
        raise ValueError(f"v must have shape {lead + (k,)} (actuated joints), got {v.shape}")
    return v


def _as_momentum(p1: np.ndarray | float | None, lead: tuple[int, ...]) -> np.ndarray:
    p1 = np.zeros(lead) if p1 is None else np.asarray(p1, dtype=float)
    if p1.shape not in ((), lead):
        raise ValueError(f"p1 must be a number or have shape {lead}, got {p1.shape}")
    return p1


def _drift(M: np.ndarray, p1: np.ndarray) -> np.ndarray:
    # The passive speed that the momentum p₁ alone gives: row 1 of M q̇ = p₁ with q̇_a = 0.
    d = np.zeros(M.shape[:-1])
    d[..., 0] = p1 / M[..., 0, 0]
    return d


def joint_velocity(arm: Arm, q: np.ndarray, v: np.ndarray, p1: np.ndarray | float | None = None) -> np.ndarray:
    """q̇ = g0(q) v + e₁ p₁ / M_11 (the last term only for a PA arm with momentum ``p1``; none by default)."""
    q = checked_joints(arm, q)
    v = _as_active(arm, v, q.shape[:-1])
    M = mass_matrix(arm, q)
    qd = np.einsum("...ij,...j->...i", _g0_from_mass(M, arm.passive_first_joint), v)
    if p1 is None:
        return qd
    _needs_passive(arm, "joint_velocity with p1")
    return qd + _drift(M, _as_momentum(p1, q.shape[:-1]))


def end_effector_drift(arm: Arm, q: np.ndarray, p1: np.ndarray | float) -> np.ndarray:
    """The end-effector velocity the momentum carries with the actuated joints still: J₁ p₁ / M_11.

    So ṗ_end = J̄ v + J₁ p₁ / M_11 on a PA arm; shape ``(..., 2)``.
    """
    _needs_passive(arm, "end_effector_drift")
    q = checked_joints(arm, q)
    M = mass_matrix(arm, q)
    return jacobian(arm, q)[..., :, 0] * (_as_momentum(p1, q.shape[:-1]) / M[..., 0, 0])[..., None]


def _needs_passive(arm: Arm, what: str) -> None:
    if not arm.passive_first_joint:
        raise ValueError(f"{what} needs a passive joint 1 (a PA arm, or dynamics.faulted(arm) after a fault)")


def reduced_jacobian(arm: Arm, q: np.ndarray) -> np.ndarray:
    """J̄ = J g0: the map from actuated velocities v to the end-effector velocity, ``(..., 2, k)``."""
    return jacobian(arm, q) @ passive_velocity_map(arm, q)


def passive_momentum(arm: Arm, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """p₁ = Σ_α M_1α(q) q̇_α, the angular momentum about joint 1's axis; its law is
    :func:`passive_momentum_rate` (conserved on a PA arm without damping, zero from rest)."""
    qd = checked_joints(arm, qd, "qd")
    return np.einsum("...a,...a->...", mass_matrix(arm, q)[..., 0, :], qd)


def passive_momentum_rate(arm: Arm, qd: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """ṗ₁ = τ₁ − b q̇₁ (damping only while joint 1 is passive) for the full joint torque ``tau``.

    Why no other term: ṗ₁ = ∂L/∂q₁ + (generalised force on q₁), and L = T = ½ q̇ᵀ M q̇ with M free of
    q₁ (turning the whole arm about its base changes no relative angle), so ∂L/∂q₁ = 0.
    """
    qd = checked_joints(arm, qd, "qd")
    return np.asarray(tau, dtype=float)[..., 0] + damping_torque(arm, qd)[..., 0]


def reduced_state(arm: Arm, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v, p₁) = (q̇_a, Σ_α M_1α q̇_α): the reduced model's state at a full state (q, q̇) of a PA arm.

    This is the map to apply at a fault: the state is kept, so p₁ is whatever the motion had.
    """
    _needs_passive(arm, "reduced_state")
    qd = checked_joints(arm, qd, "qd")
    return qd[..., 1:].copy(), passive_momentum(arm, q, qd)


def cascade_terms(arm: Arm, q: np.ndarray, v: np.ndarray, p1: np.ndarray | float | None = None) -> CascadeTerms:
    """g0, M_comb, H_comb and q̇ at (q, v), sharing one evaluation of the trigonometry.

    With ``p1`` (a PA arm's momentum; zero by default) q̇ gains the drift e₁ p₁ / M_11 and H is
    evaluated there. H_comb holds the damping b q̇₁ of a passive joint 1 (zero when b = 0).
    """
    q = checked_joints(arm, q)
    v = _as_active(arm, v, q.shape[:-1])
    D = angle_differences(link_angles(q))
    M = in_joint_coordinates(arm.lam * np.cos(D))
    g0 = _g0_from_mass(M, arm.passive_first_joint)
    qd = np.einsum("...ij,...j->...i", g0, v)
    if p1 is not None:
        _needs_passive(arm, "cascade_terms with p1")
        qd = qd + _drift(M, _as_momentum(p1, q.shape[:-1]))
    theta_dot = link_angles(qd)
    h = -np.einsum("...ab,...b->...a", arm.lam * np.sin(D), theta_dot**2)
    H = np.cumsum(h[..., ::-1], axis=-1)[..., ::-1]
    if not arm.passive_first_joint:
        return CascadeTerms(g0, M, H, qd, M)
    M_au = M[..., 1:, 0]
    inv_uu = 1.0 / M[..., 0, 0]
    M_comb = M[..., 1:, 1:] - M_au[..., :, None] * M_au[..., None, :] * inv_uu[..., None, None]
    # Row 1 reads M_11 q̈₁ + M_1a v̇ + H_1 = −b q̇₁: the damping enters where H_1 does. With b = 0
    # the added term is ±0, so the Lemma-1 numbers are bit for bit what they were.
    H_u = H[..., 0] - damping_torque(arm, qd)[..., 0]
    H_comb = H[..., 1:] - M_au * (H_u * inv_uu)[..., None]
    return CascadeTerms(g0, M_comb, H_comb, qd, M)


def g1(arm: Arm, q: np.ndarray) -> np.ndarray:
    """g1(q) = M_comb(q)⁻¹, shape ``(..., k, k)``."""
    q = checked_joints(arm, q)
    zeros = np.zeros(q.shape[:-1] + (arm.n_actuated,))
    return np.linalg.inv(cascade_terms(arm, q, zeros).M_comb)


def f1(arm: Arm, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """f1(q, v) = −M_comb⁻¹ H_comb, shape ``(..., k)``."""
    t = cascade_terms(arm, q, v)
    return -np.linalg.solve(t.M_comb, t.H_comb[..., None])[..., 0]


def _undamped(arm: Arm) -> None:
    # With b > 0 the momentum leaves zero as soon as the passive joint turns (ṗ₁ = −b q̇₁), so the
    # Lemma-1 cascade, which pins p₁ = 0, would be wrong: say so rather than drift silently.
    if arm.passive_first_joint and np.any(np.asarray(arm.passive_damping) != 0):
        raise ValueError("the cascade with p1 = 0 (Lemma 1) holds only without passive_damping; "
                         "use momentum_cascade_rk4_step, which carries p1")


def cascade_rhs(
    arm: Arm, q: np.ndarray, v: np.ndarray, tau_a: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Time derivatives (q̇, v̇) of the cascaded state under actuated torques τ_a (p₁ = 0, b = 0)."""
    _undamped(arm)
    t = cascade_terms(arm, q, v)
    vdot = np.linalg.solve(t.M_comb, (np.asarray(tau_a, dtype=float) - t.H_comb)[..., None])[..., 0]
    return t.qd, vdot


def rk4_step(rhs, x: np.ndarray, y: np.ndarray, dt: float, first=None) -> tuple[np.ndarray, np.ndarray]:
    """One classical RK4 step of a state in two parts (x, y) with derivatives ``rhs(x, y) -> (ẋ, ẏ)``; ``first`` may
    pass ``rhs(x, y)`` when the caller has it already."""
    k1x, k1y = rhs(x, y) if first is None else first
    k2x, k2y = rhs(x + 0.5 * dt * k1x, y + 0.5 * dt * k1y)
    k3x, k3y = rhs(x + 0.5 * dt * k2x, y + 0.5 * dt * k2y)
    k4x, k4y = rhs(x + dt * k3x, y + dt * k3y)
    return (x + dt / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x),
            y + dt / 6.0 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y))


def cascade_rk4_step(
    arm: Arm,
    q: np.ndarray,
    v: np.ndarray,
    tau_a: np.ndarray,
    dt: float,
    terms: CascadeTerms | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One classical RK4 step of (q, v) with τ_a held constant over ``dt`` (zero-order hold).

    ``terms`` may pass :func:`cascade_terms` at (q, v) when the caller has it already.
    """
    _undamped(arm)
    first = None
    if terms is not None:
        first = (terms.qd, np.linalg.solve(terms.M_comb, (tau_a - terms.H_comb)[..., None])[..., 0])
    return rk4_step(lambda x, y: cascade_rhs(arm, x, y, tau_a), q, v, dt, first)


def momentum_cascade_rhs(
    arm: Arm, q: np.ndarray, v: np.ndarray, p1: np.ndarray | float, tau_a: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time derivatives (q̇, v̇, ṗ₁) of a PA arm's reduced state (q, v, p₁) under torques τ_a."""
    t = cascade_terms(arm, q, v, p1)
    vdot = np.linalg.solve(t.M_comb, (np.asarray(tau_a, dtype=float) - t.H_comb)[..., None])[..., 0]
    return t.qd, vdot, damping_torque(arm, t.qd)[..., 0]


def momentum_cascade_rk4_step(
    arm: Arm, q: np.ndarray, v: np.ndarray, p1: np.ndarray | float, tau_a: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One classical RK4 step of (q, v, p₁) with τ_a held over ``dt``."""
    _needs_passive(arm, "momentum_cascade_rk4_step")
    x = (np.asarray(q, dtype=float), np.asarray(v, dtype=float), np.asarray(p1, dtype=float))

    def rhs(h: float, k: tuple[np.ndarray, ...] | None) -> tuple[np.ndarray, ...]:
        at = x if k is None else tuple(s + h * ks for s, ks in zip(x, k, strict=True))
        return momentum_cascade_rhs(arm, *at, tau_a)

    k1 = rhs(0.0, None)
    k2 = rhs(0.5 * dt, k1)
    k3 = rhs(0.5 * dt, k2)
    k4 = rhs(dt, k3)
    parts = zip(x, k1, k2, k3, k4, strict=True)
    return tuple(s + dt / 6.0 * (a + 2.0 * b + 2.0 * c + d) for s, a, b, c, d in parts)  # type: ignore[return-value]


def full_torque(arm: Arm, tau_a: np.ndarray) -> np.ndarray:
    """The full joint torque vector: τ = [0, τ_a] for a PA arm, τ_a otherwise."""
    tau_a = np.asarray(tau_a, dtype=float)
    if not arm.passive_first_joint:
        return tau_a
    return np.concatenate([np.zeros(tau_a.shape[:-1] + (1,)), tau_a], axis=-1)


def full_order_rhs(
    arm: Arm, q: np.ndarray, qd: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Time derivatives (q̇, q̈) of the full model M q̈ + C q̇ = τ − b q̇₁ e₁ (τ has all n entries;
    the damping acts only while joint 1 is passive)."""
    return np.asarray(qd, dtype=float), forward_dynamics(arm, q, qd, tau)


def full_order_rk4_step(
    arm: Arm, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """One RK4 step of the full-order state (q, q̇) with τ held over ``dt``."""
    return rk4_step(lambda x, y: full_order_rhs(arm, x, y, tau), q, qd, dt)
