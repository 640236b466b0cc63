"""Saved SB3 models as policies (pan1_env.baselines.sb3, pretrained): centralised and per-arm models, the
env forms pretrained() takes, the refusal of a model for another task, and the missing-extra message."""

from __future__ import annotations

import json
import sys

import gymnasium
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from stable_baselines3 import PPO  # noqa: E402

from pan1_env.baselines import pretrained  # noqa: E402
from pan1_env.baselines.sb3 import load_model, sb3_policy  # noqa: E402
from pan1_env.environment import parallel_env  # noqa: E402


class _Spaces(gymnasium.Env):
    """Only the spaces, to build an untrained model on them."""

    def __init__(self, n_obs: int, n_act: int) -> None:
        self.observation_space = gymnasium.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (n_act,), np.float32)


def _per_arm_model(tmp_path, env, norm: bool):
    agents = env.possible_agents
    obs_max = max(env.observation_space(a).shape[0] for a in agents)
    k_max = max(env.action_space(a).shape[0] for a in agents)
    model = PPO("MlpPolicy", _Spaces(obs_max, k_max), seed=0, device="cpu")
    path = tmp_path / "model.zip"
    model.save(path)
    meta = {"scenario": "random", "param_sharing": True, "env_kwargs": {}}
    if norm:
        rng = np.random.default_rng(0)
        meta["observation_normalization"] = {"mean": rng.normal(size=obs_max).tolist(),
                                             "var": rng.uniform(0.5, 2, obs_max).tolist(), "epsilon": 1e-8,
                                             "clip": 10.0}
    path.with_suffix(".json").write_text(json.dumps(meta))
    return path, meta


@pytest.mark.parametrize("norm", [False, True])
def test_a_per_arm_model_acts_for_each_arm_on_its_padded_observation(tmp_path, norm) -> None:
    env = parallel_env("random", random_options={"links": (2, 3, 4, 3)})
    path, meta = _per_arm_model(tmp_path, env, norm)
    policy = sb3_policy(path, env)
    model, _ = load_model(path)
    obs, _ = env.reset(seed=4)
    actions = policy(obs)
    obs_max = model.observation_space.shape[0]
    for agent in env.possible_agents:
        padded = np.zeros(obs_max, np.float32)
        padded[: obs[agent].size] = obs[agent]
        if norm:
            stats = meta["observation_normalization"]
            padded = np.clip((padded - np.asarray(stats["mean"])) / np.sqrt(np.asarray(stats["var"]) + 1e-8), -10, 10)
        expected, _ = model.predict(padded.astype(np.float32), deterministic=True)
        k = env.action_space(agent).shape[0]
        assert actions[agent].shape == (k,)
        np.testing.assert_allclose(actions[agent], expected[:k], rtol=1e-5, atol=1e-6)


def test_a_model_of_other_spaces_is_refused_naming_both_shapes(tmp_path) -> None:
    env = parallel_env("paper_pa3_square")
    PPO("MlpPolicy", _Spaces(7, 2), seed=0, device="cpu").save(tmp_path / "m.zip")
    with pytest.raises(ValueError, match=r"trained on spaces \(7,\) → \(2,\).*per arm \(padded\)"):
        sb3_policy(tmp_path / "m.zip", env)


def test_pretrained_takes_the_gymnasium_env_the_parallel_env_and_the_id() -> None:
    env_id = "pan1_env/PaperPA3Square-v0"
    gym = gymnasium.make(f"pan1_env:{env_id}")
    flat_policy = pretrained("paper_pa3_square", gym)
    obs, _ = gym.reset(seed=0)
    par = parallel_env(env_id)
    par_obs, _ = par.reset(seed=0)
    by_agent = pretrained("paper_pa3_square", par)(par_obs)
    action = flat_policy(obs)
    assert action.shape == gym.action_space.shape
    np.testing.assert_allclose(action, np.concatenate([by_agent[a] for a in par.possible_agents]), atol=1e-6)
    from_id = pretrained("paper_pa3_square", env_id)(par_obs)
    np.testing.assert_allclose(np.concatenate(list(from_id.values())), action, atol=1e-6)
    gym.step(action)


def test_pretrained_refuses_a_model_for_another_task_naming_its_task() -> None:
    with pytest.raises(ValueError, match="trained for pan1_env/WholeArmStaticFormation-v0"):
        pretrained("whole_arm_formation", parallel_env("random"))
    with pytest.raises(TypeError, match="needs a pan1_env team env"):
        pretrained("whole_arm_formation", object())


def test_without_the_rl_extra_the_message_says_what_to_install(monkeypatch, tmp_path) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch raises ImportError
    with pytest.raises(ImportError, match=r"rl extra: pip install torch --index-url .*/whl/cpu"):
        load_model(tmp_path / "model.zip")
