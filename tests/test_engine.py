"""The engine (pan1_env.engine): resets of some copies, teams loaded into a copy, the step record, the
multi-threaded kernel against the serial one, and the PIQP filter object against the compiled QP."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from pan1_env import scenario
from pan1_env.engine import Engine, Physics
from pan1_env.kernel_step import KernelQP
from pan1_env.piqp_filter import PiqpFilter


def _commands(engine: Engine, steps: int, scale: float = 1.0, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.uniform(-scale, scale, (engine.copies, engine.n_arms, engine.k_max)) for _ in range(steps)]


def test_reset_of_some_copies_leaves_the_others() -> None:
    team = scenario.load("paper_pa3_square")
    engine = Engine(team, 3, physics=Physics(max_joint_speed=2.0), safety_filter=True)
    for command in _commands(engine, 4):
        engine.step(command, 5)
    q_before, qd_before = (x.copy() for x in engine.joint_state())
    p_before = engine.positions().copy()
    engine.reset([1])
    q, qd = engine.joint_state()
    np.testing.assert_array_equal(q[1], np.array(team.q0))
    assert np.all(qd[1] == 0.0)
    for b in (0, 2):
        np.testing.assert_array_equal(q[b], q_before[b])
        np.testing.assert_array_equal(qd[b], qd_before[b])
        # the reset recomputes every copy's end-effector from q (the kernel's came from rotated angles)
        np.testing.assert_allclose(engine.positions()[b], p_before[b], rtol=0, atol=1e-12)
    assert not np.array_equal(q_before[1], q[1]), "the steps should have moved copy 1"
    # the reset copy steps as a fresh engine's copy does
    fresh = Engine(team, 1, physics=Physics(max_joint_speed=2.0), safety_filter=True)
    command = _commands(engine, 1, seed=1)[0]
    rec, fresh_rec = engine.step(command, 5), fresh.step(command[1:2], 5)
    np.testing.assert_array_equal(engine.joint_state()[0][1], fresh.joint_state()[0][0])
    np.testing.assert_array_equal(rec.v_star[1], fresh_rec.v_star[0])


def test_reset_to_a_configuration_checks_it() -> None:
    engine = Engine(scenario.load("paper_pa3_square"))
    with pytest.raises(ValueError, match="one configuration per arm"):
        engine.reset([0], [np.zeros(4)] * 3)
    with pytest.raises(ValueError, match="finite joint angles"):
        engine.reset([0], [np.array([np.nan, 0.0, 0.0, 0.0])] * 4)
    engine.reset([0], [np.full(4, 0.1)] * 4)
    np.testing.assert_array_equal(engine.joint_state()[0][0], np.full((4, 4), 0.1))


def test_load_team_refuses_another_structure() -> None:
    team = scenario.load("paper_pa3_square")
    engine = Engine(team, 2)
    with pytest.raises(ValueError, match="team structure"):
        engine.load_team(1, scenario.load("paper_pa_mixed_square"))
    with pytest.raises(ValueError, match="K_e"):
        engine.load_team(1, dataclasses.replace(team, ke=team.ke * 2))
    with pytest.raises(ValueError, match="protected bodies"):
        engine.load_team(1, dataclasses.replace(team, bodies="links", link_radius=0.03))
    moved = dataclasses.replace(team, arms=tuple(dataclasses.replace(a, base=a.base + 0.05) for a in team.arms))
    engine.load_team(1, moved)
    engine.reset([1])
    np.testing.assert_allclose(engine.bases[1], engine.bases[0] + 0.05)


def test_step_record_shapes_and_padding() -> None:
    team = scenario.load("paper_pa_mixed_square")
    B, N = 2, team.n_arms
    engine = Engine(team, B, physics=Physics(max_joint_speed=2.0), safety_filter=True)
    rec = engine.step(_commands(engine, 1)[0], 5)
    assert rec.v_star.shape == (B, N, engine.k_max) and rec.tau.shape == (B, N, engine.n_max)
    for name in ("min_clearance", "min_barrier", "max_tracking_error", "finite", "intervened", "fallback"):
        assert getattr(rec, name).shape == (B, N), name
    assert rec.qp_counts.shape == (B, N, 3) and rec.qp_counts.dtype == np.int64
    assert np.all(rec.qp_counts.sum(axis=-1) == 5), "one status per arm and sub-step"
    assert rec.all_finite and rec.finite.all()
    for i, arm in enumerate(team.arms):
        assert np.all(np.isnan(rec.v_star[:, i, arm.n_actuated:])), "padding beyond an arm's actuated joints"
        assert np.all(np.isfinite(rec.v_star[:, i, :arm.n_actuated]))
        assert np.all(np.isnan(rec.tau[:, i, arm.n_links:]))
        if arm.passive_first_joint:
            assert np.all(rec.tau[:, i, 0] == 0.0), "no torque on a passive joint"
    # every step hands out fresh arrays
    again = engine.step(_commands(engine, 1, seed=3)[0], 5)
    assert not np.shares_memory(again.v_star, rec.v_star) and not np.shares_memory(again.finite, rec.finite)
    with pytest.raises(ValueError, match="command must have shape"):
        engine.step(np.zeros((B, N, engine.k_max + 1)), 5)
    with pytest.raises(ValueError, match="substeps"):
        engine.step(np.zeros((B, N, engine.k_max)), 0)


@pytest.mark.parametrize("name", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_threaded_kernel_steps_as_the_serial_one_bit_for_bit(name: str) -> None:
    team = scenario.load(name)
    engines = [Engine(team, 6, physics=Physics(max_joint_speed=2.0), safety_filter=True, threads=t)
               for t in (False, True)]
    assert engines[1].chunks(6) > 0 and engines[0].chunks(6) == 0
    for command in _commands(engines[0], 10, scale=2.0):
        serial, threaded = (e.step(command, 5) for e in engines)
        for field in ("v_star", "tau", "min_clearance", "min_barrier", "qp_counts", "max_tracking_error", "finite"):
            np.testing.assert_array_equal(getattr(threaded, field), getattr(serial, field), err_msg=field)
    for a, b in zip(*(e.joint_state() for e in engines), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_engine_is_given_its_qp_solver() -> None:
    team = scenario.load("paper_pa3_square")
    assert isinstance(Engine(team).qp, KernelQP)
    piqp = Engine(team, physics=Physics(qp_solver="piqp"), safety_filter=True)
    assert isinstance(piqp.qp, PiqpFilter)
    with pytest.raises(ValueError, match="one copy"):
        Engine(team, 2, physics=Physics(qp_solver="piqp"))
    with pytest.raises(ValueError, match="torque-mode filter"):
        piqp.step(np.zeros((1, 4, 3)), 1, torque=True)
    with pytest.raises(ValueError, match="unknown qp_solver"):
        Engine(team, physics=Physics(qp_solver="osqp"))
    piqp.set_safety_filter(False)  # the filter off: the compiled step, torque mode included
    piqp.step(np.zeros((1, 4, 3)), 1, torque=True)


def test_piqp_filter_agrees_with_the_compiled_qp() -> None:
    """The same rows solved by PIQP (an interior-point method, to its tolerance) and by the exact active
    set: the same QP statuses, velocities and states within PIQP's accuracy, and the same clock."""
    team = scenario.load("paper_pa3_square")
    engines = {s: Engine(team, physics=Physics(max_joint_speed=2.0, physics_dt=0.01, qp_solver=s),
                         safety_filter=True) for s in ("active_set", "piqp")}
    counts = 0
    for command in _commands(engines["piqp"], 15, scale=2.0, seed=4):
        kernel, piqp = (e.step(command, 3) for e in engines.values())
        np.testing.assert_array_equal(piqp.qp_counts, kernel.qp_counts)
        np.testing.assert_allclose(piqp.v_star, kernel.v_star, atol=1e-6)
        np.testing.assert_allclose(piqp.min_barrier, kernel.min_barrier, atol=1e-6)
        counts = counts + kernel.qp_counts.sum(axis=(0, 1))
    assert counts[1] > 0, "the filter should change some commands"
    np.testing.assert_allclose(engines["piqp"].joint_state()[0], engines["active_set"].joint_state()[0], atol=1e-6)
    np.testing.assert_allclose(engines["piqp"].elapsed, engines["active_set"].elapsed, rtol=1e-12)
    assert engines["active_set"].elapsed[0] == pytest.approx(15 * 3 * 0.01)


