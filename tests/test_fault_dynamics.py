"""A fault in motion, checked independently of the cascade it extends (docs/MODEL.md §7).

The full model M q̈ + C q̇ = τ − b q̇₁ e₁ is the reference: its M and C are checked against Pinocchio
in test_dynamics_pinocchio.py, and here its damped forward dynamics against Pinocchio's ABA. Against
it: the passive momentum's law (conserved without damping, ṗ₁ = −b q̇₁ with it) and the reduced model
with p₁ ≠ 0.
"""

import dataclasses

import numpy as np
import pytest
from arms import random_arm

from pan1_env.cascade import (
    cascade_terms,
    end_effector_drift,
    full_order_rk4_step,
    full_torque,
    joint_velocity,
    momentum_cascade_rhs,
    momentum_cascade_rk4_step,
    passive_momentum,
    passive_momentum_rate,
    reduced_jacobian,
    reduced_state,
)
from pan1_env.dynamics import (
    ArmBatch,
    ArmParams,
    coriolis_vector,
    damping_torque,
    faulted,
    forward_dynamics,
    jacobian,
    mass_matrix,
)


def _rod_arm(rng: np.random.Generator, n: int, damping: float = 0.0) -> ArmParams:
    """A fully actuated arm of rod-like links (I ≈ m L²/12), so its speeds stay moderate: the test
    measures conservation, not how RK4 copes with a stiff, feather-light distal link."""
    m = rng.uniform(0.5, 2.0, n)
    L = rng.uniform(0.3, 1.0, n)
    return ArmParams(masses=m, lengths=L, com=L * rng.uniform(0.3, 0.7, n),
                     inertias=m * L**2 / 12 * rng.uniform(0.5, 1.5, n), passive_first_joint=False,
                     passive_damping=damping)


def _moving_fault(rng: np.random.Generator, n: int, arms: int, damping: float, dt: float, t_f: float = 1.0):
    """B arms driven along a moving posture under full actuation until t_f: (batch, q, q̇) at the fault."""
    batch = ArmBatch.stack([_rod_arm(rng, n, damping) for _ in range(arms)])
    q0 = rng.uniform(-1.0, 1.0, (arms, n))
    q, qd = q0.copy(), np.zeros((arms, n))
    for k in range(int(round(t_f / dt))):
        t = k * dt
        target = q0 + 0.8 * np.sin(2.0 * t + np.arange(n))
        # Computed torque: every joint acts (so ṗ₁ = τ₁ ≠ 0) and the gains scale with the inertia.
        acc = 4.0 * (target - q) - 4.0 * qd
        tau = np.einsum("bij,bj->bi", mass_matrix(batch, q), acc) + coriolis_vector(batch, q, qd)
        q, qd = full_order_rk4_step(batch, q, qd, tau, dt)
    return batch, q, qd


def _after_fault_torque(arm, q: np.ndarray, qd: np.ndarray, qa_hold: np.ndarray, t: float) -> np.ndarray:
    """Actuated torques after the fault, joint 1 getting none: a PD on joints 2..n plus a wobble,
    shaped by the inertia the actuated joints feel once joint 1 swings free (the Schur complement
    of M_11, formed here from M) so that the loop has no stiff mode for RK4 to trip on."""
    M = mass_matrix(arm, q)
    felt = M[:, 1:, 1:] - M[:, 1:, :1] * M[:, :1, 1:] / M[:, :1, :1]
    acc = 4.0 * (qa_hold - q[:, 1:]) - 2.0 * qd[:, 1:] + 0.5 * np.sin(1.7 * t)
    tau_a = np.einsum("bij,bj->bi", felt, acc)
    return np.concatenate([np.zeros((q.shape[0], 1)), tau_a], axis=1)


# ---------------------------------------------------------------- the parameter and the fault

@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "much"])
def test_bad_damping_is_a_value_error_naming_it(bad) -> None:
    arm = random_arm(np.random.default_rng(0), 3)
    with pytest.raises(ValueError, match="passive_damping"):
        dataclasses.replace(arm, passive_damping=bad)


