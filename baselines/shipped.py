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

__all__ = ["pretrained", "available", "model_for", "PRETRAINED_DIR"]

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"


def available() -> dict[str, dict[str, Any]]:
    """Every shipped model by name, with its metadata (``<name>.json``)."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(PRETRAINED_DIR.glob("*.json"))
            if p.with_suffix(".zip").exists()}


def model_for(scenario_name: str) -> str:
    """The name of the model trained for ``scenario_name`` (ValueError if none ships)."""
    matches = [name for name, meta in available().items() if meta.get("scenario") == scenario_name]
    if not matches:
        shipped = {name: meta.get("scenario") for name, meta in available().items()}
        raise ValueError(f"no pretrained model for scenario {scenario_name!r}; shipped: {shipped or 'none'}")
    return matches[0]


def pretrained(name: str, env):
    """The shipped model ``name`` as a policy on ``env`` (dict of observations → dict of actions).
    A model trained on residual actions runs on a velocity-mode env (the reference law is added)."""
    from .policies import _sb3_policy

    models = available()
    if name not in models:
        raise ValueError(f"no pretrained model {name!r}; shipped: {sorted(models) or 'none'}")
    return _sb3_policy(PRETRAINED_DIR / f"{name}.zip", env)
