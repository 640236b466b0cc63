"""Whole-arm safety foundations: pan1_env.bodies' geometry and barriers, and the scenario keys that
select the protected bodies and move obstacles (the random generator's whole-arm options are tested in
tests/test_random_scenario.py).

Geometry is checked against brute force, finite differences and tests/geometry.py, an independent
rebuild of the arms from ``state()`` that uses nothing of pan1_env's kinematics.
"""

from __future__ import annotations

import copy
import datetime
import math
from importlib import resources

import numpy as np
import pytest
import tomllib
from arms import random_arm
from geometry import (
    arms_from_state,
    inter_arm_clearances,
    joints,
    point_segment_distance,
    segment_segment_distance,
)

from pan1_env import bodies, scenario
from pan1_env.cascade import passive_velocity_map
from pan1_env.dynamics import ArmParams
from pan1_env.scenario import ScenarioError

WHOLE_ARM = {"bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.05, 0.2),
             "links": (2, 3, 4, 3)}


def _fd(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Central finite differences of f (any shape) with respect to x (n,): shape f(x).shape + (n,)."""
    cols = []
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx[k] = eps
        cols.append((f(x + dx) - f(x - dx)) / (2 * eps))
    return np.stack(cols, axis=-1)


def _arm_and_obstacles(seed: int, passive: bool, n: int = 4) -> tuple[ArmParams, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    arm = random_arm(rng, n, passive=passive, placed=True)
    q = rng.uniform(-np.pi, np.pi, n)
    centers = arm.base + rng.uniform(-arm.reach, arm.reach, (8, 2))
    return arm, q, centers, rng.uniform(0.02, 0.2, 8)


# ------------------------------------------------------------------ closest points and distances


def test_closest_point_matches_dense_sampling() -> None:
    rng = np.random.default_rng(0)
    a, b, p = rng.uniform(-1, 1, (3, 200, 2))
    x, t = bodies.closest_point_on_segment(a, b, p)
    s = np.linspace(0.0, 1.0, 20001)
    samples = a[:, None] + s[None, :, None] * (b - a)[:, None]
    dist = np.linalg.norm(samples - p[:, None], axis=-1)
    best = np.argmin(dist, axis=1)
    exact = np.linalg.norm(x - p, axis=-1)
    assert np.all(exact <= dist.min(axis=1) + 1e-15) and np.all(dist.min(axis=1) - exact < 1e-6)
    np.testing.assert_allclose(t, s[best], atol=2e-4)
    assert np.all((t >= 0) & (t <= 1)) and np.any(t == 0) and np.any(t == 1) and np.any((t > 0) & (t < 1))
    np.testing.assert_allclose(x, a + t[:, None] * (b - a))
    indep = [point_segment_distance(pi, ai, bi) for ai, bi, pi in zip(a, b, p, strict=True)]
    np.testing.assert_allclose(np.linalg.norm(x - p, axis=-1), indep, atol=1e-12)


@pytest.mark.parametrize("case", ["random", "parallel", "collinear", "crossing", "touching"])
def test_segment_distance_matches_brute_force_and_the_independent_checker(case: str) -> None:
    rng = np.random.default_rng(1)
    a1, b1, a2, b2 = rng.uniform(-1, 1, (4, 60, 2))
    if case == "parallel":
        b2 = a2 + (b1 - a1) * rng.uniform(-2, 2, (60, 1))
    elif case == "collinear":
        a2 = a1 + (b1 - a1) * rng.uniform(-1, 2, (60, 1))
        b2 = a1 + (b1 - a1) * rng.uniform(-1, 2, (60, 1))
    elif case == "crossing":
        mid = a1 + 0.4 * (b1 - a1)
        a2, b2 = mid - (b2 - a2) * 0.3, mid + (b2 - a2) * 0.7
    elif case == "touching":
        a2 = b1.copy()
    d, s, t = bodies.segment_distance(a1, b1, a2, b2)
    x1, x2 = a1 + s[:, None] * (b1 - a1), a2 + t[:, None] * (b2 - a2)
    np.testing.assert_allclose(np.linalg.norm(x1 - x2, axis=-1), d, atol=1e-12)
    grid = np.linspace(0.0, 1.0, 801)
    for k in range(0, 60, 6):
        p1 = a1[k] + grid[:, None] * (b1[k] - a1[k])
        p2 = a2[k] + grid[:, None] * (b2[k] - a2[k])
        brute = np.linalg.norm(p1[:, None] - p2[None], axis=-1).min()
        assert d[k] <= brute + 1e-12 and brute - d[k] < 5e-3, (k, d[k], brute)
    indep = [segment_segment_distance(*seg) for seg in zip(a1, b1, a2, b2, strict=True)]
    np.testing.assert_allclose(d, indep, atol=1e-9)
    if case in ("crossing", "touching"):
        np.testing.assert_allclose(d, 0.0, atol=1e-12)


# ------------------------------------------------------------------ barriers and their gradients


@pytest.mark.parametrize("passive", [True, False], ids=["PA", "fully_actuated"])
def test_link_barrier_gradient_matches_finite_differences(passive: bool) -> None:
    seen = set()
    for seed in range(6):
        arm, q, centers, radii = _arm_and_obstacles(seed, passive)
        B = bodies.link_obstacle_barrier(arm, q, centers, radii, link_radius=0.03)
        assert B.h.shape == (4, 8) and B.grad_q.shape == (4, 8, 4) and B.row.shape == (4, 8, arm.n_actuated)
        fd = _fd(lambda x, arm=arm, c=centers, r=radii: bodies.link_obstacle_barrier(arm, x, c, r, 0.03).h, q)
        # the gradient of the clamped distance is the true one away from the exact switch points
        np.testing.assert_allclose(B.grad_q, fd, atol=1e-7 * (1 + np.abs(fd).max()))
        seen |= {"t=0" if t == 0 else "t=1" if t == 1 else "interior" for t in B.t.ravel()}
        # h is d² − (r + ρ)², d the distance to the closest point, which tests/geometry.py finds independently
        P = joints(q, arm.lengths, arm.base, arm.phi)
        d = np.array([[point_segment_distance(c, P[k], P[k + 1]) for c in centers] for k in range(4)])
        np.testing.assert_allclose(B.h, d**2 - (radii + 0.03) ** 2, atol=1e-12)
    assert seen == {"t=0", "t=1", "interior"}  # every branch of the closest point was exercised


def test_gradient_at_the_switch_between_interior_and_end_point() -> None:
    """On the line through a link's end, perpendicular to it, the closest point switches from the
    interior to the end point: both one-sided difference quotients match the gradient used."""
    arm = ArmParams([1.0, 1.0], [0.5, 0.4], [0.2, 0.2], [0.01, 0.01], base=np.array([0.3, -0.2]), phi=0.4)
    q = np.array([0.7, -0.5])
    a, b = bodies.link_segments(arm, q)
    direction = (b[1] - a[1]) / np.linalg.norm(b[1] - a[1])
    normal = np.array([-direction[1], direction[0]])
    center = b[1] + 0.3 * normal  # its foot on link 1 is exactly the end point: t = 1 on the switch
    B = bodies.link_obstacle_barrier(arm, q, center[None], np.array([0.1]))
    assert B.t[1, 0] == pytest.approx(1.0)
    for k in range(2):
        dq = np.zeros(2)
        dq[k] = 1e-7
        fwd = (bodies.link_obstacle_barrier(arm, q + dq, center[None], np.array([0.1])).h - B.h) / 1e-7
        bwd = (B.h - bodies.link_obstacle_barrier(arm, q - dq, center[None], np.array([0.1])).h) / 1e-7
        np.testing.assert_allclose(fwd[1, 0], B.grad_q[1, 0, k], atol=1e-5)
        np.testing.assert_allclose(bwd[1, 0], B.grad_q[1, 0, k], atol=1e-5)


def _flow(arm: ArmParams, q: np.ndarray, v: np.ndarray, tau: float, steps: int = 4) -> np.ndarray:
    """q after ``tau`` seconds of q̇ = g0(q) v (RK4; tau may be negative)."""
    f = lambda x: passive_velocity_map(arm, x) @ v  # noqa: E731
    dt = tau / steps
    for _ in range(steps):
        k1 = f(q)
        k2 = f(q + 0.5 * dt * k1)
        k3 = f(q + 0.5 * dt * k2)
        k4 = f(q + dt * k3)
        q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return q


@pytest.mark.parametrize("passive", [True, False], ids=["PA", "fully_actuated"])
def test_row_is_the_rate_of_h_along_the_actuated_velocity(passive: bool) -> None:
    """L_g0 h · v equals d/dt h(q(t)) for q̇ = g0(q) v (central difference over ±1e-5 s)."""
    for seed in range(4):
        arm, q, centers, radii = _arm_and_obstacles(seed + 10, passive)
        v = np.random.default_rng(seed).uniform(-1, 1, arm.n_actuated)
        B = bodies.link_obstacle_barrier(arm, q, centers, radii, link_radius=0.02)
        tau = 1e-5
        h = lambda x, arm=arm, c=centers, r=radii: bodies.link_obstacle_barrier(arm, x, c, r, 0.02).h  # noqa: E731
        rate = (h(_flow(arm, q, v, tau)) - h(_flow(arm, q, v, -tau))) / (2 * tau)
        np.testing.assert_allclose(B.row @ v, rate, atol=1e-6 * (1 + np.abs(rate).max()))
        if passive:  # the row lives in actuated-velocity space: it is not just ∇_q h without the passive column
            assert not np.allclose(B.row, B.grad_q[..., 1:])


def test_batched_barrier_matches_one_at_a_time() -> None:
    arm, _, centers, radii = _arm_and_obstacles(3, True)
    qs = np.random.default_rng(3).uniform(-np.pi, np.pi, (5, 4))
    batch = bodies.link_obstacle_barrier(arm, qs, centers, radii, 0.01)
    for b in range(5):
        one = bodies.link_obstacle_barrier(arm, qs[b], centers, radii, 0.01)
        for got, want in zip(batch, one, strict=True):
            np.testing.assert_allclose(got[b], want, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(bodies.link_clearance(arm, qs, centers, radii, 0.01),
                               np.sqrt(batch.h + (radii + 0.01) ** 2) - radii - 0.01, atol=1e-12)


def test_moving_obstacle_time_term() -> None:
    """∂h/∂t = −2 (x − c)·ċ: h along the obstacle's motion, the arm held still."""
    arm, q, centers, radii = _arm_and_obstacles(5, True)
    ends = centers + np.random.default_rng(5).uniform(-0.5, 0.5, centers.shape)
    speeds = np.linspace(0.05, 0.4, len(radii))
    t0, tau = 0.37, 1e-6
    c = lambda t: bodies.obstacle_centers(centers, ends, speeds, t)  # noqa: E731
    B = bodies.link_obstacle_barrier(arm, q, c(t0), radii, 0.02,
                                     velocities=bodies.obstacle_velocities(centers, ends, speeds, t0))
    rate = (bodies.link_obstacle_barrier(arm, q, c(t0 + tau), radii, 0.02).h
            - bodies.link_obstacle_barrier(arm, q, c(t0 - tau), radii, 0.02).h) / (2 * tau)
    np.testing.assert_allclose(B.dh_dt, rate, atol=1e-6)
    assert np.all(bodies.link_obstacle_barrier(arm, q, c(t0), radii).dh_dt == 0)  # still: no time term


@pytest.mark.parametrize("lookahead", [0.3, 1.0, 3.0, np.inf])
def test_obstacle_stretch_is_the_sampled_path_and_its_ends_move_as_it_says(lookahead: float) -> None:
    """The stretch an obstacle covers in the next T s: its ends are the extremes, along the path, of the
    obstacle's sampled positions over the window, and their velocities the time derivatives of those ends;
    a still obstacle's stretch is its centre."""
    rng = np.random.default_rng(11)
    centers = rng.uniform(-1.0, 1.0, (6, 2))
    ends = centers + rng.uniform(-0.4, 0.4, (6, 2))
    speeds = rng.uniform(0.05, 0.3, 6)
    speeds[0] = 0.0
    unit = (ends - centers) / np.linalg.norm(ends - centers, axis=1)[:, None]
    for t in rng.uniform(0.0, 20.0, 5):
        start, end, v_start, v_end = bodies.obstacle_stretch(centers, ends, speeds, t, lookahead)
        window = np.linspace(t, t + min(lookahead, 100.0), 20001)
        along = np.einsum("kod,od->ko", bodies.obstacle_centers(centers, ends, speeds, window) - centers, unit)
        np.testing.assert_allclose(start, centers + along.min(0)[:, None] * unit, atol=1e-3)
        np.testing.assert_allclose(end, centers + along.max(0)[:, None] * unit, atol=1e-3)
        later = bodies.obstacle_stretch(centers, ends, speeds, t + 1e-6, lookahead)
        np.testing.assert_allclose((later[0] - start) / 1e-6, v_start, atol=1e-4)
        np.testing.assert_allclose((later[1] - end) / 1e-6, v_end, atol=1e-4)
        np.testing.assert_array_equal(start[0], centers[0])
        np.testing.assert_array_equal(end[0], centers[0])


@pytest.mark.parametrize("kinds", [(True, False), (False, True), (True, True)], ids=["PA-FA", "FA-PA", "PA-PA"])
def test_inter_arm_barrier_gradients_and_rows(kinds: tuple[bool, bool]) -> None:
    for seed in range(4):
        rng = np.random.default_rng(seed + 20)
        arm_i = random_arm(rng, 3, passive=kinds[0], placed=True)
        proto = random_arm(rng, 4, passive=kinds[1])
        arm_j = ArmParams(proto.masses, proto.lengths, proto.com, proto.inertias,
                          base=arm_i.base + rng.uniform(-1, 1, 2), phi=1.0, passive_first_joint=kinds[1])
        qi, qj = rng.uniform(-np.pi, np.pi, 3), rng.uniform(-np.pi, np.pi, 4)
        Bx = bodies.inter_arm_barrier(arm_i, qi, arm_j, qj, link_radius=0.02)
        assert Bx.h.shape == (3, 4) and Bx.row_i.shape == (3, 4, arm_i.n_actuated)
        assert Bx.row_j.shape == (3, 4, arm_j.n_actuated)
        h_i = lambda x, a=arm_i, b=arm_j, y=qj: bodies.inter_arm_barrier(a, x, b, y, 0.02).h  # noqa: E731
        h_j = lambda y, a=arm_i, b=arm_j, x=qi: bodies.inter_arm_barrier(a, x, b, y, 0.02).h  # noqa: E731
        np.testing.assert_allclose(Bx.grad_i, _fd(h_i, qi), atol=1e-7)
        np.testing.assert_allclose(Bx.grad_j, _fd(h_j, qj), atol=1e-7)
        np.testing.assert_allclose(Bx.row_i, Bx.grad_i @ passive_velocity_map(arm_i, qi), atol=1e-13)
        np.testing.assert_allclose(Bx.row_j, Bx.grad_j @ passive_velocity_map(arm_j, qj), atol=1e-13)
        indep = inter_arm_clearances([joints(qi, arm_i.lengths, arm_i.base, arm_i.phi),
                                      joints(qj, arm_j.lengths, arm_j.base, arm_j.phi)], 0.02)[0, 1]
        np.testing.assert_allclose(bodies.inter_arm_clearance(arm_i, qi, arm_j, qj, 0.02), indep, atol=1e-9)
        np.testing.assert_allclose(np.sqrt(Bx.h + 0.04**2) - 0.04, indep, atol=1e-9)


def test_link_point_jacobian_is_the_end_effector_jacobian_at_the_tip() -> None:
    from pan1_env.dynamics import jacobian

    arm, q, _, _ = _arm_and_obstacles(7, True)
    np.testing.assert_allclose(bodies.link_point_jacobian(arm, q, 3, 1.0), jacobian(arm, q), atol=1e-14)
    np.testing.assert_allclose(bodies.link_point_jacobian(arm, q, 0, 0.0), 0.0)  # the base does not move


# ------------------------------------------------------------------ segments vs the independent rebuild from state()


@pytest.mark.parametrize("source", ["random_whole_arm", "paper_pa_mixed_square", "rotated_bases"])
def test_segments_match_the_independent_rebuild_from_state(source: str) -> None:
    from pan1_env.environment import parallel_env

    if source == "random_whole_arm":
        env = parallel_env("random", random_options=WHOLE_ARM, control_dt=0.01, physics_dt=0.01)
    elif source == "rotated_bases":
        doc = _doc("paper_pa_mixed_square")
        for k, arm in enumerate(doc["arms"]):
            arm["phi"] = 0.3 * k - 0.4
        env = parallel_env(scenario.from_dict(doc), control_dt=0.01, physics_dt=0.01)
    else:
        env = parallel_env(source, control_dt=0.01, physics_dt=0.01)
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(5):
        sc = env.scenario
        state = env.state()
        arm_joints, parts = arms_from_state(state, sc)
        # the checker's end-effectors are state()'s p (float32 in state())
        np.testing.assert_allclose([P[-1] for P in arm_joints], parts["p"], atol=2e-6)
        for i, arm in enumerate(sc.arms):
            a, b = bodies.link_segments(arm, parts["q"][i])
            np.testing.assert_allclose(a, arm_joints[i][:-1], atol=1e-12)
            np.testing.assert_allclose(b, arm_joints[i][1:], atol=1e-12)
        np.testing.assert_allclose(parts["centers"], sc.obstacle_centers(env.engine.elapsed[0]), atol=1e-6)
        env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})