def test_damping_defaults_to_zero_and_is_part_of_the_arm() -> None:
    arm = random_arm(np.random.default_rng(1), 3, passive=True)
    assert arm.passive_damping == 0.0
    damped = dataclasses.replace(arm, passive_damping=0.5)
    assert damped != arm and damped == dataclasses.replace(arm, passive_damping=0.5)
    batch = ArmBatch.stack([arm, damped])
    np.testing.assert_array_equal(batch.passive_damping, [0.0, 0.5])


def test_a_fault_makes_joint_1_passive_and_keeps_the_rest() -> None:
    arm = dataclasses.replace(random_arm(np.random.default_rng(2), 4, passive=False), passive_damping=0.3)
    hit = faulted(arm)
    assert hit.passive_first_joint and hit.n_actuated == 3
    assert dataclasses.replace(hit, passive_first_joint=False) == arm
    with pytest.raises(ValueError, match="passive already"):
        faulted(hit)


def test_damping_acts_only_on_a_passive_joint_1() -> None:
    arm = dataclasses.replace(random_arm(np.random.default_rng(3), 3, passive=False), passive_damping=0.7)
    qd = np.array([[2.0, -1.0, 0.5], [-3.0, 0.0, 1.0]])
    np.testing.assert_array_equal(damping_torque(arm, qd), 0.0)
    np.testing.assert_allclose(damping_torque(faulted(arm), qd), [[-1.4, 0, 0], [2.1, 0, 0]], rtol=1e-15)


# ---------------------------------------------------------------- the passive momentum's law

#: RK4 step for the 100-s conservation run (see the test's docstring for why this one).
CONSERVATION_DT = 0.01


def test_momentum_is_conserved_for_100_s_after_a_frictionless_fault() -> None:
    """b = 0, τ₁ = 0 from t_f = 1 s on, the arm moving at the fault: p₁ stays p₁(t_f) to 1e-9 relative.

    p₁ is not an invariant RK4 keeps exactly, so the step sets the drift: with these arms (joint speeds
    ≈ 0.5 rad/s) it is 2.2e-9 at dt = 0.02, 1.3e-10 at 0.01 and 7.8e-12 at 0.005 (RK4's h⁴: ÷16 per
    halving), so 0.01 keeps a margin of ~8 under the bound.
    """
    rng = np.random.default_rng(34)
    dt = CONSERVATION_DT
    batch, q, qd = _moving_fault(rng, 3, arms=3, damping=0.0, dt=dt)
    # Before the fault every joint acts and ṗ₁ = τ₁: the arms must be moving with a momentum.
    hit = faulted(batch)
    p_f = passive_momentum(hit, q, qd)
    assert np.all(np.abs(p_f) > 0.1), p_f
    qa_hold = q[:, 1:].copy()
    worst = 0.0
    for k in range(int(round(100.0 / dt))):
        q, qd = full_order_rk4_step(hit, q, qd, _after_fault_torque(hit, q, qd, qa_hold, k * dt), dt)
        if k % 50 == 0:
            worst = max(worst, float(np.max(np.abs(passive_momentum(hit, q, qd) / p_f - 1.0))))
    worst = max(worst, float(np.max(np.abs(passive_momentum(hit, q, qd) / p_f - 1.0))))
    assert worst <= 1e-9, worst
    # The arm cannot come to rest: p₁ ≠ 0 keeps it turning (q̇ = 0 would give p₁ = 0).
    assert np.all(np.abs(qd[:, 0]) > 1e-3)


def _pinocchio_chain(arm: ArmParams):
    """Pinocchio's planar chain of revolute-z joints (no gravity): the same build as
    test_dynamics_pinocchio.py, where its (x, y) is checked to be our (y, x)."""
    pin = pytest.importorskip("pinocchio")
    model = pin.Model()
    model.gravity = pin.Motion.Zero()
    parent = 0
    for a in range(arm.n_links):
        offset = 0.0 if a == 0 else float(arm.lengths[a - 1])
        parent = model.addJoint(parent, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([offset, 0.0, 0.0])),
                                f"j{a}")
        inertia = pin.Inertia(float(arm.masses[a]), np.array([float(arm.com[a]), 0.0, 0.0]),
                              np.diag([1e-3, 1e-3, float(arm.inertias[a])]))
        model.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    return pin, model, model.createData()


