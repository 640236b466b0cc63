"""Policies trained here and shipped with the package (needs the ``rl`` extra to run them).

Each model is a Stable-Baselines3 file ``pretrained/<name>.zip`` with ``<name>.json`` beside it: the
scenario it was trained for, the env arguments and observation statistics it needs (what
:func:`~pan1_env.baselines.training.train` writes as ``model.json``), and its provenance: the exact
command, seed and package version that produced it, and its held-out evaluation.

    from pan1_env.baselines import pretrained
    policy = pretrained("random_formation", env)        # env: a parallel env, wrapped or not
    actions = policy(observations)

The policy registry's ``pretrained`` name (``pan1-env benchmark --policies pretrained``) picks the
centralised model trained for the env's task (:func:`model_for`), and ``marl`` the decentralised one (one
network shared by the arms, each arm acting on its own observation).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["pretrained", "available", "model_for", "serves", "package_model", "PRETRAINED_DIR"]

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"


def available() -> dict[str, dict[str, Any]]:
    """Every shipped model by name, with its metadata (``<name>.json``)."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(PRETRAINED_DIR.glob("*.json"))
            if p.with_suffix(".zip").exists()}


def _task(scenario: str, options: Any, action_mode: str, control_dt: float | None, physics_dt: float | None,
          ke: float | None = None) -> tuple:
    """A task as a model was trained on it or an env poses it: the scenario (its name; for random teams
    the options they are drawn with), the action mode and the time steps, defaults resolved."""
    from dataclasses import asdict

    from pan1_env.config import DEFAULT_CONTROL_DT, default_physics_dt
    from pan1_env.random_scenario import RandomScenarioOptions
    from pan1_env.scenario import load

    if scenario == "random":
        options = options if isinstance(options, RandomScenarioOptions) else RandomScenarioOptions(**(options or {}))
        ke = options.ke
        # the options' own time steps are a drawn scenario's outside an env (an env refuses others than the defaults)
        scenario = ("random", tuple(sorted((key, value) for key, value in asdict(options).items()
                                           if key not in ("physics_dt", "control_dt"))))
    elif ke is None:
        try:
            template = load(scenario)
            scenario, ke = template.name, template.ke
        except Exception:  # noqa: BLE001 - a model for a scenario file that is not here serves no env
            return (scenario,)
    control_dt = DEFAULT_CONTROL_DT if control_dt is None else control_dt
    physics_dt = default_physics_dt(control_dt, ke, action_mode) if physics_dt is None else physics_dt
    return scenario, action_mode, round(control_dt, 9), round(physics_dt, 9)


ANY_SIZE = ("n_arms", "any")  #: in a random task's options: a model trained on teams of several sizes


def _any_size(task: tuple, density: tuple[int, int] | None = None) -> tuple:
    """A random-team task as one of any size: :data:`ANY_SIZE` for its team size, the set of its arms' link counts
    for their list, and ``("obstacles_per_arms", (n_obstacles, n_arms))`` for its obstacles, at its own density or,
    if given, at ``density`` when its number of obstacles is what
    :func:`~pan1_env.random_scenario.obstacles_at_size` gives (else its number stays: another task)."""
    from pan1_env.random_scenario import obstacles_at_size

    if not isinstance(task[0], tuple):
        return task
    options = dict(task[0][1])
    n_arms, n_obstacles = options.pop("n_arms"), options.pop("n_obstacles")
    density = (n_obstacles, n_arms) if density is None else tuple(density)
    if obstacles_at_size(*density, n_arms) == n_obstacles:
        options["obstacles_per_arms"] = density
    else:
        options["n_obstacles"] = n_obstacles
    if isinstance(options.get("links"), tuple):
        options["links"] = tuple(sorted(set(options["links"])))
    return ((task[0][0], tuple(sorted([ANY_SIZE, *options.items()]))), *task[1:])


def _serves(model: tuple, env: tuple) -> bool:
    """Whether a model trained on task ``model`` can run on an env of task ``env`` (both from
    :func:`_task`, or their first two entries): the same task, except that a model trained on residual
    or gain actions also runs on the velocity-mode env (the adapter computes the paper's law), and a model
    trained on teams of several sizes (its task's options hold :data:`ANY_SIZE`) runs on a team of any size with
    the obstacles per arm it was trained with."""
    if isinstance(model[0], tuple) and ANY_SIZE in model[0][1]:
        env = _any_size(env, dict(model[0][1])["obstacles_per_arms"])
    if len(model) != len(env) or model[0] != env[0] or model[2:] != env[2:]:
        return False
    return model[1] == env[1] or (env[1] == "velocity" and model[1] in ("residual", "gain"))


def _env_task(env) -> tuple:
    from pan1_env.config import FormationConfig

    config = getattr(getattr(env, "unwrapped", env), "config", None)  # a team view of the env core, wrapped or not
    if not isinstance(config, FormationConfig):
        raise TypeError(f"the shipped models act on the team envs (parallel or Gymnasium), got {type(env).__name__}")
    random = config.random
    return _task("random" if random else config.team.name, config.random_options if random else None,
                 config.action_mode, config.control_dt, config.physics_dt, None if random else config.team.ke)


def _model_task(meta: dict[str, Any]) -> tuple:
    kwargs = meta.get("env_kwargs", {})
    task = _task(meta.get("scenario"), kwargs.get("random_options"), kwargs.get("action_mode", "velocity"),
                 kwargs.get("control_dt"), kwargs.get("physics_dt"))
    return _any_size(task) if meta.get("team_sizes") else task


def describe(meta: dict[str, Any]) -> str:
    """A shipped model's task in words: the Gymnasium id whose task it is, else its scenario."""
    from pan1_env.registration import ENV_IDS, env_arguments

    for env_id in ENV_IDS:
        if serves(meta, *env_arguments(env_id)):
            return env_id
    return str(meta.get("scenario"))


