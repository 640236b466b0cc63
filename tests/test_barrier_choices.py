"""The filter's barrier choices in the numpy reference (docs/MODEL.md §5, *Barrier choices*).

Every choice's rows are checked against independent computations: h from the independent capsule
geometry of tests/geometry.py (its own kinematics and distances), L_g0 h against central differences
of that h along q̇ = g0 v. Then: the numpy active set and PIQP give the same optimum on the new rows,
the distance barrier with the tunable ε leaves a command alone where the paper's rows freeze the arm,
Γ and δ̄ invert each other, and a closed loop with the worst tracking error δ̄ allows keeps h ≥ 0 at
every sub-step (and does not with a larger error, or a gate that relaxes rows at contact).
"""

import numpy as np
import pytest
from geometry import inter_arm_clearances, joints, obstacle_clearances

from pan1_env.bodies import inter_arm_barrier, link_obstacle_barrier
from pan1_env.cascade import passive_velocity_map, reduced_jacobian
from pan1_env.dynamics import ArmParams, end_effector
from pan1_env.safety import (
    QPStatus,
    _solve_piqp,
    activation_gate,
    active_set_projection,
    cbf_rows,
    project_velocity,
    rcbf_constraints,
    robust_epsilon,
    robust_margin,
    shaped_barrier,
    tracking_bound,
)

KAPPA, EPSILON = 0.5, 5.0


def _arm(rng: np.random.Generator, n: int, passive: bool, base=(0.0, 0.0)) -> ArmParams:
    lengths = rng.uniform(0.2, 0.45, n)
    return ArmParams(masses=rng.uniform(0.2, 1.0, n), lengths=lengths, com=0.5 * lengths,
                     inertias=rng.uniform(1e-3, 1e-2, n), base=np.array(base, float),
                     phi=float(rng.uniform(-1, 1)), passive_first_joint=passive)


def _joints(arm: ArmParams, q: np.ndarray) -> np.ndarray:
    return joints(q, arm.lengths, arm.base, arm.phi)


def _along(f, arm: ArmParams, q: np.ndarray, v: np.ndarray, s: float = 1e-6) -> np.ndarray:
    """Central difference of f(q) along the cascade's q̇ = g0(q) v (one step each side, g0 at q)."""
    dq = passive_velocity_map(arm, q) @ v
    return (f(q + s * dq) - f(q - s * dq)) / (2 * s)


# --------------------------------------------------------------------------- rows of each barrier