@pytest.mark.parametrize("n", [2, 3, 4, 6])
def test_damped_faulted_dynamics_match_pinocchio_aba(n: int) -> None:
    """q̈ = M⁻¹(τ − C q̇ − b q̇₁ e₁) against Pinocchio's articulated-body algorithm with the torque
    −b q̇₁ added at joint 1 (ABA does not read model.damping, so the torque is applied by hand)."""
    rng = np.random.default_rng(340 + n)
    for _ in range(20):
        b = float(rng.uniform(0.05, 2.0))
        arm = faulted(dataclasses.replace(random_arm(rng, n, passive=False), passive_damping=b))
        pin, model, data = _pinocchio_chain(arm)
        q = rng.uniform(-np.pi, np.pi, n)
        qd = rng.uniform(-3.0, 3.0, n)
        tau = full_torque(arm, rng.uniform(-2.0, 2.0, n - 1))
        tau_pin = tau.copy()
        tau_pin[0] -= b * qd[0]
        ref = pin.aba(model, data, q, qd, tau_pin)
        got = forward_dynamics(arm, q, qd, tau)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
        # The damping is not a rounding-level term here: without it the answers differ.
        assert np.abs(forward_dynamics(dataclasses.replace(arm, passive_damping=0.0), q, qd, tau) - ref).max() \
            > 1e-6 * np.abs(ref).max()


def test_damped_momentum_follows_its_law_along_a_trajectory() -> None:
    """b > 0 after a fault in motion: ṗ₁ (central differences of p₁ along the RK4 trajectory) equals
    −b q̇₁, and the momentum decays."""
    rng = np.random.default_rng(35)
    dt = 1e-3
    batch, q, qd = _moving_fault(rng, 4, arms=3, damping=0.8, dt=0.01)
    hit = faulted(batch)
    qa_hold = q[:, 1:].copy()
    p, rate, law = [], [], []
    for k in range(int(round(6.0 / dt))):
        tau = _after_fault_torque(hit, q, qd, qa_hold, k * dt)
        p.append(passive_momentum(hit, q, qd))
        law.append(-hit.passive_damping * qd[:, 0])
        rate.append(passive_momentum_rate(hit, qd, tau))
        q, qd = full_order_rk4_step(hit, q, qd, tau, dt)
    p, law, rate = np.array(p), np.array(law), np.array(rate)
    np.testing.assert_allclose(rate, law, rtol=0, atol=1e-15)  # the function states the same law
    # Central differences are O(dt²): ≈ 1.3e-5 of the scale just after the fault's torque jump, 3e-7
    # later. A missing, doubled or sign-flipped damping term is off by the whole scale.
    dp = (p[2:] - p[:-2]) / (2 * dt)
    scale = np.abs(law).max()
    assert np.abs(dp - law[1:-1]).max() <= 1e-4 * scale, np.abs(dp - law[1:-1]).max() / scale
    assert np.all(np.abs(p[-1]) < 0.75 * np.abs(p[0])), (p[0], p[-1])  # ≈ 0.55 after 6 s


# ---------------------------------------------------------------- the reduced model with p₁ ≠ 0

