"""Property-based tests (hypothesis) of the model's structural guarantees.

Set ``PAN1_HYPOTHESIS_EXAMPLES`` to run more examples than the default.
"""

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from pan1_env.cascade import cascade_terms, passive_velocity_map, reduced_jacobian
from pan1_env.control import nominal_velocity
from pan1_env.dynamics import ArmParams, end_effector, mass_matrix
from pan1_env.formation import (
    Formation,
    edge_errors,
    edge_vectors,
    formation_gradient,
    formation_potential,
)
from pan1_env.safety import QPStatus, project_velocity

EXAMPLES = int(os.environ.get("PAN1_HYPOTHESIS_EXAMPLES", "75"))
SETTINGS = settings(
    max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)

finite = dict(allow_nan=False, allow_infinity=False, allow_subnormal=False)
angles = st.floats(-4 * np.pi, 4 * np.pi, **finite)


@st.composite
def arms(draw, n_min: int = 2, n_max: int = 6, passive: bool | None = None) -> ArmParams:
    n = draw(st.integers(n_min, n_max))
    vec = lambda lo, hi: draw(arrays(float, n, elements=st.floats(lo, hi, **finite)))  # noqa: E731
    lengths = vec(0.05, 2.0)
    return ArmParams(
        masses=vec(0.01, 5.0),
        lengths=lengths,
        com=lengths * vec(0.01, 1.0),
        inertias=vec(1e-5, 0.5),
        base=draw(arrays(float, 2, elements=st.floats(-5.0, 5.0, **finite))),
        phi=draw(angles),
        passive_first_joint=draw(st.booleans()) if passive is None else passive,
    )


def _joint_angles(draw, n: int) -> np.ndarray:
    return draw(arrays(float, n, elements=angles))


# --------------------------------------------------------------------------- inertia


@SETTINGS
@given(data=st.data())
def test_mass_matrix_spd_and_independent_of_q1(data) -> None:
    arm = data.draw(arms())
    q = _joint_angles(data.draw, arm.n_links)
    shift = data.draw(angles)
    M = mass_matrix(arm, q)
    # Symmetric up to round-off (the two triangles are summed in different orders).
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-14 * np.abs(M).max())
    np.linalg.cholesky(M)  # raises LinAlgError unless positive definite
    eig = np.linalg.eigvalsh(M)
    # An independent lower bound: ½ q̇ᵀ M q̇ ≥ ½ I_min |θ̇|² summed over links, so the smallest
    # eigenvalue of M = Sᵀ M̄ S is at least I_min · σ_min(S)² > 0.
    s_min = np.linalg.svd(np.tril(np.ones((arm.n_links, arm.n_links))), compute_uv=False).min()
    assert eig[0] >= arm.inertias.min() * s_min**2 * (1 - 1e-9) - 1e-12 * eig[-1]
    q_shifted = q.copy()
    q_shifted[0] += shift
    np.testing.assert_allclose(mass_matrix(arm, q_shifted), M, rtol=1e-12, atol=1e-12 * eig[-1])


@SETTINGS
@given(data=st.data())
def test_m_comb_spd_and_g0_zeroes_passive_momentum(data) -> None:
    arm = data.draw(arms(passive=True))
    q = _joint_angles(data.draw, arm.n_links)
    v = data.draw(arrays(float, arm.n_links - 1, elements=st.floats(-10, 10, **finite)))
    t = cascade_terms(arm, q, v)
    Mc = t.M_comb
    M = mass_matrix(arm, q)
    # Symmetric up to the round-off of the Schur complement (cancellation at the scale of M).
    np.testing.assert_allclose(Mc, Mc.T, rtol=0, atol=1e-13 * np.abs(M).max())
    np.linalg.cholesky(0.5 * (Mc + Mc.T))
    # M_comb = g0ᵀ M g0 is the inertia seen by the active joints: vᵀ M_comb v = q̇ᵀ M q̇.
    g0 = passive_velocity_map(arm, q)
    qd = g0 @ v
    assert v @ Mc @ v == pytest.approx(qd @ M @ qd, rel=1e-9, abs=1e-12)
    # The passive momentum Σ_α M_1α q̇_α vanishes for q̇ = g0 v.
    scale = np.abs(M[0]).sum() * (np.abs(qd).max() + 1e-300)
    assert abs(M[0] @ qd) <= 1e-12 * scale
    np.testing.assert_array_equal(g0[1:], np.eye(arm.n_links - 1))


# --------------------------------------------------------------------------- safety QP