def test_a_loaded_team_brings_its_damping() -> None:
    """load_team takes a team's passive_damping into the copy it loads (it is simulated, not dropped): the
    damped copy's passive momentum changes, the undamped copy's stays what it was."""
    team = scenario.load("paper_pa3_square")
    damped = dataclasses.replace(team, arms=tuple(dataclasses.replace(a, passive_damping=2.0) for a in team.arms))
    engine = Engine(team, 2, physics=Physics(physics_dt=1e-3))
    engine.load_team(1, damped)
    engine.reset()
    q = [np.array(q0) for q0 in team.q0]
    qd = [np.array([1.0, 0.0, 0.0, 0.0])] * 4
    for b in (0, 1):
        engine.set_state(b, q, qd)
    start = engine.passive_momentum().copy()
    for _ in range(200):
        engine.step(np.zeros((2, 4, 3)), 1, torque=True)
    np.testing.assert_array_equal(engine.passive_momentum()[0], start[0])
    assert np.all(np.abs(engine.passive_momentum()[1] - start[1]) > 0.01)


def test_the_physics_is_one_part_checked_where_it_is_given_or_replaced() -> None:
    """Engine takes its step's settings as one Physics: the old loose keywords are refused with the Physics call
    (another unknown keyword plainly); a replaced physics keeps the sub-step if it names none, keeps the QP solver,
    and meets the filter's checks as the filter does."""
    from pan1_env.safety import FilterParams

    team = scenario.load("paper_pa3_square")
    with pytest.raises(TypeError, match=r"Engine\(scenario, copies, physics=Physics\(max_joint_speed=2\.0\)\)"):
        Engine(team, max_speed=2.0)
    with pytest.raises(TypeError, match="unexpected keyword argument 'thread'"):
        Engine(team, thread=True)
    with pytest.raises(TypeError, match="physics must be a pan1_env.engine.Physics, got dict"):
        Engine(team, physics={"max_joint_speed": 2.0})
    engine = Engine(team, physics=Physics(max_joint_speed=2.0),
                    safety_filter=FilterParams(0.5, 5.0, sensing_radius=0.1, gate=0.05))
    assert engine.physics_dt == team.physics_dt
    engine.physics = Physics(max_joint_speed=3.0)
    assert (engine.physics_dt, engine.max_joint_speed) == (team.physics_dt, 3.0)
    engine.step(np.zeros((1, 4, 3)), 2)
    with pytest.raises(ValueError, match="keeps the QP solver it was built with"):
        engine.physics = Physics(max_joint_speed=3.0, qp_solver="piqp")
    with pytest.raises(ValueError, match="gate relaxes rows towards the speed box"):
        engine.physics = Physics()  # no speed bound: the gate cannot act
    assert engine.max_joint_speed == 3.0  # a refused physics leaves the engine's as it was
