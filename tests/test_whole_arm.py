"""Whole-arm safety in the engine: the compiled capsule rows against the numpy reference
(pan1_env.bodies), and the shield keeping every link capsule clear, checked by an independent geometry."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from pan1_env import bodies
from pan1_env.cascade import passive_velocity_map
from pan1_env.compiled import kernels
from pan1_env.dynamics import ArmParams, link_angles, mass_matrix


def _arm(rng: np.random.Generator, n: int, passive: bool) -> ArmParams:
    return ArmParams(masses=rng.uniform(0.5, 1.5, n), lengths=rng.uniform(0.3, 0.6, n),
                     com=rng.uniform(0.1, 0.3, n), inertias=rng.uniform(0.01, 0.05, n),
                     base=rng.uniform(-0.5, 0.5, 2), passive_first_joint=passive)


def _lanes(arm: ArmParams, q: np.ndarray) -> dict:
    """One lane (W = 1) of the kernel's scratch for an arm at q."""
    ang = link_angles(q) + arm.phi
    return dict(lengths=arm.lengths[:, None].copy(), bx=np.array([arm.base[0]]), by=np.array([arm.base[1]]),
                c=np.cos(ang)[:, None].copy(), s=np.sin(ang)[:, None].copy(), M=mass_matrix(arm, q)[:, :, None].copy())


def _rows(arm: ArmParams, q: np.ndarray, caps: np.ndarray, *, links: bool = True, rho: float = 0.0,
          time: float = 0.0, kappa: float = 1.0, epsilon: float = 10.0, margin: float = 0.0, v_max: float = np.inf,
          sensing: float = np.inf, skin: float = 0.0, dt: float = 0.0, qd: np.ndarray | None = None,
          distance: bool = False, decay: float = 0.0, gate: float = 0.0, p1: float = 0.0, lookahead: float = 0.0,
          damping: float = 0.0, gain: float = 1.0, offset: float = 0.0):
    """kernels.capsules.whole_arm_rows for one arm at q (one lane; ``p1`` its passive momentum, ``damping`` the
    fault margin's b, a full arm's momentum at the sub-step's end ``gain`` M₀ v + ``offset``): (A, b, h_min) of the
    rows written."""
    n = arm.n_links
    k = n - 1 if arm.passive_first_joint else n
    m_max = kernels().capsules.most_rows(n if links else 1, caps.shape[1], caps.shape[1], k)
    A, b, active, P = np.zeros((m_max, k)), np.zeros(m_max), np.zeros(m_max, bool), np.empty((n + 1, 2))
    lane = _lanes(arm, q)
    qd = np.zeros((n, 1)) if qd is None else np.asarray(qd, float).reshape(n, 1)
    m, h_min = kernels().capsules.whole_arm_rows(
        0, 0, n, k, arm.passive_first_joint, links, rho, sensing, gate, skin, dt, lane["lengths"], lane["bx"],
        lane["by"], lane["c"], lane["s"], qd, lane["M"], p1, (damping, gain, offset), caps, caps.shape[1], time, kappa,
        epsilon, margin, distance, decay, lookahead, v_max, np.zeros(k), A, b, active, P,
        np.empty((caps.shape[1], kernels().capsules.NEAR_COLUMNS)))
    return A[:m], b[:m], h_min


def _capsules(K, segments_a, segments_b, radii, shares, paths=None, speeds=None) -> np.ndarray:
    C = len(radii)
    caps = np.zeros((1, C, K.CAPSULE_COLUMNS))
    caps[0, :, [K.CAP_AX, K.CAP_AY]] = np.asarray(segments_a).T
    caps[0, :, [K.CAP_BX, K.CAP_BY]] = np.asarray(segments_b).T
    caps[0, :, K.CAP_RADIUS], caps[0, :, K.CAP_SHARE], caps[0, :, K.CAP_ACTIVE] = radii, shares, 1.0
    caps[0, :, K.CAP_ARM] = -1.0
    if paths is not None:
        step = np.asarray(paths) - np.asarray(segments_a)
        length = np.linalg.norm(step, axis=-1)
        caps[0, :, [K.CAP_UX, K.CAP_UY]] = (step / length[:, None]).T
        caps[0, :, K.CAP_PATH], caps[0, :, K.CAP_SPEED] = length, speeds
    return caps


@pytest.mark.parametrize("n, passive", [(3, True), (4, True), (3, False)])
def test_link_obstacle_rows_match_the_numpy_barrier(n: int, passive: bool) -> None:
    """Every (link, moving disk) row of the kernel is −L_g0 h ≤ κ(h − margin) + ∂h/∂t − ‖L_g0 h‖²/ε with
    h, L_g0 h and ∂h/∂t of bodies.link_obstacle_barrier, at the obstacles' positions at that time; a PAn−1
    arm with passive momentum p₁ adds the drift's rate (∂h/∂q₁) p₁ / M_11 to b (docs/MODEL.md §7)."""
    K = kernels().capsules
    rng = np.random.default_rng(n + 10 * passive)
    arm = _arm(rng, n, passive)
    k = n - 1 if passive else n
    q = rng.uniform(-1.5, 1.5, n)
    centers = arm.base + rng.uniform(-1.0, 1.0, (5, 2))
    ends = centers + rng.uniform(-0.4, 0.4, (5, 2))
    radii, speeds, rho = rng.uniform(0.05, 0.2, 5), rng.uniform(0.1, 0.5, 5), 0.03
    time, kappa, epsilon, margin = 2.7, 0.8, 20.0, 0.01
    caps = _capsules(K, centers, centers, radii, np.ones(5), ends, speeds)
    p1 = 0.37 if passive else 0.0
    A, b, h_min = _rows(arm, q, caps, rho=rho, time=time, kappa=kappa, epsilon=epsilon, margin=margin, p1=p1)
    m = len(b)
    now = bodies.obstacle_centers(centers, ends, speeds, time)
    ref = bodies.link_obstacle_barrier(arm, q, now, radii, rho, bodies.obstacle_velocities(centers, ends, speeds,
                                                                                            time))
    assert m == n * 5
    row = ref.row.reshape(m, k)
    h = ref.h.reshape(m)
    np.testing.assert_allclose(A[:m], -row, rtol=1e-10, atol=1e-12)
    drift = ref.grad_q.reshape(m, n)[:, 0] * p1 / mass_matrix(arm, q)[0, 0]
    expected_b = kappa * (h - margin) + ref.dh_dt.reshape(m) + drift - np.sum(row ** 2, axis=-1) / epsilon
    np.testing.assert_allclose(b[:m], expected_b, rtol=1e-10, atol=1e-12)
    assert h_min == pytest.approx(h.min(), rel=1e-12)
    assert np.allclose(row, ref.grad_q.reshape(m, n) @ passive_velocity_map(arm, q))


