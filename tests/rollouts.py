"""Rollout helpers shared by the tests: random actions for any view, a bit-exact record of what each step
returned (for the tests that compare two envs step by step: pickled copies, rejected actions), and a whole
episode's safety record (for the shield's tests)."""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np


def random_actions(env, rng: np.random.Generator):
    if isinstance(env, gymnasium.Env):
        return rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
    return {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}


def random_policy(env, seed: int):
    """A policy of seeded uniform random actions for ``env`` (any view)."""
    rng = np.random.default_rng(seed)
    return lambda obs: random_actions(env, rng)


def safety_episode(env, policy, seed: int) -> dict[str, float]:
    """Run a parallel env to its end under ``policy``: the total cost, the smallest clearance over every
    sub-step, and the arm-steps in which the shield changed the action or fell back (0 without a shield)."""
    obs, _ = env.reset(seed=seed)
    out = {"cost": 0.0, "clearance": np.inf, "interventions": 0, "fallbacks": 0}
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        for info in infos.values():
            out["cost"] += info["cost"]
            out["clearance"] = min(out["clearance"], info["min_clearance"])
            out["interventions"] += int(info.get("shield_intervened", False))
            out["fallbacks"] += int(info.get("shield_fallback", False))
    return out


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


def model_acts_alike_on_both_views(path, scenario: str, seed: int = 3) -> dict[str, np.ndarray]:
    """A trained model's first actions on the team vector env (``model_policy``, flat rows) and on the parallel
    env (``sb3_policy``, per agent) after the same seeded reset agree; returns the per-agent ones."""
    from pan1_env.baselines.evaluation import model_policy
    from pan1_env.baselines.sb3 import sb3_policy
    from pan1_env.environment import parallel_env
    from pan1_env.vector import Pan1VectorEnv

    flat_policy, env_kwargs = model_policy(path)
    penv = parallel_env(scenario, **env_kwargs)
    obs, _ = penv.reset(seed=seed)
    flat, _ = Pan1VectorEnv(scenario, 1, **env_kwargs).reset(seed=[seed])
    by_agent = sb3_policy(path, penv)(obs)
    np.testing.assert_allclose(flat_policy(flat)[0], np.concatenate([by_agent[a] for a in penv.agents]), atol=1e-6)
    return by_agent


def reference_and_law(make_env, seed: int, steps: int, action_seed: int = 0):
    """A residual-mode env from ``make_env(**kw)`` after ``steps`` steps of seeded uniform actions in [−½, ½], with
    the reference policy's actions from its observations beside the env's own law from its state (the residual
    mode's zero action) for every agent: ``(env, observations, [(law, reference), …], policy)``, the law's entries
    those of the agent's action, and the reference policy (reading ``env``)."""
    from pan1_env.baselines import ReferencePolicy

    env = make_env(action_mode="residual")
    ref = ReferencePolicy(make_env())
    ref.env = env
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    for _ in range(steps):
        obs, *_ = env.step({a: rng.uniform(-0.5, 0.5, env.action_space(a).shape) for a in env.agents})
    law = env.task.nominal_velocity(env.engine)[0] / env.config.max_joint_speed
    pairs = [(law[i, : env.n_actuated[i]], ref.act(agent, obs[agent])) for i, agent in enumerate(env.agents)]
    return env, obs, pairs, ref


def reference_episode(team, patch=None):
    """One episode of the reference policy behind the shield on ``team`` (``patch(env)`` applied after the reset,
    to alter the task): ``(env, last observations, last infos, times (s), formation errors)`` per step."""
    from pan1_env.baselines import ReferencePolicy
    from pan1_env.environment import parallel_env

    env = parallel_env(team, safety_filter=True)
    policy = ReferencePolicy(env)
    obs, _ = env.reset(seed=0)
    if patch is not None:
        patch(env)
        env.task._tracked = None  # the patch changes how the targets are computed: not the reset's any more
    errors, infos = [], None
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        errors.append(infos["arm_0"]["formation_error"])
    return env, obs, infos, env.dt * np.arange(1, len(errors) + 1), np.array(errors)
