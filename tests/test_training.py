"""Stable-Baselines3 training and the policy benchmark, end to end on small settings."""

import csv
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from pan1_env.baselines.benchmark import markdown_table, run_benchmark  # noqa: E402
from pan1_env.baselines.training import latest_checkpoint, train  # noqa: E402
from pan1_env.cli import main  # noqa: E402


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_short_shielded_ppo_run_trains_with_zero_cost(tmp_path) -> None:
    out = tmp_path / "ppo"
    summary = train("ppo", "paper_pa_mixed_square", shield=True, timesteps=2048, seed=0, out=out,
                    checkpoint_every=1024, progress=False, n_envs=1, env_kwargs={"max_steps": 128},
                    algo_kwargs={"n_steps": 1024, "batch_size": 256})
    rows = _rows(out / "episodes.csv")
    assert len(rows) == 2048 // 128
    assert all(float(r["cost"]) == 0.0 for r in rows)
    assert summary["total_cost"] == 0.0
    assert (out / "model.zip").exists()
    assert latest_checkpoint(out)[1] == 2048
    # resume: continues from the newest checkpoint up to the new total
    summary = train("ppo", "paper_pa_mixed_square", shield=True, timesteps=3072, seed=0, out=out, resume=True,
                    checkpoint_every=1024, progress=False, n_envs=1, env_kwargs={"max_steps": 128},
                    algo_kwargs={"n_steps": 1024, "batch_size": 256})
    assert summary["resumed_from"] == 2048
    rows = _rows(out / "episodes.csv")
    assert len(rows) == 3072 // 128 and int(rows[-1]["timesteps"]) == 3072


def _policy_params(path):
    from stable_baselines3 import PPO

    return PPO.load(path, device="cpu").policy.state_dict()


@pytest.mark.parametrize(("param_sharing", "centralised_critic"), [(False, False), (True, False), (True, True)],
                         ids=["centralised", "ippo", "mappo"])
def test_interrupted_run_resumes_to_the_same_result(tmp_path, param_sharing, centralised_critic) -> None:
    from stable_baselines3.common.callbacks import BaseCallback

    # rollouts of 256 steps: 2 copies × 128, or with parameter sharing 2 copies × 4 arms × 32
    kwargs = dict(algo="ppo", scenario="random", shield=True, timesteps=4 * 256, seed=3, checkpoint_every=256,
                  progress=False, n_envs=2, env_kwargs={"max_steps": 100, "random_options": {"links": (2, 3, 4, 3)}},
                  algo_kwargs={"n_steps": 32 if param_sharing else 128, "batch_size": 64, "n_epochs": 2},
                  param_sharing=param_sharing, centralised_critic=centralised_critic)

    class Interrupt(BaseCallback):
        """Kills the run in the middle of its third rollout (after the 512-step checkpoint)."""

        def _on_step(self) -> bool:
            if self.num_timesteps >= 640:
                raise KeyboardInterrupt
            return True

    whole = tmp_path / "whole"
    train(out=whole, **kwargs)
    cut = tmp_path / "cut"
    with pytest.raises(KeyboardInterrupt):
        train(out=cut, extra_callbacks=[Interrupt()], **kwargs)
    assert latest_checkpoint(cut)[1] == 512
    summary = train(out=cut, resume=True, **kwargs)
    assert summary["resumed_from"] == 512
    a, b = _policy_params(whole / "model.zip"), _policy_params(cut / "model.zip")
    assert a.keys() == b.keys()
    if centralised_critic:  # resumed as MAPPO: its policy, its flag, the actor's normalisation
        from stable_baselines3 import PPO

        from pan1_env.baselines.mappo import LocalActorPolicy

        assert isinstance(PPO.load(cut / "model.zip", device="cpu").policy, LocalActorPolicy)
        meta = json.loads((cut / "model.json").read_text())
        assert meta["centralised_critic"] and json.loads((cut / "run.json").read_text())["centralised_critic"]
        actor_inputs = PPO.load(cut / "model.zip", device="cpu").policy.actor_inputs
        assert len(meta["observation_normalization"]["mean"]) == actor_inputs
    for key in a:
        assert np.array_equal(a[key].numpy(), b[key].numpy()), key
    assert _rows(whole / "episodes.csv") == _rows(cut / "episodes.csv")