@pytest.mark.parametrize("passive", [True, False])
def test_end_effector_rows_match_independent_geometry(passive: bool) -> None:
    """Both forms: h from tests/geometry.py's kinematics, L_g0 h from differences of it along g0 v, b
    from the formula with the tunable ε; the paper's rows unchanged by the general path."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        arm = _arm(rng, 3, passive)
        q = rng.uniform(-np.pi, np.pi, 3)
        p = end_effector(arm, q)
        centers = p + rng.uniform(0.3, 0.8, (3, 1)) * rng.normal(size=(3, 2))
        radii = rng.uniform(0.05, 0.15, 3)
        Jbar = reduced_jacobian(arm, q)
        v = rng.normal(size=Jbar.shape[-1])

        def dist(qq, arm=arm, centers=centers):
            return np.linalg.norm(_joints(arm, qq)[-1] - centers, axis=-1)

        forms = {"squared": lambda qq, r=radii: dist(qq) ** 2 - r**2, "distance": lambda qq, r=radii: dist(qq) - r}
        for form, h_of in forms.items():
            for decay, margin in ((0.0, 0.0), (30.0, 0.01)):
                A, b, h = rcbf_constraints(p, Jbar, centers, radii, KAPPA, EPSILON, margin=margin,
                                           barrier=form, decay=decay)
                np.testing.assert_allclose(h, h_of(q), atol=1e-12)
                np.testing.assert_allclose(-A @ v, _along(h_of, arm, q, v), rtol=1e-6, atol=1e-8)
                Lg2 = np.sum(A * A, axis=-1)
                expected = KAPPA * (h - margin) - Lg2 * np.exp(-decay * (h - margin)) / EPSILON
                np.testing.assert_allclose(b, expected, rtol=1e-12, atol=1e-14)
        # the paper's rows: the written-out formula and the general path agree
        A0, b0, h0 = rcbf_constraints(p, Jbar, centers, radii, KAPPA, EPSILON, margin=0.02)
        h1, L1 = shaped_barrier(h0, radii, "squared", -A0)
        A1, b1 = cbf_rows(h1, L1, KAPPA, EPSILON, margin=0.02)
        np.testing.assert_allclose(A1, A0, atol=0)
        np.testing.assert_allclose(b1, b0, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("passive", [True, False])
def test_distance_link_rows_match_independent_capsules(passive: bool) -> None:
    """Link–obstacle rows: the distance barrier is the independent geometry's clearance d − r − ρ, and
    its row is that clearance's rate along g0 v (a moving obstacle's ∂h/∂t scales by the same 1/2d)."""
    rng = np.random.default_rng(2)
    rho = 0.03
    for _ in range(20):
        arm = _arm(rng, 3, passive)
        q = rng.uniform(-np.pi, np.pi, 3)
        centers = arm.base + rng.uniform(-1.0, 1.0, (4, 2))
        radii = rng.uniform(0.05, 0.12, 4)
        vel = rng.normal(size=(4, 2))
        lb = link_obstacle_barrier(arm, q, centers, radii, rho, velocities=vel)
        h, row, dh_dt = shaped_barrier(lb.h, radii + rho, "distance", lb.row, lb.dh_dt)

        def clear(qq, arm=arm, centers=centers, radii=radii):
            return obstacle_clearances([_joints(arm, qq)], centers, radii, rho)[0]

        keep = np.abs(lb.t - 0.5) < 0.49  # the closest point inside the link, away from the clamp's kink
        np.testing.assert_allclose(h, clear(q), atol=1e-12)
        v = rng.normal(size=row.shape[-1])
        np.testing.assert_allclose((row @ v)[keep], _along(clear, arm, q, v)[keep], rtol=1e-5, atol=1e-7)
        # ∂h/∂t: the clearance's rate when only the obstacle moves (its centre along its velocity)
        s = 1e-6
        rate = (obstacle_clearances([_joints(arm, q)], centers + s * vel, radii, rho)[0]
                - obstacle_clearances([_joints(arm, q)], centers - s * vel, radii, rho)[0]) / (2 * s)
        np.testing.assert_allclose(dh_dt[keep], rate[keep], rtol=1e-5, atol=1e-7)


def test_distance_inter_arm_rows_match_independent_capsules() -> None:
    """Inter-arm rows: h = d − 2ρ is the independent geometry's capsule clearance, each arm's row its
    rate along that arm's g0 v (the other arm still)."""
    rng = np.random.default_rng(3)
    rho = 0.03
    checked = 0
    for _ in range(30):
        arm_i = _arm(rng, 3, True)
        arm_j = _arm(rng, 3, False, base=rng.uniform(-0.8, 0.8, 2))
        qi, qj = rng.uniform(-np.pi, np.pi, 3), rng.uniform(-np.pi, np.pi, 3)
        ib = inter_arm_barrier(arm_i, qi, arm_j, qj, rho)
        d0 = inter_arm_clearances([_joints(arm_i, qi), _joints(arm_j, qj)], rho)[0, 1]
        if np.min(d0) <= 0.01:  # crossing capsules: the distance barrier's gradient is not defined
            continue
        h, row_i, row_j = shaped_barrier(ib.h, 2 * rho, "distance", ib.row_i, ib.row_j)
        np.testing.assert_allclose(h, d0, atol=1e-12)
        keep = (np.abs(ib.s - 0.5) < 0.49) | (np.abs(ib.t - 0.5) < 0.49)  # one point interior: no kink
        vi, vj = rng.normal(size=2), rng.normal(size=3)
        def pair(Pi, Pj):
            return inter_arm_clearances([Pi, Pj], rho)[0, 1]

        Pi, Pj = _joints(arm_i, qi), _joints(arm_j, qj)
        ri = _along(lambda q, a=arm_i, Pj=Pj: pair(_joints(a, q), Pj), arm_i, qi, vi)
        rj = _along(lambda q, a=arm_j, Pi=Pi: pair(Pi, _joints(a, q)), arm_j, qj, vj)
        np.testing.assert_allclose((row_i @ vi)[keep], ri[keep], rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose((row_j @ vj)[keep], rj[keep], rtol=1e-5, atol=1e-7)
        checked += 1
    assert checked >= 10


def test_shaped_barrier_refuses_unknown_form_and_handles_the_centre() -> None:
    with pytest.raises(ValueError, match="unknown barrier 'cubic'"):
        shaped_barrier(np.ones(2), 0.1, "cubic")
    h, row = shaped_barrier(np.array([-0.25]), 0.5, "distance", np.array([[0.3, 0.4]]))  # d = 0
    assert h[0] == -0.5 and np.all(row == 0.0)


# --------------------------------------------------------------------------- Γ, δ̄ and the gate


@pytest.mark.parametrize("decay", [0.0, 1e-9, 5.0, 50.0, 1e4])
@pytest.mark.parametrize("arms", [1, 2])
def test_robust_margin_solves_its_equation_and_inverts_tracking_bound(decay: float, arms: int) -> None:
    for delta in (0.0, 0.01, 0.1, 0.5, 3.0):
        gamma = robust_margin(delta, KAPPA, EPSILON, decay, arms)
        # κ Γ e^{λΓ} = arms · ε δ² / 4: ḣ̃ ≥ −κ h̃ − ε(h̃) δ²/4 (per arm) vanishes at h̃ = −Γ
        assert KAPPA * gamma * np.exp(decay * gamma) == pytest.approx(arms * EPSILON * delta**2 / 4, rel=1e-12)
        assert tracking_bound(gamma, KAPPA, EPSILON, decay, arms) == pytest.approx(delta, rel=1e-9, abs=1e-15)
    assert robust_margin(0.2, KAPPA, EPSILON, decay, arms) <= robust_margin(0.2, KAPPA, EPSILON, 0.0, arms) + 1e-15
    assert robust_margin(0.2, KAPPA, EPSILON) == pytest.approx(EPSILON * 0.04 / (4 * KAPPA))  # Eq. 57


def test_bad_parameters_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="robust_margin: decay must be non-negative"):
        robust_margin(0.1, KAPPA, EPSILON, decay=-1.0)
    with pytest.raises(ValueError, match="tracking_bound: arms must be an integer ≥ 1"):
        tracking_bound(0.1, KAPPA, EPSILON, arms=0)
    with pytest.raises(ValueError, match="activation_gate: width must be non-negative"):
        activation_gate(np.zeros(2), 0.05, -0.01)


