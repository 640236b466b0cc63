"""The compiled engine (pan1_env.kernels) against the numpy reference formulas."""

import dataclasses

import numpy as np
import pytest
from kernel_args import kernel_groups
from numba import njit

from pan1_env import kernels
from pan1_env.cascade import cascade_rk4_step, cascade_terms, end_effector_drift, passive_momentum, reduced_jacobian
from pan1_env.compiled import kernel_filter, kernel_sizes
from pan1_env.control import backstepping_torque
from pan1_env.dynamics import ArmBatch, ArmParams, end_effector
from pan1_env.kernel_groups import plain
from pan1_env.kernels._numba_ext import _JIT, _LANES, _local, _slp_vectorised
from pan1_env.kernels.physics import _SERIES_MAX, _SERIES_SHORT, _rotate_lanes, _spd_solve
from pan1_env.kernels.qp import _first_projection_lanes
from pan1_env.kernels.substep import _advance_arms
from pan1_env.safety import (
    FilterParams,
    active_set_projection,
    clearance,
    project_velocity,
    rcbf_constraints,
    torque_rows,
)


def _rcbf(kappa: float, epsilon: float, margin: float, distance: bool, decay: float, tau_max: float = np.inf) -> tuple:
    """The kernels' ``rcbf`` for these settings, built as the engine builds it."""
    return plain(kernel_filter(FilterParams(kappa, epsilon, margin, barrier="distance" if distance else "squared",
                                            decay=decay), tau_max))


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


def _terms(batch, q, v, momentum=None, damping=None):
    A, k = v.shape
    out = dict(p=np.empty((A, 2)), Jbar=np.empty((A, 2, k)), Mc=np.empty((A, k, k)),
               Hc=np.empty((A, k)), mom=np.empty(A), drift=np.empty((A, 2)))
    kernels.group_terms(batch.lam, batch.lengths, batch.base, batch.phi, _per_arm(damping, A),
                        batch.passive_first_joint, q, v, _per_arm(momentum, A), out["p"], out["Jbar"], out["Mc"],
                        out["Hc"], out["mom"], out["drift"])
    return out


def _window(A, n_sub):
    """Every arm's sub-steps: all of a call's."""
    return np.tile(np.array([0, n_sub], dtype=np.int64), (A, 1))


def _per_arm(values, A):
    """A kernel's per-arm array of passive momenta or dampings (zeros: the paper's arm)."""
    return np.zeros(A) if values is None else np.broadcast_to(np.asarray(values, dtype=float), (A,)).copy()


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
    assert np.all(got["drift"] == 0.0), "at p₁ = 0 no drift"
    if passive:  # with a passive momentum and damping: the reduced model of docs/MODEL.md §7
        p1, damping = rng.uniform(-1.0, 1.0, len(q)), rng.uniform(0.0, 2.0, len(q))
        got = _terms(batch, q, v, p1, damping)
        ref = cascade_terms(dataclasses.replace(batch, passive_damping=damping), q, v, p1)
        np.testing.assert_allclose(got["Hc"], ref.H_comb, atol=1e-12)
        np.testing.assert_allclose(got["mom"], p1, atol=1e-12)
        np.testing.assert_allclose(got["drift"], end_effector_drift(batch, q, p1), atol=1e-12)


def _advance(batch, q, v, command, *, v_prev=None, torque=False, filter_on=False, centers=None, radii=None,
             mask=None, kappa=0.5, eps=5.0, margin=0.0, distance=False, decay=0.0,
             ke=100.0, dt=1e-3, n_sub=1, v_max=np.inf, parallel=False,
             sizes=None, n_chunks=2, momentum=None, damping=None, rows=None, window=None, tau_max=np.inf):
    A, k = v.shape
    centers = np.zeros((0, 2)) if centers is None else centers
    radii = np.zeros(0) if radii is None else radii
    mask = np.zeros((A, len(radii)), bool) if mask is None else mask
    q, v = q.copy(), v.copy()
    prev = np.zeros((A, k)) if v_prev is None else v_prev.copy()
    has_prev = np.full(A, v_prev is not None)
    out = dict(v_star=np.empty((A, k)), tau=np.empty((A, k)), qd=np.empty_like(q), p=np.empty((A, 2)),
               clear=np.full(A, np.inf), min_h=np.full(A, np.inf), counts=np.zeros((A, 3), np.int64),
               track=np.zeros(A), finite=np.zeros(A, bool))
    sizes = kernel_sizes(q.shape[1], k) if sizes is None else sizes
    momentum = _per_arm(momentum, A)
    args = (*sizes, *kernel_groups(batch, _per_arm(damping, A), batch.passive_first_joint, q, v, momentum, prev,
                                    has_prev, np.arange(A) if rows is None else rows,
                                    _window(A, n_sub) if window is None else window, command, torque, filter_on,
                                    np.broadcast_to(centers, (A, *centers.shape)).copy(),
                                    np.broadcast_to(radii, (A, len(radii))).copy(), mask,
                                    _rcbf(kappa, eps, margin, distance, decay, tau_max), ke, dt, n_sub, v_max,
                                    out.values()), None)
    if parallel:
        kernels.group_advance_parallel(*args, n_chunks)
    else:
        kernels.group_advance(*args)
    out["momentum"] = momentum
    return bool(out["finite"].all()), q, v, prev, out