# ------------------------------------------------------------------ moving obstacles


def test_moving_obstacles_turn_at_both_ends_at_constant_speed() -> None:
    centers = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, -1.0]])
    ends = np.array([[0.6, 0.8], [1.0, 1.0], [2.0, 0.5]])  # lengths 1.0, (still), 1.5
    speeds = np.array([0.25, 0.0, 0.5])  # half periods 4 s and 3 s
    t = np.linspace(0.0, 24.0, 240001)
    c = bodies.obstacle_centers(centers, ends, speeds, t)
    v = bodies.obstacle_velocities(centers, ends, speeds, t)
    np.testing.assert_allclose(c[:, 1], np.broadcast_to(centers[1], (t.size, 2)))
    np.testing.assert_allclose(v[:, 1], 0.0)
    for j, (length, half) in ((0, (1.0, 4.0)), (2, (1.5, 3.0))):
        arc = np.linalg.norm(c[:, j] - centers[j], axis=-1)
        # on the segment, between its centre and its path end
        unit = (ends[j] - centers[j]) / length
        np.testing.assert_allclose(centers[j] + arc[:, None] * unit, c[:, j], atol=1e-12)
        assert arc.max() == pytest.approx(length) and arc.min() == pytest.approx(0.0)
        # turns: at the path end after every odd half period, back at the centre after every even one
        for m in range(1, int(24 / half)):
            k = int(round(m * half / 1e-4))
            np.testing.assert_allclose(c[k, j], ends[j] if m % 2 else centers[j], atol=1e-12)
        # constant speed: every step covers speed·Δt of path, except the steps that hold a turn
        step = np.linalg.norm(np.diff(c[:, j], axis=0), axis=-1)
        turning = np.abs(np.diff(np.sign(np.diff(arc)))) > 0
        assert np.mean(np.isclose(step, speeds[j] * 1e-4, rtol=1e-6)) > 0.999
        np.testing.assert_allclose(step[1:][~turning], speeds[j] * 1e-4, rtol=1e-6)
        # the velocity is the derivative of the centre
        np.testing.assert_allclose(np.linalg.norm(v[:, j], axis=-1), speeds[j])
        np.testing.assert_allclose(v[1:-1, j][~turning], (np.diff(c[:, j], axis=0)[1:] + np.diff(c[:, j], axis=0)[:-1])
                                   [~turning] / 2e-4, atol=1e-9)


