"""The env as a BenchMARL task: ``Experiment(task=Pan1Task("random", {...}), ...)`` runs MAPPO, IPPO, … on it.

:class:`Pan1Task` is a BenchMARL ``TaskClass`` whose environment is :func:`pan1_env.marl.torchrl_env` (B copies
in one batched call, so BenchMARL needs no ``SerialEnv`` around it). Its ``name`` is any scenario or registered
id (``"paper_pa3_square"``, ``"random"``, ``"pan1_env/WholeArmStaticFormation-v0"``), its ``config`` the env's
keywords (:class:`~pan1_env.config.FormationConfig`; ``safety_filter`` defaults to True here: the shield is
on while the policies learn). :data:`TASKS` gives the standard tasks with their defaults, and
``pan1_env/benchmarl_tasks/*.yaml`` the same as YAML files, for ``Pan1Task.from_yaml(path)``.

What BenchMARL sees: one group ``arms``; the models' input is each arm's own observation (the policy acts on
local observations; a MAPPO critic may also read the global ``state``); the per-arm ``cost`` and the shield's
report are infos, which :meth:`Pan1Task.log_info` logs for every collected batch: the mean cost per arm-step, the
share of arm-steps the filter changed, the success rate of the episodes that ended in the batch and the least
clearance. BenchMARL's evaluation logs the return only; pass :class:`Pan1EvaluationMetrics` among the experiment's
callbacks (``Experiment(..., callbacks=[Pan1EvaluationMetrics()])``, as ``examples/benchmarl_mappo.py`` does) and
each evaluation also logs, and writes into BenchMARL's JSON beside the return, per episode: ``success`` (formed at
the episode's end), ``cost`` (arm-steps inside an obstacle), ``min_clearance`` (m, the least over the arms and
steps) and ``intervention_rate`` (the share of arm-steps the filter changed; with the filter on). Needs BenchMARL
(the ``benchmarl`` extra, with its own TorchRL pin).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import torch
from benchmarl.environments.common import TaskClass
from benchmarl.experiment.callback import Callback
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase

from .config import ARGUMENTS
from .marl import GROUP, torchrl_env
from .validation import refuse_unknown

__all__ = ["Pan1Task", "Pan1EvaluationMetrics", "episode_metrics", "TASKS", "YAML_DIR"]

#: the standard tasks, shielded: the paper's two squares, and the random and whole-arm teams behind the paper's
#: filter (v0) and behind the v1 filter, which holds no arm still far from the obstacles (docs/ENVIRONMENTS.md)
TASKS = {
    "paper_pa3_square": {"safety_filter": True},
    "paper_pa_mixed_square": {"safety_filter": True},
    "random": {"safety_filter": True},
    "pan1_env/WholeArmStaticFormation-v0": {"safety_filter": True},
    "pan1_env/RandomFormation-v1": {"safety_filter": True},
    "pan1_env/WholeArmStaticFormation-v1": {"safety_filter": True},
    "pan1_env/FaultFormation-v0": {"safety_filter": True},
    "pan1_env/MovingFormation-v0": {"safety_filter": True},
    # the benchmark suite's tasks that the ones above do not cover (docs/BENCHMARK.md)
    "pan1_env/WholeArmFormation-v2": {"safety_filter": True},
    "pan1_env/FaultFormation-v1": {"safety_filter": True},
    "pan1_env/MovingFormation-v1": {"safety_filter": True},
}
YAML_DIR = Path(__file__).with_name("benchmarl_tasks")


class Pan1Task(TaskClass):
    """A pan1-env scenario as a BenchMARL task (see the module docstring). ``scenario`` is the scenario or
    registered id the env is built from; ``name``, which BenchMARL puts in its run folder's name, is the same
    without slashes (``pan1_env_RandomFormation-v1``)."""

    def __init__(self, name: str = "random", config: dict[str, Any] | None = None) -> None:
        refuse_unknown("Pan1Task config", config or {}, [key for key in ARGUMENTS if key != "scenario"],
                       error=TypeError)
        self.scenario = name
        super().__init__(name.replace("/", "_"), {"safety_filter": True, **(config or {})})

    @classmethod
    def from_yaml(cls, path: str | Path) -> Pan1Task:
        """A task from a YAML file of this package's form: ``scenario: NAME`` and the env's keywords."""
        import yaml

        config = yaml.safe_load(Path(path).read_text()) or {}
        return cls(config.pop("scenario", "random"), config)

    def get_env_fun(self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any):
        if not continuous_actions:
            raise ValueError("pan1-env tasks have continuous actions only")
        name, config = self.scenario, copy.deepcopy(self.config)

        def make() -> EnvBase:
            env = torchrl_env(name, num_envs=num_envs, device=device, **config)
            if seed is not None:
                env.set_seed(seed)
            return env

        return make

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return env.core.config.max_steps

    def has_render(self, env: EnvBase) -> bool:
        return False

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return {GROUP: list(env.core.agents)}

    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched
        return Composite({GROUP: Composite({"observation": spec[GROUP, "observation"]},
                                           shape=spec[GROUP].shape)})

    def info_spec(self, env: EnvBase) -> Composite | None:
        spec = env.full_observation_spec_unbatched
        return Composite({GROUP: Composite({"cost": spec[GROUP, "cost"], "info": spec[GROUP, "info"]},
                                           shape=spec[GROUP].shape)})

    def state_spec(self, env: EnvBase) -> Composite | None:
        return Composite({"state": env.full_observation_spec_unbatched["state"]})

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None  # continuous actions: an arm ignores its padding entries itself

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return "pan1_env"

    @staticmethod
    def log_info(batch: TensorDictBase) -> dict[str, float]:
        """The collected batch's mean cost per arm-step, least clearance (m), success rate of the episodes that
        ended in it (NaN if none did) and, with the shield, the share of arm-steps it changed."""
        nxt = batch.get("next")
        ended = nxt.get("done").squeeze(-1)
        out = {"cost_per_arm_step": nxt.get((GROUP, "cost")).float().mean().item(),
               "min_clearance": nxt.get((GROUP, "info", "min_clearance")).min().item(),
               "success_rate": nxt.get(("info", "is_success"))[ended].float().mean().item()}
        if (GROUP, "info", "shield_intervened") in nxt.keys(True, True):
            out["shield_intervention_rate"] = nxt.get((GROUP, "info", "shield_intervened")).float().mean().item()
        return out


def episode_metrics(episode: TensorDictBase) -> dict[str, torch.Tensor]:
    """An episode's numbers, from its steps (``[T]``, ending where the episode ends): ``success`` (1.0 if formed at
    its last step), ``cost`` (arm-steps inside an obstacle), ``min_clearance`` (m, the least over arms and steps) and,
    with the filter on, ``intervention_rate`` (the share of arm-steps it changed). Each value is a 0-dim float."""
    nxt = episode.get("next")
    out = {"success": nxt.get(("info", "is_success"))[-1].float(),
           "cost": nxt.get((GROUP, "cost")).sum().float(),
           "min_clearance": nxt.get((GROUP, "info", "min_clearance")).min().float()}
    if (GROUP, "info", "shield_intervened") in nxt.keys(True, True):
        out["intervention_rate"] = nxt.get((GROUP, "info", "shield_intervened")).float().mean()
    return out


class Pan1EvaluationMetrics(Callback):
    """A BenchMARL callback: after each evaluation, the evaluation episodes' :func:`episode_metrics`, logged as
    ``eval/<name>`` (the mean over the episodes) and written per episode into BenchMARL's JSON beside the return."""

    def on_evaluation_end(self, rollouts: list[TensorDictBase]) -> None:
        # BenchMARL has cut each rollout at its episode's end (Logger.log_evaluation) before calling back
        episodes = [episode_metrics(rollout) for rollout in rollouts]
        if not episodes:
            return
        metrics = {name: torch.stack([episode[name] for episode in episodes]) for name in episodes[0]}
        experiment = self.experiment
        experiment.logger.log({f"eval/{name}": values.mean().item() for name, values in metrics.items()},
                              step=experiment.n_iters_performed)
        writer = experiment.logger.json_writer
        if writer is not None:  # the same evaluation step as BenchMARL's own entry, which this one extends
            writer.write(total_frames=experiment.total_frames, metrics=metrics,
                         evaluation_step=experiment.total_frames // experiment.config.evaluation_interval)
