"""The cascaded (reduced-order) model of docs/MODEL.md §2–3 against the full-order model M q̈ + C q̇ = τ.

The reference quantities are built here from ``mass_matrix`` and ``coriolis_matrix`` (both checked
against Pinocchio in test_dynamics_pinocchio.py), never from the cascade module's own terms.
"""

import numpy as np
import pytest

from pan1_env.cascade import (
    cascade_rhs,
    cascade_rk4_step,
    cascade_terms,
    f1,
    full_order_rhs,
    full_order_rk4_step,
    full_torque,
    g1,
    joint_velocity,
    passive_momentum,
    passive_velocity_map,
    reduced_jacobian,
)
from pan1_env.dynamics import (
    ArmBatch,
    ArmParams,
    coriolis_matrix,
    jacobian,
    kinetic_energy,
    mass_matrix,
)

DT = 1e-3
T_END = 5.0
N_STEPS = int(round(T_END / DT))
N_ARMS = 4  # arms integrated side by side (an ArmBatch) in each run


def _random_arm(rng: np.random.Generator, n: int, passive: bool = True) -> ArmParams:
    lengths = rng.uniform(0.2, 0.6, n)
    return ArmParams(
        masses=rng.uniform(0.1, 1.0, n),
        lengths=lengths,
        com=lengths * rng.uniform(0.2, 0.9, n),
        inertias=rng.uniform(1e-3, 2e-2, n),
        base=rng.uniform(-1.0, 1.0, 2),
        phi=float(rng.uniform(-np.pi, np.pi)),
        passive_first_joint=passive,
    )


def _schur(M: np.ndarray) -> np.ndarray:
    """M_aa − M_au M_ua / M_uu, written out for one (n, n) matrix."""
    return M[1:, 1:] - np.outer(M[1:, 0], M[0, 1:]) / M[0, 0]


def _g0_reference(M: np.ndarray) -> np.ndarray:
    n = M.shape[0]
    return np.vstack([-M[0, 1:] / M[0, 0], np.eye(n - 1)])


# --------------------------------------------------------------------------- simulation runs


def _simulate(n: int, passive: bool, seed: int) -> dict:
    """Integrate the cascaded and the full-order model side by side from rest under the same
    smooth active torques (small sinusoids, zero-order hold over each RK4 step)."""
    rng = np.random.default_rng(seed)
    arms = [_random_arm(rng, n, passive) for _ in range(N_ARMS)]
    batch = ArmBatch.stack(arms)
    k = batch.n_actuated
    amp = rng.uniform(0.005, 0.03, (N_ARMS, k))
    omega = rng.uniform(0.5, 3.0, (N_ARMS, k))
    phase = rng.uniform(0.0, 2 * np.pi, (N_ARMS, k))

    q0 = rng.uniform(-np.pi, np.pi, (N_ARMS, n))
    q_c, v = q0.copy(), np.zeros((N_ARMS, k))
    q_f, qd_f = q0.copy(), np.zeros((N_ARMS, n))
    max_dq = max_mom_c = max_mom_f = 0.0
    max_speed = 0.0
    for step in range(N_STEPS):
        tau_a = amp * np.sin(omega * step * DT + phase)
        q_c, v = cascade_rk4_step(batch, q_c, v, tau_a, DT)
        q_f, qd_f = full_order_rk4_step(batch, q_f, qd_f, full_torque(batch, tau_a), DT)
        max_dq = max(max_dq, float(np.abs(q_c - q_f).max()))
        if passive and step % 10 == 9:
            # The cascade's joint velocity is what its integrator uses: q̇ = g0(q) v.
            qd_c = cascade_terms(batch, q_c, v).qd
            M_c, M_f = mass_matrix(batch, q_c), mass_matrix(batch, q_f)
            max_mom_c = max(max_mom_c, float(np.abs(np.einsum("bj,bj->b", M_c[:, 0], qd_c)).max()))
            max_mom_f = max(max_mom_f, float(np.abs(np.einsum("bj,bj->b", M_f[:, 0], qd_f)).max()))
        max_speed = max(max_speed, float(np.abs(qd_f).max()))
    return dict(max_dq=max_dq, max_mom_c=max_mom_c, max_mom_f=max_mom_f, max_speed=max_speed)


