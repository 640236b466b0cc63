"""Numerical faults inside a step (huge torques or speeds, a state that leaves the floats) are reported
in the infos and truncate the episode; they are not raised, and a reset recovers."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest

import pan1_env  # noqa: F401  (registers the Gymnasium ids)
from pan1_env.environment import parallel_env
from pan1_env.wrappers import SafetyShield


def _full_actions(env, rng: np.random.Generator):
    return {a: rng.choice([-1.0, 1.0], env.action_space(a).shape).astype(np.float32) for a in env.agents}


def _nearest_clearance(env, agent: str, obs: np.ndarray) -> float:
    """Clearance of the agent's end-effector to its nearest obstacle, from the documented observation."""
    core = env.unwrapped
    n = core.scenario.arms[core.possible_agents.index(agent)].n_links
    k = core.config.n_obstacle_obs
    slot = obs.size - 5 * k  # the first (nearest) obstacle slot: present, dx, dy, r, h
    present, dx, dy, r = obs[slot : slot + 4].astype(float)
    assert slot >= 3 * n + 2 and present == 1.0
    return math.hypot(dx, dy) - r


_EXTREME_ENVS = {
    "torque_1e6": lambda: parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e6),
    "velocity_1e6": lambda: parallel_env("paper_pa3_square", max_joint_speed=1e6),
    "shielded_torque_1e6": lambda: SafetyShield(parallel_env("paper_pa3_square", action_mode="torque",
                                                             max_torque=1e6)),
}


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("name", sorted(_EXTREME_ENVS))
def test_extreme_actions_are_reported_not_raised(name: str) -> None:
    env = _EXTREME_ENVS[name]()
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    start = {a: o.copy() for a, o in obs.items()}
    for _ in range(200):
        obs, rewards, terms, truncs, infos = env.step(_full_actions(env, rng))
        assert set(obs) == set(rewards) == set(infos) == set(env.possible_agents)
        for agent in obs:
            assert np.all(np.isfinite(obs[agent])), (agent, obs[agent])
            assert env.observation_space(agent).contains(obs[agent])
            assert np.isfinite(rewards[agent])
            assert np.isfinite(infos[agent]["formation_error"]) and not np.isnan(infos[agent]["min_clearance"])
        assert np.all(np.isfinite(env.unwrapped.state()))
        q, qd = env.unwrapped.joint_state()
        assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd)), "the state must stay finite (or be reported)"
        faults = [infos[a].get("fault") for a in env.possible_agents]
        if any(f is not None for f in faults):
            assert all(isinstance(f, str) and f for f in faults)
            assert all(truncs.values()) and not any(terms.values())
            assert env.agents == []
            with pytest.raises(RuntimeError, match="reset"):
                env.step(_full_actions(env, rng))
        else:
            core = env.unwrapped
            assert core.num_steps >= core.config.max_steps or not any(truncs.values()), "truncated without a reason"
            for agent in obs:  # the step's minimum covers its last sub-step
                assert infos[agent]["min_clearance"] <= _nearest_clearance(env, agent, obs[agent]) + 1e-4
        if not env.agents:
            obs, _ = env.reset(seed=0)
            for agent in obs:  # a reset recovers the starting state, fault or not
                np.testing.assert_array_equal(obs[agent], start[agent])


def _blow_up(env):
    """Step the paper PA3 team with 1e300 N·m: the state cannot stay finite."""
    env.reset(seed=0)
    return env.step({a: np.ones(env.action_space(a).shape, np.float32) for a in env.agents})


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_non_finite_state_truncates_with_a_fault_and_reset_recovers() -> None:
    env = parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e300)
    fresh, _ = parallel_env("paper_pa3_square").reset(seed=0)
    obs, rewards, terms, truncs, infos = _blow_up(env)
    assert all(truncs.values()) and not any(terms.values()) and env.agents == []
    assert all("non-finite" in infos[a]["fault"] for a in env.possible_agents)
    assert all(np.all(np.isfinite(o)) for o in obs.values())
    assert all(np.isfinite(r) for r in rewards.values())
    q, qd = env.joint_state()
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(qd))
    obs, _ = env.reset(seed=0)
    for agent in obs:
        np.testing.assert_array_equal(obs[agent], fresh[agent])


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_gym_view_reports_the_fault() -> None:
    env = gymnasium.make("pan1_env/PaperPA3Square-v0", action_mode="torque", max_torque=1e300)
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(np.ones(env.action_space.shape, np.float32))
    assert truncated and not terminated
    assert "non-finite" in info["fault"]
    assert np.all(np.isfinite(obs)) and np.isfinite(reward)


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_fault_step_reports_a_finite_min_clearance() -> None:
    env = parallel_env("paper_pa3_square", action_mode="torque", max_torque=1e300)
    obs, _, _, _, infos = _blow_up(env)
    for agent in env.possible_agents:
        assert "fault" in infos[agent]
        assert infos[agent]["min_clearance"] <= _nearest_clearance(env, agent, obs[agent]) + 1e-4
