"""The compiled engine (pan1_env.kernels) against the numpy reference formulas."""

import numpy as np
import pytest

from pan1_env import kernels
from pan1_env.cascade import cascade_rk4_step, cascade_terms, passive_momentum, reduced_jacobian
from pan1_env.control import backstepping_torque
from pan1_env.dynamics import ArmBatch, ArmParams, end_effector
from pan1_env.safety import project_velocity, rcbf_constraints


def _group(rng: np.random.Generator, n: int, passive: bool, count: int = 5):
    arms = []
    for _ in range(count):
        lengths = rng.uniform(0.2, 0.8, n)
        arms.append(ArmParams(masses=rng.uniform(0.1, 1.0, n), lengths=lengths,
                              com=lengths * rng.uniform(0.1, 1.0, n),
                              inertias=rng.uniform(1e-3, 1e-2, n),
                              base=rng.uniform(-1, 1, 2), phi=rng.uniform(-1, 1),
                              passive_first_joint=passive))
    batch = ArmBatch.stack(arms)
    q = rng.uniform(-np.pi, np.pi, (count, n))
    v = rng.uniform(-2, 2, (count, batch.n_actuated))
    return batch, q, v


def _terms(batch, q, v):
    A, k = v.shape
    out = dict(p=np.empty((A, 2)), Jbar=np.empty((A, 2, k)), Mc=np.empty((A, k, k)),
               Hc=np.empty((A, k)), mom=np.empty(A))
    kernels.group_terms(batch.lam, batch.lengths, batch.base, batch.phi, batch.passive_first_joint,
                        q, v, out["p"], out["Jbar"], out["Mc"], out["Hc"], out["mom"])
    return out


@pytest.mark.parametrize("n", [2, 3, 4, 5])
@pytest.mark.parametrize("passive", [True, False])
def test_group_terms_match_reference(n: int, passive: bool) -> None:
    rng = np.random.default_rng(n + 10 * passive)
    batch, q, v = _group(rng, n, passive)
    got = _terms(batch, q, v)
    ref = cascade_terms(batch, q, v)
    np.testing.assert_allclose(got["p"], end_effector(batch, q), atol=1e-12)
    np.testing.assert_allclose(got["Jbar"], reduced_jacobian(batch, q), atol=1e-12)
    np.testing.assert_allclose(got["Mc"], ref.M_comb, atol=1e-12)
    np.testing.assert_allclose(got["Hc"], ref.H_comb, atol=1e-12)
    if passive:
        np.testing.assert_allclose(got["mom"], passive_momentum(batch, q, ref.qd), atol=1e-12)
    else:
        assert np.all(np.isnan(got["mom"]))


@pytest.mark.parametrize("n", [2, 4])
@pytest.mark.parametrize("passive", [True, False])
def test_group_rk4_matches_reference(n: int, passive: bool) -> None:
    rng = np.random.default_rng(3 * n + passive)
    batch, q, v = _group(rng, n, passive)
    tau = rng.uniform(-1, 1, v.shape)
    q_out, v_out = np.empty_like(q), np.empty_like(v)
    kernels.group_rk4(batch.lam, batch.passive_first_joint, q, v, tau, 1e-3, q_out, v_out)
    q_ref, v_ref = cascade_rk4_step(batch, q, v, tau, 1e-3)
    np.testing.assert_allclose(q_out, q_ref, atol=1e-12)
    np.testing.assert_allclose(v_out, v_ref, atol=1e-10)


@pytest.mark.parametrize("filter_on", [False, True])
def test_group_control_matches_reference(filter_on: bool) -> None:
    rng = np.random.default_rng(11)
    batch, q, v = _group(rng, 4, True, count=6)
    t = _terms(batch, q, v)
    A, k = v.shape
    # obstacles placed near each end-effector so rows bind
    centers = t["p"][:3] + rng.normal(scale=0.15, size=(3, 2))
    radii = np.full(3, 0.05)
    mask = rng.random((A, 3)) < 0.7
    v_ref = rng.normal(scale=2.0, size=(A, k))
    v_prev = rng.normal(size=(A, k))
    kappa, eps, ke, dt = 0.5, 5.0, 100.0, 1e-3
    v_star, tau = np.empty((A, k)), np.empty((A, k))
    status, min_h = np.empty(A, dtype=np.int64), np.empty(A)
    kernels.group_control(t["p"], t["Jbar"], t["Mc"], t["Hc"], v, v_ref, v_prev, True, filter_on,
                          centers, radii, mask, kappa, eps, 0.0, ke, dt, v_star, tau, status, min_h)
    if filter_on:
        A_rows, b_rows, h = rcbf_constraints(t["p"], t["Jbar"], centers, radii, kappa, eps,
                                             active=mask)
        expected = project_velocity(v_ref, A_rows, b_rows, solver="piqp")
        np.testing.assert_allclose(v_star, expected.v, atol=1e-6)
        np.testing.assert_array_equal(status, expected.status)
        np.testing.assert_allclose(min_h, np.where(mask, h, np.inf).min(axis=-1))
        assert np.any(status == 1), "the test should exercise active constraints"
    else:
        np.testing.assert_array_equal(v_star, v_ref)
    tau_ref = backstepping_torque(t["Mc"], t["Hc"], v, v_star, (v_star - v_prev) / dt, ke)
    np.testing.assert_allclose(tau, tau_ref, rtol=1e-9, atol=1e-9)
