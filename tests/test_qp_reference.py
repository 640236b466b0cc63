"""The numpy reference of the safety QP (safety.active_set_projection) against the compiled kernel
(kernels.qp_project, and kernels.compiled_projection batched as project_velocity), PIQP, and a KKT
certificate independent of all three.

The QP is min ½‖v − v0‖² s.t. A v ≤ b: strictly convex, so a feasible v with v0 − v = Aᵀλ, λ ≥ 0
and λ_j = 0 on slack rows is its unique optimum.

Tolerances. The reference and the kernel run the same search with the same tolerances, so they
take the same decisions (status, active set) and differ only in the rounding of the Gram solve
G λ = A_S v0 − b_S (LAPACK against the kernel's own LDLᵀ). That rounding is amplified by
cond(G) = κ(A_S)², so two exact solvers may differ by about ε κ² relative, however correct: a near-
parallel pair of binding rows (κ ≈ 1e5) puts the solution's 6th digit at the mercy of rounding.
Hence the bound ``_kernel_tolerance``: 1e-9 relative (the kernel's CANDIDATE_TOLERANCE: a tie
between two sets the search accepts cannot move the answer further) plus 100 ε κ_T², where κ_T is
the condition number of the rows tight at the answer (measured: the gap never exceeded 1.4 ε κ_T²
+ 4e-13 relative, and stayed under 1% of this bound on 180 000 solved problems of the families
below). NOMINAL and FALLBACK answers are v0 and 0: compared exactly.

Where rounding decides. A nearly antiparallel pair of rows (θ ≈ 1e-3…1e-5 from antiparallel) that
meets other tight rows at one point (a degenerate vertex in a sliver of feasible set) leaves the
search with sets whose multipliers are 0 ± ε/θ² or whose candidates miss a row by about the
tolerance: whether the kernel answers SOLVED or brakes is then a matter of its rounding, and the
numpy reference, rounding differently, decided otherwise in 3 to 46 of 32 000 problems per tilt
(1e-2 to 1e-5) when the tilted row went through the others' common point (the SOLVED answer being
valid: it passes the KKT check). The generators below keep the tilted row off that point (positive
slack; tilts 1e-3, or below the pivot test), where no disagreement was seen in 240 000 problems.
"""

import numpy as np
import pytest
import qpsolvers
from arms import random_arm
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import nnls

from pan1_env import kernels
from pan1_env.cascade import reduced_jacobian
from pan1_env.dynamics import ArmBatch, end_effector
from pan1_env.safety import (
    CANDIDATE_TOLERANCE,
    PIQP_SETTINGS,
    PIVOT_TOLERANCE,
    QP_SOLVERS,
    ROW_TOLERANCE,
    QPStatus,
    active_set_projection,
    project_velocity,
    rcbf_constraints,
)

EPS = np.finfo(float).eps
NOMINAL, SOLVED, FALLBACK = int(QPStatus.NOMINAL), int(QPStatus.SOLVED), int(QPStatus.FALLBACK)


# --------------------------------------------------------------------------- problems


def _kernel(v0, A, b):
    """The compiled QP, called as project_velocity calls it (rows with +inf b are off)."""
    active = np.isfinite(b)
    v, status = np.empty_like(v0), np.empty(v0.shape[0], dtype=np.int64)
    kernels.qp_project(np.ascontiguousarray(v0), np.ascontiguousarray(A), np.where(active, b, 0.0), active, v, status)
    return v, status


def _box(A, b, v_max):
    """Append the speed box |v_t| ≤ v_max (rows e_t and −e_t, as the compiled filter orders them)."""
    B, _, k = A.shape
    box = np.zeros((2 * k, k))
    box[0::2] = np.eye(k)
    box[1::2] = -np.eye(k)
    return (np.concatenate([A, np.broadcast_to(box, (B, 2 * k, k))], axis=1),
            np.concatenate([b, np.full((B, 2 * k), v_max)], axis=1))


