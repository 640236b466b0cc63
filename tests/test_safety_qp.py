"""The safety QP v* = argmin ½‖v − v0‖² s.t. A v ≤ b and its RCBF rows (docs/MODEL.md §5, Eq. 56–61).

The solvers: project_velocity's numpy active set (the reference) and PIQP, and the compiled active
set (kernels.compiled_projection), which must give the reference's answers.
Optimality is certified independently of the solvers by the KKT conditions (the QP is strictly
convex, so a feasible point with v0 − v = Aᵀλ, λ ≥ 0 on the active rows is the unique optimum);
the multipliers come from scipy's NNLS.
"""

from collections import defaultdict

import numpy as np
import pytest
from scipy.optimize import nnls

from pan1_env import kernels
from pan1_env.cascade import reduced_jacobian
from pan1_env.dynamics import ArmParams, end_effector
from pan1_env.safety import (
    QPStatus,
    barrier,
    barrier_lie_derivative,
    clearance,
    project_velocity,
    rcbf_constraints,
    robust_margin,
)

N_PROBLEMS = 1000
SOLVERS = ["active_set", "piqp", "compiled"]


def _project(v0: np.ndarray, A: np.ndarray, b: np.ndarray, solver: str):
    if solver == "compiled":
        return kernels.compiled_projection(v0, A, b)
    return project_velocity(v0, A, b, solver=solver)


# --------------------------------------------------------------------------- problem generator


