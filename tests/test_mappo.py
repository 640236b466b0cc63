"""MAPPO: the per-arm view with the global state for the critic, checked against the parallel env's own state,
the policy whose actor cannot see that state, and a trained model acting per agent on the parallel env."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402

from pan1_env.baselines.arm_vec_env import SB3ArmVecEnv  # noqa: E402
from pan1_env.baselines.mappo import ActorOnly, LocalActorPolicy  # noqa: E402
from pan1_env.cli import main  # noqa: E402
from pan1_env.environment import parallel_env  # noqa: E402

MIXED = {"random_options": {"links": (2, 3, 4, 3)}}


def test_each_row_is_the_arm_observation_then_its_copy_global_state_through_an_episode_end() -> None:
    """Copy 1 of the critic view against the parallel env seeded as copy 1 (a list of seeds), stepped with its arms'
    actions: the rows' first entries are the plain view's, the rest the parallel env's ``state()``, and at the
    episode's end the terminal rows carry the last step's state, not the next episode's."""
    arms = SB3ArmVecEnv("random", 2, critic_state=True, max_steps=4, safety_filter=True, **MIXED)
    plain = SB3ArmVecEnv("random", 2, max_steps=4, safety_filter=True, **MIXED)
    twin = parallel_env("random", max_steps=4, safety_filter=True, **MIXED)
    agents, N, local = twin.possible_agents, len(twin.possible_agents), plain.observation_space.shape[0]
    assert arms.local_size == local and arms.observation_space.shape == (local + twin.state_space.shape[0],)
    arms.venv.core.seed([7, 8])  # copy b: the one-copy env's team of seed 7 + b
    plain.venv.core.seed([7, 8])
    obs, plain_obs = arms.reset(), plain.reset()
    twin.reset(seed=8)
    rng = np.random.default_rng(2)
    for t in range(6):
        np.testing.assert_array_equal(obs[:, :local], plain_obs)
        np.testing.assert_array_equal(obs[N:2 * N, local:], np.broadcast_to(twin.state(), (N, obs.shape[1] - local)))
        actions = rng.uniform(-1, 1, (arms.num_envs, arms.action_space.shape[0])).astype(np.float32)
        for view in (arms, plain):
            view.step_async(actions)
        (obs, _, dones, infos), (plain_obs, *_) = arms.step_wait(), plain.step_wait()
        twin.step({a: actions[N + i, : twin.action_space(a).shape[0]] for i, a in enumerate(agents)})
        if dones[N]:
            assert t == 3
            terminal = np.stack([info["terminal_observation"] for info in infos[N:2 * N]])
            np.testing.assert_array_equal(terminal[:, local:], np.broadcast_to(twin.state(), terminal[:, local:].shape))
            twin.reset()


def _mappo(venv, seed: int = 0) -> PPO:
    return PPO(LocalActorPolicy, venv, n_steps=8, batch_size=16, seed=seed, device="cpu",
               policy_kwargs={"actor_inputs": venv.local_size})


def test_the_actor_reads_only_the_arm_observation_and_the_critic_reads_the_state() -> None:
    venv = SB3ArmVecEnv("paper_pa3_square", 2, critic_state=True)
    model = _mappo(venv)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(6, venv.observation_space.shape[0])).astype(np.float32)
    other = obs.copy()
    other[:, venv.local_size:] = rng.normal(size=(6, venv.observation_space.shape[0] - venv.local_size))
    with torch.no_grad():
        a, b = (model.policy.get_distribution(model.policy.obs_to_tensor(x)[0]).distribution for x in (obs, other))
        values = [model.policy.predict_values(model.policy.obs_to_tensor(x)[0]) for x in (obs, other)]
    assert torch.equal(a.mean, b.mean) and torch.equal(a.stddev, b.stddev)
    assert not torch.allclose(values[0], values[1])
    # at execution the model is its actor, on the arm's own entries
    actor = ActorOnly(model)
    assert actor.observation_space.shape == (venv.local_size,)
    acted = actor.predict(obs[:, : venv.local_size])[0]
    np.testing.assert_array_equal(acted, model.predict(other, deterministic=True)[0])