@pytest.mark.parametrize(("distance", "decay"), [(True, 0.0), (False, 20.0), (True, 50.0)])
def test_whole_arm_rows_with_the_filter_choices_match_the_numpy_reference(distance: bool, decay: float) -> None:
    """The kernel's link rows (moving disks: ∂h/∂t) and inter-arm rows (share ½) with the distance
    barrier and/or ε(h̃) = ε e^{λ h̃}: the numpy reference's shaped_barrier + cbf_rows of the same pairs
    (bodies.link_obstacle_barrier, bodies.inter_arm_barrier); h_min in the chosen barrier's unit."""
    from pan1_env.safety import cbf_rows, shaped_barrier

    K = kernels().capsules
    form = "distance" if distance else "squared"
    rng = np.random.default_rng(17 + int(decay) + 100 * distance)
    arm = _arm(rng, 3, True)
    q = rng.uniform(-1.5, 1.5, 3)
    centers = arm.base + rng.uniform(-1.0, 1.0, (5, 2))
    ends = centers + rng.uniform(-0.4, 0.4, (5, 2))
    radii, speeds, rho = rng.uniform(0.05, 0.2, 5), rng.uniform(0.1, 0.5, 5), 0.03
    time, kappa, epsilon, margin = 2.7, 0.8, 20.0, 0.01
    caps = _capsules(K, centers, centers, radii, np.ones(5), ends, speeds)
    p1, M11 = -0.29, mass_matrix(arm, q)[0, 0]  # a passive momentum: its drift's rate joins ∂h/∂t
    A, b, h_min = _rows(arm, q, caps, rho=rho, time=time, kappa=kappa, epsilon=epsilon, margin=margin,
                        distance=distance, decay=decay, p1=p1)
    now = bodies.obstacle_centers(centers, ends, speeds, time)
    ref = bodies.link_obstacle_barrier(arm, q, now, radii, rho, bodies.obstacle_velocities(centers, ends, speeds,
                                                                                            time))
    rate = ref.dh_dt.reshape(15) + ref.grad_q.reshape(15, 3)[:, 0] * p1 / M11
    h, row, dh_dt = shaped_barrier(ref.h.reshape(15), (radii[None, :] + rho).repeat(3, 0).reshape(15), form,
                                   ref.row.reshape(15, 2), rate)
    A_ref, b_ref = cbf_rows(h, row, kappa, epsilon, margin, decay, dh_dt)
    np.testing.assert_allclose(A, A_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(b, b_ref, rtol=1e-10, atol=1e-12)
    assert h_min == pytest.approx(h.min(), rel=1e-12)
    # inter-arm: another arm's links as capsules of radius ρ, half the rate each
    arm_j = _arm(rng, 4, True)
    qj = rng.uniform(-1.5, 1.5, 4)
    P = bodies.link_segments(arm_j, qj)
    caps = _capsules(K, P[0], P[1], np.full(4, rho), np.full(4, 0.5))
    A, b, _ = _rows(arm, q, caps, rho=rho, kappa=kappa, epsilon=epsilon, distance=distance, decay=decay, p1=p1)
    ref = bodies.inter_arm_barrier(arm, q, arm_j, qj, rho)
    h, row, rate = shaped_barrier(ref.h.reshape(12), 2 * rho, form, ref.row_i.reshape(12, 2),
                                  ref.grad_i.reshape(12, 3)[:, 0] * p1 / M11)  # arm i's own drift, whole
    A_ref, b_ref = cbf_rows(h, row, kappa, epsilon, 0.0, decay, rate, share=0.5)
    np.testing.assert_allclose(A, A_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("passive", [True, False])
def test_fault_margin_rows_match_the_numpy_twin(passive: bool) -> None:
    """With a damping b > 0 (the fault margin), a PAn−1 arm's link rows are cbf_rows of safety.fault_rows (each pair
    as h − c p₁ and h + c p₁, c = reach / b, with the rows and rates its damped momentum gives), its h_min still the
    geometric one; a fully actuated arm's rows are its rows without the margin, then safety.momentum_rows of its
    smallest clearance."""
    from pan1_env.safety import cbf_rows, fault_rows, momentum_rows, shaped_barrier

    K = kernels().capsules
    rng = np.random.default_rng(23 + passive)
    n = 3
    arm = _arm(rng, n, passive)
    q = rng.uniform(-1.5, 1.5, n)
    centers, radii, rho = arm.base + rng.uniform(-1.0, 1.0, (5, 2)), rng.uniform(0.05, 0.2, 5), 0.03
    kappa, epsilon, margin, decay, damping = 0.1, 20.0, 0.01, 50.0, 0.5  # κ below b / M₀₀: the floor acts
    caps = _capsules(K, centers, centers, radii, np.ones(5))
    M, reach = mass_matrix(arm, q), float(np.sum(arm.lengths))
    p1 = -0.29 if passive else 0.0
    gain, offset = (1.0, 0.0) if passive else (1.7, 0.04)  # a full arm's momentum at the sub-step's end: g M₀ v + p₀
    A, b, h_min = _rows(arm, q, caps, rho=rho, kappa=kappa, epsilon=epsilon, margin=margin, distance=True,
                        decay=decay, p1=p1, damping=damping, gain=gain, offset=offset)
    ref = bodies.link_obstacle_barrier(arm, q, centers, radii, rho)
    k = n - 1 if passive else n
    rate = ref.dh_dt.reshape(15) + ref.grad_q.reshape(15, n)[:, 0] * p1 / M[0, 0]
    h, row, rate = shaped_barrier(ref.h.reshape(15), (radii[None, :] + rho).repeat(n, 0).reshape(15), "distance",
                                  ref.row.reshape(15, k), rate)
    assert h_min == pytest.approx(h.min(), rel=1e-12)
    if passive:  # two rows a pair, h − c p₁ and h + c p₁, with κ at least b / M₀₀
        h_f, row_f, rate_f, floor = fault_rows(h, row, rate, p1, M[0], reach, damping)
        assert floor > kappa
        A_ref, b_ref = cbf_rows(h_f.reshape(30), row_f.reshape(30, k), max(kappa, floor), epsilon, margin, decay,
                                rate_f.reshape(30))
    else:
        A_ref, b_ref = cbf_rows(h, row, kappa, epsilon, margin, decay, rate)
        A_m, b_m = momentum_rows(M[0], h.min(), reach, damping, margin, gain, offset, closing=0.0)  # dt = 0: none
        A_ref, b_ref = np.concatenate([A_ref, A_m]), np.concatenate([b_ref, b_m])
    np.testing.assert_allclose(A, A_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(b, b_ref, rtol=1e-10, atol=1e-12)
    # without the margin: the plain rows, which a passive arm's margin doubles and a full arm's leaves as they are
    A0, b0, _ = _rows(arm, q, caps, rho=rho, kappa=kappa, epsilon=epsilon, margin=margin, distance=True, decay=decay,
                      p1=p1)
    assert A0.shape == (15, k) and A.shape[0] == (30 if passive else 17)
    assert passive or (np.allclose(A0, A[:15]) and np.allclose(b0, b[:15]))


@pytest.mark.parametrize("tracked", [True, False])
def test_the_momentum_rows_hold_the_momentum_at_the_sub_steps_end(tracked: bool) -> None:
    """The fault margin's momentum rows take a full arm's first-joint momentum at the sub-step's end as
    p₁⁺ = M₀ ((1 + a) v* + (1 − a) q̇ − v*₋) + dt H₀ (a = K_e dt; the kernel's _momentum_ahead), or before a last v*
    is set (``tracked`` False: the first sub-step after the tracker starts afresh) M₀ (a v* + (1 − a) q̇) + dt H₀:
    q₁ is cyclic, so ṗ₁ = τ₁ over the sub-step, τ the tracker's computed torque. The engine's momentum after a jump
    of the command agrees to RK4's error, and neither the one without dt H₀ nor the other case's does (tracked: the
    command's momentum; afresh, where a = 1 here: the tracked formula's)."""
    from pan1_env.dynamics import coriolis_vector
    from pan1_env.engine import Engine, Physics
    from pan1_env.scenario import load

    team = load("paper_pa_mixed_square")
    full = [i for i, arm in enumerate(team.arms) if not arm.passive_first_joint]
    assert full
    engine = Engine(team, 1, physics=Physics(max_joint_speed=2.0, physics_dt=0.01))
    a, dt = team.ke * engine.physics_dt, engine.physics_dt
    first = np.full((1, engine.n_arms, engine.k_max), 1.5)
    engine.step(first, 3)
    q0, qd0 = (x.copy() for x in engine.joint_state())
    if not tracked:  # the same state, the tracker afresh (no v*₋)
        engine.set_state(0, [q0[0, i, :arm.n_links] for i, arm in enumerate(team.arms)],
                         [qd0[0, i, :arm.n_links] for i, arm in enumerate(team.arms)])
    jump = np.full_like(first, -0.8)
    engine.step(jump, 1)
    q1, qd1 = engine.joint_state()
    for i in full:
        arm, n = team.arms[i], team.arms[i].n_links
        M0 = mass_matrix(arm, q0[0, i, :n])[0]
        p1_after = mass_matrix(arm, q1[0, i, :n])[0] @ qd1[0, i, :n]
        H0 = coriolis_vector(arm, q0[0, i, :n], qd0[0, i, :n])[0]
        if tracked:
            lin = M0 @ ((1 + a) * jump[0, i, :n] + (1 - a) * qd0[0, i, :n] - first[0, i, :n])
        else:
            lin = M0 @ (a * jump[0, i, :n] + (1 - a) * qd0[0, i, :n])
        # to RK4's error (p₁ is not one of its states): ten times smaller than dt H₀ here
        assert p1_after == pytest.approx(lin + dt * H0, abs=3e-5)
        # what the wrong momentum would miss: the tracker's overshoot (tracked), or the v*₋ it has not got yet
        wrong = M0 @ (jump[0, i, :n] if tracked else 2 * jump[0, i, :n] - first[0, i, :n])
        assert abs(dt * H0) > 3e-4 and abs(wrong - p1_after) > 1e-2


@pytest.mark.parametrize(("lookahead", "distance"), [(0.7, False), (2.5, True), (np.inf, True)])
def test_look_ahead_rows_keep_out_the_stretch_of_path_the_obstacle_covers(lookahead: float, distance: bool) -> None:
    """With a look-ahead T the kernel's link rows are the barrier of each link against the capsule of the
    stretch of path its obstacle covers in the next T s (bodies.obstacle_stretch, itself checked against the
    sampled path): for each link and stretch, one row at their closest pair and one at the link's other end
    (nearly parallel segments' closest pair jumps between the ends); h and L_g0 h from the segment distance and
    the link Jacobian, ∂h/∂t by a central difference in time of that barrier; T = inf is the whole path, a still
    obstacle (∂h/∂t = 0)."""
    from pan1_env.safety import cbf_rows, shaped_barrier

    K = kernels().capsules
    rng = np.random.default_rng(29 + distance)
    arm = _arm(rng, 3, True)
    q = rng.uniform(-1.5, 1.5, 3)
    centers = arm.base + rng.uniform(-1.0, 1.0, (5, 2))
    ends = centers + rng.uniform(-0.4, 0.4, (5, 2))
    radii, speeds, rho = rng.uniform(0.05, 0.2, 5), rng.uniform(0.1, 0.5, 5), 0.03
    time, kappa, epsilon, margin, form = 2.7, 0.8, 20.0, 0.01, "distance" if distance else "squared"
    caps = _capsules(K, centers, centers, radii, np.ones(5), ends, speeds)
    A, b, h_min = _rows(arm, q, caps, rho=rho, time=time, kappa=kappa, epsilon=epsilon, margin=margin,
                        distance=distance, lookahead=lookahead)
    a, e = bodies.link_segments(arm, q)
    start, end, _, _ = bodies.obstacle_stretch(centers, ends, speeds, time, lookahead)
    s_pair = bodies.segment_distance(a[:, None], e[:, None], start[None], end[None])[1]  # (3, 5)
    s_rows = np.stack([s_pair, np.where(s_pair < 0.5, 1.0, 0.0)], axis=-1)  # the pair, then the other end

    def barrier(t: float) -> tuple[np.ndarray, np.ndarray]:  # h (3·5·2,) and ∇_q h (3·5·2, 3) at time t
        start, end, _, _ = bodies.obstacle_stretch(centers, ends, speeds, t, lookahead)
        x = a[:, None, None] + s_rows[..., None] * (e - a)[:, None, None]  # (3, 5, 2, 2): the rows' link points
        y, _ = bodies.closest_point_on_segment(start[None, :, None], end[None, :, None], x)
        J = bodies.link_point_jacobian(arm, q, np.arange(3)[:, None, None], s_rows)  # (3, 5, 2, 2, 3)
        h = np.sum((x - y) ** 2, axis=-1) - (radii[:, None] + rho) ** 2
        return h.reshape(30), (2.0 * np.einsum("lopc,lopcq->lopq", x - y, J)).reshape(30, 3)

    h, grad = barrier(time)
    step = 1e-6
    rate = (barrier(time + step)[0] - barrier(time - step)[0]) / (2 * step)
    if np.isinf(lookahead):
        assert np.all(rate == 0.0)
    h, row, dh_dt = shaped_barrier(h, np.tile(np.repeat(radii + rho, 2), 3), form, grad @ passive_velocity_map(arm, q),
                                   rate)
    A_ref, b_ref = cbf_rows(h, row, kappa, epsilon, margin, 0.0, dh_dt)
    np.testing.assert_allclose(A, A_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b, b_ref, rtol=1e-6, atol=1e-7)
    assert h_min == pytest.approx(h.min(), rel=1e-12)
    now = bodies.link_obstacle_barrier(arm, q, bodies.obstacle_centers(centers, ends, speeds, time), radii, rho).h
    assert np.all(h_min <= shaped_barrier(now.reshape(15), np.tile(radii + rho, 3), form)[0])  # never less kept out


@pytest.mark.parametrize("distance", [False, True])
def test_gated_rows_match_the_numpy_activation_gate(distance: bool) -> None:
    """With a smooth gate (width 0.08 m past a 0.1 m sensing range, arm at rest, still obstacles) every link
    row within range + gate is the numpy reference's cbf_rows(..., gate=activation_gate(c, 0.1, 0.08),
    speed=v_max): whole up to 0.1 m of clearance, relaxed towards the speed box beyond, none past 0.18 m;
    the kernel leaves out exactly the rows that cannot bind in the box."""
    from pan1_env.safety import activation_gate, cbf_rows, shaped_barrier

    K = kernels().capsules
    rng = np.random.default_rng(5 + distance)
    arm = _arm(rng, 3, True)
    q = rng.uniform(-1.5, 1.5, 3)
    sensing, gate, v_max, rho, kappa, epsilon = 0.1, 0.08, 1.5, 0.03, 0.5, 5.0
    form, decay = ("distance", 50.0) if distance else ("squared", 0.0)
    start, end = bodies.link_segments(arm, q)
    # 12 disks beside the links, their clearance to the link beside them spread over [0, 0.25] m: the
    # range, the gate and beyond
    link, along = rng.integers(0, 3, 12), rng.uniform(0.3, 0.7, (12, 1))
    tangent = (end - start)[link] / np.linalg.norm((end - start)[link], axis=1, keepdims=True)
    normal = tangent @ np.array([[0.0, 1.0], [-1.0, 0.0]]) * rng.choice([-1.0, 1.0], (12, 1))
    radii = rng.uniform(0.04, 0.1, 12)
    centers = start[link] + along * (end - start)[link] + normal * (radii + rho + np.linspace(0.0, 0.25, 12))[:, None]
    caps = _capsules(K, centers, centers, radii, np.ones(12))
    A, b, _ = _rows(arm, q, caps, rho=rho, kappa=kappa, epsilon=epsilon, v_max=v_max, sensing=sensing, gate=gate,
                    dt=0.01, distance=distance, decay=decay)
    A, b = A[:-4], b[:-4]  # the speed box's rows last
    ref = bodies.link_obstacle_barrier(arm, q, centers, radii, rho, np.zeros((12, 2)))
    R = (radii[None, :] + rho).repeat(3, 0).reshape(36)
    clear = np.sqrt(ref.h.reshape(36) + R ** 2) - R
    h, row = shaped_barrier(ref.h.reshape(36), R, form, ref.row.reshape(36, 2))
    sigma = activation_gate(clear, sensing, gate)
    A_ref, b_ref = cbf_rows(h, row, kappa, epsilon, 0.0, decay, gate=sigma, speed=v_max)
    keep = (clear <= sensing + gate) & ~(sigma * v_max * np.abs(row).sum(axis=1) <= b_ref)
    middle = (sigma > 0) & (sigma < 1)
    assert 0 < keep.sum() < 36 and middle.sum() >= 3  # the gate's middle is exercised
    if not distance:  # behind the paper's robust term relaxed rows still bind
        assert (middle & keep).any()
    np.testing.assert_allclose(A, A_ref[keep], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b, b_ref[keep], rtol=1e-9, atol=1e-12)


def test_inter_arm_rows_take_half_the_rate_budget() -> None:
    """A capsule of another arm (a segment, share ½): the row of bodies.inter_arm_barrier with κ/2."""
    K = kernels().capsules
    rng = np.random.default_rng(3)
    arm_i, arm_j = _arm(rng, 3, True), _arm(rng, 4, True)
    qi, qj = rng.uniform(-1.5, 1.5, 3), rng.uniform(-1.5, 1.5, 4)
    P = bodies.link_segments(arm_j, qj)
    rho, kappa, epsilon = 0.04, 1.2, 10.0
    caps = _capsules(K, P[0], P[1], np.full(4, rho), np.full(4, 0.5))
    A, b, _ = _rows(arm_i, qi, caps, rho=rho, kappa=kappa, epsilon=epsilon)
    m = len(b)
    ref = bodies.inter_arm_barrier(arm_i, qi, arm_j, qj, rho)
    row = ref.row_i.reshape(12, 2)
    np.testing.assert_allclose(A[:m], -row, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(b[:m], 0.5 * kappa * ref.h.reshape(12) - np.sum(row ** 2, axis=-1) / epsilon,
                               rtol=1e-9, atol=1e-12)


def test_end_effector_body_gives_the_paper_row() -> None:
    """With bodies = end-effector, a still disk's row is the paper's RCBF row (safety.rcbf_constraints)."""
    from pan1_env.cascade import reduced_jacobian
    from pan1_env.dynamics import end_effector
    from pan1_env.safety import rcbf_constraints

    K = kernels().capsules
    rng = np.random.default_rng(5)
    arm = _arm(rng, 3, True)
    q = rng.uniform(-1.5, 1.5, 3)
    centers, radii = arm.base + rng.uniform(-1.0, 1.0, (3, 2)), rng.uniform(0.05, 0.2, 3)
    caps = _capsules(K, centers, centers, radii, np.ones(3))
    A, b, _ = _rows(arm, q, caps, links=False, kappa=0.7, epsilon=5.0, margin=0.02)
    m = len(b)
    rows, b_ref, _ = rcbf_constraints(end_effector(arm, q)[None], reduced_jacobian(arm, q)[None], centers, radii,
                                      0.7, 5.0, margin=0.02)
    assert m == 3
    np.testing.assert_allclose(A[:m], rows[0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(b[:m], b_ref[0], rtol=1e-10, atol=1e-12)


def test_rows_that_cannot_bind_in_the_speed_box_are_culled() -> None:
    """With a speed bound, a far obstacle's row is dropped (it holds for every v in the box) and the
    2k box rows follow; a near one stays."""
    K = kernels().capsules
    rng = np.random.default_rng(8)
    arm = _arm(rng, 3, True)
    q = np.zeros(3)
    tip = bodies.link_segments(arm, q)[1][-1]
    centers = np.array([tip + [0.12, 0.0], arm.base + [30.0, 0.0]])
    caps = _capsules(K, centers, centers, np.array([0.1, 0.1]), np.ones(2))
    A, b, _ = _rows(arm, q, caps, v_max=2.0)
    m = len(b)
    far = bodies.link_obstacle_barrier(arm, q, centers[1:], [0.1]).row.reshape(3, 2)
    assert np.all(np.abs(far).sum(-1) * 2.0 <= 1.0 * 900.0)  # the far rows hold in the box
    assert m == 1 + 4, "the near disk's last link row (the others hold in the box) and the four box rows"
    np.testing.assert_array_equal(A[m - 4: m], [[1, 0], [-1, 0], [0, 1], [0, -1]])


def test_far_pairs_get_no_row() -> None:
    """Only pairs within the sensing radius plus twice what the gap closes in a sub-step get a row: a
    disk 0.15 m from the arm has none with sensing 0.1 m at rest, one per link it is near once the arm
    moves fast enough to close the rest in a sub-step."""
    K = kernels().capsules
    rng = np.random.default_rng(9)
    arm = _arm(rng, 3, True)
    q = np.zeros(3)
    tip = bodies.link_segments(arm, q)[1][-1]
    center = tip + [0.0, 0.25]  # straight above the arm (which points up at q = 0): 0.15 m from the tip's capsule
    caps = _capsules(K, [center], [center], np.array([0.1]), np.ones(1))
    clear = bodies.link_clearance(arm, q, [center], [0.1])
    assert clear.min() == pytest.approx(0.15)
    assert len(_rows(arm, q, caps, sensing=0.1, dt=0.01)[1]) == 0
    speed = np.array([0.0, 0.0, 5.0 / arm.reach])  # reach · Σ|q̇| = 5 m/s: the gap may close by 2 · 5 · 0.01 m
    _, b, h_min = _rows(arm, q, caps, sensing=0.1, dt=0.01, qd=speed)
    assert len(b) == int(np.sum(clear <= 0.1 + 0.1))
    assert h_min == pytest.approx(((clear + 0.1) ** 2 - 0.1 ** 2).min())


# ---------------------------------------------------------------- the shield, checked by tests/geometry.py
WHOLE = {"bodies": "links", "link_radius": 0.03, "inter_arm": True}
RHO = WHOLE["link_radius"]


def _penetration(core) -> float:
    """Deepest penetration of any link capsule into an obstacle or another arm's capsule, rebuilt from
    ``state()`` by the independent geometry (0 when clear); state() is float32, hence the 1e-6 m slack."""
    import geometry

    arms, parts = geometry.arms_from_state(core.state(), core.scenario)
    depths = [p.max(initial=0.0) for p in geometry.obstacle_penetration(arms, parts["centers"], parts["radii"], RHO)]
    depths += [p.max(initial=0.0) for p in geometry.inter_arm_penetration(arms, RHO).values()]
    return max(depths) - 1e-6


def _policy(kind: str, env, rng: np.random.Generator):
    """Uniform random actions, or bang-bang ones (±1 per joint) held for 40 steps."""
    held: dict = {}

    def act(t: int) -> dict:
        if kind == "random":
            return {a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents}
        if t % 40 == 0:
            held.update({a: rng.choice([-1.0, 1.0], env.action_space(a).shape) for a in env.agents})
        return {a: held[a] for a in env.agents}
    return act


def _whole_arm_episode(seed: int, kind: str, *, shield: bool, speed=(0.0, 0.0), mode: str = "velocity",
                       steps: int = 250, options: dict | None = None, shield_kwargs: dict | None = None
                       ) -> tuple[int, int, int, float]:
    """(steps in which a penetration begins, of those steps whose shield report says fallback, steps with
    a fallback, the smallest clearance any arm reported). A penetration begins in a step that ends with a
    capsule inside something it was not inside at the step's start; once inside, the shield's rows push
    it out over the next steps."""
    from pan1_env.environment import parallel_env
    from pan1_env.safety import FilterParams
    from pan1_env.wrappers import SafetyShield

    core = parallel_env("random", random_options={**WHOLE, "obstacle_speed": speed, **(options or {})},
                        action_mode=mode, control_dt=0.01, physics_dt=0.01, max_steps=steps)
    env = SafetyShield(core, params=FilterParams.of(core.scenario, **(shield_kwargs or {}))) if shield else core
    env.reset(seed=seed)
    assert _penetration(core) <= 0.0, "starts are drawn clear"
    act = _policy(kind, env, np.random.default_rng(seed))
    hits = hits_in_fallback = fallbacks = t = 0
    inside, closest = False, np.inf
    while env.agents:
        _, _, _, _, infos = env.step(act(t))
        closest = min(closest, *(info["min_clearance"] for info in infos.values()))
        fallback = any(info.get("shield_fallback", False) for info in infos.values())
        now_inside = _penetration(core) > 0.0
        begins = now_inside and not inside
        hits, hits_in_fallback = hits + begins, hits_in_fallback + (begins and fallback)
        fallbacks += fallback
        if now_inside:
            assert any(info["cost"] > 0 for info in infos.values()), "a penetration costs"
        inside, t = now_inside, t + 1
    return hits, hits_in_fallback, fallbacks, closest


@pytest.mark.parametrize("mode", ["velocity", "torque"])
@pytest.mark.parametrize("kind", ["random", "bang-bang"])
def test_shield_keeps_every_link_clear_of_still_obstacles_and_other_arms(kind: str, mode: str) -> None:
    """Still obstacles, links and inter-arm rows, control_dt = physics_dt = 0.01: no link capsule ever
    enters an obstacle or another arm's capsule, by a geometry computed apart from the package."""
    for seed in range(4):
        hits, *_ = _whole_arm_episode(seed, kind, shield=True, mode=mode)
        assert hits == 0, f"seed {seed}: {hits} steps with a penetration"


def test_without_the_shield_the_same_policies_penetrate() -> None:
    hits = sum(_whole_arm_episode(seed, kind, shield=False)[0] > 0 for seed in range(4)
               for kind in ("random", "bang-bang"))
    assert hits >= 3


@pytest.mark.parametrize("kind", ["random", "bang-bang"])
def test_moving_obstacles_penetrate_only_in_fallback_steps(kind: str) -> None:
    """Obstacles moving at 0.05–0.2 m/s: a penetration begins only in a step the shield reports as a
    fallback, and in at most 2 % of episodes (here: none of 6; the soak test measures the rate)."""
    episodes_hit = 0
    for seed in range(6):
        hits, hits_in_fallback, *_ = _whole_arm_episode(seed, kind, shield=True, speed=(0.05, 0.2))
        assert hits == hits_in_fallback, f"seed {seed}: a penetration outside a fallback step"
        episodes_hit += hits > 0
    assert episodes_hit == 0


def test_engine_clearance_agrees_with_the_independent_geometry() -> None:
    """Engine.clearance() (links to obstacles where they are now, and to other arms) against geometry.py,
    after some unshielded steps with moving obstacles."""
    import geometry

    from pan1_env.environment import parallel_env

    core = parallel_env("random", random_options={**WHOLE, "obstacle_speed": (0.1, 0.3)}, control_dt=0.01,
                        physics_dt=0.01)
    core.reset(seed=11)
    rng = np.random.default_rng(0)
    for _ in range(60):
        core.step({a: rng.uniform(-1, 1, core.action_space(a).shape) for a in core.agents})
    arms, parts = geometry.arms_from_state(core.state(), core.scenario)
    to_obstacles = geometry.obstacle_clearances(arms, parts["centers"], parts["radii"], RHO)
    between = geometry.inter_arm_clearances(arms, RHO)
    expected = [min(to_obstacles[i].min(initial=np.inf),
                    *(c.min() for (a, b), c in between.items() if i in (a, b))) for i in range(len(arms))]
    np.testing.assert_allclose(core.engine.clearance()[0], expected, atol=1e-5)
    np.testing.assert_allclose(parts["centers"], core.scenario.obstacle_centers(0.6), atol=1e-6)


def test_paper_scenarios_keep_the_end_effector_kernel() -> None:
    """The paper's scenarios protect end-effectors, as published: the engine takes the kernel's
    end-effector path (no capsules), so their reproduction is unchanged."""
    from pan1_env.environment import parallel_env

    for name in ("paper_pa3_square", "paper_pa_mixed_square"):
        engine = parallel_env(name).engine
        assert not engine.whole_arm and all(kind.whole is None for kind in engine.kinds)


def test_least_violation_relaxes_conflicting_rows_uniformly() -> None:
    """Rows x ≤ −1 and −x ≤ −1 (x ≥ 1) cannot both hold: relaxed by t‖A_j‖ they first can at t = 1, with
    x = 0; the speed bounds |v| ≤ 2 are kept, so from v0 = (3, 3) the answer is (0, 2). A zero row
    with b < 0 (nothing the arm can do about it) is dropped."""
    K = kernels().last_resort
    A = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [1, 0], [-1, 0], [0, 1], [0, -1]])
    b = np.array([-1.0, -1.0, -5.0, 2, 2, 2, 2])
    active = np.ones(7, bool)
    m, k = 7, 2
    v = np.empty(2)
    scratch = (np.empty(m), np.empty(m), np.empty(m, np.int64), np.empty(k, np.int64), np.empty((k, k)), np.empty(k),
               np.empty(k), np.empty(k), np.empty((k, k)), np.empty(k), np.empty(m), np.empty(m))
    t = K.least_violation(np.array([3.0, 3.0]), A, b, active, m, k, 4, False, v, *scratch)
    assert t == pytest.approx(1.0, abs=1e-6)  # the QP accepts rows within its feasibility tolerance
    np.testing.assert_allclose(v, [0.0, 2.0], atol=1e-6)


@pytest.mark.parametrize("by_rate", [False, True])
def test_least_violation_by_rate_does_not_let_a_short_lever_outweigh_a_long_one(by_rate: bool) -> None:
    """Rows −0.1 x ≤ −0.1 (a short lever: x ≥ 1) and x ≤ −1 conflict. Relaxed per unit of norm, b_j + t‖A_j‖,
    they meet at t = 1 and x = 0: the long lever's row gives up as much command as the short one's. Relaxed
    by rate, b_j + t, they meet at t = 2/11 and x = −9/11: each row's rate falls short by the same 2/11, and
    the long lever's row is nearly kept. The speed bounds |v| ≤ 2 hold the other coordinate at 2."""
    K = kernels().last_resort
    A = np.array([[-0.1, 0.0], [1.0, 0.0], [1, 0], [-1, 0], [0, 1], [0, -1]])
    b = np.array([-0.1, -1.0, 2, 2, 2, 2])
    m, k = 6, 2
    v = np.empty(2)
    scratch = (np.empty(m), np.empty(m), np.empty(m, np.int64), np.empty(k, np.int64), np.empty((k, k)), np.empty(k),
               np.empty(k), np.empty(k), np.empty((k, k)), np.empty(k), np.empty(m), np.empty(m))
    t = K.least_violation(np.array([3.0, 3.0]), A, b, np.ones(m, bool), m, k, 4, by_rate, v, *scratch)
    assert t == pytest.approx(2 / 11 if by_rate else 1.0, abs=1e-5)
    np.testing.assert_allclose(v, [-9 / 11 if by_rate else 0.0, 2.0], atol=1e-5)


def test_observations_carry_the_slots_obstacle_velocities() -> None:
    """With moving obstacles an agent's observation ends with its K obstacle slots' velocities: the slot
    at (dx, dy) from the end-effector holds the obstacle there, and the velocity beside it is that
    obstacle's (Scenario.obstacle_velocities at the env's time); without, the layout is unchanged."""
    from pan1_env.environment import parallel_env

    env = parallel_env("random", random_options={**WHOLE, "obstacle_speed": (0.05, 0.2)}, control_dt=0.01,
                       physics_dt=0.01)
    plain = parallel_env("random")
    obs, _ = env.reset(seed=2)
    for _ in range(37):
        obs, *_ = env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    sc, layout = env.scenario, env.observation_layout
    K = layout.n_obstacle_obs
    centers, velocities = sc.obstacle_centers(0.37), sc.obstacle_velocities(0.37)
    assert np.abs(velocities).max() > 0.04
    for i, agent in enumerate(env.agents):
        n = sc.arms[i].n_links
        seg = layout.segments(n)
        assert env.observation_space(agent).shape == (plain.observation_space(agent).shape[0] + 2 * K,)
        slots = obs[agent][seg["obstacles"]].reshape(K, 5)
        p = env.engine.positions()[0, i]
        for slot, v in zip(slots, obs[agent][seg["obstacle_velocities"]].reshape(K, 2), strict=True):
            j = int(np.argmin(np.linalg.norm(centers - (p + slot[1:3]), axis=-1)))
            np.testing.assert_allclose(centers[j], p + slot[1:3], atol=1e-5)
            np.testing.assert_allclose(v, velocities[j], atol=1e-6)


def test_an_aggressive_filter_near_moving_obstacles_still_penetrates_only_in_fallbacks() -> None:
    """κ = 5, ε = 10⁴ lets capsules come within millimetres of obstacles (the defaults keep about 5 cm),
    so the moving obstacles' ∂h/∂t and the skin are what keeps them out: a wrong sign or a stale time
    shows here."""
    episodes_hit, closest = 0, np.inf
    for seed in range(3):
        for kind in ("random", "bang-bang"):
            hits, in_fallback, _, clear = _whole_arm_episode(seed, kind, shield=True, speed=(0.1, 0.2),
                                                             shield_kwargs={"kappa": 5.0, "epsilon": 1e4})
            assert hits == in_fallback, f"seed {seed}, {kind}: a penetration began outside a fallback step"
            episodes_hit, closest = episodes_hit + (hits > 0), min(closest, clear)
    assert closest < 0.01, "the aggressive filter should let capsules come close (else this tests nothing)"
    assert episodes_hit <= 1


def test_mixed_link_counts_keep_every_capsule_clear() -> None:
    """Arms of 2, 3, 4 and 3 links (several kernel kinds, padded capsule slots), still obstacles, arms kept
    apart: no penetration by the independent geometry."""
    for seed in range(3):
        hits, *_ = _whole_arm_episode(seed, "bang-bang", shield=True, options={"links": (2, 3, 4, 3)})
        assert hits == 0


def test_sub_steps_in_one_call_match_one_call_each() -> None:
    """Moving obstacles: a step of 5 sub-steps gives the state of 5 steps of one sub-step (the rows see
    the obstacles at each sub-step's own time)."""
    from pan1_env.engine import Engine, Physics
    from pan1_env.random_scenario import RandomScenarioOptions, random_scenario

    team = random_scenario(np.random.default_rng(4), RandomScenarioOptions(
        bodies="links", link_radius=0.03, obstacle_speed=(0.2, 0.3), physics_dt=0.01, control_dt=0.05))
    engines = [Engine(team, physics=Physics(max_joint_speed=2.0), safety_filter=True) for _ in range(2)]
    command = np.random.default_rng(0).uniform(-2, 2, (1, team.n_arms, 3))
    counts = []
    for _ in range(8):
        counts.append(engines[0].step(command, 5).qp_counts)
        for _ in range(5):
            engines[1].step(command, 1)
    assert sum(c[..., 1:].sum() for c in counts) > 0, "the filter should act"
    for a, b in zip(engines[0].kinds, engines[1].kinds, strict=True):
        np.testing.assert_allclose(a.q, b.q, atol=1e-9)
    np.testing.assert_allclose(engines[0].centers, engines[1].centers, atol=1e-12)


def test_inter_arm_steps_carry_the_states_link_angles_and_restart_from_the_state() -> None:
    """With arms kept apart the engine calls the kernel once per sub-step; the calls after a step's first
    start from the sines and cosines of the link angles the previous one ended with. Those are the
    state's (to rounding), and a step is still a function of the state: after a reset mid-run, an
    engine gives the same results, bit for bit, as a fresh one reset to the same copies."""
    from pan1_env.engine import Engine, Physics
    from pan1_env.random_scenario import RandomScenarioOptions, random_scenario

    teams = [random_scenario(np.random.default_rng(s), RandomScenarioOptions(
        bodies="links", link_radius=0.03, inter_arm=True, obstacle_speed=(0.1, 0.3), physics_dt=0.01,
        control_dt=0.05)) for s in (5, 6)]
    command = np.random.default_rng(1).uniform(-2, 2, (2, teams[0].n_arms, 3))
    used, fresh = (Engine(teams[0], 2, physics=Physics(max_joint_speed=2.0), safety_filter=True) for _ in range(2))
    for engine in (used, fresh):
        engine.load_team(1, teams[1])
        engine.reset()
    for _ in range(6):
        used.step(command, 5)
    for kind in used.kinds:
        angles = np.cumsum(kind.q, axis=1) + kind.phi[:, None]
        np.testing.assert_allclose(kind.angles, np.stack([np.cos(angles), np.sin(angles)], axis=1), atol=1e-13)
    used.reset()
    for _ in range(4):
        a, b = used.step(command, 5), fresh.step(command, 5)
        for field in ("v_star", "tau", "min_clearance", "min_barrier", "qp_counts"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    for ka, kb in zip(used.kinds, fresh.kinds, strict=True):
        np.testing.assert_array_equal(ka.q, kb.q)


def test_obstacles_are_placed_per_copy_where_the_reference_puts_them() -> None:
    """The vector engine's obstacle centres and velocities (from each copy's capsules and clock) against
    pan1_env.bodies for every copy, different teams and clocks, after steps and a partial reset."""
    from pan1_env.vector import Pan1VectorEnv

    venv = Pan1VectorEnv("random", 3, random_options={**WHOLE, "obstacle_speed": (0.1, 0.3)}, control_dt=0.05,
                         physics_dt=0.01)
    venv.reset(seed=2)
    engine = venv.engine

    def check() -> None:
        for b in range(3):
            args = (engine.start_centers[b], engine.path_ends[b], engine.speeds[b], engine.elapsed[b])
            np.testing.assert_allclose(engine.centers[b], bodies.obstacle_centers(*args), atol=1e-12)
            np.testing.assert_allclose(engine.obstacle_velocities()[b], bodies.obstacle_velocities(*args), atol=1e-12)

    for step in range(40):
        venv.step(np.random.default_rng(step).uniform(-1, 1, venv.action_space.shape).astype(np.float32))
        if step == 20:
            engine.reset(np.array([1]))
            assert engine.elapsed[1] == 0.0 and engine.elapsed[0] > 0.0
        check()
    assert np.abs(engine.obstacle_velocities()).max() > 0.05


def test_reset_rewinds_the_obstacles() -> None:
    """A reset puts a copy's clock and moving obstacles back at their start, in the parallel env and in the
    vector env's autoreset."""
    from pan1_env.environment import parallel_env
    from pan1_env.vector import Pan1VectorEnv

    env = parallel_env("random", random_options={**WHOLE, "obstacle_speed": (0.1, 0.2)}, control_dt=0.01,
                       physics_dt=0.01)
    env.reset(seed=3)
    start = env.engine.centers.copy()
    for _ in range(20):
        env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    assert np.abs(env.engine.centers - start).max() > 0.01
    env.reset(seed=3)
    np.testing.assert_array_equal(env.engine.centers, start)
    assert env.engine.elapsed[0] == 0.0
    venv = Pan1VectorEnv("random", 2, random_options={**WHOLE, "obstacle_speed": (0.1, 0.2)}, control_dt=0.01,
                         physics_dt=0.01, max_steps=5)
    venv.reset(seed=0)
    for _ in range(5):
        venv.step(np.zeros(venv.action_space.shape, np.float32))
    np.testing.assert_array_equal(venv.engine.elapsed, 0.0)  # both copies ended and started anew
    for b, team in enumerate(venv.engine.teams):
        np.testing.assert_allclose(venv.engine.centers[b], team.obstacles.centers)


def test_a_sensing_radius_frees_the_reference_and_keeps_it_safe() -> None:
    """FilterParams(sensing_radius=…) on end-effector teams: the engine filters through the whole-arm rows
    with the end-effector as the body, so far obstacles no longer hold arms still. On 8 held-out random
    teams the reference (residual mode, zero action) forms more shapes than behind the paper's filter,
    with cost 0 in both."""
    from pan1_env.engine import FilterParams
    from pan1_env.vector import Pan1VectorEnv

    seeds = list(range(1_000_000, 1_000_008))
    results = {}
    for name, params in (("paper", True), ("sensing", FilterParams(0.5, 5.0, 0.0, sensing_radius=0.1))):
        venv = Pan1VectorEnv("random", len(seeds), safety_filter=params, action_mode="residual", max_steps=1200)
        if name == "sensing":
            assert venv.engine.whole_arm and all(kind.whole.sensing == 0.1 for kind in venv.engine.kinds)
        venv.reset(seed=seeds)
        cost = 0.0
        for _ in range(1200):
            _, _, _, truncated, infos = venv.step(np.zeros(venv.action_space.shape, np.float32))
            cost += infos["cost"].sum()
        results[name] = (int((infos["final_info"]["formation_error"] < 0.01).sum()), cost)
    assert results["paper"][1] == 0 and results["sensing"][1] == 0
    assert results["sensing"][0] > results["paper"][0], results


def test_shield_with_a_sensing_radius_stops_the_adversary() -> None:
    from pan1_env.baselines import AdversarialPolicy
    from pan1_env.environment import parallel_env
    from pan1_env.safety import FilterParams
    from pan1_env.wrappers import SafetyShield

    for name in ("paper_pa3_square", "random"):
        base = parallel_env(name, max_steps=200)
        env = SafetyShield(base, params=FilterParams.of(base.scenario, sensing_radius=0.1))
        adversary = AdversarialPolicy(base)
        obs, _ = env.reset(seed=1)
        assert base.engine.whole_arm
        cost = clearance = 0.0
        clearance = np.inf
        while env.agents:
            obs, _, _, _, infos = env.step(adversary(obs))
            cost += sum(info["cost"] for info in infos.values())
            clearance = min(clearance, *(info["min_clearance"] for info in infos.values()))
        assert cost == 0.0 and clearance >= 0.0
        assert clearance < 0.05, "the adversary should press the arms against the obstacles"


def test_bad_sensing_radius() -> None:
    from pan1_env.safety import FilterParams
    from pan1_env.scenario import load

    for bad in (-0.1, 0.0, np.inf, "far"):
        with pytest.raises(ValueError, match="FilterParams: sensing_radius must be"):
            FilterParams.of(load("paper_pa3_square"), sensing_radius=bad)


def _piqp_against_kernel(team, steps: int, command_scale: float, filter_params=True,
                         max_speed: float = 2.0) -> np.ndarray:
    """Step the same team with the kernel's QP and with qp_solver='piqp' under the same commands; every
    step's records agree (QP statuses per arm exactly): returns the kernel's status counts."""
    from pan1_env.engine import Engine, Physics

    engines = {s: Engine(team, physics=Physics(max_joint_speed=max_speed, qp_solver=s), safety_filter=filter_params)
               for s in ("active_set", "piqp")}
    rng = np.random.default_rng(0)
    counts = 0
    for _ in range(steps):
        command = rng.uniform(-command_scale, command_scale, (1, team.n_arms, 3))
        kernel, piqp = (e.step(command, 5) for e in engines.values())
        np.testing.assert_array_equal(piqp.qp_counts, kernel.qp_counts)
        np.testing.assert_array_equal(piqp.finite, kernel.finite)
        for field in ("v_star", "tau", "min_clearance", "min_barrier", "max_tracking_error"):
            np.testing.assert_allclose(getattr(piqp, field), getattr(kernel, field), atol=1e-7, err_msg=field)
        counts = counts + kernel.qp_counts.sum(axis=(0, 1))
    for a, b in zip(engines["active_set"].kinds, engines["piqp"].kinds, strict=True):
        np.testing.assert_allclose(b.q, a.q, atol=1e-8)
    return counts


@pytest.mark.parametrize("inter_arm, max_speed", [(True, 2.0), (False, 2.0), (True, np.inf)],
                         ids=["other_arms", "links_only", "no_speed_bound"])
def test_piqp_solves_the_whole_arm_rows_as_the_kernel_does(inter_arm: bool, max_speed: float) -> None:
    """qp_solver='piqp' with links and moving obstacles (and other arms): PIQP on the kernel's rows (and
    the kernel's fallback where PIQP finds them infeasible) gives the kernel's run, every arm's QP
    statuses included, over steps where the filter acts (and, with other arms, falls back)."""
    from pan1_env.random_scenario import RandomScenarioOptions, random_scenario

    team = random_scenario(np.random.default_rng(4), RandomScenarioOptions(
        bodies="links", link_radius=0.03, inter_arm=inter_arm, obstacle_speed=(0.1, 0.3), physics_dt=0.01,
        control_dt=0.05))
    counts = _piqp_against_kernel(team, 30, 2.0, max_speed=max_speed)
    assert counts[1] > 20, counts
    if inter_arm and max_speed < np.inf:
        assert counts[2] > 5, counts


@pytest.mark.parametrize("gate", [0.0, 0.05])
def test_piqp_with_a_sensing_radius_matches_the_kernel(gate: float) -> None:
    """The paper's scenario behind a filter with a sensing radius (end-effector rows through the
    whole-arm path), its edge hard or a smooth gate: PIQP and the kernel agree."""
    from dataclasses import replace

    from pan1_env.scenario import load

    team = load("paper_pa3_square")
    counts = _piqp_against_kernel(team, 20, 1.0, replace(team.filter, sensing_radius=0.1, gate=gate))
    assert counts[1] > 0, counts


def test_a_moving_layout_needs_the_obstacle_velocities() -> None:
    """ObservationLayout of a scenario with moving obstacles: build without velocities, or with the wrong
    shape, is a clear error."""
    from pan1_env.environment import parallel_env

    env = parallel_env("random", random_options={**WHOLE, "obstacle_speed": (0.1, 0.2)}, control_dt=0.01,
                       physics_dt=0.01)
    env.reset(seed=0)
    layout, eng = env.observation_layout, env.engine
    q, qd = eng.joint_state()
    args = (q, qd, eng.positions(), eng.bases, np.zeros((1, 0)), eng.centers, eng.radii, 2.0)
    for bad in (None, np.zeros((1, 2, 2)), np.zeros((3, 2))):
        with pytest.raises(ValueError, match="pass velocities of shape"):
            layout.build(*args, velocities=bad)
    assert len(layout.build(*args, velocities=eng.obstacle_velocities())) == len(layout.groups)


_GEOMETRY = """
import numpy as np
from pan1_env import kernels
K = kernels.team_geometry
P = np.zeros((1, 2, 3, 2))
K.kind_joints(np.zeros((2, 2)), np.ones((2, 2)), np.zeros((2, 2)), np.zeros(2), np.arange(2), np.arange(2), P)
K.inter_arm_clearance(P, 0.03, np.full((1, 2), np.inf))
"""


def test_the_geometry_helpers_say_once_that_they_compile(tmp_path) -> None:
    """A first whole-arm step compiles the engine's geometry passes for a few seconds: one notice on an
    empty cache, none once they are cached."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    first = subprocess.run([sys.executable, "-c", _GEOMETRY], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert first.stderr.count("compiling the whole-arm geometry helpers") == 1, first.stderr
    again = subprocess.run([sys.executable, "-c", _GEOMETRY], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "compil" not in again.stderr, again.stderr[-2000:]


@pytest.mark.parametrize("by_rate", [False, True], ids=["by_command", "by_rate"])
def test_farkas_certificate_skips_only_searches_that_fail(by_rate: bool) -> None:
    """least_violation skips a bisection step when Farkas weights prove its QP infeasible: on random
    infeasible problems (k = 1, 2, 3; 2k to 3k barrier rows, some inactive or of zero norm, and the speed
    box) the box is recognised, every step so certified is one the active-set search also finds
    infeasible, the certificate's bound never exceeds the least uniform violation the bisection finds,
    and the answer is the plain bisection's, also where the rows it keeps are feasible as given (then
    least_violation takes the bisection's steps without their searches). For either measure of violation: the
    rows relaxed per unit of norm or by the same rate."""
    from pan1_env.kernels.qp import STATUS_FALLBACK, _project_one

    K = kernels().last_resort
    rng = np.random.default_rng(11)
    certified = checked = settled = 0
    for trial in range(240):
        k = 1 + trial % 3
        n_rows, v_max = int(rng.integers(2 * k, 3 * k + 1)), 1.5
        A = np.zeros((n_rows + 2 * k, k))
        A[:n_rows] = rng.normal(size=(n_rows, k))
        if trial % 5 == 0:
            A[0] = 0.0  # a row of zero norm: dropped
        b = np.concatenate([rng.normal(-1.0, 1.0, n_rows), np.full(2 * k, v_max)])
        for t in range(k):
            A[n_rows + 2 * t, t], A[n_rows + 2 * t + 1, t] = 1.0, -1.0
        m = len(b)
        active = np.ones(m, bool)
        if trial % 7 == 0:
            active[n_rows - 1] = False
        v0 = rng.uniform(-3, 3, k)

        def scratch(m=m, k=k):
            return (np.empty(m, np.int64), np.empty(k, np.int64), np.empty((k, k)), np.empty(k), np.empty(k),
                    np.empty(k), np.empty((k, k)), np.empty(k), np.empty(m), np.empty(m))

        v = np.empty(k)
        if _project_one(v0, A, b, active, m, k, v, *scratch()) != STATUS_FALLBACK:
            continue  # feasible: no fallback
        got = np.empty(k)
        kept = active.copy()
        t = K.least_violation(v0, A, b.copy(), kept, m, k, 2 * k, by_rate, got, np.empty(m), np.empty(m), *scratch())
        # least_violation's choice of rows (kept): the plain bisection runs on the same rows
        assert K._speed_box(A, b, kept, m, k, 2 * k) == v_max
        norms = np.concatenate([np.linalg.norm(A[:n_rows], axis=1), np.zeros(2 * k)])
        w = (norms > 0).astype(float) if by_rate else norms  # each row's relaxation per unit of t
        weights = np.empty(m)
        bound = K._farkas_weights(A, b, norms, kept, m, k, 2 * k, v_max, by_rate, weights)
        lo, hi = 0.0, max([0.0] + [-b[j] / w[j] for j in range(n_rows) if norms[j] > 0])  # as least_violation
        settled += bound <= 0.0 and _project_one(v0, A, b, kept, m, k, v, *scratch()) != STATUS_FALLBACK
        for _ in range(20):
            mid = 0.5 * (lo + hi)
            relaxed = b + mid * w
            infeasible = _project_one(v0, A, relaxed, kept, m, k, v, *scratch()) == STATUS_FALLBACK
            if bound > 0.0 and K._certainly_infeasible(A, relaxed, norms, m, k, 2 * k, v_max, weights):
                certified += 1
                assert infeasible, (trial, mid)
            lo, hi = (mid, hi) if infeasible else (lo, mid)
        checked += 1
        assert bound <= hi + 1e-9, (trial, bound, hi)
        expected = np.empty(k)
        if _project_one(v0, A, b + hi * w, kept, m, k, expected, *scratch()) == STATUS_FALLBACK:
            expected[:] = 0.0
        assert t == pytest.approx(hi, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)
    assert checked > 50 and certified > 200 and settled > 5, (checked, certified, settled)
