"""The Gymnasium ids (pan1_env.registration): what each id builds, its episode length, and
env_arguments, which turns an id or a scenario into the parallel env's arguments."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import pan1_env
from pan1_env.centralized import CentralizedEnv
from pan1_env.environment import parallel_env
from pan1_env.registration import ENV_IDS, REACH_ENV_ID, env_arguments, register_envs


def test_every_id_is_registered_once_registration_is_repeated() -> None:
    register_envs()  # idempotent: importing pan1_env already registered them
    for env_id in [*ENV_IDS, REACH_ENV_ID]:
        assert env_id in gymnasium.registry
    assert set(ENV_IDS) == set(pan1_env.ENV_IDS)


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_each_team_id_is_the_centralised_view_of_its_scenario(env_id: str) -> None:
    env = gymnasium.make(env_id)
    core = env.unwrapped
    assert isinstance(core, CentralizedEnv)
    assert env.spec.max_episode_steps is None and core.config.max_steps == twin_max_steps(env_id)
    scenario, kwargs = env_arguments(env_id)
    twin = parallel_env(scenario, **kwargs)
    agents = twin.possible_agents
    assert env.observation_space.shape == (sum(twin.observation_space(a).shape[0] for a in agents),)
    assert env.action_space.shape == (sum(twin.action_space(a).shape[0] for a in agents),)
    obs, info = env.reset(seed=3)
    twin_obs, _ = twin.reset(seed=3)
    np.testing.assert_allclose(obs, np.concatenate([twin_obs[a] for a in agents]), rtol=0, atol=1e-6)
    assert info["cost"] == 0.0 and info["formation_error"] > 0.0


def test_the_flat_action_is_split_in_agent_order() -> None:
    env = gymnasium.make("pan1_env/PaperMixedPA-v0").unwrapped
    sizes = [env.parallel.action_space(a).shape[0] for a in env.parallel.possible_agents]
    flat = np.arange(sum(sizes), dtype=float)
    parts = env.agent_actions(flat)
    assert list(parts) == list(env.parallel.possible_agents)
    assert [p.size for p in parts.values()] == sizes
    np.testing.assert_array_equal(np.concatenate(list(parts.values())), flat)


def test_the_gymnasium_step_sums_the_arms_costs_and_averages_their_rewards() -> None:
    env = gymnasium.make("pan1_env/PaperPA3Square-v0")
    twin = parallel_env("paper_pa3_square")
    env.reset(seed=0)
    twin.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        _, reward, _, _, info = env.step(action)
        _, rewards, _, _, per_arm = twin.step(env.unwrapped.agent_actions(action))
        assert info["cost"] == sum(i["cost"] for i in per_arm.values())
        assert info["min_clearance"] == min(i["min_clearance"] for i in per_arm.values())
        assert reward == pytest.approx(np.mean(list(rewards.values())), rel=1e-12)
    assert np.isfinite(reward)


def twin_max_steps(env_id: str) -> int:
    """The episode length an id's parallel env takes: the scenario's horizon over control_dt."""
    scenario, kwargs = env_arguments(env_id)
    return parallel_env(scenario, **kwargs).config.max_steps


def test_env_arguments_of_a_scenario_and_of_an_id() -> None:
    assert env_arguments("paper_pa_mixed_square") == ("paper_pa_mixed_square", {})
    assert env_arguments("random", {"max_steps": 7}) == ("random", {"max_steps": 7})
    for prefix in ("", "pan1_env:"):
        assert env_arguments(prefix + "pan1_env/PaperPA3Square-v0") == ("paper_pa3_square", {})
        scenario, kwargs = env_arguments(prefix + "pan1_env/WholeArmStaticFormation-v0", {"max_steps": 9})
        assert scenario == "random" and kwargs["max_steps"] == 9
        assert kwargs["random_options"] == ENV_IDS["pan1_env/WholeArmStaticFormation-v0"]["random_options"]


def test_env_arguments_merges_random_options_and_copies_the_registered_ones() -> None:
    registered = dict(ENV_IDS["pan1_env/WholeArmFormation-v0"]["random_options"])
    _, kwargs = env_arguments("pan1_env/WholeArmFormation-v0", {"random_options": {"n_obstacles": 1}})
    assert kwargs["random_options"] == registered | {"n_obstacles": 1}
    kwargs["random_options"]["inter_arm"] = False
    assert ENV_IDS["pan1_env/WholeArmFormation-v0"]["random_options"] == registered
    # on a scenario without registered options, the given ones pass through as they are
    assert env_arguments("random", {"random_options": {"n_arms": 3}}) == ("random", {"random_options": {"n_arms": 3}})


def test_gymnasium_make_passes_arguments_to_the_env() -> None:
    env = gymnasium.make("pan1_env/RandomFormation-v0", random_options={"n_arms": 3, "links": 2}, max_steps=11)
    env.reset(seed=1)
    parallel = env.unwrapped.parallel
    assert parallel.config.max_steps == 11
    assert len(parallel.possible_agents) == 3
    assert [arm.n_links for arm in parallel.scenario.arms] == [2, 2, 2]
    assert env.action_space.shape == (sum(parallel.action_space(a).shape[0] for a in parallel.possible_agents),)
