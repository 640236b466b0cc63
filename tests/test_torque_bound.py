"""Torque mode's input bound (docs/MODEL.md §5d) as the env's option ``torque_bound``: wired to the engine's filter
(the end-effector filter and the whole-arm one), off by default, refused when it is not a bool."""

import dataclasses

import numpy as np
import pytest

from pan1_env.vector import Pan1VectorEnv

TEAM = {"n_arms": 4, "links": (2, 3, 4, 3), "passive_fraction": 0.5}
ENVS = {"end-effector": ("random", {"random_options": TEAM}), "whole-arm": ("pan1_env/WholeArmStaticFormation-v1", {})}


def _largest_torque_ratio(name: str, torque_bound: bool) -> float:
    """The largest |τ| / max_torque over 150 steps of random torques on 16 copies behind the shield, one physics
    sub-step a step (every torque seen)."""
    scenario, kwargs = ENVS[name]
    venv = Pan1VectorEnv(scenario, 16, action_mode="torque", control_dt=0.002, max_steps=500, max_torque=5.0,
                         torque_bound=torque_bound, **kwargs)
    assert venv.engine.physics_dt == pytest.approx(0.002)
    venv.reset(seed=3)
    rng, largest = np.random.default_rng(3), 0.0
    for _ in range(150):
        _, _, _, _, infos = venv.step(rng.uniform(-1.0, 1.0, venv.action_space.shape))
        assert infos["cost"].sum() == 0.0
        largest = max(largest, float(np.nanmax(np.abs(venv.core.record.tau))) / 5.0)
    return largest


@pytest.mark.parametrize("name", list(ENVS))
def test_the_torque_bound_holds_every_torque_and_is_needed(name: str) -> None:
    assert _largest_torque_ratio(name, True) <= 1.0 + 1e-9
    assert _largest_torque_ratio(name, False) > 2.0  # the unbounded filter's torques: what the option changes


def test_a_torque_bound_that_is_not_a_bool_or_outside_torque_mode_is_refused() -> None:
    with pytest.raises(ValueError, match="torque_bound must be True or False"):
        Pan1VectorEnv("random", 2, random_options=TEAM, action_mode="torque", torque_bound="yes")
    with pytest.raises(ValueError, match="in action_mode='torque' only"):
        Pan1VectorEnv("random", 2, random_options=TEAM, action_mode="velocity", torque_bound=True)


def _same_range_unbounded(engine) -> None:
    """Give the bounded engine's filter its braking range explicitly, so that an unbounded twin of it (max_torque
    = inf) filters with the same rows and only the bound differs."""
    from pan1_env.engine import BRAKING_SENSING_RADIUS

    engine.set_safety_filter(dataclasses.replace(engine.filter, sensing_radius=BRAKING_SENSING_RADIUS))


def test_the_whole_arm_range_widens_behind_the_bound_in_torque_mode_only() -> None:
    """The whole-arm filter's range (docs/MODEL.md §5d): 1 m in torque mode behind the bound, the default 0.1 m in
    velocity mode and without the bound, and a filter's own sensing_radius in every case."""
    from pan1_env.engine import BRAKING_SENSING_RADIUS, SENSING_RADIUS

    engine = Pan1VectorEnv("pan1_env/WholeArmStaticFormation-v1", 1, action_mode="torque", torque_bound=True).engine
    assert engine.filter_range(True) == BRAKING_SENSING_RADIUS == 1.0
    assert engine.filter_range(False) == SENSING_RADIUS == 0.1
    engine.physics = dataclasses.replace(engine.physics, max_torque=np.inf)
    assert engine.filter_range(True) == SENSING_RADIUS
    engine.physics = dataclasses.replace(engine.physics, max_torque=5.0)
    engine.set_safety_filter(dataclasses.replace(engine.filter, sensing_radius=0.3))
    assert engine.filter_range(True) == engine.filter_range(False) == 0.3


def _pose_inside_an_obstacle(team, centers, radii, rng) -> tuple[int, np.ndarray]:
    """A fully actuated arm of ``team`` and joint angles that put one of its links 6-12 cm inside an obstacle."""
    from pan1_env.dynamics import joint_positions

    for arm, params in enumerate(team.arms):
        if params.n_actuated < params.n_links:
            continue
        for _ in range(5_000):
            q = rng.uniform(-np.pi, np.pi, params.n_links)
            P = joint_positions(params, q)
            a, d = P[:-1, None], (P[1:] - P[:-1])[:, None]
            t = np.clip(((centers - a) * d).sum(-1) / (d * d).sum(-1), 0.0, 1.0)
            gap = np.linalg.norm(a + t[..., None] * d - centers, axis=-1) - radii - team.link_radius
            if -0.12 < gap.min() < -0.06:
                return arm, q
    raise AssertionError("no fully actuated arm reaches into an obstacle")