def _real_rows(rng: np.random.Generator, k: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows like the real filter's: A_j = −2 (p − o_j)ᵀ J̄ with J̄ the reduced Jacobian of a random
    PA arm with k + 1 links (so rank A ≤ 2)."""
    n = k + 1
    lengths = rng.uniform(0.2, 0.5, n)
    arm = ArmParams(
        masses=rng.uniform(0.1, 1.0, n), lengths=lengths, com=0.5 * lengths,
        inertias=rng.uniform(1e-3, 1e-2, n),
    )
    q = rng.uniform(-np.pi, np.pi, n)
    p = end_effector(arm, q)
    centers = p + rng.normal(scale=0.5, size=(m, 2))
    return -barrier_lie_derivative(p, reduced_jacobian(arm, q), centers), centers


def _random_problem(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """A feasible problem (by construction: b = A v_f + s with s ≥ 0, some s = 0 so that rows are
    exactly tight at v_f), often degenerate, with some rows switched off (b = +inf)."""
    k = int(rng.integers(1, 5))
    m = int(rng.integers(1, 5))
    kind = ["generic", "rank2", "parallel", "duplicate", "real"][int(rng.integers(5))]
    if kind == "generic":
        A = rng.normal(size=(m, k))
    elif kind == "rank2":  # every row w_jᵀ J: rank ≤ 2 whatever m and k
        A = rng.normal(size=(m, 2)) @ rng.normal(size=(2, k))
    elif kind == "parallel":  # rows are multiples (of either sign) of one row
        A = np.outer(rng.normal(size=m), rng.normal(size=k))
    elif kind == "duplicate":  # a row repeated, scaled by a positive factor
        A = rng.normal(size=(m, k))
        A[-1] = A[0] * rng.uniform(0.5, 2.0)
    else:
        A, _ = _real_rows(rng, k, m)
    v_f = rng.normal(size=k)
    slack = np.where(rng.random(m) < 0.3, 0.0, rng.exponential(1.0, m))
    b = A @ v_f + slack
    off = rng.random(m) < 0.2
    if off.any():
        b[off] = np.inf
        if rng.random() < 0.5:
            A[off] = 0.0  # how rcbf_constraints switches a row off
    v0 = v_f + rng.normal(scale=3.0, size=k)
    return v0, A, b, kind


@pytest.fixture(scope="module")
def problems() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, str]]:
    rng = np.random.default_rng(0)
    return [_random_problem(rng) for _ in range(N_PROBLEMS)]


def _solve_grouped(problems, solver: str) -> list[tuple[np.ndarray, int]]:
    """Solve all problems, batching those with the same (m, k) into one call."""
    groups: dict[tuple[int, int], list[int]] = defaultdict(list)
    for i, (_, A, _, _) in enumerate(problems):
        groups[A.shape].append(i)
    out: list = [None] * len(problems)
    for idx in groups.values():
        v0 = np.stack([problems[i][0] for i in idx])
        A = np.stack([problems[i][1] for i in idx])
        b = np.stack([problems[i][2] for i in idx])
        res = _project(v0, A, b, solver)
        assert res.v.shape == v0.shape and res.status.shape == (len(idx),)
        for j, i in enumerate(idx):
            out[i] = (res.v[j], int(res.status[j]))
    return out


@pytest.fixture(scope="module")
def active_set_answers(problems):
    return _solve_grouped(problems, "active_set")


@pytest.fixture(scope="module")
def compiled_answers(problems):
    return _solve_grouped(problems, "compiled")


@pytest.fixture(scope="module")
def piqp_answers(problems):
    return _solve_grouped(problems, "piqp")


def _kkt_violation(
    v0: np.ndarray, A: np.ndarray, b: np.ndarray, v: np.ndarray, active_tol: float = 1e-8
) -> float:
    """Scaled KKT residual of v for min ½‖v − v0‖² s.t. A v ≤ b (0 at the exact optimum).

    Rows with scaled slack ≤ ``active_tol`` count as active (may carry a multiplier)."""
    finite = np.isfinite(b)
    A, b = A[finite], b[finite]
    scale = 1.0 + np.abs(b) + np.linalg.norm(A, axis=1) * (1.0 + np.linalg.norm(v))
    slack = (b - A @ v) / scale
    primal = max(0.0, float(-slack.min())) if slack.size else 0.0
    active = slack <= active_tol
    step = v0 - v
    if not active.any():
        return max(primal, float(np.linalg.norm(step)) / (1.0 + np.linalg.norm(v0)))
    _, residual = nnls(A[active].T, step)  # v0 − v = A_actᵀ λ with λ ≥ 0?
    return max(primal, residual / (1.0 + np.linalg.norm(v0)))


# --------------------------------------------------------------------------- the two solvers


def test_problem_mix_is_degenerate_enough(problems) -> None:
    kinds = {kind for *_, kind in problems}
    assert kinds == {"generic", "rank2", "parallel", "duplicate", "real"}
    rank_deficient = sum(
        np.linalg.matrix_rank(A[np.isfinite(b)]) < min(np.isfinite(b).sum(), A.shape[1])
        for _, A, b, _ in problems
    )
    assert rank_deficient > 200
    assert sum(np.isinf(b).any() for _, _, b, _ in problems) > 200
    for _, A, _, kind in problems:
        if kind == "real":
            assert np.linalg.matrix_rank(A) <= 2


def test_active_set_is_the_exact_optimum(problems, active_set_answers) -> None:
    statuses = [s for _, s in active_set_answers]
    assert statuses.count(QPStatus.SOLVED) > 300  # most problems have a binding row
    for (v0, A, b, kind), (v, status) in zip(problems, active_set_answers, strict=True):
        assert status in (QPStatus.NOMINAL, QPStatus.SOLVED), (kind, A, b, v0)
        assert _kkt_violation(v0, A, b, v) < 1e-9, (kind, A, b, v0, v)


def test_piqp_answers_are_feasible_and_nearly_optimal(problems, piqp_answers) -> None:
    """PIQP, an interior-point method, stops a little inside binding rows: count rows within 1e-5
    as active. Measured largest residual on this set 5e-9."""
    for (v0, A, b, kind), (v, status) in zip(problems, piqp_answers, strict=True):
        assert status in (QPStatus.NOMINAL, QPStatus.SOLVED), (kind, A, b, v0)
        finite = np.isfinite(b)
        assert np.all(A[finite] @ v <= b[finite] + 1e-8 * (1.0 + np.abs(b[finite])))
        assert _kkt_violation(v0, A, b, v, active_tol=1e-5) < 1e-5, (kind, A, b, v0, v)


def test_solvers_agree(problems, active_set_answers, piqp_answers) -> None:
    """Same status and v within 1e-8 on every problem (issue 5's bar; with PIQP_SETTINGS the
    measured largest gap on these 1000 problems is 5.0e-11)."""
    for (v0, A, b, kind), (va, sa), (vp, sp) in zip(
        problems, active_set_answers, piqp_answers, strict=True
    ):
        assert sa == sp, (kind, A, b, v0)
        np.testing.assert_allclose(va, vp, rtol=0, atol=1e-8, err_msg=f"{kind} {A} {b} {v0}")


def test_compiled_active_set_is_the_reference(problems, active_set_answers, compiled_answers) -> None:
    """The compiled enumeration takes the numpy reference's decisions (same status) and differs only
    in the rounding of its Gram solve (tests/test_qp_reference.py bounds it by the rows' condition;
    measured here under 1e-12), and its answers pass the KKT check on their own."""
    for (v0, A, b, kind), (va, sa), (vc, sc) in zip(problems, active_set_answers, compiled_answers, strict=True):
        assert sa == sc, (kind, A, b, v0)
        tol = 1e-9 * (1.0 + np.linalg.norm(v0))
        np.testing.assert_allclose(vc, va, rtol=0, atol=tol, err_msg=f"{kind} {A} {b} {v0}")
        assert _kkt_violation(v0, A, b, vc) < 1e-9, (kind, A, b, v0, vc)


# A problem found by an earlier version of the generator above (inputs rounded to 6 digits): one
# binding row with a small multiplier (λ ≈ 1.4e-3) and ‖v0‖ ≈ 12.
_HARD_V0 = np.array([1.240337, 3.043209, 8.836358, -8.048416])
_HARD_A = np.array(
    [
        [1.823621, 0.400448, -0.656603, 1.151079],
        [-0.873445, -0.429896, 0.550951, 0.427447],
        [-1.557993, 2.043961, 0.615711, 1.320370],
    ]
)
_HARD_B = np.array([4.053322, -0.965477, 2.603457])


def test_hard_problem_active_set_is_optimal() -> None:
    res = project_velocity(_HARD_V0[None], _HARD_A[None], _HARD_B[None], solver="active_set")
    assert res.status[0] == QPStatus.SOLVED
    v = res.v[0]
    assert _kkt_violation(_HARD_V0, _HARD_A, _HARD_B, v) < 1e-12
    # Independently: the optimum is the projection onto row 1's hyperplane alone.
    a, beta = _HARD_A[1], _HARD_B[1]
    v_ref = _HARD_V0 - (a @ _HARD_V0 - beta) / (a @ a) * a
    assert np.all(_HARD_A @ v_ref <= _HARD_B + 1e-12)
    np.testing.assert_allclose(v, v_ref, rtol=0, atol=1e-12)


def test_hard_problem_piqp_is_accurate() -> None:
    res = project_velocity(_HARD_V0[None], _HARD_A[None], _HARD_B[None], solver="piqp")
    a, beta = _HARD_A[1], _HARD_B[1]
    v_ref = _HARD_V0 - (a @ _HARD_V0 - beta) / (a @ a) * a
    assert res.status[0] == QPStatus.SOLVED
    np.testing.assert_allclose(res.v[0], v_ref, rtol=0, atol=1e-8)


def test_batched_equals_single(problems, active_set_answers) -> None:
    for (v0, A, b, _), (v, status) in list(zip(problems, active_set_answers, strict=True))[:200]:
        res = project_velocity(v0[None], A[None], b[None], solver="active_set")
        np.testing.assert_allclose(res.v[0], v, rtol=0, atol=1e-12)
        assert int(res.status[0]) == status


@pytest.mark.parametrize("solver", SOLVERS)
def test_feasible_v0_returned_unchanged(solver: str) -> None:
    rng = np.random.default_rng(1)
    for _ in range(100):
        k, m = int(rng.integers(1, 5)), int(rng.integers(1, 5))
        A = rng.normal(size=(m, k))
        v0 = rng.normal(size=k)
        b = A @ v0 + rng.uniform(0.0, 1.0, m)  # v0 satisfies every row (some nearly tight)
        b[rng.random(m) < 0.2] = np.inf
        res = _project(v0[None], A[None], b[None], solver)
        np.testing.assert_array_equal(res.v[0], v0)
        assert res.status[0] == QPStatus.NOMINAL


@pytest.mark.parametrize("solver", SOLVERS)
def test_infeasible_gives_braking_fallback(solver: str) -> None:
    rng = np.random.default_rng(2)
    v0_list, A_list, b_list = [], [], []
    for _ in range(50):
        k = int(rng.integers(1, 5))
        a = rng.normal(size=k)
        c = rng.uniform(0.3, 3.0)
        beta = rng.normal()
        gap = rng.uniform(0.1, 2.0)
        # a·v ≤ β and −c a·v ≤ −c β − gap, i.e. a·v ≥ β + gap/c: contradictory. Farkas
        # certificate y = (c, 1): yᵀA = 0, yᵀb = −gap < 0.
        rows = [a, -c * a]
        rhs = [beta, -c * beta - gap]
        for _ in range(int(rng.integers(0, 3))):
            rows.append(rng.normal(size=k))
            rhs.append(rng.choice([rng.normal(), np.inf]))
        order = rng.permutation(len(rows))
        v0_list.append(rng.normal(size=k))
        A_list.append(np.array(rows)[order])
        b_list.append(np.array(rhs)[order])
    # the textbook case: a·v ≤ −1 and −a·v ≤ −1
    v0_list.append(np.array([0.3, -0.2]))
    A_list.append(np.array([[1.0, 2.0], [-1.0, -2.0]]))
    b_list.append(np.array([-1.0, -1.0]))
    # a zero row that cannot hold: 0·v ≤ −1
    v0_list.append(np.array([0.5]))
    A_list.append(np.array([[0.0]]))
    b_list.append(np.array([-1.0]))
    for v0, A, b in zip(v0_list, A_list, b_list, strict=True):
        res = _project(v0[None], A[None], b[None], solver)
        assert res.status[0] == QPStatus.FALLBACK, (A, b, v0, res)
        np.testing.assert_array_equal(res.v[0], np.zeros_like(v0))


def test_zero_row_infeasible_active_set() -> None:
    # The bare case: 0·v ≤ −1 (infeasible) next to an ordinary row.
    res = project_velocity(
        np.array([[0.0]]), np.array([[[0.0], [1.0]]]), np.array([[-1.0, -1.0]]), "active_set"
    )
    assert res.status[0] == QPStatus.FALLBACK
    np.testing.assert_array_equal(res.v[0], 0.0)


def _zero_row_filter_problem() -> tuple[np.ndarray, np.ndarray]:
    """How a zero row arises in the filter: J̄ of rank 1 cannot move the end-effector towards
    obstacle 0 (its row is zero), and the arm is within the margin of that obstacle (h < margin,
    so b_0 = κ (h − margin) < 0): no velocity satisfies row 0, the filter must brake."""
    p = np.array([0.0, 0.0])
    Jbar = np.array([[1.0, 0.5], [0.0, 0.0]])
    centers = np.array([[0.0, 0.3], [1.0, 0.0]])
    radii = np.array([0.2, 0.1])
    A, b, h = rcbf_constraints(p, Jbar, centers, radii, 0.5, 2.0, margin=0.1)
    assert np.all(A[0] == 0.0) and h[0] < 0.1 and b[0] < 0  # the row is infeasible
    return A, b


def test_zero_row_infeasible_active_set_from_rcbf_rows() -> None:
    A, b = _zero_row_filter_problem()
    res = project_velocity(np.array([[1.0, 1.0]]), A[None], b[None], "active_set")
    assert res.status[0] == QPStatus.FALLBACK
    np.testing.assert_array_equal(res.v[0], 0.0)


def test_zero_row_infeasible_piqp() -> None:
    """The same problems through PIQP: correctly infeasible."""
    res = project_velocity(
        np.array([[0.0]]), np.array([[[0.0], [1.0]]]), np.array([[-1.0, -1.0]]), "piqp"
    )
    assert res.status[0] == QPStatus.FALLBACK
    np.testing.assert_array_equal(res.v[0], 0.0)
    A, b = _zero_row_filter_problem()
    res = project_velocity(np.array([[1.0, 1.0]]), A[None], b[None], "piqp")
    assert res.status[0] == QPStatus.FALLBACK
    np.testing.assert_array_equal(res.v[0], 0.0)


def test_mixed_batch_statuses() -> None:
    """One call with a nominal, a solved and an infeasible arm: each gets its own answer."""
    A = np.array([[[1.0, 0.0], [0.0, 0.0]], [[1.0, 0.0], [0.0, 0.0]], [[1.0, 0.0], [-1.0, 0.0]]])
    b = np.array([[1.0, np.inf], [1.0, np.inf], [-1.0, -1.0]])
    v0 = np.array([[0.5, 2.0], [3.0, 2.0], [1.0, 1.0]])
    for solver in ("active_set", "piqp"):
        res = project_velocity(v0, A, b, solver=solver)
        assert list(res.status) == [QPStatus.NOMINAL, QPStatus.SOLVED, QPStatus.FALLBACK]
        np.testing.assert_allclose(res.v, [[0.5, 2.0], [1.0, 2.0], [0.0, 0.0]], atol=1e-7)


def test_unknown_solver_raises() -> None:
    with pytest.raises(ValueError):
        project_velocity(np.zeros((1, 2)), np.zeros((1, 1, 2)), np.zeros((1, 1)), solver="osqp")


# --------------------------------------------------------------------------- RCBF rows by hand


def test_rcbf_constraints_hand_example() -> None:
    # p = (1, 0); J̄ = diag(1, 2); κ = 0.5, ε = 2.
    p = np.array([1.0, 0.0])
    Jbar = np.array([[1.0, 0.0], [0.0, 2.0]])
    centers = np.array([[0.0, 0.0], [1.0, 2.0]])
    radii = np.array([0.5, 1.0])
    kappa, eps = 0.5, 2.0
    # Obstacle 0: p − o = (1, 0): h = 1 − 0.25 = 0.75; L_g0 h = 2 (1, 0) J̄ = (2, 0);
    #   A = (−2, 0); b = κ h − ‖L_g0 h‖²/ε = 0.375 − 4/2 = −1.625.
    # Obstacle 1: p − o = (0, −2): h = 4 − 1 = 3; L_g0 h = 2 (0, −2) J̄ = (0, −8);
    #   A = (0, 8); b = 1.5 − 64/2 = −30.5.
    A, b, h = rcbf_constraints(p, Jbar, centers, radii, kappa, eps)
    np.testing.assert_allclose(h, [0.75, 3.0], rtol=1e-15)
    np.testing.assert_allclose(A, [[-2.0, 0.0], [0.0, 8.0]], rtol=1e-15)
    np.testing.assert_allclose(b, [-1.625, -30.5], rtol=1e-15)
    np.testing.assert_allclose(barrier(p, centers, radii), [0.75, 3.0], rtol=1e-15)
    np.testing.assert_allclose(clearance(p, centers, radii), [0.5, 1.0], rtol=1e-15)
    # The rows say L_g0 h · v ≥ −κ h + ‖L_g0 h‖²/ε (Eq. 56): check at a point.
    v = np.array([-0.3, 0.7])
    assert np.all((A @ v <= b) == (-A @ v >= -kappa * h + np.array([4.0, 64.0]) / eps))

    # Tightening by a margin Γ replaces h by h − Γ in b only; h is returned untightened.
    A_m, b_m, h_m = rcbf_constraints(p, Jbar, centers, radii, kappa, eps, margin=0.1)
    np.testing.assert_allclose(A_m, A, rtol=0)
    np.testing.assert_allclose(b_m, [-1.625 - 0.05, -30.5 - 0.05], rtol=1e-15)
    np.testing.assert_allclose(h_m, h, rtol=0)

    # Switching obstacle 1 off: zero row, b = +inf.
    A_o, b_o, _ = rcbf_constraints(
        p, Jbar, centers, radii, kappa, eps, active=np.array([True, False])
    )
    np.testing.assert_allclose(A_o, [[-2.0, 0.0], [0.0, 0.0]], rtol=0)
    assert b_o[0] == pytest.approx(-1.625) and b_o[1] == np.inf


def test_rcbf_constraints_batched_and_match_real_arm() -> None:
    rng = np.random.default_rng(3)
    k, m, n_arms = 3, 4, 6
    P, J = [], []
    for _ in range(n_arms):
        n = k + 1
        lengths = rng.uniform(0.2, 0.5, n)
        arm = ArmParams(
            masses=np.ones(n), lengths=lengths, com=0.5 * lengths, inertias=np.full(n, 0.01),
            base=rng.uniform(-1.0, 1.0, 2),
        )
        q = rng.uniform(-np.pi, np.pi, n)
        P.append(end_effector(arm, q))
        J.append(reduced_jacobian(arm, q))
    centers = rng.normal(size=(m, 2))
    radii = rng.uniform(0.05, 0.2, m)
    A, b, h = rcbf_constraints(np.array(P), np.array(J), centers, radii, 0.7, 3.0)
    assert A.shape == (n_arms, m, k) and b.shape == (n_arms, m) and h.shape == (n_arms, m)
    for i in range(n_arms):
        for j in range(m):
            d = P[i] - centers[j]
            lg = 2.0 * d @ J[i]
            assert h[i, j] == pytest.approx(d @ d - radii[j] ** 2, rel=1e-13)
            np.testing.assert_allclose(A[i, j], -lg, rtol=1e-13, atol=1e-15)
            assert b[i, j] == pytest.approx(0.7 * h[i, j] - lg @ lg / 3.0, rel=1e-12, abs=1e-14)
        assert np.linalg.matrix_rank(A[i]) <= 2  # every row lies in the row space of J̄


# --------------------------------------------------------------------------- robust margin


def test_robust_margin_formula_and_meaning() -> None:
    assert robust_margin(0.1, 0.5, 5.0) == pytest.approx(5.0 * 0.01 / 2.0, rel=1e-15)
    assert robust_margin(0.0, 0.5, 5.0) == 0.0
    rng = np.random.default_rng(4)
    for _ in range(200):
        delta, kappa, eps = rng.uniform(0.0, 2.0), rng.uniform(0.05, 5.0), rng.uniform(0.1, 50.0)
        gamma = robust_margin(delta, kappa, eps)
        # Eq. 57: a velocity error of norm δ costs at most ‖L_g0 h‖ δ in ḣ, which the robust term
        # ‖L_g0 h‖²/ε pays back except for min_x (x²/ε − x δ) = −ε δ²/4 = −κ Γ(δ), reached at
        # x = ε δ / 2. So ḣ ≥ −κ (h + Γ): the set h ≥ −Γ is forward invariant.
        x = np.linspace(0.0, 4.0 * eps * delta + 1.0, 20001)
        assert np.min(x**2 / eps - x * delta) >= -kappa * gamma - 1e-12
        x_star = eps * delta / 2.0
        assert x_star**2 / eps - x_star * delta == pytest.approx(-kappa * gamma, rel=1e-12, abs=1e-15)