def _rcbf_batch(rng, n, passive, B, O, box, margin=0.0, v_max=None):
    """The filter's own rows: rcbf_constraints of B random arms (n links) near O obstacles each,
    some obstacles switched off, and optionally the speed box."""
    batch = ArmBatch.stack([random_arm(rng, n, passive=passive, placed=True) for _ in range(B)])
    q = rng.uniform(-np.pi, np.pi, (B, n))
    p, Jbar = end_effector(batch, q), reduced_jacobian(batch, q)
    k = Jbar.shape[-1]
    A, b = np.empty((B, O, k)), np.empty((B, O))
    for i in range(B):  # each arm's own obstacles, around its end-effector
        centers = p[i] + rng.normal(scale=0.4, size=(O, 2))
        A[i], b[i], _ = rcbf_constraints(p[i], Jbar[i], centers, rng.uniform(0.05, 0.25, O), rng.uniform(0.2, 2.0),
                                         rng.uniform(1.0, 20.0), active=rng.random(O) < 0.8, margin=margin)
    v0 = rng.normal(scale=2.0, size=(B, k))
    if box:
        A, b = _box(A, b, rng.uniform(0.3, 3.0) if v_max is None else v_max)
    return v0, A, b


def _synthetic_batch(rng, kind, B, k, m, feasible):
    """Random rows of one kind; ``feasible``: b = A v_f + s with s ≥ 0 (often 0, so several rows
    are tight at v_f: degenerate vertices), else b random (a share of the problems is infeasible)."""
    A = rng.normal(size=(B, m, k))
    if kind == "rank2":  # like the RCBF rows: rank ≤ 2 whatever m and k
        A = rng.normal(size=(B, m, 2)) @ rng.normal(size=(B, 2, k))
    elif kind in ("parallel", "antiparallel"):  # the last row a (±) multiple of the first, tilted
        sign = 1.0 if kind == "parallel" else -1.0
        # 1e-12 and 1e-30 fall below the pivot test (θ² < 1e-12: treated as parallel), 1e-3 well
        # above; near 1e-5 the pair's Gram matrix (cond ≈ 1/θ²) decides by rounding (docstring)
        tilt = 10.0 ** rng.choice([-3.0, -12.0, -30.0], size=(B, 1))
        A[:, -1] = sign * rng.uniform(0.5, 2.0, (B, 1)) * A[:, 0] + tilt * rng.normal(size=(B, k))
    elif kind == "duplicate":
        A[:, -1] = A[:, 0]
    if feasible:
        v_f = rng.normal(size=(B, k))
        slack = np.where(rng.random((B, m)) < 0.4, 0.0, rng.exponential(1.0, (B, m)))
        if kind in ("parallel", "antiparallel"):  # the tilted row not through v_f (docstring)
            slack[:, -1] += 0.05 + rng.exponential(1.0, B)
        b = np.einsum("bmk,bk->bm", A, v_f) + slack
        v0 = v_f + rng.normal(scale=3.0, size=(B, k))
    else:
        b = rng.normal(scale=2.0, size=(B, m))
        v0 = rng.normal(scale=3.0, size=(B, k))
    off = rng.random((B, m)) < 0.15
    b[off] = np.inf
    A[off & (rng.random((B, m)) < 0.5)] = 0.0  # how rcbf_constraints switches a row off
    return v0, A, b


SYNTHETIC = ("generic", "rank2", "parallel", "antiparallel", "duplicate")


def _batches(seed, feasible):
    """(v0, A, b) batches: every synthetic kind at several sizes, then RCBF rows with and without
    the speed box."""
    rng = np.random.default_rng(seed)
    for kind in SYNTHETIC:
        for k in (1, 2, 3, 4):
            yield _synthetic_batch(rng, kind, 40, k, int(rng.integers(2, 7)), feasible)
    for n, passive in ((2, True), (3, True), (3, False), (4, True), (5, True)):
        for box in (False, True):
            yield _rcbf_batch(rng, n, passive, 40, int(rng.integers(1, 5)), box)