@pytest.mark.parametrize("n", [2, 4])
@pytest.mark.parametrize("passive", [True, False])
def test_advance_velocity_mode_is_backstepping_plus_rk4(n: int, passive: bool) -> None:
    rng = np.random.default_rng(3 * n + passive)
    batch, q, v = _group(rng, n, passive)
    command, v_prev = rng.uniform(-1, 1, v.shape), rng.uniform(-1, 1, v.shape)
    centers, radii = rng.uniform(-2, 2, (3, 2)), np.full(3, 0.1)
    ok, q1, v1, prev, out = _advance(batch, q, v, command, v_prev=v_prev, centers=centers, radii=radii)
    assert ok
    t = cascade_terms(batch, q, v)
    tau = backstepping_torque(t.M_comb, t.H_comb, v, command, (command - v_prev) / 1e-3, 100.0)
    q_ref, v_ref = cascade_rk4_step(batch, q, v, tau, 1e-3)
    np.testing.assert_allclose(out["tau"], tau, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(q1, q_ref, atol=1e-12)
    np.testing.assert_allclose(v1, v_ref, atol=1e-9)
    np.testing.assert_array_equal(prev, command)
    np.testing.assert_allclose(out["track"], np.linalg.norm(v - command, axis=-1))
    np.testing.assert_allclose(out["clear"], clearance(end_effector(batch, q1), centers, radii).min(-1), atol=1e-12)


def test_advance_torque_mode_without_filter_applies_the_torque() -> None:
    rng = np.random.default_rng(5)
    batch, q, v = _group(rng, 3, True)
    tau = rng.uniform(-1, 1, v.shape)
    ok, q1, v1, _, out = _advance(batch, q, v, tau, torque=True, n_sub=3)
    q_ref, v_ref = q, v
    for _ in range(3):
        q_ref, v_ref = cascade_rk4_step(batch, q_ref, v_ref, tau, 1e-3)
    np.testing.assert_allclose(out["tau"], tau)
    np.testing.assert_allclose(q1, q_ref, atol=1e-12)
    np.testing.assert_allclose(v1, v_ref, atol=1e-9)


def test_rotated_angles_match_cos_and_sin() -> None:
    # the RK4 stages' link angles come from the step's start by a small rotation (a short series for
    # |δ| ≤ 0.03, a long one to 0.125, np.cos/np.sin beyond): each branch against cos and sin of the
    # summed angle, as links × lanes arrays
    rng = np.random.default_rng(11)
    n, W = 6, 5
    for h in (1e-3, 5e-3, 0.05, 0.5):
        theta = rng.uniform(-np.pi, np.pi, (n, W))
        thd = rng.uniform(-20.0, 20.0, (n, W))
        c, s = np.empty((n, W)), np.empty((n, W))
        _rotate_lanes(np.cos(theta), np.sin(theta), thd, h, n, W, c, s)
        np.testing.assert_allclose(c, np.cos(theta + h * thd), rtol=0, atol=2e-15)
        np.testing.assert_allclose(s, np.sin(theta + h * thd), rtol=0, atol=2e-15)
    # every increment δ = h θ̇ on a grid through both series' ranges and their edges (one link, the
    # increments along the lanes: the series are selected lane by lane)
    edges = [_SERIES_SHORT, _SERIES_MAX]
    d = np.concatenate([np.linspace(-0.2, 0.2, 801), edges, np.nextafter(edges, 1.0), np.nextafter(edges, 0.0)])
    d = np.concatenate([d, -d])[None]
    theta = rng.uniform(-np.pi, np.pi, d.shape)
    c, s = np.empty(d.shape), np.empty(d.shape)
    _rotate_lanes(np.cos(theta), np.sin(theta), d, 1.0, 1, d.shape[1], c, s)
    np.testing.assert_allclose(c, np.cos(theta + d), rtol=0, atol=1e-15)
    np.testing.assert_allclose(s, np.sin(theta + d), rtol=0, atol=1e-15)
    # rotating the angle 0 gives cos δ and sin δ themselves: within an ulp of np.cos/np.sin (a wrong
    # coefficient or a series used beyond its range is off by several)
    d = d[:, d[0] != 0]
    c, s = np.empty(d.shape), np.empty(d.shape)
    _rotate_lanes(np.ones(d.shape), np.zeros(d.shape), d, 1.0, 1, d.shape[1], c, s)
    assert np.all(np.abs(c - np.cos(d)) <= np.spacing(np.cos(d)))
    assert np.all(np.abs(s - np.sin(d)) <= np.spacing(np.abs(np.sin(d))))


def test_advance_fast_joints_match_rk4() -> None:
    # joints fast enough that the rotation of an RK4 stage leaves the series' range
    rng = np.random.default_rng(12)
    batch, q, v = _group(rng, 4, True)
    v = v * 10.0
    tau = rng.uniform(-1, 1, v.shape)
    ok, q1, v1, _, out = _advance(batch, q, v, tau, torque=True, dt=1e-2, n_sub=2)
    q_ref, v_ref = q, v
    for _ in range(2):
        q_ref, v_ref = cascade_rk4_step(batch, q_ref, v_ref, tau, 1e-2)
    assert ok
    np.testing.assert_allclose(q1, q_ref, atol=1e-11)
    np.testing.assert_allclose(v1, v_ref, atol=1e-8)
    np.testing.assert_allclose(out["p"], end_effector(batch, q1), atol=1e-12)


def test_advance_rejects_sizes_that_do_not_match_the_arrays() -> None:
    # sizes of arm kinds the other tests compile anyway (each new kind costs a compilation)
    rng = np.random.default_rng(13)
    three, q3, v3 = _group(rng, 3, True)  # (n, k) = (3, 2)
    four, q4, v4 = _group(rng, 4, True)  # (4, 3)
    with pytest.raises(ValueError, match="kernel_sizes"):  # wrong n
        _advance(three, q3, v3, np.zeros_like(v3), sizes=kernel_sizes(2, 1))
    with pytest.raises(ValueError, match="kernel_sizes"):  # wrong k
        _advance(four, q4, v4, np.zeros_like(v4), sizes=kernel_sizes(4, 4))
    with pytest.raises(ValueError, match="kernel_sizes"):  # the multi-threaded kernel checks too
        _advance(three, q3, v3, np.zeros_like(v3), sizes=kernel_sizes(4, 3), parallel=True)
    # the kernel takes `passive` from k < n: a flag that disagrees is refused
    full = dataclasses.replace(four, passive_first_joint=False)
    for parallel in (False, True):
        with pytest.raises(ValueError, match="PAn-1"):
            _advance(full, q4, v4, np.zeros_like(v4), parallel=parallel)
    with pytest.raises(ValueError, match="n_chunks"):  # no chunk: nothing would be advanced
        _advance(four, q4, v4, np.zeros_like(v4), parallel=True, n_chunks=0)


# plain @njit (no cache): numba's cache of a test helper would not notice a change to the kernels it inlines
@njit
def _spd_solve_all(G, r, scratch):
    size = G.shape[1]
    x, L, y = np.zeros((G.shape[0], size)), np.empty((scratch, scratch)), np.empty(scratch)
    ok = np.zeros(G.shape[0], dtype=np.bool_)
    for i in range(G.shape[0]):
        ok[i] = _spd_solve(G[i], r[i], x[i], size, L, y)
    return ok, x


@pytest.mark.parametrize("size", [1, 2, 3, 5])
def test_spd_solve_matches_numpy_and_refuses_matrices_that_are_not_positive_definite(size: int) -> None:
    rng = np.random.default_rng(size)
    F = rng.normal(size=(200, size, size))
    G = F @ F.transpose(0, 2, 1) + 1e-3 * np.eye(size)  # SPD, some badly conditioned
    r = rng.normal(size=(200, size))
    ok, x = _spd_solve_all(G, r, size)
    assert ok.all()
    ok2, x2 = _spd_solve_all(G, r, 6)  # scratch larger than the system, as in the QP's active sets
    assert ok2.all()
    np.testing.assert_array_equal(x2, x)
    np.testing.assert_allclose(G @ x[..., None], r[..., None], rtol=0, atol=1e-9 * (1 + np.abs(r).max()))
    np.testing.assert_allclose(x, np.linalg.solve(G, r[..., None])[..., 0], rtol=1e-6, atol=1e-9)
    # a clearly negative eigenvalue (−λ_max: no rounding makes it positive) is refused
    w, V = np.linalg.eigh(G)
    w[:, 0] = -w[:, -1]
    ok, _ = _spd_solve_all(V @ (w[..., None] * V.transpose(0, 2, 1)), r, size)
    assert not ok.any()
    # exactly singular or indefinite by construction: G = L D Lᵀ with L unit lower triangular with small
    # integer entries and D from {1, 2, 4} with one pivot set to 0 or −1. Every entry and every step of
    # the factorisation is then an exact integer (division by powers of two only), so the pivot the
    # solver meets is exactly 0 or −1 on any IEEE machine, whatever the BLAS or the compiler's rounding.
    for bad in (0.0, -1.0):
        L = np.tril(rng.integers(-3, 4, size=(200, size, size)), -1) + np.eye(size)
        D = rng.choice([1.0, 2.0, 4.0], size=(200, size))
        D[np.arange(200), rng.integers(0, size, 200)] = bad
        ok, _ = _spd_solve_all(L @ (D[..., None] * L.transpose(0, 2, 1)), r, size)
        assert not ok.any()
    # and with every pivot positive the same construction is accepted and solved exactly
    D = rng.choice([1.0, 2.0, 4.0], size=(200, size))
    G = L @ (D[..., None] * L.transpose(0, 2, 1))
    ok, x = _spd_solve_all(G, r, size)
    assert ok.all()
    residual = np.abs(np.einsum("bij,bj->bi", G, x) - r)  # backward error: these G can be ill-conditioned
    assert (residual <= 1e-12 * (np.einsum("bij,bj->bi", np.abs(G), np.abs(x)) + np.abs(r))).all()


@njit
def _local_arrays(links, actuated):
    a = _local((links, actuated), np.float64)
    b = _local((actuated,), np.int64)
    c = _local(((0, 0), links), np.bool_)
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            a[i, j] = 10 * i + j
    for j in range(b.shape[0]):
        b[j] = -j
    for i in range(2):
        for j in range(c.shape[1]):
            c[i, j] = (i + j) % 2 == 0
    return a.copy(), b.copy(), c.copy(), (a.strides, b.strides, c.strides), (a.itemsize, b.itemsize, c.itemsize)


def test_local_arrays_have_the_shape_of_their_size_tuples() -> None:
    a, b, c, strides, itemsizes = _local_arrays(*kernel_sizes(4, 3))
    assert a.shape == (4, 3) and a.dtype == np.float64
    assert strides == (np.empty((4, 3)).strides, np.empty(3, np.int64).strides, np.empty((2, 4), np.bool_).strides)
    assert itemsizes == (8, 8, 1)
    np.testing.assert_array_equal(a, 10 * np.arange(4)[:, None] + np.arange(3)[None])
    np.testing.assert_array_equal(b, -np.arange(3))
    assert c.dtype == np.bool_
    np.testing.assert_array_equal(c, (np.arange(2)[:, None] + np.arange(4)[None]) % 2 == 0)


def _binding_obstacles(rng, batch, q, v):
    t = _terms(batch, q, v)
    centers = t["p"][:3] + rng.normal(scale=0.15, size=(3, 2))
    return t, centers, np.full(3, 0.05)


def test_advance_filter_matches_rcbf_rows_and_piqp() -> None:
    rng = np.random.default_rng(11)
    batch, q, v = _group(rng, 4, True, count=6)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    mask = rng.random((6, 3)) < 0.7
    command, v_prev = rng.normal(scale=2.0, size=v.shape), rng.normal(size=v.shape)
    ok, q1, _, _, out = _advance(batch, q, v, command, v_prev=v_prev, filter_on=True, centers=centers,
                                 radii=radii, mask=mask)
    A_rows, b_rows, h = rcbf_constraints(t["p"], t["Jbar"], centers, radii, 0.5, 5.0, active=mask)
    expected = project_velocity(command, A_rows, b_rows, solver="piqp")
    np.testing.assert_allclose(out["v_star"], expected.v, atol=1e-6)
    np.testing.assert_array_equal(out["counts"].argmax(-1), expected.status)
    assert np.any(expected.status == 1), "the test should exercise active constraints"
    np.testing.assert_allclose(out["min_h"], np.where(mask, h, np.inf).min(axis=-1))
    ref = cascade_terms(batch, q, v)
    tau = backstepping_torque(ref.M_comb, ref.H_comb, v, out["v_star"], (out["v_star"] - v_prev) / 1e-3, 100.0)
    np.testing.assert_allclose(out["tau"], tau, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(q1, cascade_rk4_step(batch, q, v, tau, 1e-3)[0], atol=1e-12)


def test_advance_torque_filter_projects_the_one_step_velocity() -> None:
    rng = np.random.default_rng(12)
    batch, q, v = _group(rng, 3, True, count=6)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    mask = np.ones((6, 3), bool)
    tau_cmd, dt, v_max = rng.normal(scale=3.0, size=v.shape), 1e-3, 2.5
    ok, _, _, _, out = _advance(batch, q, v, tau_cmd, torque=True, filter_on=True, centers=centers, radii=radii,
                                mask=mask, v_max=v_max)
    ref = cascade_terms(batch, q, v)
    v_des = v + dt * np.linalg.solve(ref.M_comb, (tau_cmd - ref.H_comb)[..., None])[..., 0]
    A_rows, b_rows, _ = rcbf_constraints(t["p"], t["Jbar"], centers, radii, 0.5, 5.0, active=mask)
    k = v.shape[1]
    box = np.concatenate([np.eye(k), -np.eye(k)])
    A_all = np.concatenate([A_rows, np.broadcast_to(box, (6, 2 * k, k))], axis=1)
    b_all = np.concatenate([b_rows, np.full((6, 2 * k), v_max)], axis=1)
    expected = project_velocity(v_des, A_all, b_all, solver="piqp")
    changed = expected.status != 0
    assert changed.any(), "the test should exercise the filter"
    tau = np.where(changed[:, None],
                   np.einsum("aij,aj->ai", ref.M_comb, (expected.v - v) / dt) + ref.H_comb, tau_cmd)
    np.testing.assert_allclose(out["tau"], tau, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("passive", [True, False])
def test_advance_torque_filter_keeps_the_torque_bound(passive: bool) -> None:
    """With ``tau_max``, a lane whose filtered velocity needs more torque than the bound in its sub-step gets the
    projection onto its RCBF rows, the speed box and barriers.torque_rows (PIQP on the numpy rows), or, where those
    have no solution, the velocity nearest the unbounded filter's answer within the torque rows alone. No torque
    exceeds the bound, where the unbounded filter's do."""
    rng = np.random.default_rng(31 + passive)
    count, dt, v_max, tau_max = 12, 1e-2, 2.5, 3.0
    batch, q, v = _group(rng, 3, passive, count=count)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    mask = np.ones((count, 3), bool)
    tau_cmd = rng.uniform(-tau_max, tau_max, v.shape)
    run = dict(torque=True, filter_on=True, centers=centers, radii=radii, mask=mask, v_max=v_max, dt=dt)
    free = _advance(batch, q, v, tau_cmd, **run)[4]
    out = _advance(batch, q, v, tau_cmd, tau_max=tau_max, **run)[4]
    assert np.abs(out["tau"]).max() <= tau_max * (1 + 1e-9)
    ref = cascade_terms(batch, q, v)
    torque = [torque_rows(ref.M_comb[a], ref.H_comb[a], v[a], dt, tau_max) for a in range(count)]
    beyond = np.array([np.any(A @ free["v_star"][a] > b + 1e-9) for a, (A, b) in enumerate(torque)])
    assert beyond.any() and np.abs(free["tau"]).max() > tau_max, "the test should need the bound"
    v_des = v + dt * np.linalg.solve(ref.M_comb, (tau_cmd - ref.H_comb)[..., None])[..., 0]
    A_rows, b_rows, _ = rcbf_constraints(t["p"], t["Jbar"], centers, radii, 0.5, 5.0, active=mask)
    k = v.shape[1]
    box = np.broadcast_to(np.concatenate([np.eye(k), -np.eye(k)]), (count, 2 * k, k))
    A_all = np.concatenate([A_rows, box, np.stack([A for A, _ in torque])], axis=1)
    b_all = np.concatenate([b_rows, np.full((count, 2 * k), v_max), np.stack([b for _, b in torque])], axis=1)
    bounded = project_velocity(v_des, A_all, b_all, solver="piqp")
    nearest = project_velocity(free["v_star"], np.stack([A for A, _ in torque]), np.stack([b for _, b in torque]),
                               solver="piqp")
    solved = bounded.status != 2
    expected = np.where(beyond[:, None], np.where(solved[:, None], bounded.v, nearest.v), free["v_star"])
    assert (beyond & solved).any() and (beyond & ~solved).any(), "the test should reach both answers"
    np.testing.assert_allclose(out["v_star"], expected, atol=1e-6)
    np.testing.assert_array_equal(out["counts"][:, 2] > 0, beyond & ~solved | (free["counts"][:, 2] > 0))


@pytest.mark.parametrize("torque", [False, True])
def test_parallel_kernel_equals_serial_and_reports_state(torque: bool) -> None:
    rng = np.random.default_rng(21 + torque)
    batch, q, v = _group(rng, 4, True, count=9)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    command = rng.normal(scale=2.0, size=v.shape)
    kw = dict(torque=torque, filter_on=True, centers=centers, radii=radii, mask=np.ones((9, 3), bool), n_sub=5,
              v_max=2.0, momentum=rng.uniform(-0.5, 0.5, 9), damping=rng.uniform(0.0, 2.0, 9))
    ok_s, q_s, v_s, _, out_s = _advance(batch, q, v, command, **kw)
    ok_p, q_p, v_p, _, out_p = _advance(batch, q, v, command, parallel=True, **kw)
    assert ok_s and ok_p
    # the same _advance_arms on 9 arms, whole (two groups of 4 lanes and a padded one) and in 2 chunks
    # (other padded groups): each lane computes its arm alone, so bit for bit alike
    np.testing.assert_array_equal(_bits(q_p), _bits(q_s))
    np.testing.assert_array_equal(_bits(v_p), _bits(v_s))
    for key in out_s:
        np.testing.assert_array_equal(_bits(out_p[key]), _bits(out_s[key]))
    # the reported q̇ and end-effector are those of the final state
    np.testing.assert_allclose(out_s["qd"], cascade_terms(batch, q_s, v_s, out_s["momentum"]).qd, atol=1e-12)
    np.testing.assert_allclose(out_s["p"], end_effector(batch, q_s), atol=1e-12)


@pytest.mark.parametrize("parallel", [False, True])
def test_kernel_steps_only_its_rows(parallel: bool) -> None:
    """``rows`` picks the arms a call advances: they end as in a call on every arm (each lane computes its arm
    alone), and the others, state and outputs, are left as they were."""
    rng = np.random.default_rng(23)
    batch, q, v = _group(rng, 4, True, count=9)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    command = rng.normal(scale=2.0, size=v.shape)
    kw = dict(filter_on=True, centers=centers, radii=radii, mask=np.ones((9, 3), bool), n_sub=5, v_max=2.0,
              momentum=rng.uniform(-0.5, 0.5, 9), damping=rng.uniform(0.0, 2.0, 9), parallel=parallel)
    _, q_all, v_all, _, out_all = _advance(batch, q, v, command, **kw)
    rows = np.array([0, 3, 4, 8])
    _, q_some, v_some, _, out_some = _advance(batch, q, v, command, rows=rows, **kw)
    rest = np.setdiff1d(np.arange(9), rows)
    np.testing.assert_array_equal(_bits(q_some[rows]), _bits(q_all[rows]))
    np.testing.assert_array_equal(_bits(v_some[rows]), _bits(v_all[rows]))
    np.testing.assert_array_equal(q_some[rest], q[rest])
    np.testing.assert_array_equal(v_some[rest], v[rest])
    for key in ("clear", "min_h", "counts", "track", "finite", "momentum"):
        np.testing.assert_array_equal(_bits(out_some[key][rows]), _bits(out_all[key][rows]))
    assert np.all(out_some["counts"][rest] == 0) and not out_some["finite"][rest].any()
    assert np.all(out_some["momentum"][rest] == kw["momentum"][rest])
    with pytest.raises(ValueError, match="rows must index the arms"):
        _advance(batch, q, v, command, rows=np.array([0, 9]), **kw)


@pytest.mark.parametrize("parallel", [False, True])
def test_kernel_steps_each_arm_within_its_window(parallel: bool) -> None:
    """``window`` picks each arm's sub-steps within a call: an arm stepped in sub-steps [0, 3) of 5 ends as in a
    3-sub-step call, one stepped in [2, 5) or [0, 5) as in a 3- or 5-sub-step call from its state (held
    meanwhile), one in [4, 4) is left as it was; outputs count only its own sub-steps."""
    rng = np.random.default_rng(29)
    batch, q, v = _group(rng, 4, True, count=9)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    command = rng.normal(scale=2.0, size=v.shape)
    kw = dict(filter_on=True, centers=centers, radii=radii, mask=np.ones((9, 3), bool), v_max=2.0,
              momentum=rng.uniform(-0.5, 0.5, 9), damping=rng.uniform(0.0, 2.0, 9), parallel=parallel)
    window = np.array([[0, 3], [2, 5], [0, 5], [4, 4], [0, 3], [2, 5], [0, 99], [1, 4], [0, 5]], dtype=np.int64)
    _, q_w, v_w, _, out_w = _advance(batch, q, v, command, n_sub=5, window=window, **kw)
    steps = window.clip(0, 5)[:, 1] - window.clip(0, 5)[:, 0]
    for n_sub in (0, 3, 5):
        if n_sub == 0:
            q_n, v_n = q, v
        else:
            _, q_n, v_n, _, out_n = _advance(batch, q, v, command, n_sub=n_sub, **kw)
        same = steps == n_sub
        np.testing.assert_array_equal(_bits(q_w[same]), _bits(q_n[same]))
        np.testing.assert_array_equal(_bits(v_w[same]), _bits(v_n[same]))
        if n_sub:
            for key in ("counts", "clear", "min_h", "momentum"):
                np.testing.assert_array_equal(_bits(out_w[key][same]), _bits(out_n[key][same]))
    assert np.array_equal(out_w["counts"].sum(axis=1), steps)
    with pytest.raises(ValueError, match="window needs a"):
        _advance(batch, q, v, command, n_sub=5, window=window[:, :1].copy(), **kw)


def test_per_arm_obstacles_equal_one_arm_at_a_time() -> None:
    """Each arm's filter sees its own obstacle rows (the vector env gives every copy its own)."""
    rng = np.random.default_rng(31)
    batch, q, v = _group(rng, 3, True, count=4)
    t = _terms(batch, q, v)
    centers = t["p"][:, None, :] + rng.normal(scale=0.15, size=(4, 2, 2))
    radii = rng.uniform(0.03, 0.08, (4, 2))
    command = rng.normal(scale=2.0, size=v.shape)
    A, k = v.shape
    args = dict(v_star=np.empty((A, k)), tau=np.empty((A, k)), qd=np.empty_like(q), p=np.empty((A, 2)),
                clear=np.full(A, np.inf), min_h=np.full(A, np.inf), counts=np.zeros((A, 3), np.int64),
                track=np.zeros(A), finite=np.zeros(A, bool))
    q_all, v_all = q.copy(), v.copy()
    kernels.group_advance(*kernel_sizes(q.shape[1], k),
                          *kernel_groups(batch, np.zeros(A), True, q_all, v_all, np.zeros(A), np.zeros((A, k)),
                                          np.zeros(A, bool), np.arange(A), _window(A, 3), command, False, True, centers,
                                          radii, np.ones((A, 2), bool), _rcbf(0.5, 5.0, 0.0, False, 0.0), 100.0, 1e-3,
                                          3, 2.0, args.values()), None)
    for i in range(A):
        one = ArmBatch(lam=batch.lam[i : i + 1], lengths=batch.lengths[i : i + 1], base=batch.base[i : i + 1],
                       phi=batch.phi[i : i + 1], passive_first_joint=True)
        ok, q1, v1, _, out = _advance(one, q[i : i + 1], v[i : i + 1], command[i : i + 1], filter_on=True,
                                      centers=centers[i], radii=radii[i], mask=np.ones((1, 2), bool), n_sub=3,
                                      v_max=2.0)
        np.testing.assert_array_equal(q1[0], q_all[i])
        np.testing.assert_array_equal(out["v_star"][0], args["v_star"][i])
        np.testing.assert_array_equal(out["clear"][0], args["clear"][i])


def test_piqp_and_active_set_records_agree_on_barriers() -> None:
    """Both QP paths report the smallest filtered barrier h of each arm (the PIQP path once lost it)."""
    from pan1_env.scenario import load
    from pan1_env.simulation import Simulation

    scenario = load("paper_pa3_square")
    sims = {s: Simulation(scenario, qp_solver=s, physics_dt=0.01) for s in ("active_set", "piqp")}
    command = np.random.default_rng(0).uniform(-2, 2, (scenario.n_arms, 3))
    recs = {s: sim.step(command, 3, max_speed=2.0) for s, sim in sims.items()}
    mask = scenario.obstacle_mask().any(axis=1)
    assert mask.any() and np.isfinite(recs["active_set"].min_barrier[mask]).all()
    np.testing.assert_allclose(recs["piqp"].min_barrier, recs["active_set"].min_barrier, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(recs["piqp"].qp_counts.sum(axis=1), [3] * scenario.n_arms)


# plain @njit (no cache): numba's cache of a test helper would not notice a change to the kernels it inlines
@njit(error_model="numpy", fastmath=_JIT["fastmath"])  # as the kernels: 0/0 is NaN, not an exception
def _first_candidates(px, py, Jbar, obstacles, active, filtered, v0, kappa, epsilon, margin, v_max, distance=False,
                      decay=0.0, drift=None):
    """_first_projection_lanes on W lanes (end-effector drift ``(2, W)``, default none), with the rows it used
    as a (W, m, k) QP batch."""
    O, k, W = obstacles.shape[1], v0.shape[0], v0.shape[1]
    m = O + 2 * k
    arm_h = np.full(W, np.inf)
    A, b, h, norm, act = np.empty((k, W)), np.empty(W), np.empty(W), np.empty(W), np.empty(W, np.bool_)
    rows, violated, best, best_viol = np.empty((O, k + 2, W)), np.empty(W, np.bool_), np.empty(W, np.int64), np.empty(W)
    Ab, bb, cand, found = np.empty((k, W)), np.empty(W), np.empty((k, W)), np.empty(W, np.bool_)
    drift = np.zeros((2, W)) if drift is None else drift
    _first_projection_lanes(px, py, Jbar, drift, obstacles, active, filtered, kappa, epsilon, margin,
                            distance, decay, v_max, O, k, W, v0, arm_h, A, b, h, norm, act, rows, violated, best,
                            best_viol, Ab, bb, cand, found)
    A_all, b_all = np.zeros((W, m, k)), np.zeros((W, m))
    for w in range(W):
        for j in range(O):
            for t in range(k):
                A_all[w, j, t] = rows[j, t, w]
            b_all[w, j] = rows[j, k, w]
        for t in range(k):
            A_all[w, O + 2 * t, t] = 1.0
            A_all[w, O + 2 * t + 1, t] = -1.0
            b_all[w, O + 2 * t] = v_max
            b_all[w, O + 2 * t + 1] = v_max
    return violated, found, cand, A_all, b_all, arm_h


@pytest.mark.parametrize("v_max", [2.5, np.inf])
def test_first_projection_of_the_lanes_is_the_active_set_answer(v_max: float) -> None:
    """The vectorised first stage of the safety QP (all lanes at once) settles a lane only with what
    the scalar active-set search (qp_project, checked against PIQP in test_safety_qp) returns for the
    same rows, bit for bit; it leaves to that search the lanes whose optimum needs more than one row,
    and those with a zero or non-finite row."""
    rng = np.random.default_rng(41)
    O, k, W = 3, 2, 4000
    px, py = rng.normal(size=W), rng.normal(size=W)
    Jbar = rng.normal(size=(2, k, W))
    Jbar[:, :, :40] = 0.0  # a zero Jacobian: zero RCBF rows
    obstacles = np.stack([px + rng.normal(scale=0.3, size=(O, W)), py + rng.normal(scale=0.3, size=(O, W)),
                          rng.uniform(0.05, 0.2, (O, W))])
    obstacles[2, 0, 40:60] = np.nan  # a non-finite row
    v0 = rng.normal(scale=2.0, size=(k, W))
    active = np.zeros((O + 2 * k, W), bool)
    active[:O] = rng.random((O, W)) < 0.8
    active[O:] = v_max < np.inf
    filtered = rng.random(W) < 0.95
    active[:O, :60] = filtered[:60] = True  # the zero and non-finite rows above count
    violated, found, cand, A_all, b_all, arm_h = _first_candidates(px, py, Jbar, obstacles, active, filtered, v0, 0.5,
                                                                   5.0, 0.01, v_max)
    v_out, status = np.empty((W, k)), np.zeros(W, np.int64)
    kernels.qp_project(np.ascontiguousarray(v0.T), A_all, b_all, np.ascontiguousarray(active.T), v_out, status)
    clean = np.ones(W, bool)
    clean[:60] = False
    np.testing.assert_array_equal(violated[clean], (status != kernels.STATUS_NOMINAL)[clean] & filtered[clean])
    assert not violated[~filtered].any()
    settled = violated & found
    assert not settled[:60].any(), "zero and non-finite rows go to the full search"
    assert settled.sum() > 0.3 * violated.sum() and (violated & ~found).any(), "both stages should be exercised"
    assert np.all(status[settled] == kernels.STATUS_SOLVED)
    np.testing.assert_array_equal(cand.T[settled], v_out[settled])
    # the smallest barrier h_j = ‖p − o_j‖² − r_j² of the active obstacles, for the filtered lanes
    h = (px - obstacles[0]) ** 2 + (py - obstacles[1]) ** 2 - obstacles[2] ** 2
    expected = np.where(active[:O] & filtered & (h < np.inf), h, np.inf).min(axis=0)
    np.testing.assert_allclose(arm_h[clean], expected[clean], rtol=1e-14)


def _four_products(a, b, out):
    x0, x1, x2, x3 = a[0] * b[0], a[1] * b[1], a[2] * b[2], a[3] * b[3]
    out[0], out[1], out[2], out[3] = x0, x1, x2, x3


def test_slp_vectorised_dispatchers_compile_with_slp_and_leave_numba_as_it_was() -> None:
    from numba.core import config

    before = config.SLP_VECTORIZE
    slp = _slp_vectorised(njit(_four_products))
    plain = njit(_four_products)
    a, b = np.arange(4.0), np.arange(4.0) + 1
    for f in (slp, plain):
        out = np.empty(4)
        f(a, b, out)
        np.testing.assert_array_equal(out, a * b)
    assert "<4 x double>" in next(iter(slp.inspect_llvm().values()))
    assert "<4 x double>" not in next(iter(plain.inspect_llvm().values())) or before
    assert config.SLP_VECTORIZE == before


def _bits(x: np.ndarray) -> np.ndarray:
    return x.view(np.int64) if x.dtype == np.float64 else x


@pytest.mark.slow
def test_vectorised_kernel_equals_the_kernel_compiled_without_slp() -> None:
    """The sub-step kernel is compiled with LLVM's SLP vectoriser (_slp_vectorised), which
    numba leaves off by default after miscompilations; the same code compiled without it (scalar
    instructions) must give the same bits, in both modes, with the filter, with an arm that goes
    non-finite and with a group whose size is not a multiple of the lanes."""
    from numba import njit as plain_njit
    from numba.core import config

    before = config.SLP_VECTORIZE
    unvectorised = plain_njit(error_model="numpy", fastmath=_JIT["fastmath"])(_advance_arms.py_func)
    rng = np.random.default_rng(51)
    A = 37
    batch, q, v = _group(rng, 3, True, count=A)
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    mask = rng.random((A, 3)) < 0.8
    mask[3] = False  # arm 3 goes unfiltered, with a command that makes its state non-finite
    # the paper's rows, and the distance barrier with the tunable ε (its own loop in _rcbf_row_lanes)
    for torque, v_max, distance, decay in ((False, 2.0, False, 0.0), (True, np.inf, False, 0.0),
                                           (False, 2.0, True, 50.0)):
        command = rng.normal(scale=5.0 if torque else 2.5, size=v.shape)
        command[3] = 1e300
        runs = []
        for kernel in ("slp", "plain"):
            qk, vk = q.copy(), v.copy()
            out = [np.zeros((A, 2)), np.zeros(A, bool), np.empty((A, 2)), np.empty((A, 2)), np.empty((A, 3)),
                   np.empty((A, 2)), np.full(A, np.inf), np.full(A, np.inf), np.zeros((A, 3), np.int64), np.zeros(A),
                   np.zeros(A, bool)]
            groups = kernel_groups(batch, np.zeros(A), True, qk, vk, np.zeros(A), out[0], out[1], np.arange(A),
                                    _window(A, 5), command, torque, True, np.broadcast_to(centers, (A, 3, 2)).copy(),
                                    np.broadcast_to(radii, (A, 3)).copy(), mask, _rcbf(0.5, 5.0, 0.01, distance, decay),
                                    100.0, 1e-2, 5, v_max, out[2:])
            if kernel == "slp":
                kernels.group_advance(*kernel_sizes(3, 2), *groups, None)
            else:
                unvectorised(*kernel_sizes(3, 2), _LANES, None, True, 0, A, *groups, None)
            runs.append([qk, vk, *out])
        finite, counts = runs[0][-1], runs[0][-3]
        assert not finite[3] and finite.sum() == A - 1
        assert (counts[:, kernels.STATUS_SOLVED] > 0).any(), "the filter should change some commands"
        assert np.all(counts[finite].sum(axis=1) == 5), "one status per arm and sub-step (no padded lane's)"
        for got, expected in zip(runs[0], runs[1], strict=True):
            np.testing.assert_array_equal(_bits(got), _bits(expected))
    assert config.SLP_VECTORIZE == before, "compiling the kernel must leave numba's own setting as it was"


@pytest.mark.parametrize("n, passive", [(2, False), (3, True), (4, True)])
def test_generic_kernel_equals_the_per_kind_kernel(n: int, passive: bool) -> None:
    """kernels.group_advance_generic (one kernel for every arm kind, n and k at run time, one lane, no
    lane-batched first QP candidate) gives the per-kind kernel's results bit for bit: velocity mode
    shielded with a speed bound, torque mode shielded, both unfiltered, with an arm that goes
    non-finite and a group that is not a multiple of the lanes; passive arms with a momentum and damping."""
    rng = np.random.default_rng(60 + n)
    A = 11
    batch, q, v = _group(rng, n, passive, count=A)
    k = v.shape[1]
    t, centers, radii = _binding_obstacles(rng, batch, q, v)
    mask = rng.random((A, 3)) < 0.8
    momentum = rng.uniform(-0.5, 0.5, A) if passive else np.zeros(A)
    damping = rng.uniform(0.0, 2.0, A) if passive else np.zeros(A)
    # the last: the distance barrier with the tunable ε (the generic kernel's rows are _filter_rows_lanes')
    for torque, filter_on, v_max, distance, decay in ((False, True, 2.0, False, 0.0), (True, True, 3.0, False, 0.0),
                                                      (False, False, np.inf, False, 0.0),
                                                      (True, False, np.inf, False, 0.0),
                                                      (False, True, 2.0, True, 50.0)):
        command = rng.normal(scale=5.0 if torque else 2.5, size=v.shape)
        command[3] = 1e300
        runs = []
        for kernel in (kernels.group_advance, kernels.group_advance_generic):
            qk, vk = q.copy(), v.copy()
            out = [np.zeros((A, k)), np.zeros(A, bool), np.empty((A, k)), np.full((A, n), 7.0), np.empty((A, n)),
                   np.empty((A, 2)), np.full(A, np.inf), np.full(A, np.inf), np.zeros((A, 3), np.int64), np.zeros(A),
                   np.zeros(A, bool)]
            pk = momentum.copy()
            for _ in range(2):  # the second call starts from the first's v_prev / has_prev
                kernel(*kernel_sizes(n, k),
                       *kernel_groups(batch, damping, passive, qk, vk, pk, out[0], out[1], np.arange(A),
                                       _window(A, 5), command, torque, filter_on,
                                       np.broadcast_to(centers, (A, 3, 2)).copy(),
                                       np.broadcast_to(radii, (A, 3)).copy(), mask,
                                       _rcbf(0.5, 5.0, 0.01, distance, decay), 100.0, 1e-2, 5, v_max, out[2:]), None)
            runs.append([qk, vk, pk, *out])
        finite, counts = runs[0][-1], runs[0][-3]
        assert not finite[3]
        if filter_on:
            assert (counts[:, kernels.STATUS_SOLVED] > 0).any(), "the filter should change some commands"
        for got, expected in zip(runs[1], runs[0], strict=True):
            np.testing.assert_array_equal(_bits(got), _bits(expected))


def test_generic_kernel_checks_its_sizes() -> None:
    rng = np.random.default_rng(0)

    def call(n: int, k: int, batch, q, v, damping=None, rows=None) -> None:
        damping = np.zeros(1) if damping is None else damping
        rows = np.arange(1) if rows is None else rows
        outputs = (np.empty((1, k)), np.empty((1, k)), np.empty((1, n)), np.empty((1, 2)), np.full(1, np.inf),
                   np.full(1, np.inf), np.zeros((1, 3), np.int64), np.zeros(1), np.zeros(1, bool))
        groups = kernel_groups(batch, damping, True, q, v, np.zeros(1), np.zeros((1, k)), np.zeros(1, bool), rows,
                                _window(1, 1), np.zeros((1, k)), False, False, np.zeros((1, 0, 2)), np.zeros((1, 0)),
                                np.zeros((1, 0), bool), _rcbf(0.5, 5.0, 0.0, False, 0.0), 100.0, 1e-3, 1, np.inf,
                                outputs)
        kernels.group_advance_generic(*kernel_sizes(n, k), *groups, None)

    batch, q, v = _group(rng, 9, True, count=1)
    with pytest.raises(ValueError, match="n ≤ 8"):
        call(9, 8, batch, q, v)
    batch, q, v = _group(rng, 3, True, count=1)
    call(3, 2, batch, q, v)  # the sizes the checks below break, one at a time
    with pytest.raises(ValueError, match="kernel_sizes"):  # size tuples that disagree with the arrays
        call(3, 3, batch, q, v)
    with pytest.raises(ValueError, match="kernel_sizes"):  # a passive first joint needs k = n − 1
        call(3, 3, batch, q, np.zeros((1, 3)))
    with pytest.raises(ValueError, match="momentum and damping"):
        call(3, 2, batch, q, v, damping=np.zeros(2))
    for rows in (np.array([1]), np.array([0.0]), np.zeros((1, 1), np.int64)):
        with pytest.raises(ValueError, match="rows must be int64 indices"):
            call(3, 2, batch, q, v, rows=rows)


@pytest.mark.parametrize(("barrier", "decay"), [("squared", 0.0), ("squared", 20.0), ("distance", 0.0),
                                                ("distance", 5.0), ("distance", 50.0)])
def test_compiled_filter_choices_match_the_numpy_reference(barrier: str, decay: float) -> None:
    """The compiled end-effector rows with each barrier and λ (``_first_projection_lanes``, which
    writes them) against the numpy reference ``rcbf_constraints(..., barrier=, decay=)``, and its
    answers (first candidate where it settles a lane, the full compiled search elsewhere) against the
    reference's ``active_set_projection`` on the reference's rows. Lanes with the end-effector on an
    obstacle's centre (d = 0: a zero distance row, b < 0) and far from every obstacle (exp capped)
    are included; every end-effector drifts (a passive momentum's J₁ p₁ / M_11, ``drift=``)."""
    rng = np.random.default_rng(7 + int(decay) + 100 * (barrier == "distance"))
    O, k, W, v_max, margin = 3, 2, 600, 2.5, 0.01
    centers, radii = rng.uniform(-0.5, 0.5, (O, 2)), rng.uniform(0.05, 0.2, O)
    p = centers[rng.integers(0, O, W)] + rng.normal(scale=0.4, size=(W, 2))
    p[:5] = centers[0]  # d = 0
    p[5:10] += 40.0  # far: λ h̃ beyond the exponent's cap at λ = 50
    Jbar = rng.normal(size=(W, 2, k))
    v0 = rng.normal(scale=2.0, size=(W, k))
    drift = rng.normal(scale=0.3, size=(W, 2))
    active = np.zeros((O + 2 * k, W), bool)
    active[:O] = rng.random((O, W)) < 0.9
    active[O:] = True
    active[:O, :10] = True
    filtered = np.ones(W, bool)
    obstacles = np.stack([np.repeat(centers[:, :1], W, 1), np.repeat(centers[:, 1:], W, 1),
                          np.repeat(radii[:, None], W, 1)])
    violated, found, cand, A_all, b_all, arm_h = _first_candidates(
        np.ascontiguousarray(p[:, 0]), np.ascontiguousarray(p[:, 1]), np.ascontiguousarray(Jbar.transpose(1, 2, 0)),
        obstacles, active, filtered, np.ascontiguousarray(v0.T), 0.5, 5.0, margin, v_max, barrier == "distance",
        decay, np.ascontiguousarray(drift.T))
    A_ref, b_ref, h_ref = rcbf_constraints(p, Jbar, centers, radii, 0.5, 5.0, margin=margin, barrier=barrier,
                                           decay=decay, drift=drift)
    _, b_still, _ = rcbf_constraints(p, Jbar, centers, radii, 0.5, 5.0, margin=margin, barrier=barrier, decay=decay)
    assert np.abs(b_ref - b_still)[5:].min() > 0.0, "the drift moves every row but the zero ones"
    np.testing.assert_allclose(A_all[:, :O], A_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(b_all[:, :O], b_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(arm_h, np.where(active[:O].T, h_ref, np.inf).min(axis=1), rtol=1e-14)
    if barrier == "distance":
        assert np.all(A_all[:5, 0] == 0.0) and np.all(b_all[:5, 0] < 0.0), "d = 0: a zero row that cannot hold"
    # the answers: the reference's projection on the reference's rows and the same box
    A_box, b_box = A_all.copy(), b_all.copy()
    A_box[:, :O], b_box[:, :O] = A_ref, b_ref
    ref = active_set_projection(v0, A_box, b_box, active.T)
    v_out, status = np.empty((W, k)), np.zeros(W, np.int64)
    kernels.qp_project(v0, A_all, b_all, np.ascontiguousarray(active.T), v_out, status)
    np.testing.assert_array_equal(status, ref.status)
    np.testing.assert_allclose(v_out, ref.v, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(violated, status != kernels.STATUS_NOMINAL)
    settled = violated & found
    assert settled.any() and (status == kernels.STATUS_SOLVED).sum() > settled.sum()
    np.testing.assert_array_equal(cand.T[settled], v_out[settled])
    assert (status == kernels.STATUS_NOMINAL).any()