def test_activation_gate_is_c1_and_only_relaxes() -> None:
    on, width = 0.05, 0.04
    c = np.linspace(-0.1, 0.2, 30001)
    sigma = activation_gate(c, on, width)
    assert np.all(sigma[c <= on] == 1.0) and np.all(sigma[c >= on + width] == 0.0)
    slope = np.diff(sigma) / np.diff(c)
    dc = c[1] - c[0]
    assert np.max(np.abs(np.diff(slope))) <= 1.01 * 6 / width**2 * dc  # bounded σ'': the slope has no jump (C¹)
    assert np.max(np.abs(slope)) == pytest.approx(1.5 / width, rel=1e-3)
    assert np.array_equal(activation_gate(c, on, 0.0), np.where(c <= on, 1.0, 0.0))
    # every v that meets the full row meets the gated one; σ = 0 is a zero row with b ≥ 0
    rng = np.random.default_rng(4)
    row, h = rng.normal(size=(200, 3)), rng.uniform(-0.05, 0.4, 200)
    A, b = cbf_rows(h, row, KAPPA, EPSILON, decay=20.0)
    s = rng.uniform(0, 1, 200)
    s[:20] = 0.0
    Ag, bg = cbf_rows(h, row, KAPPA, EPSILON, decay=20.0, gate=s, speed=2.0)
    for v in rng.uniform(-2, 2, (500, 3)):
        meets = A @ v <= b
        assert np.all((Ag @ v)[meets] <= bg[meets] + 1e-12)
    assert np.all(Ag[:20] == 0.0) and np.all(bg[:20] >= 0.0)
    with pytest.raises(ValueError, match="speed"):
        cbf_rows(h, row, KAPPA, EPSILON, gate=s)