@pytest.mark.parametrize("b", [0.0, 0.6])
@pytest.mark.parametrize("n", [2, 3, 5])
def test_reduced_model_with_momentum_is_the_full_model_at_a_state(n: int, b: float) -> None:
    """At random states of a faulted arm: q̇, v̇, ṗ₁ and the end-effector velocity of the reduced
    model (q, v, p₁) equal the full model's."""
    rng = np.random.default_rng(360 + n)
    arms = [faulted(dataclasses.replace(random_arm(rng, n, passive=False), passive_damping=b)) for _ in range(6)]
    batch = ArmBatch.stack(arms)
    q = rng.uniform(-np.pi, np.pi, (6, n))
    qd = rng.uniform(-2.0, 2.0, (6, n))
    tau = full_torque(batch, rng.uniform(-1.0, 1.0, (6, n - 1)))
    v, p1 = reduced_state(batch, q, qd)
    assert np.all(np.abs(p1) > 1e-3)  # a state in motion, not Lemma 1's p₁ = 0
    scale = np.abs(qd).max()
    np.testing.assert_allclose(joint_velocity(batch, q, v, p1), qd, rtol=0, atol=1e-12 * scale)
    qd_r, vdot, p1dot = momentum_cascade_rhs(batch, q, v, p1, tau[:, 1:])
    qdd = forward_dynamics(batch, q, qd, tau)
    np.testing.assert_allclose(qd_r, qd, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(vdot, qdd[:, 1:], rtol=0, atol=1e-10 * np.abs(qdd).max())
    np.testing.assert_allclose(p1dot, passive_momentum_rate(batch, qd, tau), rtol=0, atol=1e-15)
    # ṗ_end = J q̇ = J̄ v + J₁ p₁ / M_11: the drift is the whole difference from Lemma 1's J̄ v.
    pe_dot = np.einsum("bij,bj->bi", jacobian(batch, q), qd)
    pe_red = np.einsum("bij,bj->bi", reduced_jacobian(batch, q), v) + end_effector_drift(batch, q, p1)
    np.testing.assert_allclose(pe_red, pe_dot, rtol=0, atol=1e-12 * np.abs(pe_dot).max())
    # p₁ = 0 and b = 0 is Lemma 1's cascade, bit for bit.
    undamped = ArmBatch.stack([dataclasses.replace(arm, passive_damping=0.0) for arm in arms])
    old, new = cascade_terms(undamped, q, v), cascade_terms(undamped, q, v, np.zeros(6))
    for a, c in zip(old, new, strict=True):
        np.testing.assert_array_equal(a, c)


#: RK4 step of the side-by-side run of the reduced and the full model
REDUCED_DT = 1e-3


@pytest.mark.parametrize("b", [0.0, 0.6])
@pytest.mark.parametrize("n", [2, 4])
def test_reduced_model_with_momentum_tracks_the_full_model(n: int, b: float) -> None:
    """From one state in motion (p₁ ≠ 0) and under the same actuated torques, RK4 on (q, v, p₁) and
    RK4 on (q, q̇) agree to 1e-9 over 3 s. Both are RK4 of the same ODE in other coordinates, so
    they differ by the two truncation errors: ≤ 5e-11 at dt = 1e-3 (7e-10 at 2e-3, 3e-8 at 5e-3)."""
    rng = np.random.default_rng(370 + n)
    batch, q, qd = _moving_fault(rng, n, arms=3, damping=b, dt=0.01)
    hit = faulted(batch)
    v, p1 = reduced_state(hit, q, qd)
    assert np.all(np.abs(p1) > 0.1), p1
    p_scale = np.abs(p1).max()
    qr = q.copy()
    for k in range(int(round(3.0 / REDUCED_DT))):
        tau = full_torque(hit, 0.3 * np.sin(2.3 * k * REDUCED_DT + np.arange(n - 1)) * np.ones((3, 1)))
        q, qd = full_order_rk4_step(hit, q, qd, tau, REDUCED_DT)
        qr, v, p1 = momentum_cascade_rk4_step(hit, qr, v, p1, tau[:, 1:], REDUCED_DT)
    np.testing.assert_allclose(qr, q, rtol=0, atol=1e-9)
    np.testing.assert_allclose(joint_velocity(hit, qr, v, p1), qd, rtol=0, atol=1e-9)
    np.testing.assert_allclose(p1, passive_momentum(hit, q, qd), rtol=0, atol=1e-9 * p_scale)


def test_lemma_1_cascade_refuses_a_damped_passive_arm() -> None:
    """With b > 0 the momentum leaves zero, so the p₁ = 0 cascade would be silently wrong."""
    from pan1_env.cascade import cascade_rk4_step

    arm = dataclasses.replace(random_arm(np.random.default_rng(5), 3, passive=True), passive_damping=0.2)
    with pytest.raises(ValueError, match="momentum_cascade_rk4_step"):
        cascade_rk4_step(arm, np.zeros(3), np.ones(2), np.zeros(2), 0.01)
