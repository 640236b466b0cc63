"""Residual and gain actions: the action corrects (``"residual"``) or re-weights (``"gain"``) the
paper's distributed law.

The zero action must be the reference controller, computed here independently from the agents'
observations by :class:`~pan1_env.baselines.ReferencePolicy`; the vector env must agree with the
parallel env; the correction is added and clipped to the speed limit; a gain multiplies each joint's
term of the law before it is scaled to the speed limit.
"""

import numpy as np
import pytest

from pan1_env.baselines import ReferencePolicy
from pan1_env.environment import parallel_env
from pan1_env.vector import Pan1VectorEnv
from pan1_env.wrappers import SafetyShield


def _zeros(env):
    return {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents}


@pytest.mark.parametrize("scenario", ["paper_pa3_square", "random"])
def test_the_nominal_velocity_is_the_reference_policy(scenario) -> None:
    env = parallel_env(scenario, action_mode="residual")
    ref = ReferencePolicy(parallel_env(scenario))
    ref.env = env  # it reads the env's scenario (the team drawn at the reset), layout and speed limit
    rng = np.random.default_rng(1)
    obs, _ = env.reset(seed=4)
    for _ in range(5):
        nominal = env.task.nominal_velocity(env.engine)[0] / env.config.max_joint_speed
        for i, agent in enumerate(env.agents):
            expected = ref.act(agent, obs[agent])  # from float32 observations
            np.testing.assert_allclose(nominal[i, : env.n_actuated[i]], expected, rtol=1e-4, atol=1e-5)
        obs, *_ = env.step({a: rng.uniform(-0.5, 0.5, env.action_space(a).shape) for a in env.agents})


def test_zero_residual_behind_the_shield_follows_the_reference() -> None:
    residual = SafetyShield(parallel_env("paper_pa_mixed_square", action_mode="residual", max_steps=60))
    reference = SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=60))
    policy = ReferencePolicy(reference)
    obs_r, _ = residual.reset(seed=0)
    obs_p, _ = reference.reset(seed=0)
    while residual.agents:
        obs_r, *_ = residual.step(_zeros(residual))
        obs_p, *_ = reference.step(policy(obs_p))
    # the reference reads float32 observations, the residual env the exact state: close, not equal
    np.testing.assert_allclose(residual.unwrapped.end_effectors(), reference.unwrapped.end_effectors(), atol=1e-5)


def test_the_correction_is_added_and_clipped_to_the_speed_limit() -> None:
    env = parallel_env("paper_pa3_square", action_mode="residual", safety_filter=False)
    env.reset(seed=0)
    nominal = env.task.nominal_velocity(env.engine)[0]
    command, effort = env.commands({a: np.full(env.action_space(a).shape, 0.25, np.float32) for a in env.agents})
    k = env.n_actuated[0]
    speed = env.config.max_joint_speed
    expected = np.clip(nominal[:, :k] + 0.25 * speed, -speed, speed)
    np.testing.assert_allclose(command[0, :, :k], expected, rtol=1e-12)
    np.testing.assert_allclose(effort, 0.25**2)  # the effort term sees the correction only
    command, _ = env.commands({a: np.full(env.action_space(a).shape, 1.0, np.float32) for a in env.agents})
    assert np.all(command <= env.config.max_joint_speed) and np.any(command == env.config.max_joint_speed)


@pytest.mark.parametrize("mode", ["residual", "gain"])
def test_vector_env_residual_and_gain_match_the_parallel_env(mode) -> None:
    venv = Pan1VectorEnv("random", 3, action_mode=mode, max_steps=30)
    obs, _ = venv.reset(seed=[7, 8, 9])
    penv = SafetyShield(parallel_env("random", action_mode=mode, max_steps=30))
    pobs, _ = penv.reset(seed=8)
    np.testing.assert_array_equal(obs[1], np.concatenate([pobs[a] for a in penv.possible_agents]))
    rng = np.random.default_rng(0)
    for _ in range(10):
        a = rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32)
        obs, reward, *_ = venv.step(a)
        split = np.split(a[1], np.cumsum(penv.unwrapped.n_actuated)[:-1])
        pobs, prew, *_ = penv.step(dict(zip(penv.possible_agents, split, strict=True)))
        np.testing.assert_allclose(obs[1], np.concatenate([pobs[a] for a in penv.possible_agents]), atol=1e-6)
        assert reward[1] == pytest.approx(np.mean(list(prew.values())), abs=1e-9)


def test_residual_mode_is_a_listed_action_mode_and_reference_policy_refuses_it() -> None:
    with pytest.raises(ValueError, match="residual"):
        parallel_env("paper_pa3_square", action_mode="residul")
    with pytest.raises(ValueError, match="velocit"):
        ReferencePolicy(parallel_env("paper_pa3_square", action_mode="residual"))


def test_the_gate_scales_each_arms_correction_by_its_squared_edge_error() -> None:
    gate = 5.0  # m: larger than the start's edge errors, so every arm's correction is scaled down
    env = parallel_env("random", action_mode="residual", safety_filter=False, residual_gate=gate)
    env.reset(seed=3)
    nominal = env.task.nominal_velocity(env.engine)[0]
    command, _ = env.commands({a: np.full(env.action_space(a).shape, 0.1, np.float32) for a in env.agents})
    P, f = env.end_effectors(), env.scenario.formation
    for i in range(len(env.agents)):
        errors = [abs(np.linalg.norm(P[a] - P[b]) - d) for (a, b), d in zip(f.edges, f.distances, strict=True)
                  if i in (a, b)]
        scale = min(1.0, (max(errors) / gate) ** 2)
        assert 0 < scale < 1
        k = env.n_actuated[i]
        speed = env.config.max_joint_speed
        expected = np.clip(nominal[i, :k] + scale * float(np.float32(0.1)) * speed, -speed, speed)
        np.testing.assert_allclose(command[0, i, :k], expected, rtol=1e-12)
    with pytest.raises(ValueError, match="residual_gate"):
        parallel_env("random", residual_gate=-1.0)


