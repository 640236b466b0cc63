"""Policies trained here and shipped with the package (needs the ``rl`` extra to run them).

Each model is a Stable-Baselines3 file ``pretrained/<name>.zip`` with ``<name>.json`` beside it: the
scenario it was trained for, the env arguments and observation statistics it needs (what
:func:`~pan1_env.baselines.training.train` writes as ``model.json``), and its provenance: the exact
command, seed and package version that produced it, and its held-out evaluation.

    from pan1_env.baselines import pretrained
    policy = pretrained("random_formation", env)        # env: a parallel env, wrapped or not
    actions = policy(observations)

The policy registry's ``pretrained`` name (``pan1-env benchmark --policies pretrained``) picks the
model trained for the env's scenario.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["pretrained", "available", "model_for", "package_model", "training_command", "PRETRAINED_DIR"]

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"


def available() -> dict[str, dict[str, Any]]:
    """Every shipped model by name, with its metadata (``<name>.json``)."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(PRETRAINED_DIR.glob("*.json"))
            if p.with_suffix(".zip").exists()}


def model_for(env) -> str:
    """The name of the shipped model trained for ``env``'s task (ValueError if none ships): the same
    scenario and, where the model's run set them, the same random-team options and time steps; a model
    trained on residual actions still serves a velocity-mode env (the adapter adds the reference law)."""
    from pan1_env.random_scenario import RandomScenarioOptions

    env = getattr(env, "unwrapped", env)
    name = env.scenario.name if not getattr(env, "_random", False) else "random"

    def same_task(meta: dict[str, Any]) -> bool:
        kwargs = meta.get("env_kwargs", {})
        if meta.get("scenario") != name:
            return False
        if name == "random" and RandomScenarioOptions(**kwargs.get("random_options", {})) != env.random_options:
            return False
        return all(getattr(env, key) == kwargs[key] for key in ("physics_dt", "control_dt") if key in kwargs)

    matches = [model for model, meta in available().items() if same_task(meta)]
    if not matches:
        shipped = {model: meta.get("scenario") for model, meta in available().items()}
        raise ValueError(f"no pretrained model for scenario {name!r} with these options; shipped: "
                         f"{shipped or 'none'} (pretrained:NAME picks one by name)")
    return matches[0]


def pretrained(name: str, env):
    """The shipped model ``name`` as a policy on ``env`` (dict of observations → dict of actions).
    A model trained on residual actions runs on a velocity-mode env (the reference law is added)."""
    from .policies import _sb3_policy

    models = available()
    if name not in models:
        raise ValueError(f"no pretrained model {name!r}; shipped: {sorted(models) or 'none'}")
    return _sb3_policy(PRETRAINED_DIR / f"{name}.zip", env)


def training_command(run: dict[str, Any], out: str = "runs/train") -> str:
    """The ``pan1-env train`` command that reproduces a run from its ``run.json`` into ``out``
    (evaluation and checkpoint settings, which do not change the model, left out)."""
    parts = ["pan1-env train", f"--algo {run['algo']}", f"--scenario {run['scenario']}",
             "--shield" if run["shield"] else "--no-shield", f"--timesteps {run['timesteps']}",
             f"--seed {run['seed']}", f"--n-envs {run['n_envs']}"]
    if run.get("param_sharing"):
        parts.append("--param-sharing")
    if not run.get("normalize", True):
        parts.append("--no-normalize")
    if run.get("critic_warmup"):
        parts.append(f"--critic-warmup {run['critic_warmup']}")
    for flag, key in (("--env-kwargs", "env_kwargs"), ("--algo-kwargs", "algo_kwargs")):
        if run.get(key):
            parts.append(f"{flag} '{json.dumps(run[key], sort_keys=True)}'")
    return " ".join([*parts, f"--out {out}"])


def package_model(run_dir: str | Path, name: str, steps: int | None = None, dest: str | Path | None = None,
                  evaluation: dict[str, Any] | None = None) -> Path:
    """Copy a training run's final model (or its checkpoint at ``steps``) into the shipped models as
    ``name``, with its ``model.json`` and provenance: the run's arguments, the command that reproduces
    it, the steps, the package version and, when given, its held-out ``evaluation``. Returns the zip."""
    import shutil
    from importlib.metadata import PackageNotFoundError, version

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
    meta["provenance"] = {"run": run, "command": training_command(run, f"runs/{name}"),
                          "steps": steps or run["timesteps"], "package_version": package_version,
                          "evaluation": evaluation}
    dest = PRETRAINED_DIR if dest is None else Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(model, dest / f"{name}.zip")
    (dest / f"{name}.json").write_text(json.dumps(meta, indent=1) + "\n")
    return dest / f"{name}.zip"
