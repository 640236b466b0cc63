"""Boundary checks added with the unified engine: simulation, env options, shield, reproduce."""

import numpy as np
import pytest

from pan1_env import experiment, scenario
from pan1_env.environment import parallel_env
from pan1_env.random_scenario import RandomScenarioOptions
from pan1_env.simulation import Simulation
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


def test_random_scenario_options_attributes_are_one_list() -> None:
    """Google style: the Attributes section is one list with an entry per field, nothing in between."""
    import dataclasses
    import inspect

    doc = inspect.cleandoc(RandomScenarioOptions.__doc__)
    head, _, section = doc.partition("\nAttributes:\n")
    assert section, "no Attributes section"
    names = []
    for line in section.splitlines():
        assert line.startswith("    "), f"not part of the attribute list: {line!r}"
        if not line.startswith("     "):  # an entry ("name: text"); deeper lines continue it
            name, sep, text = line.strip().partition(": ")
            assert sep and name.isidentifier() and text, f"not an attribute entry: {line!r}"
            names.append(name)
    assert names == [f.name for f in dataclasses.fields(RandomScenarioOptions)]


def test_simulation_rejects_bad_q0_and_substeps() -> None:
    sim = Simulation(scenario.load("paper_pa3_square"))
    with pytest.raises(ValueError, match=r"q0\[0\] must be 4 finite"):
        sim.reset([np.zeros(3)] * 4)
    with pytest.raises(ValueError, match="one configuration per arm"):
        sim.reset([np.zeros(4)] * 3)
    with pytest.raises(ValueError, match="finite"):
        sim.reset([np.array([np.nan, 0, 0, 0])] * 4)
    for bad in (0, -3, 2.7, True):
        with pytest.raises(ValueError, match="substeps"):
            sim.step(np.zeros((4, 3)), bad)
    assert sim.time == 0.0


@pytest.mark.parametrize("kwargs, match", [
    ({"physics_dt": 0.05, "control_dt": 0.05}, "too long for the tracker gain"),
    ({"control_dt": np.float32(0.05)}, None),
    ({"qp_solver": "osqp"}, "qp_solver"),
    ({"max_joint_speed": "2"}, "max_joint_speed must be a number"),
])
def test_env_arguments(kwargs, match) -> None:
    if match is None:
        assert parallel_env("paper_pa3_square", **kwargs).control_dt == pytest.approx(0.05)
    else:
        with pytest.raises(ValueError, match=match):
            parallel_env("paper_pa3_square", **kwargs)


@pytest.mark.parametrize("options, match", [
    ({"size": 0.5}, "size must be a range"),
    ({"passive_fraction": "half"}, "passive_fraction must be a number"),
    ({"passive_fraction": 1.5}, r"\[0, 1\]"),
    ({"kp": "2"}, "kp must be a number"),
    ({"links": (2, 3)}, "links must be"),
    ({"n_arms": 1}, "n_arms"),
    ({"colour": "red"}, "unknown option 'colour'"),
])
def test_random_options_errors(options, match) -> None:
    with pytest.raises(ValueError, match=match):
        parallel_env("random", random_options=options)


def test_shield_arguments_and_double_wrapping() -> None:
    with pytest.raises(ValueError, match="tracking_bound must be a number"):
        SafetyShield(parallel_env("paper_pa3_square"), tracking_bound="0.1")
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
            solved += infos["arm_3"]["shield"]["qp_counts"][1]
        rollouts.append((np.array(out), solved))
    assert rollouts[0][1] == rollouts[1][1] > 0
    np.testing.assert_allclose(rollouts[0][0], rollouts[1][0], atol=1e-4)


def test_reproduce_holds_the_nominal_law_over_control_dt(tmp_path) -> None:
    text = scenario.resources.files("pan1_env.scenarios").joinpath("paper_pa_mixed_square.toml").read_text()
    path = tmp_path / "held.toml"
    path.write_text(text.replace("control_dt = 0.001", "control_dt = 0.01"))
    sc = scenario.load(path)
    held = experiment.run(sc, "safe", horizon=2.0).metrics
    every = experiment.run(scenario.load("paper_pa_mixed_square"), "safe", horizon=2.0).metrics
    assert held["control_dt"] == pytest.approx(0.01) and held["physics_dt"] == pytest.approx(0.001)
    assert held["steps"] == every["steps"] == 2000
    # holding v0 for 10 ms changes the run a little, not a lot (arm 0 moves freely)
    assert held["final_max_edge_error_m"] != every["final_max_edge_error_m"]
    assert held["arms"][0]["min_clearance_m"] != every["arms"][0]["min_clearance_m"]
    assert abs(held["final_max_edge_error_m"] - every["final_max_edge_error_m"]) < 0.02


def test_reproduce_refuses_absurd_sample_counts() -> None:
    with pytest.raises(ValueError, match="trajectory samples"):
        experiment.run(scenario.load("paper_pa3_square"), "safe", horizon=1e9)