# --------------------------------------------------------------------------- the QP on the new rows


CHOICES = {
    "paper": {},
    "distance": {"barrier": "distance"},
    "distance+tunable": {"barrier": "distance", "decay": 50.0},
    "squared+tunable": {"barrier": "squared", "decay": 50.0},
    "distance+tunable+gate": {"barrier": "distance", "decay": 50.0, "gate": (0.05, 0.05), "speed": 2.0},
    "distance+range": {"barrier": "distance", "gate": (0.1, 0.0), "speed": 2.0},
}


@pytest.mark.parametrize("choice", CHOICES)
def test_active_set_and_piqp_agree_on_the_new_rows(choice: str) -> None:
    pytest.importorskip("qpsolvers")
    rng = np.random.default_rng(5)
    B, O, n = 150, 4, 4
    v0, A, b = np.zeros((B, n - 1)), np.zeros((B, O + 2 * (n - 1), n - 1)), np.zeros((B, O + 2 * (n - 1)))
    box = np.concatenate([np.eye(n - 1), -np.eye(n - 1)])
    for i in range(B):
        arm = _arm(rng, n, True)
        q = rng.uniform(-np.pi, np.pi, n)
        p = end_effector(arm, q)
        centers = p + rng.uniform(0.1, 0.5, (O, 1)) * rng.normal(size=(O, 2))
        A[i, :O], b[i, :O], _ = rcbf_constraints(p, reduced_jacobian(arm, q), centers, rng.uniform(0.05, 0.1, O),
                                                 KAPPA, EPSILON, **CHOICES[choice])
        A[i, O:], b[i, O:] = box, 2.0
        v0[i] = rng.uniform(-3, 3, n - 1)
    ours = active_set_projection(v0, A, b)
    theirs, found = _solve_piqp(v0, A, b)
    solved = ours.status != QPStatus.FALLBACK
    assert np.sum(ours.status == QPStatus.SOLVED) >= 30  # the rows bind often enough to test something
    assert np.array_equal(found, solved)
    np.testing.assert_allclose(ours.v[solved], theirs[solved], atol=1e-7)


# --------------------------------------------------------------------------- the freeze


def test_distance_barrier_with_tunable_epsilon_leaves_a_far_arm_alone() -> None:
    """The freeze algebra: the paper's row at v = 0 has b = κ (d² − r²) − 4 d² ‖J̄ᵀn‖²/ε, negative at any
    distance once ‖J̄ᵀn‖ > √(κε)/2 · √(1 − r²/d²). Here an arm 0.6 m clear of an obstacle with
    ‖J̄ᵀn‖ > √(κε)/2 is pushed away by the paper's filter even when asked to stay still; behind the
    distance barrier with ε(h) = ε e^{50 h} its command (still, or a move along the obstacle) passes."""
    arm = ArmParams(masses=[0.5, 0.5, 0.5], lengths=[0.5, 0.5, 0.5], com=[0.25, 0.25, 0.25],
                    inertias=[0.01, 0.01, 0.01], passive_first_joint=False)
    q = np.array([0.3, 0.5, 0.4])
    p, Jbar = end_effector(arm, q), reduced_jacobian(arm, q)
    # put the obstacle where J̄ᵀn is largest: n the top left singular vector of J̄
    U, sv, _ = np.linalg.svd(Jbar)
    n_hat = U[:, 0]
    radius, clear = 0.1, 0.6
    centers, radii = (p - (radius + clear) * n_hat)[None], np.array([radius])
    assert np.linalg.norm(Jbar.T @ n_hat) > np.sqrt(KAPPA * EPSILON) / 2
    tangent = np.linalg.lstsq(Jbar, np.array([-n_hat[1], n_hat[0]]), rcond=None)[0]  # along the obstacle
    for v0 in (np.zeros(3), 0.3 * tangent / np.linalg.norm(tangent)):
        A, b, _ = rcbf_constraints(p, Jbar, centers, radii, KAPPA, EPSILON)
        paper = active_set_projection(v0[None], A[None], b[None])
        assert b[0] < 0 and paper.status[0] == QPStatus.SOLVED and np.linalg.norm(paper.v[0] - v0) > 0.05
        A, b, _ = rcbf_constraints(p, Jbar, centers, radii, KAPPA, EPSILON, barrier="distance", decay=50.0)
        ours = active_set_projection(v0[None], A[None], b[None])
        assert b[0] > 0 and ours.status[0] == QPStatus.NOMINAL and np.array_equal(ours.v[0], v0)


