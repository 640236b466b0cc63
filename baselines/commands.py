"""The ``pan1-env train`` command behind a run, from its ``run.json``: what a shipped model's provenance records and
what ``pan1-env plot`` suggests to continue a run (one builder, so that the two cannot drift apart)."""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

__all__ = ["training_command"]


def training_command(run: dict[str, Any], out: str | Path = "runs/train", *, timesteps: int | None = None,
                     resume: bool = False) -> str:
    """The ``pan1-env train`` command that reproduces a run from its ``run.json`` into ``out``, or with ``resume``
    continues it there to ``timesteps`` (default: the run's). Evaluation and checkpoint settings, which do not
    change the model, are left out. Raises KeyError if ``run`` lacks the scenario, ``n_envs`` or the budget."""
    words = ["pan1-env", "train", "--algo", str(run.get("algo", "ppo")), "--scenario", str(run["scenario"]),
             "--shield" if run.get("shield", True) else "--no-shield", "--seed", str(run.get("seed", 0)),
             "--n-envs", str(run["n_envs"])]
    for flag, key in (("--param-sharing", "param_sharing"), ("--centralised-critic", "centralised_critic")):
        if run.get(key):
            words.append(flag)
    if run.get("normalize") is False:
        words.append("--no-normalize")
    for option, key in (("--env-kwargs", "env_kwargs"), ("--algo-kwargs", "algo_kwargs")):
        if run.get(key):
            words += [option, json.dumps(run[key], sort_keys=True)]
    for option, key in (("--critic-warmup", "critic_warmup"), ("--cost-limit", "cost_limit"),
                        ("--lagrangian-lr", "lagrangian_lr")):
        if key in run:
            words += [option, str(run[key])]
    if run.get("team_sizes"):
        words += ["--team-sizes", ",".join(str(n) for n in run["team_sizes"])]
    words += ["--timesteps", str(run["timesteps"] if timesteps is None else timesteps), "--out", str(out)]
    return shlex.join([*words, *(["--resume"] if resume else [])])