def test_normalised_residual_model_runs_as_a_velocity_policy(tmp_path) -> None:
    from stable_baselines3 import PPO

    from pan1_env.baselines import ReferencePolicy, make_policy
    from pan1_env.baselines.evaluation import model_policy
    from pan1_env.environment import parallel_env

    train("ppo", "paper_pa3_square", shield=True, timesteps=256, seed=0, out=tmp_path, checkpoint_every=256,
          progress=False, n_envs=2, env_kwargs={"max_steps": 64, "action_mode": "residual", "residual_gate": 0.5},
          algo_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 1})
    meta = json.loads((tmp_path / "model.json").read_text())
    assert meta["env_kwargs"]["action_mode"] == "residual"
    norm = meta["observation_normalization"]
    assert np.all(np.asarray(norm["var"]) > 0) and np.any(np.asarray(norm["mean"]) != 0)  # statistics were kept
    assert (tmp_path / "checkpoints" / "model_256_steps.json").exists()
    env = parallel_env("paper_pa3_square", max_steps=64)  # velocity mode: the reference law is added
    policy = make_policy(f"sb3:{tmp_path / 'model.zip'}", env, 0)
    obs, _ = env.reset(seed=0)
    model = PPO.load(tmp_path / "model.zip", device="cpu")
    flat = np.concatenate([obs[a] for a in env.possible_agents])
    flat = np.clip((flat - norm["mean"]) / np.sqrt(np.asarray(norm["var"]) + norm["epsilon"]), -10, 10)
    residual, _ = model.predict(flat.astype(np.float32), deterministic=True)
    nominal = ReferencePolicy(env)(obs)
    actions = policy(obs)
    k, P, f = env.n_actuated[0], env.end_effectors(), env.scenario.formation
    for i, a in enumerate(env.possible_agents):
        errors = [abs(np.linalg.norm(P[u] - P[w]) - d) for (u, w), d in zip(f.edges, f.distances, strict=True)
                  if i in (u, w)]
        gate = min(1.0, (max(errors) / 0.5) ** 2)
        expected = np.clip(nominal[a] + gate * np.clip(residual[i * k:(i + 1) * k], -1, 1), -1, 1)
        np.testing.assert_allclose(actions[a], expected, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="residual"):
        make_policy(f"sb3:{tmp_path / 'model.zip'}", parallel_env("paper_pa3_square", action_mode="torque"), 0)
    # the same model for the batched evaluation: flat observations, the run's statistics, its env arguments
    batch_policy, env_kwargs = model_policy(tmp_path / "model.zip")
    assert env_kwargs == meta["env_kwargs"]
    np.testing.assert_allclose(batch_policy(np.stack([np.concatenate([obs[a] for a in env.possible_agents])] * 2)),
                               np.stack([residual] * 2), rtol=1e-5, atol=1e-6)


def test_critic_warmup_freezes_the_actor_until_its_end(tmp_path) -> None:
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback

    class Initial(BaseCallback):
        def _on_training_start(self) -> None:
            self.params = {k: v.clone().numpy() for k, v in self.model.policy.state_dict().items()}

        def _on_step(self) -> bool:
            return True

    kwargs = dict(shield=True, seed=0, checkpoint_every=1024, progress=False, n_envs=2,
                  env_kwargs={"max_steps": 32, "action_mode": "residual"},
                  algo_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 2})
    initial = Initial()
    train("ppo", "paper_pa3_square", timesteps=256, out=tmp_path / "warm", critic_warmup=10_000,
          extra_callbacks=[initial], **kwargs)
    train("ppo", "paper_pa3_square", timesteps=256, out=tmp_path / "none", **kwargs)
    warm = PPO.load(tmp_path / "warm" / "model.zip", device="cpu").policy.state_dict()
    none = PPO.load(tmp_path / "none" / "model.zip", device="cpu").policy.state_dict()
    actor = [k for k in warm if k == "log_std" or k.startswith(("mlp_extractor.policy_net", "action_net"))]
    critic = [k for k in warm if k.startswith(("mlp_extractor.value_net", "value_net"))]
    for k in actor:  # frozen through both updates
        assert np.array_equal(warm[k].numpy(), initial.params[k]), k
    assert any(not np.array_equal(none[k].numpy(), initial.params[k]) for k in actor)  # without warm-up it moves
    assert any(not np.array_equal(warm[k].numpy(), initial.params[k]) for k in critic)  # the critic learned
    with pytest.raises(ValueError, match="critic_warmup"):
        train("ppo", out=tmp_path / "bad", critic_warmup=-1)
    with pytest.raises(ValueError, match="critic_warmup"):
        train("sac", out=tmp_path / "bad", critic_warmup=100)


def test_unshielded_training_sees_cost(tmp_path) -> None:
    # SAC's first steps are uniform random actions: without the shield, 5.2's PA arm reaches the obstacle
    summary = train("sac", "paper_pa_mixed_square", shield=False, timesteps=600, seed=0, out=tmp_path,
                    checkpoint_every=300, progress=False, n_envs=1, env_kwargs={"max_steps": 300},
                    algo_kwargs={"learning_starts": 600})
    assert summary["n_episodes"] == 2
    assert (tmp_path / "checkpoints" / "model_replay_buffer_600_steps.pkl").exists()