# --------------------------------------------------------------------------- invariance


def _closed_loop(arm: ArmParams, q: np.ndarray, center: np.ndarray, radius: float, choice: dict, margin: float,
                 delta: float, epsilon: float, dt: float = 0.004, seconds: float = 1.6) -> float:
    """The smallest clearance ‖p − o‖ − r over every sub-step of a loop where the nominal command pulls
    the end-effector into the obstacle's centre, the filter (re-solved every sub-step, speed box 2 rad/s)
    holds it off, and the arm moves with v = v* + ẽ, ‖ẽ‖ = δ pointing down the row's gradient (the
    worst error for this barrier), RK4 with v held over the sub-step."""
    centers, radii = center[None], np.array([radius])
    k = reduced_jacobian(arm, q).shape[-1]
    box_A, box_b = np.concatenate([np.eye(k), -np.eye(k)]), np.full(2 * k, 2.0)
    worst = np.inf
    for _ in range(int(round(seconds / dt))):
        p, Jbar = end_effector(arm, q), reduced_jacobian(arm, q)
        v0 = np.clip(-20.0 * Jbar.T @ (p - center), -2.0, 2.0)
        A, b, _ = rcbf_constraints(p, Jbar, centers, radii, LOOP_KAPPA, epsilon, margin=margin, **choice)
        v = active_set_projection(v0, np.concatenate([A[0][None], box_A]), np.concatenate([b, box_b])).v
        # the worst error: down the barrier's gradient (the ungated row, so also where a gate relaxes it)
        row = -rcbf_constraints(p, Jbar, centers, radii, LOOP_KAPPA, epsilon,
                                barrier=choice.get("barrier", "squared"))[0][0]
        v = v - delta * row / np.linalg.norm(row)

        def qdot(qq, v=v):
            return passive_velocity_map(arm, qq) @ v

        k1 = qdot(q)
        k2 = qdot(q + 0.5 * dt * k1)
        k3 = qdot(q + 0.5 * dt * k2)
        k4 = qdot(q + dt * k3)
        q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        worst = min(worst, float(np.linalg.norm(end_effector(arm, q) - center) - radius))
    return worst


LOOP_KAPPA = 5.0  # the closed loops' κ: the arm settles on the set's edge within their 1.6 s (1/κ = 0.2 s)
INVARIANCE = {
    "paper": {},
    "distance": {"barrier": "distance"},
    "distance+tunable": {"barrier": "distance", "decay": 50.0},
    "squared+tunable": {"barrier": "squared", "decay": 200.0},
    "distance+tunable+gate": {"barrier": "distance", "decay": 50.0, "gate": (0.05, 0.05), "speed": 2.0},
}


def _tight_setup(choice: dict, delta: float, passive: bool):
    """An arm whose end-effector the nominal law drives into an obstacle, and the ε that makes the square
    completion behind Γ tight where the arm meets it: ‖L_g0 h‖ = ε δ / 2 at the contact point (so the
    worst error pushes as far as Γ allows, and a larger error or a smaller margin gets in)."""
    arm = ArmParams(masses=[0.4, 0.3, 0.3], lengths=[0.4, 0.35, 0.3], com=[0.2, 0.17, 0.15],
                    inertias=[0.005, 0.003, 0.003], passive_first_joint=passive)
    q = np.array([0.3, 1.2, 1.0])
    p = end_effector(arm, q)
    center, radius = p + 0.25 * np.linalg.svd(reduced_jacobian(arm, q))[0][:, 0], 0.08
    qc = q.copy()
    while np.linalg.norm(end_effector(arm, qc) - center) > radius:  # unfiltered, to the contact point
        Jbar = reduced_jacobian(arm, qc)
        qc = qc + 0.001 * passive_velocity_map(arm, qc) @ np.clip(-20.0 * Jbar.T @ (end_effector(arm, qc) - center),
                                                                  -2.0, 2.0)
    pc = end_effector(arm, qc)
    grad = reduced_jacobian(arm, qc).T @ (pc - center) / np.linalg.norm(pc - center)
    if choice.get("barrier", "squared") == "squared":
        grad = 2 * radius * grad
    return arm, q, center, radius, 2 * np.linalg.norm(grad) / delta


