"""Boundary checks: the shared validators, env options and the shield's arguments."""

import numpy as np
import pytest

from pan1_env.environment import parallel_env
from pan1_env.validation import float_array, positive_int, real, whole_ratio
from pan1_env.wrappers import SafetyShield


@pytest.mark.parametrize("value, match", [("1", "number"), (True, "number"), (float("nan"), "finite"),
                                          (float("inf"), "finite"), (-1.0, "positive"), (0, "positive")])
def test_real_rejects(value, match) -> None:
    with pytest.raises(ValueError, match=match):
        real("x", value, positive=True)


def test_real_and_int_accept_numpy_scalars() -> None:
    assert real("x", np.float32(0.5), positive=True) == 0.5
    assert positive_int("n", np.int64(3)) == 3
    with pytest.raises(ValueError, match="integer"):
        positive_int("n", 2.0)
    assert whole_ratio("a", 0.05, "b", 0.001) == 50
    with pytest.raises(ValueError, match="whole multiple"):
        whole_ratio("a", 0.0015, "b", 0.001)


@pytest.mark.parametrize("value, match", [
    ({"arm_0": [0.0]}, r"action must be an array of numbers of shape \(3,\), got dict \{'arm_0': \[0.0\]\}"),
    ("full", r"action must be an array of numbers of shape \(3,\), got str 'full'"),
    ([1.0, [2.0], 3.0], r"action must be an array of numbers of shape \(3,\), got list"),
    ({i: i for i in range(100)}, r"got dict \{0: 0, .*\.\.\.$"),
    (None, r"action must have shape \(3,\), got \(\)"),
    (np.zeros(4), r"action must have shape \(3,\), got \(4,\)"),
])
def test_float_array_names_the_shape_and_what_it_got(value, match) -> None:
    with pytest.raises(ValueError, match=match):
        float_array("action", value, (3,))


def test_float_array_passes_numbers_through() -> None:
    out = float_array("action", [1, 2.5, np.float32(3)], (3,))
    assert out.dtype == float and out.tolist() == [1.0, 2.5, 3.0]
    assert np.isnan(float_array("action", [np.nan, 0, 0], (3,))[0])  # NaN is the caller's to report


@pytest.mark.parametrize("kwargs, match", [
    ({"physics_dt": 0.05, "control_dt": 0.05}, "too long for the tracker gain"),
    ({"control_dt": np.float32(0.05)}, None),
    ({"qp_solver": "osqp"}, "qp_solver"),
    ({"max_joint_speed": "2"}, "max_joint_speed must be a number"),
])
def test_env_arguments(kwargs, match) -> None:
    if match is None:
        assert parallel_env("paper_pa3_square", **kwargs).dt == pytest.approx(0.05)
    else:
        with pytest.raises(ValueError, match=match):
            parallel_env("paper_pa3_square", **kwargs)


def test_a_time_step_in_random_options_is_refused_with_the_envs_own() -> None:
    """An env steps at its own control_dt and physics_dt: the drawn team's (random_options', which an env would
    ignore) are refused, naming the argument to use; the default values, or a RandomScenarioOptions left at them,
    pass."""
    from pan1_env.random_scenario import RandomScenarioOptions

    for options in ({"control_dt": 0.01}, RandomScenarioOptions(physics_dt=0.0005)):
        with pytest.raises(ValueError, match=r"random_options (control|physics)_dt=0\.0\d+: an env steps at its own "
                                             r"(control|physics)_dt; pass (control|physics)_dt= to the env"):
            parallel_env("random", random_options=options)
    assert parallel_env("random", random_options=RandomScenarioOptions(), control_dt=0.1).dt == 0.1
    assert parallel_env("pan1_env/RandomFormation-v1", random_options={"n_arms": 3}).dt == 0.05


def test_shield_arguments_and_double_wrapping() -> None:
    from pan1_env.safety import FilterParams

    base = parallel_env("paper_pa3_square")
    with pytest.raises(ValueError, match="tracking_bound must be a number"):
        FilterParams.of(base.scenario, tracking_bound="0.1")
    env = SafetyShield(parallel_env("paper_pa3_square"))
    with pytest.raises(ValueError, match="already shielded"):
        SafetyShield(env)


def test_piqp_shield_matches_active_set_in_the_env() -> None:
    rollouts = []
    for solver in ("active_set", "piqp"):
        env = SafetyShield(parallel_env("paper_pa_mixed_square", qp_solver=solver, max_steps=20))
        obs, _ = env.reset(seed=0)
        rng = np.random.default_rng(0)
        out, solved = [], 0
        while env.agents:
            obs, _, _, _, infos = env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})
            out.append(np.concatenate([obs[a] for a in env.possible_agents]))
            solved += infos["arm_3"]["qp_counts"][1]
        rollouts.append((np.array(out), solved))
    assert rollouts[0][1] == rollouts[1][1] > 0
    np.testing.assert_allclose(rollouts[0][0], rollouts[1][0], atol=1e-4)