def test_the_blocked_gate_opens_only_where_the_filter_changed_the_last_command() -> None:
    env = parallel_env("paper_pa_mixed_square", action_mode="residual", safety_filter=True, blocked_gate=0.5)
    env.reset(seed=0)
    full = {a: np.full(env.action_space(a).shape, 0.5, np.float32) for a in env.agents}
    nominal = env.task.nominal_velocity(env.engine)[0]
    command, _ = env.commands(full)  # after a reset nothing was blocked: the paper's law alone
    np.testing.assert_allclose(command[0], nominal, atol=1e-12)
    env.step(full)
    rec, k = env.last_step, env.n_actuated
    sent = np.zeros_like(rec.v_star[0])
    for i in range(len(env.agents)):  # what was commanded at that step: the nominal alone (gate shut)
        sent[i, : k[i]] = nominal[i, : k[i]]
    blocked = [np.sum((sent[i, : k[i]] - rec.v_star[0, i, : k[i]]) ** 2) / k[i] / env.config.max_joint_speed**2
               for i in range(len(env.agents))]
    nominal = env.task.nominal_velocity(env.engine)[0]
    command, _ = env.commands(full)
    for i in range(len(env.agents)):
        scale = min(1.0, blocked[i] / 0.5)
        expected = np.clip(nominal[i, : k[i]] + scale * float(np.float32(0.5)) * env.config.max_joint_speed,
                           -env.config.max_joint_speed, env.config.max_joint_speed)
        np.testing.assert_allclose(command[0, i, : k[i]], expected, rtol=1e-9, atol=1e-12)
    assert any(b > 0 for b in blocked) and any(b == 0 for b in blocked)  # the filter held some arms only


@pytest.mark.parametrize("scenario", ["paper_pa_mixed_square", "random"])
def test_a_gain_multiplies_each_joints_term_of_the_law_before_the_speed_limit(scenario) -> None:
    env = parallel_env(scenario, action_mode="gain", safety_filter=False, gain_range=3.0)
    ref = ReferencePolicy(parallel_env(scenario))
    ref.env = env  # it reads the env's scenario (the team drawn at the reset), layout and speed limit
    obs, _ = env.reset(seed=2)
    rng = np.random.default_rng(0)
    for _ in range(3):
        actions = {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}
        command, effort = env.commands(actions)
        for i, agent in enumerate(env.agents):
            k = env.n_actuated[i]
            expected = ref.act(agent, obs[agent], 3.0 ** actions[agent].astype(float))  # from observations
            np.testing.assert_allclose(command[0, i, :k] / env.config.max_joint_speed, expected, rtol=1e-4, atol=1e-5)
            assert effort[i] == pytest.approx(np.mean(actions[agent].astype(float) ** 2), rel=1e-6)
        obs, *_ = env.step(actions)
    # a gain of g on every joint is the law with K_P·g
    fast = ReferencePolicy(parallel_env(scenario), kp=env.scenario.kp * 3.0)
    fast.env = env
    full = {a: np.ones(env.action_space(a).shape, np.float32) for a in env.agents}
    command, _ = env.commands(full)
    for i, agent in enumerate(env.agents):
        np.testing.assert_allclose(command[0, i, : env.n_actuated[i]] / env.config.max_joint_speed,
                                   fast.act(agent, obs[agent]), rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("value", [1.0, 0.5, -2.0, np.nan, "wide"])
def test_a_gain_range_that_is_not_above_one_is_a_clear_error(value) -> None:
    with pytest.raises(ValueError, match="gain_range"):
        parallel_env("paper_pa3_square", action_mode="gain", gain_range=value)


@pytest.mark.parametrize("mode", ["velocity", "torque", "gain"])
@pytest.mark.parametrize("gate", ["residual_gate", "blocked_gate"])
def test_the_residual_gates_are_refused_in_other_action_modes(mode, gate) -> None:
    with pytest.raises(ValueError, match=f"need action_mode='residual', got action_mode='{mode}'"):
        parallel_env("paper_pa3_square", action_mode=mode, **{gate: 0.1})


def test_reference_policy_gains_must_be_one_positive_number_per_actuated_joint() -> None:
    env = parallel_env("paper_pa3_square")
    obs, _ = env.reset(seed=0)
    agent, k = env.agents[0], env.n_actuated[0]
    with pytest.raises(ValueError, match="positive numbers"):
        ReferencePolicy(env).act(agent, obs[agent], np.full(k + 1, 2.0))
    with pytest.raises(ValueError, match="positive numbers"):
        ReferencePolicy(env).act(agent, obs[agent], np.r_[np.ones(k - 1), -1.0])


@pytest.mark.parametrize("name, value", [("residual_gate", -0.1), ("blocked_gate", -1.0), ("blocked_gate", np.nan),
                                         ("success_bonus", np.inf), ("intervention_penalty", np.nan),
                                         ("intervention_penalty", "high")])
def test_bad_shaping_and_gate_arguments_are_clear_errors(name, value) -> None:
    with pytest.raises(ValueError, match=name):
        parallel_env("paper_pa3_square", action_mode="residual", **{name: value})