def test_parameter_sharing_keeps_its_budget_and_logs_one_row_per_team_episode(tmp_path) -> None:
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # 2 copies × 4 arms = 8 SB3 envs; no n_steps given: the rollout is fitted to the budget (64 × 8)
        summary = train("ppo", "paper_pa3_square", shield=True, timesteps=512, seed=1, out=tmp_path,
                        param_sharing=True, n_envs=2, checkpoint_every=512, progress=False,
                        env_kwargs={"max_steps": 32}, eval_every=256)
    assert not [w for w in caught if "render_mode" in str(w.message)]
    # the shared model evaluated on the team env, each arm on its own observation: the shield keeps cost 0
    evaluations = _rows(tmp_path / "eval.csv")
    assert [int(r["timesteps"]) for r in evaluations] == [0] and float(evaluations[0]["cost"]) == 0.0
    # the model on the team vector env (flat rows cut into arms) acts as on the parallel env (per agent)
    from rollouts import model_acts_alike_on_both_views

    model_acts_alike_on_both_views(tmp_path / "model.zip", "paper_pa3_square")
    assert summary["timesteps"] == 512 and latest_checkpoint(tmp_path)[1] == 512
    rows = _rows(tmp_path / "episodes.csv")
    # 64 team steps per copy, episodes of 32: two per copy, one row each (not one per arm)
    assert len(rows) == 4 and summary["n_episodes"] == 4
    assert all(int(r["length"]) == 32 for r in rows) and summary["total_cost"] == 0.0


def test_the_budget_is_rounded_once_and_said_and_every_count_agrees(tmp_path, capsys) -> None:
    from stable_baselines3 import PPO

    # 4 copies × 64 steps = rollouts of 256: 1000 rounds to 1024, announced before training
    summary = train("ppo", "paper_pa_mixed_square", timesteps=1000, seed=0, out=tmp_path, n_envs=4,
                    checkpoint_every=10_000, progress=True, env_kwargs={"max_steps": 16})
    err = capsys.readouterr().err
    assert "--timesteps 1,000 rounded to 1,024" in err and "256" in err
    assert "no episode may end" not in err
    assert summary["timesteps"] == 1024
    assert json.loads((tmp_path / "run.json").read_text())["timesteps"] == 1024
    assert latest_checkpoint(tmp_path)[1] == 1024
    assert PPO.load(tmp_path / "model.zip", device="cpu").num_timesteps == 1024
    assert "1024/1024" in err  # the progress bar ends at the same count
    assert err.count("rounded to") == 1