# --------------------------------------------------------------------------- checks


def _scale(A, b, v):
    return 1.0 + np.abs(b) + np.linalg.norm(A, axis=-1) * (1.0 + np.linalg.norm(v))


def _tight_condition(A, b, v):
    """κ of the rows tight at v (nonzero singular values only: repeated rows do not count)."""
    on = np.isfinite(b)
    A, b = A[on], b[on]
    tight = np.abs(A @ v - b) <= 1e-8 * _scale(A, b, v)
    if not tight.any():
        return 1.0
    s = np.linalg.svd(A[tight], compute_uv=False)
    s = s[s > 1e-7 * s[0]]
    return float(s[0] / s[-1])


def _kernel_tolerance(v0, A, b, v):
    """|v_numpy − v_kernel| bound (module docstring): rounding of the Gram solve, amplified by κ²."""
    rel = CANDIDATE_TOLERANCE + 100.0 * EPS * _tight_condition(A, b, v) ** 2
    return rel * (1.0 + np.linalg.norm(v0) + np.linalg.norm(v))


def _kkt_residual(v0, A, b, v, active_tol=1e-8):
    """Scaled KKT residual of v (≈ 0 only at the optimum), from nothing but A, b, v0 and v:
    primal infeasibility, and the distance of v0 − v from the cone of the rows active at v
    (non-negative multipliers by scipy's NNLS: λ ≥ 0 and zero on slack rows)."""
    on = np.isfinite(b)
    A, b = A[on], b[on]
    scale = _scale(A, b, v)
    slack = (b - A @ v) / scale
    primal = max(0.0, float(-slack.min())) if slack.size else 0.0
    active = slack <= active_tol
    step = v0 - v
    size = 1.0 + np.linalg.norm(v0) + np.linalg.norm(v)  # a far optimum's step rounds in proportion
    if not active.any():
        return max(primal, float(np.linalg.norm(step)) / size)
    _, residual = nnls(A[active].T, step)
    return max(primal, residual / size)


def _assert_same_as_kernel(v0, A, b, res, vk, sk):
    np.testing.assert_array_equal(res.status, sk)
    for i in range(len(sk)):
        if sk[i] == NOMINAL:
            np.testing.assert_array_equal(res.v[i], v0[i])
        elif sk[i] == FALLBACK:
            np.testing.assert_array_equal(res.v[i], 0.0)
        elif not np.all(np.isfinite(vk[i])):  # e.g. a row whose squared norm is subnormal: λ = inf
            np.testing.assert_array_equal(res.v[i], vk[i])
        else:
            gap = np.linalg.norm(res.v[i] - vk[i])
            assert gap <= _kernel_tolerance(v0[i], A[i], b[i], vk[i]), (gap, A[i], b[i], v0[i], vk[i], res.v[i])


# --------------------------------------------------------------------------- (1) numpy against the kernel


@pytest.mark.parametrize("feasible", [True, False])
@pytest.mark.parametrize("seed", [0, 1])
def test_numpy_matches_the_compiled_kernel(seed: int, feasible: bool) -> None:
    counts = np.zeros(3, dtype=int)
    for v0, A, b in _batches(seed, feasible):
        res = active_set_projection(v0, A, b)
        vk, sk = _kernel(v0, A, b)
        _assert_same_as_kernel(v0, A, b, res, vk, sk)
        counts += np.bincount(sk, minlength=3)
    assert counts[SOLVED] > 500 and counts[NOMINAL] > 50, counts  # the search itself is exercised
    if not feasible:
        assert counts[FALLBACK] > 100, counts


