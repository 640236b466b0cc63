"""The one-arm reaching task against Gymnasium's checker and against the same arm in the team env."""

import gymnasium
import numpy as np
import pytest

import pan1_env
from pan1_env.cascade import reduced_jacobian
from pan1_env.dynamics import end_effector
from pan1_env.environment import parallel_env
from pan1_env.reach import PAReachEnv
from pan1_env.registration import REACH_ENV_ID
from pan1_env.scenario import load
from pan1_env.wrappers import GymSafetyShield, SafetyShield


def test_make_reset_and_spaces() -> None:
    """(``check_env`` runs on it with the team envs in ``tests/test_env.py``.)"""
    assert REACH_ENV_ID in gymnasium.registry and pan1_env.__version__
    env = gymnasium.make(REACH_ENV_ID)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs) and info["cost"] == 0.0
    obs, _, _, _, info = env.step(env.action_space.sample())
    assert env.observation_space.contains(obs) and set(info) >= {"cost", "min_clearance", "distance", "is_success"}


@pytest.mark.parametrize("shielded", [True, False])
@pytest.mark.parametrize("scenario,arm", [("paper_pa3_square", 0), ("paper_pa_mixed_square", 2)])
def test_arm_follows_the_same_trajectory_as_in_the_team_env(scenario: str, arm: int, shielded: bool) -> None:
    reach = PAReachEnv(scenario, arm, safety_filter=shielded, max_steps=60)
    team = parallel_env(scenario, max_steps=60)
    if shielded:
        team = SafetyShield(team)
    reach.reset(seed=0)
    team.reset(seed=0)
    core = team.unwrapped
    agent = core.possible_agents[arm]
    rng = np.random.default_rng(3)
    n, K = reach.arm.n_links, reach.config.n_obstacle_obs
    assert K == core.config.n_obstacle_obs
    for _ in range(60):
        actions = {a: rng.uniform(-1.3, 1.3, team.action_space(a).shape) for a in core.possible_agents}
        obs, _, _, _, info = reach.step(actions[agent])
        team_obs, _, _, _, infos = team.step(actions)
        # the layouts share the arm's own entries (cos q, sin q, q̇, p − base) and the K obstacle slots
        np.testing.assert_allclose(obs[: 3 * n + 2], team_obs[agent][: 3 * n + 2], rtol=0, atol=1e-6)
        np.testing.assert_allclose(obs[-5 * K :], team_obs[agent][-5 * K :], rtol=0, atol=1e-6)
        q_team, _ = core.joint_state()
        np.testing.assert_allclose(reach.q, q_team[arm, :n], rtol=0, atol=1e-12)
        np.testing.assert_allclose(reach.end_effector, core.end_effectors()[arm], rtol=0, atol=1e-12)
        assert info["min_clearance"] == pytest.approx(infos[agent]["min_clearance"], abs=1e-12)
        assert info["cost"] == infos[agent]["cost"]
        if shielded:
            team_arm = infos[agent]
            assert info["shield_intervened"] == team_arm["shield_intervened"]
            np.testing.assert_array_equal(info["shield_applied"], team_arm["shield_applied"])


def _seek(env: PAReachEnv, gain: float = 2.0, damping: float = 0.05) -> np.ndarray:
    """A damped least-squares reaching law, v = J̄ᵀ (J̄ J̄ᵀ + λ² I)⁻¹ K (goal − p), in action units."""
    Jbar = reduced_jacobian(env.arm, env.q)
    v = Jbar.T @ np.linalg.solve(Jbar @ Jbar.T + damping**2 * np.eye(2), gain * (env.goal - env.end_effector))
    return np.clip(v / env.config.max_joint_speed, -1, 1)


def test_the_filter_keeps_a_goal_inside_an_obstacle_out_of_reach() -> None:
    """Driven at an obstacle's centre, the unfiltered arm enters it and the filtered one stops at its edge."""
    results = {}
    for shielded in (False, True):
        env = PAReachEnv(safety_filter=shielded, max_steps=300)
        centre = env.scenario.obstacles.centers[0]
        env.reset(options={"goal": centre})
        costs, clearances = [], []
        for _ in range(300):
            _, _, _, truncated, info = env.step(_seek(env))
            costs.append(info["cost"])
            clearances.append(info["min_clearance"])
            if truncated:
                break
        results[shielded] = (sum(costs), min(clearances), info["distance"])
    assert results[False][0] > 0 and results[False][1] < 0  # it would have collided
    cost, clearance, distance = results[True]
    assert cost == 0 and clearance >= 0
    radius = PAReachEnv().scenario.obstacles.radii[0]
    assert radius <= distance < radius + 0.05  # held at the obstacle's edge, not frozen far away


