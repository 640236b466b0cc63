"""The paper's control laws: the distributed nominal formation law and the backstepping tracker.

    v_i0 = −K_P J̄_iᵀ ê_i                                  (Eq. 39, docs/MODEL.md §4)
    τ_a  = M_comb (v̇* − K_e (v − v*)) + H_comb            (Eq. 64, docs/MODEL.md §5)

(for a fully actuated arm M_comb = M and H_comb = C q̇). The tracker makes the cascaded model's
error dynamics ẽ̇ = −K_e ẽ exactly; v̇* is supplied by the caller (the simulation uses a backward
finite difference over the physics step, as the paper does, Remark 5).
"""

from __future__ import annotations

import numpy as np

__all__ = ["nominal_velocity", "within_speed", "MAX_JOINT_SPEED", "backstepping_torque", "finite_difference"]


def nominal_velocity(Jbar: np.ndarray, e_hat: np.ndarray, kp: float, drift: np.ndarray | None = None,
                     feed_forward: np.ndarray | None = None) -> np.ndarray:
    """v0 = −K_P J̄ᵀ ê for ``J̄ (..., 2, k)`` and ``ê (..., 2)``: shape ``(..., k)``. With a PAn−1 arm's
    end-effector ``drift`` d = J₁ p₁ / M_11 ``(..., 2)``, v0 − J̄⁺ d: the actuated joints cancel what of the drift
    they can (all of it where J̄ has rank 2), so the end-effector moves as the paper's law says
    (docs/MODEL.md §7). With a moving formation's ``feed_forward`` ṗ_ff ``(..., 2)``, v0 + J̄⁺ (ṗ_ff − d): the
    end-effector also goes where the moving shape goes (docs/MODEL.md §8)."""
    v0 = -kp * np.einsum("...ck,...c->...k", Jbar, e_hat)
    if feed_forward is not None:  # to the law, a feed-forward is a drift the other way
        drift = -feed_forward if drift is None else drift - feed_forward
    if drift is None or not np.any(drift):
        return v0
    return v0 - np.einsum("...kc,...c->...k", np.linalg.pinv(Jbar), drift)


MAX_JOINT_SPEED = 2.0  # rad/s: the envs' default bound on a commanded joint speed (an action of 1)


def within_speed(v0: np.ndarray, max_speed: float) -> np.ndarray:
    """Each arm's command ``v0 (..., k)`` scaled down as a whole, in place, so that no joint exceeds ``max_speed``:
    the same direction, so a descent direction of the formation's error stays one."""
    peak = np.abs(v0).max(axis=-1, initial=0.0) / max_speed
    v0 /= np.maximum(peak, 1.0)[..., None]
    return v0


def backstepping_torque(
    M_comb: np.ndarray,
    H_comb: np.ndarray,
    v: np.ndarray,
    v_star: np.ndarray,
    v_star_dot: np.ndarray,
    ke: float,
) -> np.ndarray:
    """τ_a = M_comb (v̇* − K_e (v − v*)) + H_comb, batched over a leading axis."""
    accel = v_star_dot - ke * (v - v_star)
    return np.einsum("...ij,...j->...i", M_comb, accel) + H_comb


def finite_difference(current: np.ndarray, previous: np.ndarray | None, dt: float) -> np.ndarray:
    """Backward difference (current − previous) / dt; zero when there is no previous value."""
    if previous is None:
        return np.zeros_like(current)
    return (current - previous) / dt