def test_compiled_projection_equals_project_velocity() -> None:
    """kernels.compiled_projection, the compiled QP for callers with many problems, gives the numpy
    project_velocity's statuses and answers (within the Gram solve's rounding) on random problems,
    infeasible ones included, through the same nominal pre-check."""
    counts = np.zeros(3, dtype=int)
    for v0, A, b in _batches(2, feasible=False):
        ref = project_velocity(v0, A, b, solver="active_set")
        res = kernels.compiled_projection(v0, A, b)
        np.testing.assert_array_equal(res.status, ref.status)
        for i in range(len(v0)):
            assert np.linalg.norm(res.v[i] - ref.v[i]) <= _kernel_tolerance(v0[i], A[i], b[i], ref.v[i])
        counts += np.bincount(res.status, minlength=3)
    assert counts.min() > 50, counts  # every outcome is compared


def test_the_simulator_solvers_are_the_references() -> None:
    assert QP_SOLVERS == ("active_set", "piqp")
    with pytest.raises(ValueError, match="unknown QP solver"):
        project_velocity(np.zeros((1, 2)), np.zeros((1, 1, 2)), np.zeros((1, 1)), solver="numpy")


def test_leading_batch_axes_and_explicit_mask() -> None:
    """Any leading shape; an explicit ``active`` mask switches rows off whatever their b (the kernel's
    ``active`` argument), and the default mask is isfinite(b)."""
    rng = np.random.default_rng(5)
    v0, A, b = _synthetic_batch(rng, "generic", 12, 3, 5, feasible=False)
    flat = active_set_projection(v0, A, b)
    shaped = active_set_projection(v0.reshape(3, 4, 3), A.reshape(3, 4, 5, 3), b.reshape(3, 4, 5))
    assert shaped.v.shape == (3, 4, 3) and shaped.status.shape == (3, 4)
    np.testing.assert_array_equal(shaped.v.reshape(12, 3), flat.v)
    np.testing.assert_array_equal(shaped.status.reshape(12), flat.status)
    mask = rng.random((12, 5)) < 0.6
    masked = active_set_projection(v0, A, np.where(mask, b, -7.0), active=mask)  # −7: ignored rows
    np.testing.assert_array_equal(masked.v, active_set_projection(v0, A, np.where(mask, b, np.inf)).v)


@st.composite
def _problems(draw):
    """One arm: k ≤ 4 unknowns, m ≤ 6 rows; rows may repeat an earlier row times a factor of either
    sign, or be switched off; b of any sign (infeasible problems included)."""
    k, m = draw(st.integers(1, 4)), draw(st.integers(1, 6))
    # six decimals: exact zeros and ties, but no 1e-160 entries, whose subnormal squares the kernel
    # (fastmath reciprocals) and numpy round apart (both answer a non-finite v with status SOLVED)
    value = st.floats(-4.0, 4.0, allow_nan=False).map(lambda x: round(x, 6))
    rows, b = [], []
    for j in range(m):
        if j and draw(st.booleans()):  # a copy of row i: exact, or tilted (off row i's b: docstring)
            i = draw(st.integers(0, j - 1))
            factor = draw(st.sampled_from([1.0, 2.5, -1.0, -0.5]))
            tilt = draw(st.sampled_from([0.0, 1e-12, 1e-3]))
            rows.append(factor * rows[i] + tilt * np.arange(1.0, k + 1.0))
            b.append(factor * b[i] + (draw(value) if tilt == 0.0 else draw(st.floats(0.05, 4.0))))
        else:
            rows.append(np.array(draw(st.lists(value, min_size=k, max_size=k))))
            b.append(draw(value))
    off = draw(st.lists(st.integers(0, 3).map(lambda x: x == 0), min_size=m, max_size=m))  # a quarter
    b = np.where(off, np.inf, b)
    v0 = np.array(draw(st.lists(value, min_size=k, max_size=k)))
    return v0[None], np.array(rows)[None], b[None]


@settings(max_examples=300, deadline=None)
@given(_problems())
def test_numpy_matches_the_kernel_on_drawn_problems(problem) -> None:
    v0, A, b = problem
    vk, sk = _kernel(v0, A, b)
    _assert_same_as_kernel(v0, A, b, active_set_projection(v0, A, b), vk, sk)