def test_scenario_with_moving_obstacles_parses_and_moves() -> None:
    doc = _doc("paper_pa_mixed_square")
    doc["safety"].update(bodies="links", link_radius=0.02, inter_arm=True)
    doc["obstacles"][0].update(path_end=[1.0, 2.7], speed=0.1)
    doc["obstacles"].append({"center": [3.0, 2.0], "radius": 0.05})
    sc = scenario.from_dict(doc)
    assert (sc.bodies, sc.link_radius, sc.inter_arm) == ("links", 0.02, True)
    np.testing.assert_array_equal(sc.moving_obstacles, [True, False])
    np.testing.assert_allclose(sc.obstacle_speeds, [0.1, 0.0])
    np.testing.assert_allclose(sc.obstacle_centers(0.0), sc.obstacles.centers)
    np.testing.assert_allclose(sc.obstacle_centers(6.0), [[1.0, 2.7], [3.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(sc.obstacle_centers(9.0), [[1.0, 3.0], [3.0, 2.0]], atol=1e-12)
    np.testing.assert_allclose(sc.obstacle_velocities(9.0), [[0.0, 0.1], [0.0, 0.0]], atol=1e-12)
    plain = scenario.load("paper_pa_mixed_square")  # defaults: the paper's end-effectors, still obstacles
    assert (plain.bodies, plain.link_radius, plain.inter_arm) == ("end_effector", 0.0, False)
    assert plain.obstacle_paths is None and plain.obstacle_speeds is None
    np.testing.assert_array_equal(plain.obstacle_centers(5.0), plain.obstacles.centers)


def test_env_moves_obstacles_and_state_reports_where_they_are() -> None:
    """An env built from a scenario with a moving obstacle moves it along its path: after 20 steps of
    0.01 s at 0.1 m/s from (1, 3.3) towards (1, 2.7), state() has it at (1, 3.28)."""
    from pan1_env.environment import parallel_env

    doc = _doc("paper_pa_mixed_square")
    doc["safety"].update(bodies="links", link_radius=0.02)
    doc["obstacles"][0].update(path_end=[1.0, 2.7], speed=0.1)
    env = parallel_env(scenario.from_dict(doc), control_dt=0.01, physics_dt=0.01)
    env.reset(seed=0)
    for _ in range(20):
        env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    np.testing.assert_allclose(env.state()[-3:-1], [1.0, 3.28], atol=1e-6)


# ------------------------------------------------------------------ scenario files: bad inputs


def _doc(name: str) -> dict:
    return tomllib.loads(resources.files("pan1_env.scenarios").joinpath(f"{name}.toml").read_text())


def _links(doc: dict, **safety) -> dict:
    doc["safety"].update(bodies="links", **safety)
    return doc


def _obstacle(doc: dict, **keys) -> dict:
    doc["obstacles"][0].update(keys)
    return doc


def _base_near(doc: dict) -> dict:
    doc["arms"][1]["base"] = [0.7, 2.0]  # its first link crosses arm 0's second link
    return doc


MIXED = "paper_pa_mixed_square"
# id: (scenario, edit, message excerpt); arms and links are numbered from 0
BAD_INPUTS = {
    "negative_link_radius": (MIXED, lambda d: _links(d, link_radius=-0.01),
                             "safety.link_radius: must be non-negative, got -0.01"),
    "bodies_misspelt": (MIXED, lambda d: d | {"safety": {**d["safety"], "bodies": "link"}},
                        "safety.bodies: unknown protected bodies 'link'; allowed values are "
                        "\"end_effector\" or \"links\""),
    "bodies_not_a_string": (MIXED, lambda d: d | {"safety": {**d["safety"], "bodies": 1}},
                            "safety.bodies: unknown protected bodies 1; allowed values are"),
    "inter_arm_not_bool": (MIXED, lambda d: _links(d, inter_arm="yes"),
                           "safety.inter_arm: expected true or false, got 'yes'"),
    "link_radius_without_links": (MIXED, lambda d: d | {"safety": {**d["safety"], "link_radius": 0.02}},
                                  "safety.link_radius: 0.02 has no effect with bodies = \"end_effector\""),
    "inter_arm_without_links": (MIXED, lambda d: d | {"safety": {**d["safety"], "inter_arm": True}},
                                "safety.inter_arm: true needs bodies = \"links\""),
    "speed_without_path": (MIXED, lambda d: _obstacle(d, speed=0.1), "obstacles[0].speed: a speed without a path"),
    "path_without_speed": (MIXED, lambda d: _obstacle(d, path_end=[1.0, 2.7]),
                           "obstacles[0].path_end: a path without a speed"),
    "zero_speed": (MIXED, lambda d: _obstacle(d, path_end=[1.0, 2.7], speed=0), "obstacles[0].speed: must be positive"),
    "path_of_length_zero": (MIXED, lambda d: _obstacle(d, path_end=[1.0, 3.3], speed=0.1),
                            "obstacles[0].path_end: equals center [1.0, 3.3]"),
    "path_end_in_base_clearance": (MIXED, lambda d: _obstacle(d, path_end=[0.55, 3.05], speed=0.1),
                                   "obstacles[0].path_end: the path from center to path_end comes within 0.0707 m of "
                                   "arm 3's base, inside its clearance r + link_radius = 0.1000 m"),
    "path_crossing_base_clearance": (MIXED, lambda d: _obstacle(d, path_end=[0.0, 2.7], speed=0.1),
                                     "obstacles[0].path_end: the path from center to path_end comes within 0.0000 m"),
    "path_in_link_radius_of_base": (MIXED, lambda d: _links(_obstacle(d, path_end=[0.5, 3.12], speed=0.1),
                                                             link_radius=0.03),
                                    "obstacles[0].path_end: the path from center to path_end comes within 0.1200 m "
                                    "of arm 3's base, inside its clearance r + link_radius = 0.1300 m"),
    "link_inside_obstacle": ("paper_pa3_square", lambda d: _links(d),
                             "arms[3].q0: link 3 starts inside or on obstacle 1 (clearance -0.0510 m"),
    "link_capsule_touches_obstacle": (MIXED, lambda d: _links(d, link_radius=0.11),
                                      "arms[3].q0: link 1 starts inside or on obstacle 0 (clearance -0.0100 m"),
    "links_touch_other_arm": (MIXED, lambda d: _links(_base_near(d), inter_arm=True),
                              "arms[1].q0: link 0 starts touching link 1 of arm 0"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_whole_arm_bad_input(case: str) -> None:
    name, edit, message = BAD_INPUTS[case]
    doc = edit(_doc(name))
    with pytest.raises(ScenarioError) as err:
        scenario.from_dict(doc, source="bad.toml")
    assert str(err.value).startswith("bad.toml: " + message), str(err.value)


def test_the_bad_inputs_are_bad_only_for_their_key() -> None:
    """Each bad input's neighbour is accepted: a path clear of the bases, links kept apart without inter_arm,
    a path 0.12 m from a base with end-effectors only (its clearance is then r = 0.1 m)."""
    scenario.from_dict(_obstacle(_doc(MIXED), path_end=[1.0, 2.7], speed=0.1))
    scenario.from_dict(_links(_base_near(_doc(MIXED))))
    scenario.from_dict(_obstacle(_doc(MIXED), path_end=[0.5, 3.12], speed=0.1))
    scenario.from_dict(_links(_doc(MIXED), link_radius=0.09))
    scenario.from_dict(_doc("paper_pa3_square"))  # its arm 3 crosses an obstacle with a link: fine for end-effectors


ODD_VALUES = [math.nan, math.inf, -math.inf, -1.0, 0.0, -0.0, 1e-9, 1e9, 2**63 - 1, -(2**63), 3, True, "", "pi/0",
              "x", "links", "end_effector", [], [math.nan], [1.0], [1.0, 2.0], [1e9, -1e9], [[0, 1]], {}, {"x": 1},
              datetime.date(2000, 1, 1)]


@pytest.mark.parametrize("slot", ["safety.bodies", "safety.link_radius", "safety.inter_arm", "obstacles.path_end",
                                  "obstacles.speed"])
@pytest.mark.parametrize("links", [False, True], ids=["end_effector", "links"])
def test_new_keys_with_odd_values_give_a_scenario_or_a_scenario_error(slot: str, links: bool) -> None:
    table, key = slot.split(".")
    for value in ODD_VALUES:
        doc = _doc(MIXED)
        if links:
            doc["safety"].update(bodies="links", link_radius=0.02, inter_arm=True)
        if table == "obstacles":
            doc["obstacles"][0].update(path_end=[1.0, 2.7], speed=0.1)
            doc["obstacles"][0][key] = copy.deepcopy(value)
        else:
            doc[table][key] = copy.deepcopy(value)
        try:
            scenario.from_dict(doc, source="odd.toml")
        except ScenarioError as err:
            assert str(err).startswith(("odd.toml: safety.", "odd.toml: obstacles[0].", "odd.toml: arms[")), str(err)


def test_scenario_constructor_defaults_keep_old_calls_working() -> None:
    sc = scenario.load("paper_pa3_square")
    fields = {k: getattr(sc, k) for k in ("name", "description", "arms", "q0", "formation", "obstacles", "kp", "ke",
                                          "filter", "physics_dt", "control_dt", "horizon")}
    rebuilt = scenario.Scenario(**fields)
    assert (rebuilt.bodies, rebuilt.link_radius, rebuilt.inter_arm, rebuilt.obstacle_paths) == \
        ("end_effector", 0.0, False, None)
    with pytest.raises(ValueError, match="Scenario.bodies must be one of"):
        scenario.Scenario(**fields, bodies="arms")
    with pytest.raises(ValueError, match="obstacle_paths and obstacle_speeds go together"):
        scenario.Scenario(**fields, obstacle_paths=sc.obstacles.centers)
    copy.deepcopy(rebuilt)


def test_the_floors_bound_every_configurations_clearance_from_below() -> None:
    """obstacle_floors and arm_pair_floors against the independent geometry: for random arms placed anywhere, any
    joint angles, obstacles anywhere on their paths, no link capsule comes closer than its floor; and a stretched arm
    pointing at an obstacle reaches its floor."""
    rng = np.random.default_rng(0)
    rho = 0.03
    for _ in range(20):
        arms = [random_arm(rng, int(rng.integers(2, 5)), placed=True) for _ in range(3)]
        bases, reach = np.array([a.base for a in arms]), np.array([a.reach for a in arms])
        centers, ends = rng.uniform(-2, 2, (4, 2)), rng.uniform(-2, 2, (4, 2))
        radii = rng.uniform(0.05, 0.3, 4)
        world = bodies.obstacle_floors(bases, reach, centers, ends, radii, rho)
        pairs = bodies.arm_pair_floors(bases, reach, rho)
        for _ in range(10):
            P = [joints(rng.uniform(-np.pi, np.pi, a.n_links), a.lengths, a.base, a.phi) for a in arms]
            where = centers + rng.uniform(0, 1, (4, 1)) * (ends - centers)
            for i, Pi in enumerate(P):
                for o in range(4):
                    near = min(point_segment_distance(where[o], Pi[k], Pi[k + 1]) for k in range(len(Pi) - 1))
                    assert near - radii[o] - rho >= world[i, o] - 1e-12
            for (i, j), c in inter_arm_clearances(P, rho).items():
                assert c.min() >= pairs[i, j] - 1e-12 and pairs[i, j] == pytest.approx(pairs[j, i], abs=1e-12)
    arm = random_arm(rng, 3, placed=True)
    stretched = joints(np.zeros(3), arm.lengths, arm.base, arm.phi)  # every joint at 0: the arm straight out
    ahead = arm.base + (stretched[-1] - arm.base) * (arm.reach + 0.5) / arm.reach
    floor = bodies.obstacle_floors(arm.base[None], np.array([arm.reach]), ahead[None], ahead[None], np.array([0.1]),
                                   0.0)[0, 0]
    assert floor == pytest.approx(point_segment_distance(ahead, stretched[-2], stretched[-1]) - 0.1, abs=1e-9)