def serves(meta: dict[str, Any], scenario: str, env_kwargs: dict[str, Any]) -> bool:
    """Whether a model (its metadata) runs on the task of an env made with ``scenario`` and ``env_kwargs``: the same
    scenario (with its options) and action mode, as :func:`model_for` matches them, time steps aside (an id sets
    none)."""
    return _serves(_model_task(meta)[:2], _model_task({"scenario": scenario, "env_kwargs": env_kwargs})[:2])


def model_for(env, decentralised: bool = False) -> str:
    """The name of the shipped model trained for ``env``'s task (ValueError if none ships): the same
    scenario (for random teams, the same options), action mode and time steps. A model trained on
    residual or gain actions serves a velocity-mode env (the adapter computes the reference law).
    ``decentralised`` picks among the models shared by the arms, each acting on its own observation
    (``pan1-env train --param-sharing``), else among the centralised ones."""
    task = _env_task(env)
    models = available()
    matches = [name for name, meta in models.items()
               if _serves(_model_task(meta), task) and bool(meta.get("param_sharing")) == decentralised]
    if not matches:
        label = task[0] if isinstance(task[0], str) else "random teams with these options"
        kind = _kind({"param_sharing": decentralised})
        shipped = ", ".join(f"{name} ({describe(meta)}, {_kind(meta)})" for name, meta in models.items()) or "none"
        raise ValueError(f"no {kind} pretrained model for {label} in {task[1]} mode with control_dt={task[2]}, "
                         f"physics_dt={task[3]}; shipped: {shipped}")
    return matches[0]


def _kind(meta: dict[str, Any]) -> str:
    return "decentralised" if meta.get("param_sharing") else "centralised"


def pretrained(name: str, env):
    """The shipped model ``name`` as a policy on ``env``, which may be:

    * a parallel env (wrapped or not): the policy maps observations by agent to actions by agent;
    * a Gymnasium env of a pan1_env id (``gymnasium.make("pan1_env:pan1_env/…")``, wrapped or not): the
      policy maps its flat observation to its flat action;
    * a registered id or scenario name: a parallel env of it is made, and the policy is as for one.

    The env must pose the task the model was trained for (ValueError naming it otherwise), except that a
    model trained on residual or gain actions runs on a velocity-mode env (the adapter computes the
    reference law from observations)."""
    from .sb3 import sb3_policy

    models = available()
    if name not in models:
        raise ValueError(f"no pretrained model {name!r}; shipped: {sorted(models) or 'none'}")
    target = env
    if isinstance(env, str):
        from pan1_env.environment import parallel_env

        target = parallel_env(env)
    inner = getattr(target, "unwrapped", target)
    gym_view = getattr(inner, "parallel", None)  # the Gymnasium view of the team: its parallel view
    if not (hasattr(inner, "possible_agents") or gym_view is not None) or not hasattr(inner, "config"):
        raise TypeError(f"pretrained() needs a pan1_env team env (parallel, Gymnasium or an id), got "
                        f"{type(env).__name__}")
    if not _serves(_model_task(models[name]), _env_task(inner)):
        _, mode, control_dt, physics_dt = _model_task(models[name])
        raise ValueError(f"pretrained model {name!r} was trained for {describe(models[name])} ({mode} actions, "
                         f"control_dt={control_dt}, physics_dt={physics_dt}); this env poses another task "
                         "(model_for(env) names the model for an env's task)")
    policy = sb3_policy(PRETRAINED_DIR / f"{name}.zip", gym_view if gym_view is not None else target)
    if gym_view is None:
        return policy
    agents = gym_view.possible_agents
    splits = np.cumsum([gym_view.observation_space(a).shape[0] for a in agents])[:-1]

    def flat_policy(observation: np.ndarray) -> np.ndarray:
        actions = policy(dict(zip(agents, np.split(np.asarray(observation, np.float32), splits), strict=True)))
        return np.concatenate([actions[a] for a in agents])

    return flat_policy


def package_model(run_dir: str | Path, name: str, steps: int | None = None, dest: str | Path | None = None,
                  evaluation: dict[str, Any] | None = None) -> Path:
    """Copy a training run's final model (or its checkpoint at ``steps``) into the shipped models as
    ``name``, with its ``model.json`` and provenance: the run's arguments, the command that reproduces
    it, the steps, the package version and, when given, its held-out ``evaluation``. Returns the zip."""
    import shutil
    from importlib.metadata import PackageNotFoundError, version

    from .commands import training_command

    run_dir = Path(run_dir)
    model = run_dir / "model.zip" if steps is None else run_dir / "checkpoints" / f"model_{steps}_steps.zip"
    if not model.exists() or not model.with_suffix(".json").exists():
        raise ValueError(f"{model} (and the .json beside it) not found: is {run_dir} a training run?")
    run = json.loads((run_dir / "run.json").read_text())
    try:
        package_version = version("pan1-env")
    except PackageNotFoundError:  # pragma: no cover - a source tree that is not installed
        package_version = "unknown"
    meta = json.loads(model.with_suffix(".json").read_text())
    if run.get("team_sizes"):  # what makes it serve a team of any size: a model.json may predate recording it
        meta["team_sizes"] = list(run["team_sizes"])
    meta["provenance"] = {"run": run, "command": training_command(run, f"runs/{name}"),
                          "steps": steps or run["timesteps"], "package_version": package_version,
                          "evaluation": evaluation}
    dest = PRETRAINED_DIR if dest is None else Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(model, dest / f"{name}.zip")
    (dest / f"{name}.json").write_text(json.dumps(meta, indent=1) + "\n")
    return dest / f"{name}.zip"