def test_actor_inputs_larger_than_the_observation_are_refused() -> None:
    venv = SB3ArmVecEnv("paper_pa3_square", 1, critic_state=True)
    with pytest.raises(ValueError, match="actor_inputs"):
        PPO(LocalActorPolicy, venv, policy_kwargs={"actor_inputs": venv.observation_space.shape[0] + 1})


def test_a_trained_mappo_model_acts_per_agent_on_the_parallel_env_as_on_the_team_vector_env(tmp_path) -> None:
    from rollouts import model_acts_alike_on_both_views

    out = tmp_path / "mappo"
    assert main(["train", "--scenario", "random", "--param-sharing", "--centralised-critic", "--timesteps", "512",
                 "--n-envs", "2", "--max-steps", "32", "--action-mode", "gain", "--eval-every", "256",
                 "--checkpoint-every", "512", "--env-kwargs", json.dumps(MIXED), "--out", str(out),
                 "--no-progress"]) == 0
    meta = json.loads((out / "model.json").read_text())
    run = json.loads((out / "run.json").read_text())
    assert meta["centralised_critic"] and run["centralised_critic"]
    local = SB3ArmVecEnv("random", 1, **MIXED).observation_space.shape[0]
    assert len(meta["observation_normalization"]["mean"]) == local  # the actor's input, not the critic's
    assert all(float(row["cost"]) == 0.0 for row in _rows(out / "eval.csv"))  # evaluated during training, shielded
    by_agent = model_acts_alike_on_both_views(out / "model.zip", "random")
    # what the trained network does on its training rows (own observation, then the real global state, both
    # standardised with the run's full VecNormalize statistics) is what each agent does at execution
    with (out / "checkpoints" / "state_512_steps.pkl").open("rb") as fh:
        stats = pickle.load(fh)["normalize"]["obs_rms"]
    view = SB3ArmVecEnv("random", 1, critic_state=True, **meta["env_kwargs"])
    view.venv.core.seed([3])  # the one-copy env's team of seed 3
    rows = np.clip((view.reset() - stats.mean) / np.sqrt(stats.var + 1e-8), -10.0, 10.0).astype(np.float32)
    trained = PPO.load(out / "model.zip", device="cpu")
    assert isinstance(trained.policy, LocalActorPolicy)
    actions = trained.predict(rows, deterministic=True)[0]
    for i, agent in enumerate(by_agent):  # in agent order
        np.testing.assert_allclose(by_agent[agent], actions[i, : by_agent[agent].size], atol=1e-6)


def _rows(path):
    import csv

    with path.open() as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("extra", [[], ["--algo", "sac", "--param-sharing"]])
def test_a_centralised_critic_without_parameter_sharing_or_with_sac_exits_2_with_one_line(tmp_path, capsys,
                                                                                        extra) -> None:
    out = tmp_path / "run"
    assert main(["train", "--scenario", "paper_pa3_square", "--centralised-critic", *extra, "--out", str(out),
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pan1-env: error: ") and err.count("\n") == 1 and "centralised_critic" in err
    assert not out.exists()


def test_mappo_lagrangian_trains_and_a_mappo_run_resumes_only_as_mappo(tmp_path, capsys) -> None:
    """ppo-lagrangian with the centralised critic (MAPPO-Lagrangian, unshielded) trains and logs its
    multiplier; resuming a MAPPO run without --centralised-critic exits 2 with one line naming the flag."""
    from pan1_env.baselines.sb3 import load_model

    out = tmp_path / "lag"
    common = ["--scenario", "paper_pa3_square", "--param-sharing", "--timesteps", "256", "--n-envs", "2",
              "--max-steps", "16", "--checkpoint-every", "128", "--out", str(out), "--no-progress"]
    assert main(["train", "--algo", "ppo-lagrangian", "--no-shield", "--centralised-critic", *common]) == 0
    assert isinstance(load_model(out / "model.zip")[0], ActorOnly) and (out / "lagrangian.csv").is_file()
    capsys.readouterr()
    assert main(["train", "--algo", "ppo-lagrangian", "--no-shield", *common, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--centralised-critic" in err and "resume it with the same" in err
