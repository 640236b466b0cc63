"""The paper's closed loop: pan1_env.simulation (one copy of a team, stepped with given commands) and
experiment.run, which drives it with the nominal or the safe controller."""

from __future__ import annotations

import numpy as np
import pytest

from pan1_env import experiment, scenario
from pan1_env.simulation import Simulation


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


def _max_edge_error(sim: Simulation) -> float:
    formation = sim.scenario.formation
    p = sim.positions()
    lengths = [np.linalg.norm(p[i] - p[j]) for i, j in formation.edges]
    return float(np.max(np.abs(np.asarray(lengths) - formation.distances)))


@pytest.mark.parametrize("name", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_the_nominal_law_shrinks_the_formation_error(name: str) -> None:
    sim = Simulation(scenario.load(name), safety_filter=False)
    sim.reset()
    start = _max_edge_error(sim)
    for _ in range(200):  # 2 s of 10 ms control periods, 1 ms physics steps
        sim.step(sim.nominal_velocity(), 10)
    assert sim.time == pytest.approx(2.0)
    assert _max_edge_error(sim) < 0.8 * start


def test_the_passive_joints_momentum_stays_zero_from_rest() -> None:
    # no torque acts on a passive first joint and nothing else depends on its angle: its momentum is conserved
    sim = Simulation(scenario.load("paper_pa_mixed_square"), safety_filter=False)
    sim.reset()
    passive = [i for i, arm in enumerate(sim.scenario.arms) if arm.passive_first_joint]
    assert passive
    for _ in range(100):
        sim.step(sim.nominal_velocity(), 10)
    q, qd = sim.joint_state()
    assert np.abs(qd[passive]).max() > 1e-3, "the passive joints should move"
    np.testing.assert_allclose(sim.passive_momentum()[passive], 0.0, atol=1e-6)


def test_the_safe_loop_stays_clear_and_reset_returns_to_the_start() -> None:
    sim = Simulation(scenario.load("paper_pa3_square"), safety_filter=True)
    sim.reset()
    start = sim.positions().copy()
    for _ in range(100):
        record = sim.step(sim.nominal_velocity(), 10)
        assert record.all_finite
    assert np.all(sim.min_clearance >= 0.0)
    assert not np.allclose(sim.positions(), start)
    sim.reset()
    assert sim.time == 0.0
    np.testing.assert_allclose(sim.positions(), start, atol=1e-12)


def test_the_command_must_have_the_teams_shape() -> None:
    sim = Simulation(scenario.load("paper_pa_mixed_square"))
    sim.reset()
    with pytest.raises(ValueError, match="command must have shape"):
        sim.step(np.zeros((4, 1)), 1)
    assert sim.time == 0.0
