"""A rejected action (NaN, inf, a wrong shape or type, a wrong container) raises ValueError and leaves
the env exactly as it was: it then steps as a twin that never saw the bad action."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from rollouts import random_actions, replay

import pan1_env  # noqa: F401  (registers the Gymnasium ids)
from pan1_env.environment import parallel_env
from pan1_env.wrappers import SafetyShield

_BAD_PARALLEL = {  # mode, corruption of a good action dict, what the error says
    "torque_inf": ("torque", lambda good: {**good, "arm_1": np.array([0.0, np.inf, 0.0], np.float32)}, "NaN or inf"),
    "torque_minus_inf": ("torque", lambda good: {**good, "arm_0": np.array([-np.inf, 0.0, 0.0])}, "NaN or inf"),
    "torque_nan": ("torque", lambda good: {**good, "arm_3": np.array([0.0, 0.0, np.nan])}, "NaN or inf"),
    "torque_string": ("torque", lambda good: {**good, "arm_2": "full"},
                      r"action for arm_2 must be an array of numbers of shape \(3,\), got str 'full'"),
    "torque_dict": ("torque", lambda good: {**good, "arm_1": {"q": 1.0}},
                    r"action for arm_1 must be an array of numbers of shape \(3,\), got dict \{'q': 1.0\}"),
    "velocity_ragged": ("velocity", lambda good: {**good, "arm_0": [0.1, [0.2, 0.3], 0.4]},
                        r"action for arm_0 must be an array of numbers of shape \(3,\), got list"),
    "torque_none": ("torque", lambda good: {**good, "arm_2": None}, "shape"),
    "velocity_list_not_dict": ("velocity", lambda good: list(good.values()), "dict keyed by agent"),
    "velocity_scalar": ("velocity", lambda good: {**good, "arm_0": 0.5}, "shape"),
}


@pytest.mark.parametrize("shielded", [False, True], ids=["plain", "shielded"])
@pytest.mark.parametrize("case", sorted(_BAD_PARALLEL))
def test_rejected_action_leaves_no_trace(case: str, shielded: bool) -> None:
    mode, corrupt, match = _BAD_PARALLEL[case]

    def make():
        env = parallel_env("paper_pa3_square", action_mode=mode)
        return SafetyShield(env) if shielded else env

    env, twin = make(), make()
    rng = np.random.default_rng(1)
    env.reset(seed=0)
    twin.reset(seed=0)
    for _ in range(3):  # mid-episode, with a previous command and v* in the state
        act = random_actions(env, rng)
        env.step(act)
        twin.step(act)
    good = random_actions(env, rng)
    with pytest.raises(ValueError, match=match):
        env.step(corrupt(good))
    assert env.unwrapped.num_steps == twin.unwrapped.num_steps == 3
    for _ in range(5):
        act = random_actions(env, rng)
        assert replay(env, [act]) == replay(twin, [act])


_GYM_VIEW_MESSAGES = {
    "nan": "NaN or inf", "inf": "NaN or inf", "short": r"shape \(12,\), got \(11,\)",
    "long": r"shape \(12,\), got \(13,\)",
    "dict": r"action must be an array of numbers of shape \(12,\), got dict \{'arm_0'",
    "string": r"action must be an array of numbers of shape \(12,\), got str 'zeros'",
}


@pytest.mark.parametrize("bad", sorted(_GYM_VIEW_MESSAGES))
def test_gym_view_rejects_bad_action_without_trace(bad: str) -> None:
    env, twin = gymnasium.make("pan1_env/PaperPA3Square-v0"), gymnasium.make("pan1_env/PaperPA3Square-v0")
    rng = np.random.default_rng(2)
    env.reset(seed=0)
    twin.reset(seed=0)
    for _ in range(2):
        act = random_actions(env, rng)
        env.step(act)
        twin.step(act)
    action = random_actions(env, rng)
    if bad in ("nan", "inf"):
        action[4] = np.nan if bad == "nan" else np.inf
    elif bad in ("short", "long"):
        action = action[:-1] if bad == "short" else np.append(action, 0.0)
    elif bad == "dict":  # the parallel env's per-agent dict, given to the one-agent view
        action = {f"arm_{i}": part for i, part in enumerate(np.split(action, 4))}
    else:
        action = "zeros"
    with pytest.raises(ValueError, match=_GYM_VIEW_MESSAGES[bad]):
        env.step(action)
    for _ in range(5):
        act = random_actions(env, rng)
        assert replay(env, [act]) == replay(twin, [act])
