"""Rollout helpers shared by the tests that compare two envs step by step (pickled copies, rejected
actions): random actions for any view, and a bit-exact record of what each step returned."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np


def random_actions(env, rng: np.random.Generator):
    if isinstance(env, gymnasium.Env):
        return rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
    return {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}


def bits(x: Any) -> Any:
    """A comparable, bit-exact image of an observation, reward or info (NaN == NaN, −0 ≠ +0)."""
    if isinstance(x, dict):
        return {k: bits(v) for k, v in sorted(x.items())}
    if isinstance(x, (np.ndarray, np.generic, float)):
        a = np.asarray(x)
        return (a.dtype.str, a.shape, a.tobytes())
    return x


def _cost(info: dict) -> Any:
    if "cost" in info:  # the Gymnasium view: the team's total
        return info["cost"]
    return {a: i["cost"] for a, i in info.items()}


def replay(env, actions: list) -> list:
    out = []
    for act in actions:
        obs, reward, term, trunc, info = env.step(act)
        out.append((bits(obs), bits(reward), bits(term), bits(trunc), _cost(info), bits(info)))
    return out
