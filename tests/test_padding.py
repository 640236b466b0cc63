"""PadToLargestArm: one set of spaces for a mixed team's arms, the arms' own entries unchanged."""

import numpy as np
from pettingzoo.test import parallel_api_test

from pan1_env.environment import parallel_env
from pan1_env.wrappers import PadToLargestArm, SafetyShield


def test_padded_env_passes_pettingzoo_api_test() -> None:
    parallel_api_test(PadToLargestArm(SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=30))),
                      num_cycles=30)


def test_each_arm_applies_its_own_entries_and_sees_its_observation_first() -> None:
    base = parallel_env("paper_pa_mixed_square", max_steps=10)
    env = PadToLargestArm(SafetyShield(base))
    twin = SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=10))
    sizes = {a: base.action_space(a).shape[0] for a in base.possible_agents}
    assert len(set(sizes.values())) > 1  # a mixed team, else this test shows nothing
    k = max(sizes.values())
    assert all(env.action_space(a).shape == (k,) for a in env.possible_agents)
    assert env.action_spaces == {a: env.action_space(a) for a in env.possible_agents}
    assert env.observation_spaces == {a: env.observation_space(a) for a in env.possible_agents}
    obs, _ = env.reset(seed=2)
    twin_obs, _ = twin.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(5):
        for a in env.possible_agents:
            n = len(twin_obs[a])
            np.testing.assert_array_equal(obs[a][:n], twin_obs[a])
            assert (obs[a][n:] == 0).all() and env.observation_space(a).contains(obs[a])
        actions = {a: rng.uniform(-1, 1, k).astype(np.float32) for a in env.possible_agents}
        obs, rewards, _, _, infos = env.step(actions)
        twin_obs, twin_rewards, _, _, twin_infos = twin.step({a: u[: sizes[a]] for a, u in actions.items()})
        assert rewards == twin_rewards
        for a in env.possible_agents:
            applied = infos[a]["shield_applied"]
            assert applied.shape == (k,) and (applied[sizes[a]:] == 0).all()
            np.testing.assert_array_equal(applied[: sizes[a]], twin_infos[a]["shield_applied"])