@pytest.mark.parametrize("passive", [True, False])
@pytest.mark.parametrize("choice", INVARIANCE)
def test_tracking_within_delta_bar_keeps_h_nonnegative(choice: str, passive: bool) -> None:
    """h ≥ 0 at every sub-step with the worst tracking error δ̄ = tracking_bound(margin) allows, ending
    within millimetres of the obstacle (Γ is nearly tight here); and the test can fail: half that margin
    (a Γ off by a factor 2) lets the same loop into the obstacle."""
    kw = INVARIANCE[choice]
    delta = 0.3
    arm, q, center, radius, eps = _tight_setup(kw, delta, passive)
    decay = kw.get("decay", 0.0)
    margin = robust_margin(delta, LOOP_KAPPA, eps, decay)
    assert tracking_bound(margin, LOOP_KAPPA, eps, decay) == pytest.approx(delta)
    clear = _closed_loop(arm, q, center, radius, kw, margin, delta, eps)
    assert clear >= -1e-6, f"{choice}: clearance {clear}"
    assert clear < 0.005, f"{choice}: the loop never came near the obstacle ({clear})"
    assert _closed_loop(arm, q, center, radius, kw, margin / 2, delta, eps) < -1e-3


def test_a_range_shorter_than_a_sub_steps_travel_is_not_safe() -> None:
    """The activation's condition: a row must be whole (σ = 1) from one sub-step's travel out. This loop's
    end-effector moves up to ~1.6 cm in a 4 ms sub-step; a hard range of 2 mm lets it jump from out of
    range to inside the obstacle (a 5 cm gate, above, keeps it out)."""
    kw = {"barrier": "distance", "decay": 50.0, "gate": (0.002, 0.0), "speed": 2.0}
    delta = 0.3
    arm, q, center, radius, eps = _tight_setup(kw, delta, False)
    margin = robust_margin(delta, LOOP_KAPPA, eps, 50.0)
    assert _closed_loop(arm, q, center, radius, kw, margin, delta, eps) < -1e-3


def test_robust_epsilon_is_the_paper_epsilon_at_the_edge() -> None:
    h = np.array([-0.1, 0.0, 0.1, 1e6])
    np.testing.assert_allclose(robust_epsilon(h, 5.0, 20.0)[:3], 5.0 * np.exp(20.0 * h[:3]))
    assert np.isfinite(robust_epsilon(h, 5.0, 20.0)).all()
    assert np.all(robust_epsilon(h, 5.0) == 5.0)


@pytest.mark.parametrize("lever, standoff", [(0.5, 0.0265), (1.0, 0.0441), (2.0, 0.0643)])
def test_a_point_pushed_straight_at_an_obstacle_stops_where_the_rows_bound_vanishes(lever: float,
                                                                                   standoff: float) -> None:
    """docs/MODEL.md §5a, *Where a blocked arm stops*: behind v1's rows (distance barrier, κ = 0.5, ε = 5,
    λ = 50) a point whose command points straight at an obstacle comes to rest where κh̃ = ‖L_g0 h‖²/ε(h̃),
    the clearances the docs give for levers of 0.5, 1 and 2 m/rad; the point moves by the filtered
    velocity, ṗ = J̄ v*, with a constant J̄ = lever · I."""
    centre, radius, dt = np.zeros((1, 2)), np.array([0.1]), 0.005
    p, Jbar = np.array([0.35, 0.0]), lever * np.eye(2)
    for _ in range(4000):
        A, b, _ = rcbf_constraints(p[None], Jbar[None], centre, radius, 0.5, 5.0, barrier="distance", decay=50.0)
        v0 = -Jbar.T @ p / np.linalg.norm(p)  # the point's command: straight at the centre
        v = project_velocity(v0[None], A, b).v[0]
        p = p + dt * (Jbar @ v)
    assert np.linalg.norm(p) - radius[0] == pytest.approx(standoff, abs=5e-4)
