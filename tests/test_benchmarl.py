"""The BenchMARL task: BenchMARL's own Experiment runs MAPPO on it for a few thousand frames, behind the
shield, prints a finite return, and logs the cost, the shield's work, success and clearance, in its evaluation and
its JSON too (skipped without BenchMARL; `make test` sets PAN1_REQUIRE_BENCHMARL, so a missing BenchMARL is a
failure there)."""

import importlib.util
import json
import math
import os
from pathlib import Path

import pytest

if os.environ.get("PAN1_REQUIRE_BENCHMARL"):
    import benchmarl  # noqa: F401
else:
    pytest.importorskip("benchmarl")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from pan1_env.benchmarl_task import TASKS, YAML_DIR, Pan1Task  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "benchmarl_mappo.py"


@pytest.mark.parametrize("name", sorted(TASKS))
def test_the_task_builds_envs_benchmarl_can_use(name: str) -> None:
    task = Pan1Task(name, {"max_steps": 20})
    assert task.scenario == name and "/" not in task.name  # BenchMARL makes its run folder's name of it
    env = task.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    check_env_specs(env, seed=0)
    assert task.group_map(env) == {"arms": [f"arm_{i}" for i in range(4)]}
    assert list(task.observation_spec(env).keys(True, True)) == [("arms", "observation")]
    assert task.max_steps(env) == 20 and env.core.engine.filter is not None  # shielded by default
    if name.endswith("-v1"):  # behind the v1 filter, not the paper's
        assert (env.core.engine.filter.barrier, env.core.engine.filter.decay) == ("distance", 50.0)
    with pytest.raises(ValueError, match="continuous"):
        task.get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")


def test_an_unknown_task_keyword_gets_a_did_you_mean() -> None:
    with pytest.raises(TypeError, match="unknown argument 'max_step'; did you mean 'max_steps'"):
        Pan1Task("paper_pa3_square", {"max_step": 20})


def test_the_yaml_files_name_the_standard_tasks() -> None:
    names = {Pan1Task.from_yaml(path).scenario for path in YAML_DIR.glob("*.yaml")}
    assert names == set(TASKS)


@pytest.mark.slow
def test_mappo_runs_a_few_thousand_frames_and_logs_the_cost(tmp_path: Path) -> None:
    """The example's batches hold whole episodes, so every iteration has a finite return; each evaluation logs, and
    writes into BenchMARL's JSON beside the return, every episode's success, cost, clearance and interventions."""
    spec = importlib.util.spec_from_file_location("benchmarl_mappo", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    experiment = example.main(["--task", str(YAML_DIR / "random_v1.yaml"), "--frames", "3000", "--max-steps", "100",
                               "--copies", "10", "--epochs", "1", "--eval-episodes", "3", "--out", str(tmp_path)])
    assert experiment.total_frames >= 3000 and experiment.n_iters_performed == 3
    assert math.isfinite(experiment.mean_return)
    scalars = next(tmp_path.rglob("scalars"))
    costs = (scalars / "cost_per_arm_step.csv").read_text().split()
    assert len(costs) == 3 and all(float(row.split(",")[-1]) == 0.0 for row in costs)  # behind the shield
    assert (scalars / "shield_intervention_rate.csv").exists()
    for name in ("success", "cost", "min_clearance", "intervention_rate"):
        assert len((scalars / f"eval_{name}.csv").read_text().split()) == 3  # after every iteration
    steps = [value for key, value in _run_data(next(tmp_path.rglob("*.json"))).items() if key.startswith("step_")]
    assert len(steps) == 3
    for step in steps:
        assert {"return", "success", "cost", "min_clearance", "intervention_rate"} <= set(step)
        assert len(step["success"]) == 3 and all(math.isfinite(value) for value in step["return"])
        assert step["cost"] == [0.0] * 3 and all(0 < clearance < 10 for clearance in step["min_clearance"])


def _run_data(path: Path) -> dict:
    """The one run's entry of BenchMARL's JSON (environment → task → algorithm → seed)."""
    (tasks,) = json.loads(path.read_text()).values()
    (algorithms,) = tasks.values()
    (seeds,) = algorithms.values()
    (run,) = seeds.values()
    return run


def test_a_benchmarl_entry_trains_resumes_and_is_scored_on_held_out_teams(tmp_path: Path) -> None:
    """The suite's BenchMARL entry, shrunk: ``train_entry`` runs BenchMARL's Experiment to the task's budget in arm-
    steps and marks the run finished; a bigger budget continues from the newest checkpoint (BenchMARL's frame count
    goes on from it); the suite scores the run's actor on held-out teams, deterministically."""
    import dataclasses

    import numpy as np

    from pan1_env.baselines import leaderboard as board
    from pan1_env.baselines.benchmarl_training import checkpoint_policy, train_benchmarl
    from pan1_env.baselines.suite import SuiteTask
    from pan1_env.vector import Pan1VectorEnv

    recipe = board.entry("benchmarl-mappo").recipe | {
        "copies": 2, "rollout_steps": 50, "minibatch_frames": 50, "epochs": 1, "eval_every": 2, "eval_episodes": 2,
        "checkpoint_every": 1}
    small = board.Entry("benchmarl-mappo", "shrunk", recipe=recipe)
    task = SuiteTask("tiny", "pan1_env/RandomFormation-v1", env_kwargs={"max_steps": 60}, train_steps=4 * 200,
                     train_seeds=(0,), held_out_teams=3)
    board.train_entry(small, task, runs=tmp_path, seeds=[0], say=lambda text: None)
    run = board.task_dir(tmp_path, small, task) / "seed_0"
    first = json.loads((run / "model.json").read_text())
    assert first["frames"] == 200 and board.finished_runs(tmp_path, small, task) == [run / "model.json"]
    (run / "model.json").unlink()  # as if killed after its last checkpoint, and given more budget
    longer = dataclasses.replace(task, train_steps=4 * 400)
    board.train_entry(small, longer, runs=tmp_path, seeds=[0], say=lambda text: None)
    final = json.loads((run / "model.json").read_text())
    assert final["frames"] == 400 and final["checkpoint"].endswith("checkpoint_400.pt")
    assert len([path for path in run.iterdir() if path.is_dir()]) == 1  # the same experiment folder, continued
    said = []
    board.train_entry(small, dataclasses.replace(task, train_steps=4 * 600), runs=tmp_path, seeds=[0], say=said.append)
    assert said == [f"{run}: finished, left as it is"]  # a finished run is not trained again, whatever the budget
    with pytest.raises(ValueError, match="trained with another recipe or task"):
        train_benchmarl("pan1_env/RandomFormation-v1", 0, 4 * 800, run, recipe | {"lr": 1e-3}, task.env_kwargs)

    policy, kwargs = checkpoint_policy(run / "model.json")
    data = board.run_suite([longer], [small], runs=tmp_path, teams=3, bar=False)
    (record,) = data["raw"]["pan1_env"][task.env_id]["benchmarl-mappo"].values()
    metrics = record["absolute_metrics"]
    assert len(metrics["success"]) == 3 and metrics["cost"] == [0.0] * 3  # behind the shield

    venv = Pan1VectorEnv(first["scenario"], 3, **kwargs)
    obs, _ = venv.reset(seed=[5, 6, 7])
    actions = policy(obs)
    assert actions.shape == (3, venv.action_space.shape[-1]) and np.abs(actions).max() <= 1
    np.testing.assert_array_equal(actions, policy(obs))  # deterministic
