"""A leaderboard entry trained through BenchMARL's own ``Experiment``, and its checkpoints as team policies.

:func:`train_benchmarl` runs one training seed of a recipe (:data:`pan1_env.baselines.leaderboard.ENTRIES`'
``benchmarl-mappo``) on a suite task, into ``out``: BenchMARL's experiment folder with its CSV logs, its JSON in
marl-eval's layout (each evaluation's return, success, cost, least clearance and intervention rate:
:class:`~pan1_env.benchmarl_task.Pan1EvaluationMetrics`) and a checkpoint every few iterations. A killed run
continues from its newest checkpoint that loads (BenchMARL's ``Experiment.reload_from_file``); the continued run
is not bit-identical to an uninterrupted one, since BenchMARL rebuilds the env and reseeds. When the frame budget is
spent, ``out/model.json`` names the final checkpoint and says how it was made: that file marks the run finished.

:func:`checkpoint_policy` turns that checkpoint's actor into a policy on the team views' flat observations, for
:func:`~pan1_env.baselines.evaluation.evaluate`: each arm's zero-padded observation in, the actor's deterministic
action (tanh of its mean) out, each arm keeping its own first entries. Needs the ``benchmarl`` extra.

The budget is the suite's, in arm-steps: BenchMARL counts a frame per team step, so a task of N arms trains for
``train_steps / N`` frames. The padded entries of a smaller arm's action are sampled and count in PPO's
log-probability, though the env ignores them (BenchMARL's TanhNormal has no mask).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["train_benchmarl", "latest_checkpoint", "checkpoint_policy", "MODEL_FILE", "GROUP"]

MODEL_FILE = "model.json"  #: written when a run has spent its budget: the final checkpoint and the run's recipe
GROUP = "arms"  #: the one BenchMARL group (pan1_env.marl.GROUP)


def _experiment(task_id: str, env_kwargs: dict[str, Any], recipe: dict[str, Any], seed: int, out: Path, frames: int):
    """A fresh BenchMARL experiment of the recipe: BenchMARL's default configs with the recipe's settings."""
    from benchmarl.algorithms import IppoConfig, MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from pan1_env.benchmarl_task import Pan1EvaluationMetrics, Pan1Task

    algorithm = {"mappo": MappoConfig, "ippo": IppoConfig}[recipe["algorithm"]].get_from_yaml()
    algorithm.scale_mapping = f"biased_softplus_{recipe['initial_std']}"  # the actor's std at a zero input
    algorithm.lmbda = recipe["gae_lambda"]
    batch = recipe["copies"] * recipe["rollout_steps"]
    config = ExperimentConfig.get_from_yaml()
    config.sampling_device = config.train_device = config.buffer_device = "cpu"
    config.gamma, config.lr, config.clip_grad_val = recipe["gamma"], recipe["lr"], recipe["max_grad_norm"]
    config.max_n_frames = frames
    config.on_policy_collected_frames_per_batch = batch
    config.on_policy_n_envs_per_worker = recipe["copies"]
    config.on_policy_minibatch_size = recipe["minibatch_frames"]
    config.on_policy_n_minibatch_iters = recipe["epochs"]
    config.evaluation, config.render = True, False
    config.evaluation_interval = batch * recipe["eval_every"]
    config.evaluation_episodes = recipe["eval_episodes"]
    config.loggers, config.create_json = ["csv"], True
    config.checkpoint_interval = batch * recipe["checkpoint_every"]
    config.checkpoint_at_end, config.exclude_buffer_from_checkpoint = True, True
    config.save_folder = str(out.resolve())
    task = Pan1Task(task_id, {"safety_filter": recipe["shield"], **env_kwargs})
    return Experiment(task=task, algorithm_config=algorithm, model_config=MlpConfig.get_from_yaml(),
                      critic_model_config=MlpConfig.get_from_yaml(), seed=seed, config=config,
                      callbacks=[Pan1EvaluationMetrics()])


def latest_checkpoint(out: str | Path) -> Path | None:
    """The newest ``checkpoint_<frames>.pt`` under ``out`` that loads (a kill while torch saves one can leave it
    cut short: it is passed over), or None."""
    import torch

    found = sorted(Path(out).glob("*/checkpoints/checkpoint_*.pt"), key=lambda f: int(f.stem.split("_")[1]))
    for path in reversed(found):
        try:
            torch.load(path, map_location="cpu", weights_only=False)
        except Exception as err:  # noqa: BLE001 - any failure to load means the file is not a usable checkpoint
            print(f"{path}: not loadable ({type(err).__name__}), an older checkpoint is used")
            continue
        return path
    return None


def train_benchmarl(task_id: str, seed: int, arm_steps: int, out: str | Path, recipe: dict[str, Any],
                    env_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train the recipe on the task (its id, and the suite's arguments for it) with one seed into ``out``, from the
    newest checkpoint there if any; then write ``out/model.json``. Returns that file's content."""
    from benchmarl.experiment import Experiment

    from pan1_env.config import FormationConfig
    from pan1_env.registration import env_arguments

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    kwargs = recipe["env_kwargs"] | (env_kwargs or {})
    scenario, resolved = env_arguments(task_id, kwargs)
    arms = FormationConfig.of(scenario, **resolved).team.n_arms
    frames = arm_steps // arms
    run = {**recipe, "seed": seed, "task": task_id, "task_env_kwargs": env_kwargs or {}, "timesteps": arm_steps}
    checkpoint = latest_checkpoint(out)
    if checkpoint is not None:  # the checkpoint holds the recipe's settings: only the budget may change
        before = json.loads((out / "run.json").read_text()) if (out / "run.json").is_file() else {}
        if {**before, "timesteps": arm_steps} != run:
            raise ValueError(f"{out}: its checkpoints were trained with another recipe or task ({out / 'run.json'}); "
                             "train into a new folder")
    (out / "run.json").write_text(json.dumps(run, indent=1, sort_keys=True))
    if checkpoint is None:
        experiment = _experiment(task_id, kwargs, recipe, seed, out, frames)
    else:
        print(f"resuming from {checkpoint}")
        experiment = Experiment.reload_from_file(str(checkpoint.resolve()), experiment_patch={"max_n_frames": frames})
    experiment.run()
    final = latest_checkpoint(out)
    meta = {"trainer": "benchmarl", "checkpoint": str(final.relative_to(out)), "frames": experiment.total_frames,
            "scenario": scenario, "env_kwargs": resolved, "shield": recipe["shield"], "param_sharing": True,
            "provenance": {"run": run}}
    (out / MODEL_FILE).write_text(json.dumps(meta, indent=1, sort_keys=True))
    return meta


