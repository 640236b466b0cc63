"""Torque mode's input bound (docs/MODEL.md §5d) as the env's option ``torque_bound``: wired to the engine's filter
(the end-effector filter and the whole-arm one), off by default, refused when it is not a bool."""

import numpy as np
import pytest

from pan1_env.vector import Pan1VectorEnv

TEAM = {"n_arms": 4, "links": (2, 3, 4, 3), "passive_fraction": 0.5}
ENVS = {"end-effector": ("random", {"random_options": TEAM}), "whole-arm": ("pan1_env/WholeArmStaticFormation-v1", {})}


def _largest_torque_ratio(name: str, torque_bound: bool) -> float:
    """The largest |τ| / max_torque over 150 steps of random torques on 16 copies behind the shield, one physics
    sub-step a step (every torque seen)."""
    scenario, kwargs = ENVS[name]
    venv = Pan1VectorEnv(scenario, 16, action_mode="torque", control_dt=0.002, max_steps=500, max_torque=5.0,
                         torque_bound=torque_bound, **kwargs)
    assert venv.engine.physics_dt == pytest.approx(0.002)
    venv.reset(seed=3)
    rng, largest = np.random.default_rng(3), 0.0
    for _ in range(150):
        _, _, _, _, infos = venv.step(rng.uniform(-1.0, 1.0, venv.action_space.shape))
        assert infos["cost"].sum() == 0.0
        largest = max(largest, float(np.nanmax(np.abs(venv.core.record.tau))) / 5.0)
    return largest


@pytest.mark.parametrize("name", list(ENVS))
def test_the_torque_bound_holds_every_torque_and_is_needed(name: str) -> None:
    assert _largest_torque_ratio(name, True) <= 1.0 + 1e-9
    assert _largest_torque_ratio(name, False) > 2.0  # the unbounded filter's torques: what the option changes


def test_a_torque_bound_that_is_not_a_bool_is_refused() -> None:
    with pytest.raises(ValueError, match="torque_bound must be True or False"):
        Pan1VectorEnv("random", 2, random_options=TEAM, action_mode="torque", torque_bound="yes")