def test_drawn_goals_are_reachable_and_clear_of_obstacles() -> None:
    env = PAReachEnv(terminate_on_success=True)
    obstacles = env.scenario.obstacles
    reached = 0
    for seed in range(8):
        _, info = env.reset(seed=seed)
        goal = env.goal
        assert (np.linalg.norm(obstacles.centers - goal, axis=1) - obstacles.radii).min() >= env.config.goal_clearance
        for _ in range(env.config.max_steps):
            _, reward, terminated, truncated, info = env.step(_seek(env))
            assert info["cost"] == 0.0
            assert reward == pytest.approx(-info["distance"])
            if terminated or truncated:
                break
        reached += bool(info["is_success"] and terminated)
    assert reached >= 7  # a plain damped least-squares law reaches (nearly) every goal within the episode


def test_seeding_and_goal_option() -> None:
    a, b = PAReachEnv(), PAReachEnv()
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    np.testing.assert_array_equal(oa, ob)
    np.testing.assert_array_equal(a.goal, b.goal)
    b.reset(seed=8)
    assert not np.array_equal(a.goal, b.goal)
    obs, info = a.reset(options={"goal": (1.0, 0.5)})
    np.testing.assert_array_equal(a.goal, [1.0, 0.5])
    n = a.arm.n_links
    p = end_effector(a.arm, a.q)
    np.testing.assert_allclose(obs[3 * n + 2 : 3 * n + 4], np.array([1.0, 0.5]) - p, atol=1e-6)
    assert info["distance"] == pytest.approx(np.hypot(*(np.array([1.0, 0.5]) - p)))


@pytest.mark.parametrize("make,match", [
    (lambda: PAReachEnv(arm=4), "arm must be below"),
    (lambda: PAReachEnv(arm=-1), "arm must be an integer"),
    (lambda: PAReachEnv(physics_dt=0.05), "too long for the tracker gain"),
    (lambda: PAReachEnv(control_dt=0.05, physics_dt=0.003), "control_dt"),
    (lambda: PAReachEnv(goal_tolerance=0), "goal_tolerance must be positive"),
    (lambda: PAReachEnv(render_mode="human"), "no render modes"),
])
def test_bad_arguments(make, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_actions_and_calls() -> None:
    env = PAReachEnv(max_steps=2)
    with pytest.raises(RuntimeError, match="before reset"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="only option is 'goal'"):
        env.reset(options={"start": 1})
    with pytest.raises(ValueError, match="options\\['goal'\\]"):
        env.reset(options={"goal": (np.nan, 0.0)})
    env.reset(seed=0)
    q = env.q
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(4))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"action must be an array of numbers of shape \(3,\), got dict"):
        env.step({"arm_0": np.zeros(3)})
    with pytest.raises(ValueError, match=r"action must be an array of numbers of shape \(3,\), got str 'zero'"):
        env.step("zero")
    np.testing.assert_array_equal(env.q, q)  # a refused action changes nothing
    env.step(np.zeros(3))
    _, _, _, truncated, _ = env.step(np.zeros(3))
    assert truncated
    with pytest.raises(RuntimeError, match="after the episode ended"):
        env.step(np.zeros(3))
    with pytest.raises(TypeError, match="filter built in"):
        GymSafetyShield(gymnasium.make(REACH_ENV_ID))


def test_the_reach_env_takes_the_ids_of_fixed_scenarios() -> None:
    env, mixed = PAReachEnv("pan1_env/PaperMixedPA-v0", 3), load("paper_pa_mixed_square")
    assert env.scenario.name == mixed.name and env.arm == mixed.arms[3]
    with pytest.raises(ValueError, match="takes an arm of a fixed scenario, not random teams"):
        PAReachEnv("pan1_env/RandomFormation-v0")