def checkpoint_policy(model: str | Path, env_kwargs: dict[str, Any] | None = None
                      ) -> tuple[Callable[[np.ndarray], np.ndarray], dict[str, Any]]:
    """A finished run (its ``model.json``) as a deterministic policy for
    :func:`~pan1_env.baselines.evaluation.evaluate`, and the env arguments to evaluate it with (its own, or
    ``env_kwargs``). The experiment is rebuilt in a scratch folder, so the run's folder is left as it is."""
    import torch
    from benchmarl.experiment import Experiment
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from pan1_env.vector import Pan1VectorEnv

    model = Path(model)
    meta = json.loads(model.read_text())
    kwargs = dict(meta["env_kwargs"] if env_kwargs is None else env_kwargs)
    scratch = tempfile.mkdtemp(prefix="pan1_benchmarl_")
    try:
        experiment = Experiment.reload_from_file(str((model.parent / meta["checkpoint"]).resolve()), experiment_patch={
            "save_folder": scratch, "loggers": [], "create_json": False, "evaluation": False,
            "restore_map_location": "cpu"})
        actor = experiment.group_policies[GROUP]
        actor.eval()
        experiment.close()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    layout = Pan1VectorEnv(meta["scenario"], 1, **kwargs).core  # the team's sizes only

    def policy(obs: np.ndarray) -> np.ndarray:
        padded = torch.from_numpy(layout.padded_from_flat(obs)).float()
        rows, arms = padded.shape[:2]
        td = TensorDict({GROUP: TensorDict({"observation": padded}, batch_size=(rows, arms))}, batch_size=(rows,))
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            action = actor(td).get((GROUP, "action")).numpy()
        return layout.flat_actions(action).astype(np.float32)

    return policy, kwargs