@pytest.fixture(scope="module", params=[2, 3, 4, 5], ids=lambda n: f"PA{n - 1}")
def pa_run(request) -> dict:
    return _simulate(request.param, passive=True, seed=40 + request.param)


@pytest.fixture(scope="module")
def fa_run() -> dict:
    return _simulate(3, passive=False, seed=77)


def test_cascade_matches_full_order_pa(pa_run: dict) -> None:
    # The run must actually move (otherwise agreement is trivial): joint speeds of ~1 rad/s.
    assert pa_run["max_speed"] > 0.5
    assert pa_run["max_dq"] < 1e-6


def test_cascade_matches_full_order_fully_actuated(fa_run: dict) -> None:
    assert fa_run["max_speed"] > 0.5
    assert fa_run["max_dq"] < 1e-6


def test_passive_momentum_zero_in_cascade(pa_run: dict) -> None:
    # Σ_α M_1α q̇_α with q̇ = g0 v is zero by construction: only round-off (measured ≤ 2e-15).
    assert pa_run["max_mom_c"] < 1e-9


def test_passive_momentum_small_in_full_order(pa_run: dict) -> None:
    # The full-order integrator carries the momentum as a state-dependent quantity M_1(q)·q̇, which
    # RK4 does not conserve exactly: it drifts by the integrator's global error, O(dt⁴). Measured
    # at dt = 1 ms over 5 s (checked every 10th step) with joint speeds up to ~7 rad/s: 2.4e-12
    # (n = 5), ≤ 2e-13 (n ≤ 4); other random draws with faster motions reached 4e-11. The bound
    # 1e-9 leaves a factor ≥ 25 on all of these; the dt-scaling test below shows the drift is
    # integration error, not a modelling error (which would not shrink with dt).
    assert pa_run["max_mom_f"] < 1e-9


def test_full_order_momentum_drift_is_integration_error() -> None:
    """Halving dt must shrink the full-order momentum drift by about 2⁴ = 16 (RK4)."""
    rng = np.random.default_rng(5)
    arms = [_random_arm(rng, 4) for _ in range(N_ARMS)]
    batch = ArmBatch.stack(arms)
    q0 = rng.uniform(-np.pi, np.pi, (N_ARMS, 4))
    qd_a = rng.uniform(-4.0, 4.0, (N_ARMS, 3))
    # Start on the zero-momentum manifold, with large speeds so that the drift is well above
    # round-off, and no torque.
    qd0 = np.stack(
        [_g0_reference(mass_matrix(arm, q0[i])) @ qd_a[i] for i, arm in enumerate(arms)]
    )

    def drift(dt: float) -> float:
        q, qd = q0.copy(), qd0.copy()
        worst = 0.0
        for _ in range(int(round(1.0 / dt))):
            q, qd = full_order_rk4_step(batch, q, qd, np.zeros((N_ARMS, 4)), dt)
            worst = max(worst, float(np.abs(passive_momentum(batch, q, qd)).max()))
        return worst

    coarse, fine = drift(4e-3), drift(2e-3)
    assert fine > 1e-13, "drift at round-off level: the ratio below would be meaningless"
    assert 6.0 < coarse / fine < 40.0


# --------------------------------------------------------------------------- algebraic identities