def test_a_run_shorter_than_an_episode_says_so_and_plot_says_what_to_run(tmp_path, capsys) -> None:
    out = tmp_path / "short"
    # the paper scenario's episodes are 2000 steps: with 4 copies the first end after 8000 steps
    assert main(["train", "--scenario", "paper_pa_mixed_square", "--timesteps", "256", "--n-envs", "4",
                 "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "no episode may end in this run" in err and "8,000" in err
    assert "--max-steps 16" in err and "--n-envs" in err
    assert main(["plot", str(out), "--out", str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no finished episode" in err
    assert "pan1-env train --algo ppo --scenario paper_pa_mixed_square --shield --seed 0 --n-envs 4 " \
           f"--timesteps 8000 --out {out} --resume" in err
    assert not (tmp_path / "c.png").exists()


@pytest.mark.parametrize(("option", "text", "hint"), [
    ("--env-kwargs", '{"sucess_bonus": 1}', "did you mean 'success_bonus'?"),
    ("--env-kwargs", '{"success_bonus": "big"}', "success_bonus must be a number"),
    ("--algo-kwargs", '{"gama": 0.9}', "did you mean 'gamma'?"),
    ("--algo-kwargs", '{"batch_size": 1}', "batch_size"),
])
def test_a_typo_in_a_json_option_exits_2_with_one_line_and_creates_nothing(tmp_path, capsys, option, text,
                                                                           hint) -> None:
    out = tmp_path / "run"
    assert main(["train", "--scenario", "paper_pa_mixed_square", "--out", str(out), option, text,
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pan1-env: error: ") and err.count("\n") == 1 and hint in err, err
    assert not out.exists()


def test_bad_training_arguments() -> None:
    with pytest.raises(ValueError, match="algo"):
        train("dqn", out="unused")
    with pytest.raises(ValueError, match="timesteps"):
        train("ppo", timesteps=0, out="unused")


def test_benchmark_end_to_end(tmp_path, capsys) -> None:
    code = main(["benchmark", "--scenarios", "paper_pa_mixed_square", "--policies", "reference,zero,random",
                 "--episodes", "2", "--max-steps", "60", "--out", str(tmp_path)])
    assert code == 0
    rows = json.loads((tmp_path / "benchmark.json").read_text())
    assert len(rows) == 3 * 2
    by = {(r["policy"], r["shield"]): r for r in rows}
    assert all(r["total_cost"] == 0.0 for r in rows if r["shield"])
    assert by[("reference", False)]["total_cost"] > 0  # 5.2: the nominal law drives arm 4 in
    assert by[("zero", True)]["intervention_rate"] == 0.0
    assert (tmp_path / "benchmark.png").read_bytes()[:4] == b"\x89PNG"
    assert "| reference | on |" in (tmp_path / "benchmark.md").read_text()


def test_benchmark_rejects_unknown_policy_and_mismatched_model(tmp_path) -> None:
    with pytest.raises(ValueError, match="unknown policy"):
        run_benchmark(["paper_pa3_square"], ["greedy"], episodes=1)
    train("ppo", "paper_pa_mixed_square", timesteps=64, out=tmp_path, progress=False, checkpoint_every=64,
          env_kwargs={"max_steps": 32}, algo_kwargs={"n_steps": 64, "batch_size": 64})
    with pytest.raises(ValueError, match="trained on spaces"):
        run_benchmark(["paper_pa3_square"], [f"sb3:{tmp_path / 'model.zip'}"], episodes=1, max_steps=5)
    rows = run_benchmark(["paper_pa_mixed_square"], [f"sb3:{tmp_path / 'model.zip'}"], episodes=1, max_steps=5)
    assert np.isfinite(rows[0]["mean_return"]) and "sb3:" in markdown_table(rows)


def test_pretrained_models_are_found_by_scenario(tmp_path, monkeypatch) -> None:
    import shlex

    from pan1_env.baselines import make_policy, shipped
    from pan1_env.cli import _parser
    from pan1_env.environment import parallel_env

    train("ppo", "paper_pa3_square", shield=True, timesteps=128, seed=3, out=tmp_path / "run", checkpoint_every=128,
          progress=False, n_envs=2, env_kwargs={"max_steps": 32, "success_bonus": 0.5},
          algo_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 1})
    models = tmp_path / "pretrained"
    monkeypatch.setattr(shipped, "PRETRAINED_DIR", models)
    shipped.package_model(tmp_path / "run", "square", evaluation={"success_1cm": 1.0})
    assert list(shipped.available()) == ["square"]
    provenance = shipped.available()["square"]["provenance"]
    args = _parser().parse_args(shlex.split(provenance["command"])[1:])  # the command reproduces the run
    assert (args.algo, args.scenario, args.shield, args.timesteps, args.seed, args.n_envs) == \
        ("ppo", "paper_pa3_square", True, 128, 3, 2)
    assert args.env_kwargs == {"max_steps": 32, "success_bonus": 0.5} and args.algo_kwargs["n_steps"] == 64
    assert provenance["steps"] == 128 and provenance["evaluation"] == {"success_1cm": 1.0}
    env = parallel_env("paper_pa3_square", max_steps=32)
    obs, _ = env.reset(seed=0)
    by_scenario = make_policy("pretrained", env)(obs)
    by_name = make_policy("pretrained:square", env)(obs)
    for a in env.agents:
        np.testing.assert_array_equal(by_scenario[a], by_name[a])
    with pytest.raises(ValueError, match="no centralised pretrained model for paper_pa_mixed_square in velocity mode"):
        make_policy("pretrained", parallel_env("paper_pa_mixed_square"))
    with pytest.raises(ValueError, match="no decentralised pretrained model for paper_pa3_square.*square .*central"):
        make_policy("marl", env)
    # a model shared by the arms: `marl` picks it, `pretrained` keeps picking the centralised one
    train("ppo", "paper_pa3_square", shield=True, timesteps=128, seed=4, out=tmp_path / "arms", progress=False,
          n_envs=1, param_sharing=True, env_kwargs={"max_steps": 32}, algo_kwargs={"n_steps": 32, "batch_size": 64})
    shipped.package_model(tmp_path / "arms", "square_arms", evaluation={"success_1cm": 1.0})
    assert "--param-sharing" in shipped.available()["square_arms"]["provenance"]["command"]
    by_marl = make_policy("marl", env)(obs)
    by_arms = make_policy("pretrained:square_arms", env)(obs)
    for a in env.agents:
        np.testing.assert_array_equal(by_marl[a], by_arms[a])
        np.testing.assert_array_equal(make_policy("pretrained", env)(obs)[a], by_name[a])
    with pytest.raises(ValueError, match="no pretrained model 'nope'"):
        make_policy("pretrained:nope", env)
    with pytest.raises(ValueError, match="training run"):
        shipped.package_model(tmp_path, "x")


def test_a_blocked_gate_model_acts_only_after_the_filter_held_an_arm_back(tmp_path) -> None:
    from stable_baselines3 import PPO

    from pan1_env.baselines import ReferencePolicy, decode_observation, make_policy
    from pan1_env.environment import parallel_env
    from pan1_env.wrappers import SafetyShield

    train("ppo", "paper_pa_mixed_square", shield=True, timesteps=128, seed=0, out=tmp_path, checkpoint_every=128,
          progress=False, n_envs=2, env_kwargs={"max_steps": 32, "action_mode": "residual", "blocked_gate": 0.05},
          algo_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 1, "policy_kwargs": {"log_std_init": 0.0}})
    env = SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=32))
    policy, reference = make_policy(f"sb3:{tmp_path / 'model.zip'}", env), ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    first, nominal = policy(obs), reference(obs)
    for a in env.agents:  # at rest nothing was blocked yet: the reference law alone
        np.testing.assert_array_equal(first[a], nominal[a])
    obs, *_ = env.step(first)
    meta = json.loads((tmp_path / "model.json").read_text())["observation_normalization"]
    flat = np.concatenate([obs[a] for a in env.possible_agents])
    flat = np.clip((flat - meta["mean"]) / np.sqrt(np.asarray(meta["var"]) + meta["epsilon"]), -10, 10)
    raw, _ = PPO.load(tmp_path / "model.zip", device="cpu").predict(flat.astype(np.float32), deterministic=True)
    actions, nominal = policy(obs), reference(obs)
    offset = 0
    for a in env.possible_agents:
        k = env.action_space(a).shape[0]
        qd = decode_observation(obs[a], env.observation_layout)["qd_scaled"][-k:]
        scale = min(1.0, np.mean((first[a] - qd) ** 2) / 0.05)
        expected = np.clip(nominal[a] + scale * np.clip(raw[offset:offset + k], -1, 1), -1, 1)
        np.testing.assert_allclose(actions[a], expected, rtol=1e-5, atol=1e-6)
        offset += k


def test_the_pretrained_model_is_picked_by_the_envs_task(tmp_path, monkeypatch) -> None:
    import gymnasium

    from pan1_env.baselines import shipped
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments

    monkeypatch.setattr(shipped, "PRETRAINED_DIR", tmp_path)
    whole_arm = env_arguments("pan1_env/WholeArmStaticFormation-v0")[1]
    for name, kwargs in (("plain", {"action_mode": "residual"}), ("whole_arm", whole_arm | {"physics_dt": 0.01})):
        (tmp_path / f"{name}.zip").write_bytes(b"")  # model_for reads only the metadata
        (tmp_path / f"{name}.json").write_text(json.dumps({"scenario": "random", "env_kwargs": kwargs}))
    assert shipped.model_for(parallel_env("random")) == "plain"
    assert shipped.model_for(parallel_env("random", **whole_arm)) == "whole_arm"  # 10 ms is the default step
    assert shipped.model_for(gymnasium.make("pan1_env:pan1_env/WholeArmStaticFormation-v0")) == "whole_arm"
    assert shipped.describe(shipped.available()["whole_arm"]) == "pan1_env/WholeArmStaticFormation-v0"
    for other, why in (({"random_options": {"n_obstacles": 2}}, "random teams with these options in velocity"),
                       (whole_arm | {"physics_dt": 0.005}, "physics_dt=0.005"),
                       ({"control_dt": 0.1}, "control_dt=0.1"),
                       (whole_arm | {"action_mode": "torque"}, "in torque mode")):
        with pytest.raises(ValueError,
                           match=f"no centralised pretrained model for .*{why}.*whole_arm \\(pan1_env/WholeArmStatic"):
            shipped.model_for(parallel_env("random", **other))


def test_gymnasium_ids_name_tasks_for_training_and_the_benchmark(tmp_path) -> None:
    from pan1_env.baselines import register_policy
    from pan1_env.baselines.policies import ZeroPolicy
    from pan1_env.registration import ENV_IDS, env_arguments

    assert env_arguments("paper_pa3_square") == ("paper_pa3_square", {})
    scenario, kwargs = env_arguments("pan1_env:pan1_env/WholeArmFormation-v0", {"random_options": {"n_obstacles": 2}})
    assert scenario == "random" and kwargs["random_options"]["obstacle_speed"] == (0.05, 0.2)
    assert kwargs["random_options"]["n_obstacles"] == 2 and kwargs["random_options"]["bodies"] == "links"
    kwargs["random_options"]["link_radius"] = 1.0  # a copy: the registered options stay as they are
    assert ENV_IDS["pan1_env/WholeArmFormation-v0"]["random_options"]["link_radius"] == 0.03
    out = tmp_path / "run"
    train("ppo", "pan1_env/WholeArmStaticFormation-v0", timesteps=64, seed=0, out=out, checkpoint_every=64,
          progress=False, n_envs=2, env_kwargs={"max_steps": 16}, algo_kwargs={"n_steps": 32, "batch_size": 64})
    run = json.loads((out / "run.json").read_text())
    assert run["scenario"] == "random" and run["env_kwargs"]["random_options"]["bodies"] == "links"
    assert run["env_kwargs"]["max_steps"] == 16
    seen = []

    def probe(env, seed):  # what the benchmark built for the id
        seen.append(env.unwrapped.config.random_options)
        return ZeroPolicy(env)

    register_policy("probe_whole_arm", probe)
    rows = run_benchmark(["pan1_env/WholeArmStaticFormation-v0"], ["probe_whole_arm"], episodes=1, max_steps=3,
                         shield_settings=(True,))
    assert rows[0]["scenario"] == "pan1_env/WholeArmStaticFormation-v0" and rows[0]["total_cost"] == 0.0
    assert seen[0].bodies == "links" and seen[0].link_radius == 0.03 and seen[0].inter_arm


def test_the_benchmark_fails_before_running_when_a_policy_cannot_be_built() -> None:
    from pan1_env.baselines import register_policy
    from pan1_env.baselines.policies import ZeroPolicy

    calls = []
    register_policy("counting_zero", lambda env, seed: calls.append(1) or ZeroPolicy(env))
    with pytest.raises(ValueError, match="no centralised pretrained model for random teams with these options"):
        run_benchmark(["random", "pan1_env/WholeArmFormation-v0"], ["counting_zero", "pretrained"], episodes=1,
                      max_steps=2, shield_settings=(True,), progress=lambda message: calls.append(message))
    assert all(c == 1 for c in calls)  # policies were built, no row started


# the Gymnasium id each shipped model was trained for: a model must be picked on that id's env
SHIPPED_TASKS = {"random_formation": "pan1_env/RandomFormation-v0",
                 "whole_arm_formation": "pan1_env/WholeArmStaticFormation-v0",
                 "paper_pa3_square": "pan1_env/PaperPA3Square-v0",
                 "paper_pa_mixed_square": "pan1_env/PaperMixedPA-v0",
                 # decentralised: one network shared by the arms (--param-sharing), picked by `marl`
                 "random_formation_v1_ippo": "pan1_env/RandomFormation-v1",
                 "moving_formation_v1_ippo": "pan1_env/MovingFormation-v1",
                 "whole_arm_formation_v2_ippo": "pan1_env/WholeArmFormation-v2",
                 "whole_arm_static_formation_v1_mappo": "pan1_env/WholeArmStaticFormation-v1",
                 "fault_formation_v1_ippo": "pan1_env/FaultFormation-v1",
                 "paper_pa3_square_ippo": "pan1_env/PaperPA3Square-v0",
                 "paper_pa_mixed_square_ippo": "pan1_env/PaperMixedPA-v0",
                 # trained on ring teams of 3-8 arms at once: serves the task at any size
                 "random_formation_v2_ippo_sizes": "pan1_env/RandomFormation-v2"}


def test_every_shipped_model_has_its_task_listed() -> None:
    from pan1_env.baselines import shipped

    assert sorted(shipped.available()) == sorted(SHIPPED_TASKS)


@pytest.mark.parametrize("name", sorted(SHIPPED_TASKS))
def test_each_shipped_model_is_picked_for_its_task_and_runs_there(name) -> None:
    import shlex

    from pan1_env.baselines import make_policy, shipped
    from pan1_env.cli import _parser
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments
    from pan1_env.wrappers import SafetyShield

    scenario, kwargs = env_arguments(SHIPPED_TASKS[name], {"max_steps": 4})
    env = SafetyShield(parallel_env(scenario, **kwargs))  # velocity mode: the residual models' adapter
    decentralised = bool(shipped.available()[name]["param_sharing"])
    assert decentralised == name.endswith(("_ippo", "_mappo", "_ippo_sizes"))  # the name says how it was trained
    assert shipped.model_for(env, decentralised) == name
    assert shipped.describe(shipped.available()[name]) == SHIPPED_TASKS[name]
    policy = make_policy("marl" if decentralised else "pretrained", env)
    obs, _ = env.reset(seed=0)
    for _ in range(4):
        actions = policy(obs)
        assert all(env.action_space(a).contains(actions[a]) for a in env.agents)
        obs, _, _, _, infos = env.step(actions)
        assert all(infos[a]["cost"] == 0.0 for a in infos)
    provenance = shipped.available()[name]["provenance"]
    args = _parser().parse_args(shlex.split(provenance["command"])[1:])  # the command that made it parses back
    run = provenance["run"]
    parsed = (args.scenario, args.seed, args.timesteps, args.env_kwargs, args.algo_kwargs, args.team_sizes,
              args.centralised_critic)
    assert parsed == (run["scenario"], run["seed"], run["timesteps"], run["env_kwargs"], run["algo_kwargs"],
                      run.get("team_sizes"), run.get("centralised_critic", False))


@pytest.mark.parametrize("n_arms", [16, 32])
def test_the_model_for_any_team_size_is_picked_and_runs_on_large_teams(n_arms) -> None:
    """`marl` on a 16-arm LargeFormation-v0 team and a 32-arm RandomFormation-v2 team (24 obstacles, the density
    it trained at) picks the model trained on 3-8 arms, and its actions are in the arms' spaces (its success at
    these sizes is docs/LEARNING_STUDIES.md's, measured over whole episodes)."""
    from pan1_env.baselines import make_policy, shipped
    from pan1_env.environment import parallel_env
    from pan1_env.wrappers import SafetyShield

    env_id = "pan1_env/LargeFormation-v0" if n_arms == 16 else "pan1_env/RandomFormation-v2"
    options = {} if n_arms == 16 else {"random_options": {"n_arms": 32, "n_obstacles": 24}}
    env = SafetyShield(parallel_env(env_id, max_steps=3, action_mode="gain", **options))
    assert shipped.model_for(env, decentralised=True) == "random_formation_v2_ippo_sizes"
    policy = make_policy("marl", env)
    obs, _ = env.reset(seed=2_000_000)
    assert len(env.agents) == n_arms
    for _ in range(3):
        actions = policy(obs)
        assert all(env.action_space(a).contains(actions[a]) for a in env.agents)
        obs, _, _, _, _ = env.step(actions)


def test_a_file_that_is_not_a_saved_model_is_refused(tmp_path) -> None:
    from pan1_env.baselines.evaluation import model_policy

    (tmp_path / "model.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="is not a PPO or SAC model saved by Stable-Baselines3"):
        model_policy(tmp_path / "model.zip")
    with pytest.raises(ValueError, match="no such model file"):
        model_policy(tmp_path / "checkpoints" / "model_100_steps.zip")


def test_a_gain_model_runs_as_a_velocity_policy_by_re_weighting_the_law(tmp_path) -> None:
    from stable_baselines3 import PPO

    from pan1_env.baselines import ReferencePolicy, make_policy
    from pan1_env.environment import parallel_env
    from pan1_env.wrappers import SafetyShield

    train("ppo", "paper_pa_mixed_square", shield=True, timesteps=128, seed=0, out=tmp_path, checkpoint_every=128,
          progress=False, n_envs=2, env_kwargs={"max_steps": 32, "action_mode": "gain", "gain_range": 2.5},
          algo_kwargs={"n_steps": 64, "batch_size": 64, "n_epochs": 1, "policy_kwargs": {"log_std_init": 0.0}})
    env = SafetyShield(parallel_env("paper_pa_mixed_square", max_steps=32))  # velocity mode
    policy, reference = make_policy(f"sb3:{tmp_path / 'model.zip'}", env), ReferencePolicy(env)
    meta = json.loads((tmp_path / "model.json").read_text())["observation_normalization"]
    model = PPO.load(tmp_path / "model.zip", device="cpu")
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        flat = np.concatenate([obs[a] for a in env.possible_agents])
        flat = np.clip((flat - meta["mean"]) / np.sqrt(np.asarray(meta["var"]) + meta["epsilon"]), -10, 10)
        raw, _ = model.predict(flat.astype(np.float32), deterministic=True)
        actions, offset = policy(obs), 0
        for a in env.possible_agents:
            k = env.action_space(a).shape[0]
            gain = 2.5 ** np.clip(raw[offset:offset + k].astype(float), -1, 1)
            np.testing.assert_allclose(actions[a], reference.act(a, obs[a], gain), rtol=1e-5, atol=1e-6)
            offset += k
        obs, *_ = env.step(actions)
    with pytest.raises(ValueError, match="gain"):
        make_policy(f"sb3:{tmp_path / 'model.zip'}", parallel_env("paper_pa_mixed_square", action_mode="torque"), 0)
    with pytest.raises(ValueError, match="gain_range=2.5; this env has gain_range=4.0"):
        make_policy(f"sb3:{tmp_path / 'model.zip'}", parallel_env("paper_pa_mixed_square", action_mode="gain"), 0)
    # on a gain env with its gains the model's actions go through as they are
    gain_env = parallel_env("paper_pa_mixed_square", action_mode="gain", gain_range=2.5)
    obs, _ = gain_env.reset(seed=0)
    flat = np.concatenate([obs[a] for a in gain_env.possible_agents])
    flat = np.clip((flat - meta["mean"]) / np.sqrt(np.asarray(meta["var"]) + meta["epsilon"]), -10, 10)
    raw, _ = model.predict(flat.astype(np.float32), deterministic=True)
    np.testing.assert_array_equal(np.concatenate(list(make_policy(f"sb3:{tmp_path / 'model.zip'}", gain_env)(obs)
                                                      .values())), raw)


def test_a_circulation_model_trains_per_arm_and_is_refused_where_its_actions_would_mean_otherwise(tmp_path) -> None:
    """The leaderboard's mappo-circulation set-up in miniature (a network shared by the arms, circulation actions,
    whole arms): it trains, runs on its own env, and is refused on an env whose circulation settings differ and on a
    velocity env (whose law it cannot turn from observations)."""
    from pan1_env.baselines import make_policy
    from pan1_env.environment import parallel_env

    whole = "pan1_env/WholeArmStaticFormation-v1"
    train("ppo", whole, shield=True, timesteps=256, seed=0, out=tmp_path, checkpoint_every=256, progress=False,
          n_envs=2, param_sharing=True, centralised_critic=True,
          env_kwargs={"max_steps": 32, "action_mode": "circulation", "circulation_gain": 0.5},
          algo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1})
    model = f"sb3:{tmp_path / 'model.zip'}"
    env = parallel_env(whole, action_mode="circulation", circulation_gain=0.5, max_steps=32)
    policy = make_policy(model, env)
    obs, _ = env.reset(seed=0)
    actions = policy(obs)
    assert [len(actions[a]) for a in env.agents] == [k + 1 for k in env.core.n_actuated]
    env.step(actions)
    with pytest.raises(ValueError, match="circulation_gain=0.5; this env has circulation_gain=1.0"):
        make_policy(model, parallel_env(whole, action_mode="circulation"), 0)
    with pytest.raises(ValueError, match="action_mode='circulation'"):
        make_policy(model, parallel_env(whole), 0)


def test_a_gain_model_serves_velocity_and_gain_envs_but_not_residual_ones() -> None:
    from pan1_env.baselines import shipped
    from pan1_env.environment import parallel_env

    assert shipped.model_for(parallel_env("paper_pa3_square")) == "paper_pa3_square"
    assert shipped.model_for(parallel_env("paper_pa3_square", action_mode="gain")) == "paper_pa3_square"
    with pytest.raises(ValueError, match="no centralised pretrained model for paper_pa3_square in residual mode"):
        shipped.model_for(parallel_env("paper_pa3_square", action_mode="residual"))
    assert shipped.available()["paper_pa3_square"]["env_kwargs"]["gain_range"] > 1  # recorded, not a default


def test_a_model_trained_on_several_team_sizes_serves_any_size_of_its_task_only() -> None:
    """A model trained with team_sizes on RandomFormation-v2 (its record: the id's options, no team size) serves
    a team of any size with three obstacles per four arms, rounded half up (as the training drew them); a model of
    one size serves that size only."""
    from pan1_env.baselines import shipped
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments

    _, kwargs = env_arguments("pan1_env/RandomFormation-v2")
    mixed = {"scenario": "random", "env_kwargs": {"random_options": kwargs["random_options"], "action_mode": "gain"},
             "team_sizes": [3, 5, 8], "param_sharing": True}
    one_size = {key: value for key, value in mixed.items() if key != "team_sizes"}
    for n_arms, n_obstacles, by_mixed, by_one in ((3, 2, True, False), (4, 3, True, True), (16, 12, True, False),
                                                  (32, 24, True, False), (16, 9, False, False), (8, 3, False, False)):
        env = parallel_env("pan1_env/RandomFormation-v2", random_options={"n_arms": n_arms, "n_obstacles": n_obstacles})
        assert shipped._serves(shipped._model_task(mixed), shipped._env_task(env)) is by_mixed, (n_arms, n_obstacles)
        assert shipped._serves(shipped._model_task(one_size), shipped._env_task(env)) is by_one, (n_arms, n_obstacles)
    assert shipped.describe(mixed) == "pan1_env/RandomFormation-v2"
    # a density whose half-way ties the training's rounding breaks upwards: the model serves what it trained on
    from pan1_env.random_scenario import obstacles_at_size

    tie = {**mixed, "env_kwargs": {**mixed["env_kwargs"], "random_options": kwargs["random_options"] | {
        "n_arms": 6, "n_obstacles": 5}}}
    assert obstacles_at_size(5, 6, 3) == 3  # 2.5 rounded half up
    env = parallel_env("pan1_env/RandomFormation-v2", random_options={"n_arms": 3, "n_obstacles": 3})
    assert shipped._serves(shipped._model_task(tie), shipped._env_task(env))


@pytest.mark.parametrize("name", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_the_shipped_paper_models_form_the_shape_before_the_paper_law(name) -> None:
    """The shipped model forms its scenario's shape behind the shield by the time its provenance
    records (half a second of slack, for numerical differences between library versions), at zero
    cost, while the paper's law has not yet."""
    from pan1_env.baselines import ReferencePolicy, make_policy
    from pan1_env.environment import parallel_env
    from pan1_env.wrappers import SafetyShield

    recorded = shipped_evaluation(name)["time_to_formation_s"]
    errors = {}
    for policy_name in ("pretrained", "reference"):
        env = SafetyShield(parallel_env(name))
        policy = make_policy("pretrained", env) if policy_name == "pretrained" else ReferencePolicy(env)
        obs, _ = env.reset(seed=0)
        trace = []
        for _ in range(int(round((recorded + 0.5) / env.unwrapped.dt))):
            obs, _, _, _, infos = env.step(policy(obs))
            trace.append(max(i["formation_error"] for i in infos.values()))
            assert all(i["cost"] == 0.0 for i in infos.values())
        errors[policy_name] = trace
    assert errors["pretrained"][-1] < 0.01 and errors["reference"][-1] > 0.01


def shipped_evaluation(name: str) -> dict:
    from pan1_env.baselines import shipped

    return shipped.available()[name]["provenance"]["evaluation"]


def _heldout():
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("pan1_heldout", Path(__file__).resolve().parents[1] / "benchmarks"
                                                  / "heldout.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_heldout_compares_gain_models_with_the_law_and_refuses_what_it_cannot_compare(tmp_path, capsys) -> None:
    heldout = _heldout()
    tiny = {"n_steps": 16, "batch_size": 32, "n_epochs": 1}
    for name, kwargs in (("gain", {"action_mode": "gain"}), ("gain_other", {"action_mode": "gain", "gain_range": 2.0}),
                         ("velocity", {})):
        train("ppo", "random", shield=True, timesteps=32, seed=0, out=tmp_path / name, checkpoint_every=32,
              progress=False, n_envs=2, env_kwargs={"max_steps": 8, **kwargs}, algo_kwargs=tiny)
    heldout.main([str(tmp_path / "gain" / "model.zip"), "--teams", "3"])
    table = capsys.readouterr().out
    assert "| reference |" in table and f"| {tmp_path / 'gain' / 'model.zip'} |" in table
    with pytest.raises(SystemExit):
        heldout.main([str(tmp_path / "velocity" / "model.zip"), "--teams", "2"])
    err = capsys.readouterr().err
    assert "has no reference to compare with" in err and "action_mode 'residual', 'gain' or 'circulation'" in err
    with pytest.raises(SystemExit):
        heldout.main([str(tmp_path / "gain" / "model.zip"), str(tmp_path / "gain_other" / "model.zip"), "--teams", "2"])
    assert "was trained on other env arguments" in capsys.readouterr().err