def test_tolerances_are_the_kernels() -> None:
    """One owner: the compiled QP reads the reference's constants (numba freezes them at compile time)."""
    assert ROW_TOLERANCE == kernels.qp.ROW_TOLERANCE and CANDIDATE_TOLERANCE == kernels.qp.CANDIDATE_TOLERANCE
    assert PIVOT_TOLERANCE == kernels.physics.PIVOT_TOLERANCE


@pytest.mark.parametrize("pivot", [0.25, 0.9, 1.1, 4.0])
def test_pivot_threshold_is_the_kernels(pivot: float) -> None:
    """Two orthogonal rows, both binding at the optimum (1, 2), the second scaled by √t: their Gram
    matrix diag(1, t) passes the independence test iff t > PIVOT_TOLERANCE. Below it the QP is
    feasible but the search has no other set that works, and both solvers brake (FALLBACK, v = 0)."""
    t = pivot * PIVOT_TOLERANCE
    A = np.array([[[1.0, 0.0], [0.0, np.sqrt(t)]]])
    b = np.array([[1.0, 2.0 * np.sqrt(t)]])
    v0 = np.array([[3.0, 5.0]])
    vk, sk = _kernel(v0, A, b)
    res = active_set_projection(v0, A, b)
    expected = SOLVED if pivot > 1.0 else FALLBACK
    assert sk[0] == expected and res.status[0] == expected
    np.testing.assert_allclose(res.v[0], [1.0, 2.0] if pivot > 1.0 else [0.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(vk[0], res.v[0], rtol=0, atol=1e-12)


_E = np.eye(2)
_C = CANDIDATE_TOLERANCE * 2.0  # the candidate test's allowance on a unit row with b = 0, ‖v‖ ≈ 0


@pytest.mark.parametrize("v0, A, b, expected, status", [
    # v0 breaks row 0 by half, then by twice ROW_TOLERANCE·(1 + |b|): nominal, then projected
    ([1.0 + 0.5e-12 * 2.0, 0.0], _E[:1], [1.0], [1.0 + 1e-12, 0.0], NOMINAL),
    ([1.0 + 2.0e-12 * 2.0, 0.0], _E[:1], [1.0], [1.0, 0.0], SOLVED),
    # the projection onto row 0 misses row 1 by half, then by twice the candidate allowance: taken,
    # then refused (the pair's vertex is the answer)
    ([1.0, 0.5 * _C], _E, [0.0, 0.0], [0.0, 0.5 * _C], SOLVED),
    ([1.0, 2.0 * _C], _E, [0.0, 0.0], [0.0, 0.0], SOLVED),
    # both single-row projections pass the allowance: the more violated row is tried first ...
    ([3e-10, 5e-10], _E, [0.0, 0.0], [3e-10, 0.0], SOLVED),
    ([5e-10, 3e-10], _E, [0.0, 0.0], [0.0, 3e-10], SOLVED),
    # ... by violation per unit norm (row 1 scaled by 4 breaks its b by more, but less per norm) ...
    ([5e-10, 3e-10], np.diag([1.0, 4.0]), [0.0, 0.0], [0.0, 3e-10], SOLVED),
    # ... and on a tie, the lower row
    ([4e-10, 4e-10], _E, [0.0, 0.0], [0.0, 4e-10], SOLVED),
])
def test_search_order_and_tolerances_are_the_kernels(v0, A, b, expected, status) -> None:
    """Where the tolerances let more than one answer through, the numpy reference makes the
    kernel's choice: the expected v (exact to rounding of these few operations) and status."""
    v0, A, b = np.array([v0]), np.array([A]), np.array([b])
    vk, sk = _kernel(v0, A, b)
    res = active_set_projection(v0, A, b)
    assert sk[0] == status and res.status[0] == status
    np.testing.assert_allclose(vk[0], expected, rtol=0, atol=1e-18)
    np.testing.assert_allclose(res.v[0], expected, rtol=0, atol=1e-18)


# --------------------------------------------------------------------------- (2) numpy against PIQP


def _piqp(v0, A, b):
    """PIQP on one arm's finite rows, with the filter's settings: (v, multipliers, rows used)."""
    on = np.isfinite(b)
    sol = qpsolvers.solve_problem(qpsolvers.Problem(np.eye(len(v0)), -v0, A[on], b[on]), solver="piqp",
                                  **PIQP_SETTINGS)
    assert sol.found
    return sol.x, sol.z, on


def test_numpy_matches_piqp_on_feasible_problems() -> None:
    """Where PIQP solves, both give the same status and the same v within 1e-8 relative (PIQP's
    accuracy with PIQP_SETTINGS, as test_safety_qp's bar: an interior-point method stops a little
    inside binding rows; measured largest gap 6.4e-11 on 10 000 problems of these families), and
    PIQP's own multipliers certify the numpy answer: z ≥ 0, v0 − v = Aᵀz and z_j = 0 on slack rows,
    within 1e-8. PIQP declares a few nearly antiparallel binding pairs infeasible (3 in 10 000: a
    far optimum with no room inside; RCBF rows of real arms too): there the numpy answer must pass
    the independent KKT check, and such cases must stay rare."""
    solved = piqp_failed = 0
    for v0, A, b in _batches(3, feasible=True):
        res = project_velocity(v0, A, b, solver="active_set")
        pq = project_velocity(v0, A, b, solver="piqp")
        for i in range(len(v0)):
            if pq.status[i] == FALLBACK and res.status[i] == SOLVED:
                assert _kkt_residual(v0[i], A[i], b[i], res.v[i]) < 1e-8, (A[i], b[i], v0[i], res.v[i])
                piqp_failed += 1
                continue
            assert res.status[i] == pq.status[i], (A[i], b[i], v0[i], res.v[i], pq.v[i])
            if res.status[i] != SOLVED:
                continue
            scale = 1.0 + np.linalg.norm(v0[i]) + np.linalg.norm(res.v[i])
            assert np.linalg.norm(res.v[i] - pq.v[i]) <= 1e-8 * scale, (A[i], b[i], v0[i], res.v[i], pq.v[i])
            x, z, on = _piqp(v0[i], A[i], b[i])
            Ai, bi = A[i][on], b[i][on]
            assert np.all(z >= -1e-9 * (1.0 + np.abs(z).max()))
            np.testing.assert_allclose(v0[i] - res.v[i], Ai.T @ z, rtol=0, atol=1e-8 * scale)
            slack = (bi - Ai @ res.v[i]) / _scale(Ai, bi, res.v[i])
            assert np.all(slack >= -1e-9) and np.all(np.abs(z * slack) <= 1e-8 * scale)
            solved += 1
    assert solved > 500 and piqp_failed <= 0.02 * solved, (solved, piqp_failed)


# --------------------------------------------------------------------------- (3) an independent certificate


@pytest.mark.parametrize("seed", [4, 5])
def test_numpy_answers_satisfy_kkt(seed: int) -> None:
    """Every NOMINAL or SOLVED answer is feasible and stationary (NNLS multipliers ≥ 0 on the active
    rows), to 1e-8: the kernel's own acceptance is 1e-9 relative on rows and multipliers, and the
    scaled NNLS residual adds rounding. Checked with nothing from the solvers but the answer."""
    checked = 0
    for v0, A, b in _batches(seed, feasible=False):
        res = active_set_projection(v0, A, b)
        for i in np.flatnonzero(res.status != FALLBACK):
            assert _kkt_residual(v0[i], A[i], b[i], res.v[i]) < 1e-8, (A[i], b[i], v0[i], res.v[i])
            checked += 1
    assert checked > 800


def test_kkt_check_rejects_wrong_answers() -> None:
    """The certificate above can fail: moving the optimum by 1e-4 in a random direction, or
    returning the projection onto the most violated row alone when other rows bind, is caught."""
    rng = np.random.default_rng(6)
    moved = single = 0
    for v0, A, b in _batches(7, feasible=True):
        res = active_set_projection(v0, A, b)
        for i in np.flatnonzero(res.status == SOLVED):
            if _tight_condition(A[i], b[i], res.v[i]) > 1e2:
                continue  # an ill-conditioned corner: a 1e-4 step may look stationary
            d = rng.normal(size=v0.shape[1])
            wrong = res.v[i] + 1e-4 * (1.0 + np.linalg.norm(res.v[i])) * d / np.linalg.norm(d)
            assert _kkt_residual(v0[i], A[i], b[i], wrong) > 1e-8
            moved += 1
            on = np.isfinite(b[i]) & (np.linalg.norm(A[i], axis=1) > 0)
            Ai, bi = A[i][on], b[i][on]
            j = np.argmax((Ai @ v0[i] - bi) / np.linalg.norm(Ai, axis=1))
            one = v0[i] - (Ai[j] @ v0[i] - bi[j]) / (Ai[j] @ Ai[j]) * Ai[j]
            if np.linalg.norm(one - res.v[i]) > 1e-6 * (1.0 + np.linalg.norm(res.v[i])):
                assert _kkt_residual(v0[i], A[i], b[i], one) > 1e-8
                single += 1
    assert moved > 300 and single > 50, (moved, single)


# --------------------------------------------------------------------------- infeasible problems


def _infeasible_problems(rng):
    """Problems with a Farkas certificate of infeasibility (y ≥ 0, yᵀA = 0, yᵀb < 0), one arm each."""
    out = []
    for _ in range(40):  # a·v ≤ β and −c a·v ≤ −c β − gap (y = (c, 1)), among random rows
        k = int(rng.integers(1, 5))
        a, c, beta, gap = rng.normal(size=k), rng.uniform(0.3, 3.0), rng.normal(), rng.uniform(0.1, 2.0)
        A = np.vstack([a, -c * a, rng.normal(size=(2, k))])
        b = np.array([beta, -c * beta - gap, rng.normal(), np.inf])
        order = rng.permutation(4)
        out.append((rng.normal(size=k), A[order], b[order]))
    # the filter's zero row: J̄ of rank 1 cannot move the end-effector away from obstacle 0, and the
    # arm is inside its margin (b_0 = κ (h − margin) < 0): 0·v ≤ b_0 < 0
    A, b, h = rcbf_constraints(np.zeros(2), np.array([[1.0, 0.5], [0.0, 0.0]]), np.array([[0.0, 0.3], [1.0, 0.0]]),
                               np.array([0.2, 0.1]), 0.5, 2.0, margin=0.1)
    assert np.all(A[0] == 0.0) and b[0] < 0.0
    out.append((np.array([1.0, 1.0]), A, b))
    # RCBF rows against the speed box: a row A_j v ≤ b_j with b_j < min over the box of A_j v
    # = −‖A_j‖₁ v_max (y = 1 on row j and |A_jt| on the box row of joint t that opposes it)
    for n in (2, 3, 4):
        v0, A, b = _rcbf_batch(rng, n, True, 60, 3, box=True, margin=0.5, v_max=0.05)
        O = 3
        certified = np.any(b[:, :O] < -0.05 * np.abs(A[:, :O]).sum(axis=-1) - 1e-3, axis=1)
        out += [(v0[i], A[i], b[i]) for i in np.flatnonzero(certified)]
    return out


def test_infeasible_problems_brake_in_all_three_solvers() -> None:
    problems = _infeasible_problems(np.random.default_rng(8))
    assert len(problems) > 80
    for v0, A, b in problems:
        res = active_set_projection(v0[None], A[None], b[None])
        vk, sk = _kernel(v0[None], A[None], b[None])
        pq = project_velocity(v0[None], A[None], b[None], solver="piqp")
        assert res.status[0] == sk[0] == pq.status[0] == FALLBACK, (A, b, v0)
        np.testing.assert_array_equal(res.v[0], 0.0)
        np.testing.assert_array_equal(vk[0], 0.0)