def test_a_whole_arm_fallback_stays_one_and_moves_towards_the_filters_answer_within_the_bound() -> None:
    """A fully actuated arm put at rest with a link deep inside an obstacle: the whole-arm filter's QP has no solution
    and its last resort asks for more than the bound. Behind the bound the lane is still reported as a fallback, and
    its velocity is the point nearest the unbounded filter's answer within the torque rows (PIQP on
    barriers.torque_rows; at rest H = 0)."""
    import pickle

    from pan1_env.dynamics import mass_matrix
    from pan1_env.safety import project_velocity, torque_rows

    tau_max, dt = 0.5, 0.002
    venv = Pan1VectorEnv("pan1_env/WholeArmStaticFormation-v1", 1, action_mode="torque", control_dt=dt,
                         max_torque=tau_max, torque_bound=True)
    venv.reset(seed=7)
    engine = venv.engine
    team = engine.teams[0]
    q0, _ = engine.joint_state()
    q = [q0[0, i][: a.n_links] for i, a in enumerate(team.arms)]
    qd = [np.zeros(a.n_links) for a in team.arms]
    arm, pose = _pose_inside_an_obstacle(team, engine.centers[0], engine.radii[0], np.random.default_rng(0))
    q[arm] = pose
    engine.set_state(0, q, qd)
    _same_range_unbounded(engine)
    assert engine.clearance()[0, arm] < -0.05
    free_engine = pickle.loads(pickle.dumps(engine))
    free_engine.physics = dataclasses.replace(free_engine.physics, max_torque=np.inf)
    command = np.zeros((1, engine.n_arms, engine.k_max))
    free = free_engine.step(command.copy(), 1, torque=True)
    bounded = engine.step(command.copy(), 1, torque=True)
    k = team.arms[arm].n_actuated
    assert free.qp_counts[0, arm, 2] == 1 and np.abs(free.tau[0, arm, :k]).max() > tau_max, "should need the bound"
    assert bounded.qp_counts[0, arm, 2] == 1  # still a fallback
    A, b = torque_rows(mass_matrix(team.arms[arm], q[arm]), np.zeros(k), np.zeros(k), dt, tau_max)
    nearest = project_velocity(free.v_star[0, arm, :k][None], A[None], b[None], solver="piqp")
    np.testing.assert_allclose(bounded.v_star[0, arm, :k], nearest.v[0], atol=1e-6)
    assert np.abs(bounded.tau[0, arm, :k]).max() <= tau_max * (1 + 1e-9)


@pytest.mark.slow
def test_behind_the_bound_every_fallback_of_the_filter_is_still_reported_one() -> None:
    """Twin engines from the same state at every step, one with the bound and one without, on moving-obstacle
    whole-arm teams with a tight bound (0.5 N·m) and random torques: wherever the unbounded filter falls back,
    the bounded one reports a fallback too (its rows may have been relaxed by then, so solving them again with the
    torque rows is not a solution of the filter's QP), and no torque exceeds the bound. 950 steps reach the first
    lanes where a re-solve would have been reported as solved."""
    import pickle

    tau_max = 0.5
    venv = Pan1VectorEnv("pan1_env/WholeArmFormation-v0", 32, action_mode="torque", control_dt=0.002,
                         max_steps=100_000, max_torque=tau_max, torque_bound=True)
    venv.reset(seed=5)
    engine, rng = venv.engine, np.random.default_rng(0)
    _same_range_unbounded(engine)
    shape = (engine.copies, engine.n_arms, engine.k_max)
    unbounded_fallbacks = 0
    for _ in range(950):
        free_engine = pickle.loads(pickle.dumps(engine))
        free_engine.physics = dataclasses.replace(free_engine.physics, max_torque=np.inf)
        command = rng.uniform(-1.0, 1.0, shape) * tau_max
        free = free_engine.step(command.copy(), 1, torque=True)
        bounded = engine.step(command.copy(), 1, torque=True)
        fell_back = free.qp_counts[..., 2] > 0
        unbounded_fallbacks += int(fell_back.sum())
        assert np.all(bounded.qp_counts[..., 2][fell_back] > 0)
        assert np.nanmax(np.abs(bounded.tau)) <= tau_max * (1 + 1e-9)
    assert unbounded_fallbacks > 100