@st.composite
def qp_problems(draw):
    k = draw(st.integers(1, 4))
    m = draw(st.integers(1, 4))
    # zeros, or magnitudes in [1e-3, 10] (so that products of entries never underflow)
    entries = st.one_of(
        st.just(0.0), st.floats(1e-3, 10.0, **finite), st.floats(-10.0, -1e-3, **finite)
    )
    structure = draw(st.sampled_from(["generic", "rank1", "rank2"]))
    if structure == "generic":
        A = draw(arrays(float, (m, k), elements=entries))
    elif structure == "rank1":
        A = np.outer(draw(arrays(float, m, elements=entries)), draw(arrays(float, k, elements=entries)))
    else:
        A = draw(arrays(float, (m, 2), elements=entries)) @ draw(
            arrays(float, (2, k), elements=entries)
        )
    b = draw(arrays(float, m, elements=st.one_of(entries, st.just(np.inf))))
    v0 = draw(arrays(float, k, elements=entries))
    return v0, A, b


@SETTINGS
@given(problem=qp_problems(), solver=st.sampled_from(["active_set", "piqp"]))
def test_project_velocity_is_feasible_or_falls_back(problem, solver: str) -> None:
    v0, A, b = problem
    res = project_velocity(v0[None], A[None], b[None], solver=solver)
    v, status = res.v[0], int(res.status[0])
    assert np.all(np.isfinite(v))
    if status == QPStatus.FALLBACK:
        np.testing.assert_array_equal(v, 0.0)
        return
    if status == QPStatus.NOMINAL:
        np.testing.assert_array_equal(v, v0)
    fin = np.isfinite(b)
    tol = 1e-7 * (1.0 + np.abs(b[fin]) + np.linalg.norm(A[fin], axis=1) * (1.0 + np.linalg.norm(v)))
    assert np.all(A[fin] @ v <= b[fin] + tol), (A @ v - b, status)
    # A solved answer is never farther from v0 than any other feasible point we know: here,
    # v0 itself when feasible (then it must be returned), else nothing to compare.
    if np.all(A[fin] @ v0 <= b[fin]):
        assert status == QPStatus.NOMINAL


# --------------------------------------------------------------------------- formation law


@st.composite
def teams(draw):
    n_agents = draw(st.integers(3, 5))
    shape = "square" if n_agents == 4 and draw(st.booleans()) else "polygon"
    form = Formation.from_shape(shape, draw(st.floats(0.2, 2.0, **finite)), n_agents)
    team = [draw(arms(2, 4)) for _ in range(n_agents)]
    qs = [_joint_angles(draw, arm.n_links) for arm in team]
    kp = draw(st.floats(0.1, 5.0, **finite))
    return form, team, qs, kp


def _potential_of(form: Formation, team, qs, kp: float) -> float:
    p = np.stack([end_effector(arm, q) for arm, q in zip(team, qs, strict=True)])
    z = edge_vectors(form.incidence, p)
    return float(formation_potential(edge_errors(z, form.distances), kp))


@SETTINGS
@given(team=teams())
def test_nominal_law_never_increases_potential(team) -> None:
    form, arms_, qs, kp = team
    B = form.incidence
    p = np.stack([end_effector(arm, q) for arm, q in zip(arms_, qs, strict=True)])
    z = edge_vectors(B, p)
    e = edge_errors(z, form.distances)
    e_hat = formation_gradient(B, z, e)
    dV = 0.0
    qdots = []
    for i, (arm, q) in enumerate(zip(arms_, qs, strict=True)):
        Jbar = reduced_jacobian(arm, q)
        v0 = nominal_velocity(Jbar, e_hat[i], kp)
        assert v0.shape == (arm.n_actuated,)
        dV += kp * e_hat[i] @ Jbar @ v0
        qdots.append(passive_velocity_map(arm, q) @ v0)
    scale = kp * np.abs(e_hat).max() ** 2 * kp + 1e-300
    assert dV <= 1e-12 * scale
    # Independently: the directional derivative of V along q̇ = g0 v0, by central differences
    # (step scaled so that no joint moves more than 1e-6 rad).
    speed = max(float(np.abs(qd).max()) for qd in qdots)
    h = 1e-6 / max(speed, 1.0)
    plus = _potential_of(form, arms_, [q + h * qd for q, qd in zip(qs, qdots, strict=True)], kp)
    minus = _potential_of(form, arms_, [q - h * qd for q, qd in zip(qs, qdots, strict=True)], kp)
    dV_fd = (plus - minus) / (2 * h)
    # Round-off in V: each e_k = ‖z_k‖² − d_k² carries ~eps (‖z_k‖² + d_k²).
    round_off = kp * np.sum(np.abs(e) * (np.sum(z * z, axis=-1) + form.distances**2))
    assert abs(dV_fd - dV) <= 1e-4 * abs(dV) + 1e3 * np.finfo(float).eps * round_off / h
