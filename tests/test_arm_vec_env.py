"""SB3ArmVecEnv: one SB3 env per arm of the batched engine (parameter sharing), checked against SuperSuit's
padding of the PettingZoo env and against the team vector env it reshapes."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
ss = pytest.importorskip("supersuit")

from pan1_env.baselines.arm_vec_env import SB3ArmVecEnv  # noqa: E402
from pan1_env.environment import parallel_env  # noqa: E402
from pan1_env.vector import Pan1VectorEnv  # noqa: E402
from pan1_env.wrappers import SafetyShield  # noqa: E402

CASES = [("paper_pa_mixed_square", {}), ("random", {"random_options": {"links": (2, 3, 4, 3)}})]


@pytest.mark.parametrize(("scenario", "kwargs"), CASES)
def test_each_arm_sees_what_supersuit_padding_gives_the_parallel_env(scenario, kwargs) -> None:
    """Copy 0 of the per-arm view against SuperSuit's pad_observations_v0 and pad_action_space_v0 over the
    shielded parallel env, step for step with the same padded actions, through an episode's end."""
    arms = SB3ArmVecEnv(scenario, 2, safety_filter=True, max_steps=6, **kwargs)
    twin = ss.pad_action_space_v0(ss.pad_observations_v0(SafetyShield(parallel_env(scenario, max_steps=6, **kwargs))))
    agents, N = twin.possible_agents, len(twin.possible_agents)
    assert arms.num_envs == 2 * N
    assert arms.observation_space == twin.observation_space(agents[0])
    assert arms.action_space.shape == twin.action_space(agents[0]).shape
    arms.venv.core.seed([5, None])  # copy 0: the one-copy env's generator of seed 5 (an int seed would spawn)
    obs = arms.reset()
    twin_obs, _ = twin.reset(seed=5)
    rng = np.random.default_rng(0)
    for t in range(8):  # the episode ends at step 6 and the next one starts (copy 0 re-seeded from its stream)
        np.testing.assert_array_equal(obs[:N], np.stack([twin_obs[a] for a in agents]))
        actions = rng.uniform(-1, 1, (arms.num_envs, arms.action_space.shape[0])).astype(np.float32)
        arms.step_async(actions)
        obs, rewards, dones, infos = arms.step_wait()
        twin_obs, twin_rewards, term, trunc, twin_infos = twin.step(dict(zip(agents, actions[:N], strict=True)))
        np.testing.assert_allclose(rewards[:N], [twin_rewards[a] for a in agents], rtol=1e-6)
        assert list(dones[:N]) == [term[a] or trunc[a] for a in agents]
        for i, a in enumerate(agents):
            assert infos[i]["cost"] == twin_infos[a]["cost"]
            assert infos[i]["shield_intervened"] == twin_infos[a]["shield_intervened"]
        if dones[0]:
            assert t == 5 and all(info["TimeLimit.truncated"] for info in infos[:N])
            np.testing.assert_array_equal(np.stack([info["terminal_observation"] for info in infos[:N]]),
                                          np.stack([twin_obs[a] for a in agents]))
            twin_obs, _ = twin.reset()


def test_the_view_reshapes_the_team_vector_env_and_converts_its_rows_both_ways() -> None:
    """The same copies as Pan1VectorEnv (seeded alike): its flat observations are the arm rows, and
    the arm actions, turned into team actions, step it to the same observations and rewards."""
    kwargs = {"random_options": {"links": (2, 3, 4, 3)}, "action_mode": "gain"}
    arms = SB3ArmVecEnv("random", 3, **kwargs, control_dt=0.1)
    team = Pan1VectorEnv("random", 3, **kwargs, control_dt=0.1)
    assert arms.dt == arms.config.control_dt == team.dt == 0.1  # every view says its step
    N, rng = 4, np.random.default_rng(1)
    arms.seed(11)
    obs = arms.reset()
    flat, _ = team.reset(seed=11)
    for _ in range(4):
        np.testing.assert_array_equal(arms.arm_observations(flat), obs)
        actions = rng.uniform(-1, 1, (arms.num_envs, arms.action_space.shape[0])).astype(np.float32)
        arms.step_async(actions)
        obs, rewards, _, _ = arms.step_wait()
        flat, team_rewards, *_ = team.step(arms.team_actions(actions))
        np.testing.assert_allclose(rewards.reshape(3, N).mean(axis=1), team_rewards, rtol=1e-6)


def test_bad_actions_are_refused_at_the_boundary() -> None:
    arms = SB3ArmVecEnv("paper_pa3_square", 1)
    arms.reset()
    arms.step_async(np.zeros((arms.num_envs, arms.action_space.shape[0] + 1), np.float32))
    with pytest.raises(ValueError, match="shape"):
        arms.step_wait()
    arms.step_async(np.full((arms.num_envs, arms.action_space.shape[0]), np.nan, np.float32))
    with pytest.raises(ValueError, match="NaN"):
        arms.step_wait()