@pytest.mark.parametrize("n", [2, 3, 4, 5, 6])
def test_cascade_terms_match_direct_formulas(n: int) -> None:
    rng = np.random.default_rng(300 + n)
    for _ in range(20):
        arm = _random_arm(rng, n)
        q = rng.uniform(-np.pi, np.pi, n)
        v = rng.uniform(-2.0, 2.0, n - 1)
        tau_a = rng.uniform(-1.0, 1.0, n - 1)
        M = mass_matrix(arm, q)
        g0_ref = _g0_reference(M)
        Mc_ref = _schur(M)

        t = cascade_terms(arm, q, v)
        np.testing.assert_allclose(t.M, M, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(t.M_comb, Mc_ref, rtol=1e-12, atol=1e-14)
        # The Schur complement is also the reduced inertia g0ᵀ M g0.
        np.testing.assert_allclose(g0_ref.T @ M @ g0_ref, Mc_ref, rtol=1e-10, atol=1e-13)
        np.testing.assert_allclose(t.g0, g0_ref, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(passive_velocity_map(arm, q), g0_ref, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(g1(arm, q), np.linalg.inv(Mc_ref), rtol=1e-9, atol=1e-9)

        # g0 makes the passive momentum zero, for any v.
        qd = g0_ref @ v
        np.testing.assert_allclose(t.qd, qd, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(joint_velocity(arm, q, v), qd, rtol=1e-12, atol=1e-14)
        scale = np.abs(M[0]).max() * np.abs(qd).max()
        assert abs(M[0] @ (t.g0 @ v)) <= 1e-13 * scale
        assert abs(passive_momentum(arm, q, t.g0 @ v)) <= 1e-13 * scale

        # v̇ = f1 + g1 τ_a equals the full-order q̈ (restricted to the active joints) on the
        # zero-momentum manifold; q̈ from M q̈ = [0, τ_a] − C(q, q̇) q̇ with C the matrix form.
        qdd = np.linalg.solve(M, np.concatenate([[0.0], tau_a]) - coriolis_matrix(arm, q, qd) @ qd)
        vdot = f1(arm, q, v) + g1(arm, q) @ tau_a
        np.testing.assert_allclose(vdot, qdd[1:], rtol=1e-9, atol=1e-9)
        _, vdot_rhs = cascade_rhs(arm, q, v, tau_a)
        np.testing.assert_allclose(vdot_rhs, qdd[1:], rtol=1e-9, atol=1e-9)
        _, qdd_full = full_order_rhs(arm, q, qd, full_torque(arm, tau_a))
        np.testing.assert_allclose(qdd_full, qdd, rtol=1e-9, atol=1e-9)
        # ... and the passive joint's acceleration keeps the momentum zero: d/dt (M_1 q̇) = 0
        # means q̈_1 is consistent with q̇_1 = g0[0] v differentiated along the motion.
        h = 1e-6
        q_p, q_m = q + h * qd, q - h * qd
        v_p, v_m = v + h * vdot, v - h * vdot
        qd1_p = _g0_reference(mass_matrix(arm, q_p))[0] @ v_p
        qd1_m = _g0_reference(mass_matrix(arm, q_m))[0] @ v_m
        assert abs((qd1_p - qd1_m) / (2 * h) - qdd[0]) < 1e-6 * (1.0 + abs(qdd[0]))

        # Reduced Jacobian J̄ = J g0.
        np.testing.assert_allclose(reduced_jacobian(arm, q), jacobian(arm, q) @ g0_ref, atol=1e-12)

        # The cascade's kinetic energy is ½ vᵀ M_comb v = ½ q̇ᵀ M q̇.
        assert 0.5 * v @ Mc_ref @ v == pytest.approx(0.5 * qd @ M @ qd, rel=1e-10)


def test_fully_actuated_terms_are_the_full_model() -> None:
    rng = np.random.default_rng(11)
    for n in (2, 3, 5):
        arm = _random_arm(rng, n, passive=False)
        q = rng.uniform(-np.pi, np.pi, n)
        v = rng.uniform(-2.0, 2.0, n)
        tau = rng.uniform(-1.0, 1.0, n)
        M = mass_matrix(arm, q)
        t = cascade_terms(arm, q, v)
        np.testing.assert_allclose(t.g0, np.eye(n), atol=0)
        np.testing.assert_allclose(t.M_comb, M, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(t.H_comb, coriolis_matrix(arm, q, v) @ v, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(full_torque(arm, tau), tau, atol=0)
        qdd = np.linalg.solve(M, tau - coriolis_matrix(arm, q, v) @ v)
        np.testing.assert_allclose(cascade_rhs(arm, q, v, tau)[1], qdd, rtol=1e-9, atol=1e-9)


def test_full_torque_and_shapes() -> None:
    rng = np.random.default_rng(12)
    arm = _random_arm(rng, 4)
    np.testing.assert_array_equal(full_torque(arm, [1.0, 2.0, 3.0]), [0.0, 1.0, 2.0, 3.0])
    batch_tau = rng.normal(size=(3, 3))
    out = full_torque(arm, batch_tau)
    assert out.shape == (3, 4)
    np.testing.assert_array_equal(out[:, 0], 0.0)
    np.testing.assert_array_equal(out[:, 1:], batch_tau)
    with pytest.raises(ValueError):
        joint_velocity(arm, np.zeros(4), np.zeros(4))  # v has n − 1 entries for a PA arm


def test_batched_cascade_equals_per_arm() -> None:
    rng = np.random.default_rng(13)
    arms = [_random_arm(rng, 3) for _ in range(4)]
    batch = ArmBatch.stack(arms)
    q = rng.uniform(-np.pi, np.pi, (4, 3))
    v = rng.uniform(-1.0, 1.0, (4, 2))
    tau = rng.uniform(-0.1, 0.1, (4, 2))
    qb, vb = cascade_rk4_step(batch, q, v, tau, 0.01)
    for i, arm in enumerate(arms):
        qi, vi = cascade_rk4_step(arm, q[i], v[i], tau[i], 0.01)
        np.testing.assert_allclose(qb[i], qi, rtol=0, atol=1e-13)
        np.testing.assert_allclose(vb[i], vi, rtol=0, atol=1e-13)
    # Passing precomputed terms gives the same step.
    q2, v2 = cascade_rk4_step(batch, q, v, tau, 0.01, terms=cascade_terms(batch, q, v))
    np.testing.assert_allclose(q2, qb, rtol=0, atol=1e-14)
    np.testing.assert_allclose(v2, vb, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------- energy


def _energy_drift(n: int, seed: int, dt: float, t_end: float) -> tuple[float, float]:
    """Largest relative change of ½ q̇ᵀ M q̇ over a torque-free full-order RK4 run of a batch of
    random arms, and the largest joint speed seen."""
    rng = np.random.default_rng(seed)
    batch = ArmBatch.stack([_random_arm(rng, n) for _ in range(N_ARMS)])
    q = rng.uniform(-np.pi, np.pi, (N_ARMS, n))
    qd = rng.uniform(-1.0, 1.0, (N_ARMS, n))
    E0 = kinetic_energy(batch, q, qd)
    worst = speed = 0.0
    for _ in range(int(round(t_end / dt))):
        q, qd = full_order_rk4_step(batch, q, qd, np.zeros((N_ARMS, n)), dt)
        worst = max(worst, float(np.abs(kinetic_energy(batch, q, qd) / E0 - 1.0).max()))
        speed = max(speed, float(np.abs(qd).max()))
    return worst, speed


@pytest.mark.parametrize("n", [3, 5])
def test_kinetic_energy_conserved_without_torque(n: int) -> None:
    """No gravity and no torque: ½ q̇ᵀ M q̇ is a first integral of the full-order model.

    RK4 at dt = 1 ms over 5 s from random speeds in [−1, 1] rad/s (peak speeds then reach
    ~3 rad/s for n = 3 and ~14 rad/s for n = 5 as light distal links whip): measured relative
    drift 1e-12 (n = 3) and 2.2e-8 (n = 5). The drift grows like (peak speed · dt)⁴: doubling the
    initial speeds gives 1e-10 and 1.1e-6. Bound 1e-6, ~45× the measured worst case; a wrong sign or
    factor in C (a non-conservative model) changes the energy by O(1) within a second.
    """
    worst, speed = _energy_drift(n, seed=500 + n, dt=DT, t_end=T_END)
    assert speed > 1.0  # it really moved
    assert worst < 1e-6


def test_energy_drift_is_fourth_order_in_dt() -> None:
    """The energy error is RK4's truncation error: halving dt divides it by about 16."""
    coarse, _ = _energy_drift(4, seed=504, dt=4e-3, t_end=2.5)
    fine, _ = _energy_drift(4, seed=504, dt=2e-3, t_end=2.5)
    assert fine > 1e-13
    assert 8.0 < coarse / fine < 32.0
