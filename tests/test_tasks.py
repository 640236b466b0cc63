"""The tasks' step outcomes against the documented formulas, written here in plain numpy."""

from __future__ import annotations

import numpy as np
import pytest

from pan1_env.config import FormationConfig
from pan1_env.engine import Engine, Physics, StepRecord
from pan1_env.environment import parallel_env
from pan1_env.tasks import FormationTask


@pytest.mark.parametrize("B, N, E", [(1, 4, 5), (7, 6, 9), (3, 2, 1)])
def test_formation_outcome_matches_the_documented_reward(B: int, N: int, E: int) -> None:
    rng = np.random.default_rng(B * 100 + E)
    parallel_env("paper_pa3_square")
    weights = {"formation_weight": 1.7, "effort_weight": 0.3, "collision_penalty": 2.0, "success_bonus": 0.6}
    config = FormationConfig("paper_pa3_square", max_joint_speed=2.0, success_tolerance=0.05,
                             terminate_on_collision=True, terminate_on_success=False, **weights)
    task = FormationTask(config, B)
    err = rng.uniform(-0.1, 0.1, (B, E))
    err[0] = rng.uniform(-0.01, 0.01, E)  # copy 0 succeeds
    clear = rng.uniform(-0.05, 1.0, (B, N))
    effort = rng.uniform(0, 1, (B, N))
    blank = np.zeros((B, N))
    record = StepRecord(np.zeros((B, N, 1)), np.zeros((B, N, 1)), clear, blank, np.zeros((B, N, 3), int), blank,
                        np.ones((B, N), bool))
    out = task.evaluate(record, None, err, effort)
    cost = (clear < 0).astype(float)
    success = np.abs(err).max(axis=1) < 0.05
    reward = -1.7 * np.abs(err).mean(axis=1)[:, None] - 0.3 * effort - 2.0 * cost + 0.6 * success[:, None]
    np.testing.assert_allclose(out.reward, reward, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(out.cost, cost)
    np.testing.assert_allclose(sum(np.broadcast_to(t, (B, N)) for t in out.terms.values()), out.reward, rtol=1e-12)
    np.testing.assert_array_equal(out.measures["formation_error"], np.abs(err).max(axis=1))
    np.testing.assert_array_equal(out.success, np.abs(err).max(axis=1) < 0.05)
    np.testing.assert_array_equal(out.terminated, cost.any(axis=1))
    assert out.success[0]


def test_engine_step_record_covers_every_arm_of_every_copy() -> None:
    """A mixed team (three arm kinds, not in team order) in three copies: every arm gets its results."""
    env = parallel_env("paper_pa_mixed_square")
    engine = Engine(env.scenario, 3, physics=Physics(physics_dt=0.01, max_joint_speed=2.0), safety_filter=True)
    rec = engine.step(np.full((3, engine.n_arms, engine.k_max), 0.5), 5)
    assert len(engine.kinds) > 1 and not engine.team_order
    assert np.isfinite(rec.min_clearance).all() and rec.all_finite
    np.testing.assert_array_equal(rec.qp_counts.sum(axis=-1), 5)
    for i, k in enumerate(engine.n_actuated):
        assert np.isfinite(rec.v_star[:, i, :k]).all() and np.isnan(rec.v_star[:, i, k:]).all()
    # the copies started alike and got the same command: the same results, bit for bit
    np.testing.assert_array_equal(rec.v_star[0], rec.v_star[2])


def test_intervention_term_is_the_filters_change_of_the_command() -> None:
    env = parallel_env("paper_pa_mixed_square", intervention_penalty=0.5, safety_filter=True)
    env.reset(seed=0)
    _, rewards, _, _, infos = env.step({a: np.full(env.action_space(a).shape, 1.0) for a in env.agents})
    rec = env.last_step
    for i, agent in enumerate(env.agents):
        k = env.n_actuated[i]
        change = np.sum((env.config.max_joint_speed - rec.v_star[0, i, :k]) ** 2) / k / env.config.max_joint_speed**2
        assert infos[agent]["reward_intervention"] == pytest.approx(-0.5 * change, rel=1e-12)
    assert any(infos[a]["reward_intervention"] < 0 for a in env.agents)  # the filter acted
    plain = parallel_env("paper_pa_mixed_square", intervention_penalty=0.5)  # no filter: v* is the command
    plain.reset(seed=0)
    _, _, _, _, infos = plain.step({a: np.full(plain.action_space(a).shape, 0.3) for a in plain.agents})
    assert all(abs(info["reward_intervention"]) < 1e-20 for info in infos.values())


def test_reward_terms_in_infos_sum_to_the_reward() -> None:
    from pan1_env.reach import PAReachEnv
    from pan1_env.vector import Pan1VectorEnv

    kw = {"effort_weight": 0.2, "collision_penalty": 1.0}
    env = parallel_env("paper_pa_mixed_square", **kw)
    env.reset(seed=0)
    _, rewards, _, _, infos = env.step({a: np.full(env.action_space(a).shape, 0.7) for a in env.agents})
    for agent, info in infos.items():
        terms = {key: value for key, value in info.items() if key.startswith("reward_")}
        assert set(terms) == {"reward_formation", "reward_effort", "reward_collision"}
        assert sum(terms.values()) == pytest.approx(rewards[agent], abs=1e-12)
    venv = Pan1VectorEnv("paper_pa_mixed_square", 2, **kw)
    venv.reset(seed=0)
    _, reward, _, _, info = venv.step(np.full(venv.action_space.shape, 0.7))
    np.testing.assert_allclose(info["reward_formation"] + info["reward_effort"] + info["reward_collision"], reward,
                               atol=1e-12)
    reach = PAReachEnv(**kw)
    reach.reset(seed=0)
    _, r, _, _, info = reach.step(np.full(reach.action_space.shape, 0.7))
    terms = {key: value for key, value in info.items() if key.startswith("reward_")}
    assert set(terms) == {"reward_distance", "reward_effort", "reward_collision"}
    assert sum(terms.values()) == pytest.approx(r, abs=1e-12)


def _reach_twin(goal, p, clear, effort, effort_weight, collision_penalty, tolerance, on_success, on_collision):
    """The reach task's documented outcome in plain numpy: reward −‖goal − p‖ − w_e·effort − w_c·cost."""
    distance = np.linalg.norm(goal - p, axis=1)
    cost = (clear < 0).astype(float)
    terms = {"distance": -distance}
    if effort_weight:
        terms["effort"] = -effort_weight * effort
    if collision_penalty:
        terms["collision"] = -collision_penalty * cost
    success = distance < tolerance
    terminated = (success & on_success) | ((cost > 0) & on_collision)
    return distance, cost, terms, sum(terms.values()), success, terminated


@pytest.mark.parametrize("weights", [(0.0, 0.0), (0.3, 0.0), (0.0, 2.0), (0.4, 1.5)])
@pytest.mark.parametrize("ends", [(False, False), (True, True)])
def test_reach_outcome_matches_its_numpy_twin(weights: tuple[float, float], ends: tuple[bool, bool]) -> None:
    from pan1_env.reach import PAReachEnv

    rng = np.random.default_rng(int(10 * sum(weights)) + ends[0])
    env = PAReachEnv(effort_weight=weights[0], collision_penalty=weights[1], terminate_on_success=ends[0],
                     terminate_on_collision=ends[1])
    B = 9
    task, engine = type(env.task)(env.config, B), Engine(env.config.team, B, env.config.physics)
    task.goal[:] = rng.uniform(-1, 1, (B, 2))
    engine.kinds[0].p[:] = task.goal + rng.uniform(-0.05, 0.05, (B, 2))
    engine.kinds[0].p[3:5] = task.goal[3:5] + 0.01  # within the 2 cm tolerance
    engine.kinds[0].p[0] = np.nan  # a copy gone non-finite: its distance is NaN, no success
    clear = rng.uniform(-0.05, 0.3, (B, 1))
    clear[[2, 5], 0] = -0.01, 0.0  # a collision, and a touch that is none
    effort = rng.uniform(0, 1, (B, 1))
    blank = np.zeros((B, 1))
    record = StepRecord(np.zeros((B, 1, 3)), np.zeros((B, 1, 4)), clear, blank, np.zeros((B, 1, 3), int), blank,
                        np.ones((B, 1), bool))
    out = task.evaluate(record, engine, None, effort)
    distance, cost, terms, reward, success, terminated = _reach_twin(
        task.goal, engine.kinds[0].p, clear[:, 0], effort[:, 0], *weights, env.config.goal_tolerance, *ends)
    np.testing.assert_allclose(out.measures["distance"], distance, rtol=1e-14)
    np.testing.assert_array_equal(out.cost[:, 0], cost)
    assert set(out.terms) == set(terms)
    for name, value in terms.items():
        np.testing.assert_allclose(out.terms[name][:, 0], value, rtol=1e-14)
    np.testing.assert_allclose(out.reward[:, 0], reward, rtol=1e-14)
    np.testing.assert_array_equal(out.success, success)
    np.testing.assert_array_equal(out.terminated, terminated)
    assert success[1:].any() and not success.all() and cost.any()  # the draw covers both sides


@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_filter_report_matches_its_numpy_twin(mode: str) -> None:
    """The core's shield infos of a mixed team (padding) with faults (a lost first joint reads 0) against numpy."""
    env = parallel_env("paper_pa_mixed_square", safety_filter=True, action_mode=mode,
                       **({"max_torque": 3.0} if mode == "torque" else {}))
    core, rng = env.core, np.random.default_rng(3)
    B, N, k_max, n_max = 1, core.engine.n_arms, core.k_max, core.engine.n_max
    counts = rng.integers(0, 3, (B, N, 3))
    record = StepRecord(rng.normal(size=(B, N, k_max)), rng.normal(size=(B, N, n_max)), np.zeros((B, N)),
                        rng.normal(size=(B, N)), counts, np.zeros((B, N)), np.ones((B, N), bool))
    core.engine.faulted[0, 1] = True
    infos = core._shield_infos(record, (B, N))
    solved, fallback = counts[..., 1] > 0, counts[..., 2] > 0
    np.testing.assert_array_equal(infos["shield_intervened"], solved | fallback)
    np.testing.assert_array_equal(infos["shield_fallback"], fallback)
    np.testing.assert_array_equal(infos["shield_status"], np.where(fallback, 2, solved.astype(int)))
    unit = 3.0 if mode == "torque" else env.config.max_joint_speed
    for i, (n, k) in enumerate(zip(core.n_links, core.n_actuated, strict=True)):
        values = record.tau[0, i, n - k: n] if mode == "torque" else record.v_star[0, i, :k]
        expected = np.zeros(k_max, np.float32)
        expected[:k] = np.multiply(values, 1.0 / unit, dtype=np.float32)
        if i == 1:
            expected[0] = 0.0
        np.testing.assert_array_equal(infos["shield_applied"][0, i], expected)
    assert (np.asarray(core.n_actuated) < k_max).any()  # some padding
