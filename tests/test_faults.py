"""An arm that loses its first joint's actuator during an episode (docs/MODEL.md §7): the engine's switch to
the arm's PAn−1 model, checked against an engine whose team has that arm passive from the fault's state on
(:meth:`Engine.set_state`, itself checked against the numpy reference in tests/test_passive_momentum.py),
and the momentum a frictionless fault leaves, read back from the joint speeds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from geometry import inter_arm_clearances, joints, obstacle_clearances

from pan1_env import scenario
from pan1_env.dynamics import mass_matrix
from pan1_env.engine import Engine, Physics
from pan1_env.random_scenario import RandomScenarioOptions, random_scenario


def _mixed(fault_times) -> scenario.Scenario:
    """The paper's mixed team (three full 2-link arms, one PA2) with these fault times."""
    return dataclasses.replace(scenario.load("paper_pa_mixed_square"), fault_times=fault_times)


def _passive(team: scenario.Scenario, arms) -> scenario.Scenario:
    """``team`` with the first joint of ``arms`` passive from the start, and no faults."""
    new = tuple(dataclasses.replace(arm, passive_first_joint=True) if i in arms else arm
                for i, arm in enumerate(team.arms))
    return dataclasses.replace(team, arms=new, fault_times=None)


def _torques(rng, steps, shape):
    return rng.uniform(-0.6, 0.6, (steps, *shape))


def _whole_arm_team(seed: int, fault_times=None, inter_arm: bool = True) -> scenario.Scenario:
    """A random team of four full 3-link arms, whole-arm safety (with other arms) and moving obstacles."""
    options = RandomScenarioOptions(links=3, passive_fraction=0.0, bodies="links", link_radius=0.02,
                                    inter_arm=inter_arm, obstacle_speed=(0.05, 0.2), physics_dt=0.002, control_dt=0.02)
    team = random_scenario(np.random.default_rng(seed), options)
    return dataclasses.replace(team, fault_times=fault_times)


@pytest.mark.parametrize("bodies", ["end_effector", "links", "links_and_arms"])
def test_a_fault_mid_step_equals_a_passive_arm_from_the_faults_state(bodies: str) -> None:
    """Torque mode, 10 sub-steps per step: arm 0 faults inside the third step, at 23.4 sub-steps (from the
    start of the sub-step that contains it, the 24th), arm 2 inside the sixth. Until a fault the engine is
    the team without faults; from it, the team with that arm passive, put at the fault's joint angles and
    speeds, its lost joint's command ignored. Whole-arm: a random team of 3-link arms with moving obstacles,
    and other arms (their filters must see the faulted arm where it is), the filter on; the one-call step
    (kernel windows) and the inter-arm one (a call per sub-step)."""
    rng = np.random.default_rng(5)
    whole_arm = bodies != "end_effector"
    dt = 0.002 if whole_arm else 0.001
    times = [23.4 * dt, np.inf, 51 * dt, np.inf]
    team = _whole_arm_team(2, times, bodies == "links_and_arms") if whole_arm else _mixed(times)
    n = team.arms[0].n_links
    kw = dict(safety_filter=whole_arm, physics=Physics(max_joint_speed=3.0 if whole_arm else np.inf))
    faulty = Engine(team, 1, **kw)
    plain = Engine(dataclasses.replace(team, fault_times=None), 1, **kw)
    tau = _torques(rng, 9, (1, 4, n))
    before = 3  # sub-steps of the third step before the one that contains arm 0's fault
    acted = 0

    def lost_joint(command):
        command = command.copy()
        command[0, 0] = np.append(command[0, 0, 1:], np.nan)  # its actuated joints are 2 … n
        return command

    for s in range(5):
        rec = faulty.step(tau[s], 10, torque=True)
        if s == 2:
            first = plain.step(tau[s], before, torque=True)
            q, qd = plain.joint_state()
            passive = Engine(_passive(team, {0}), 1, **kw)
            passive.set_state(0, list(q[0]), list(qd[0]))
            passive.elapsed[:] = plain.elapsed  # the moving obstacles where they are
            passive.place_obstacles()
            alone = passive.step(lost_joint(tau[s]), 10 - before, torque=True)
            # the fault's step: the smallest clearance of its sub-steps before the fault and after it (the twin
            # must see the obstacles at the step's clock, not where they were when its rows last ran)
            np.testing.assert_allclose(rec.min_clearance, np.minimum(first.min_clearance, alone.min_clearance),
                                       rtol=0, atol=1e-12)
        elif s < 2:
            plain.step(tau[s], 10, torque=True)
            np.testing.assert_array_equal(faulty.joint_state()[0], plain.joint_state()[0])
            assert not np.isfinite(faulty.passive_momentum()[0, :3]).any()
            continue
        else:
            alone = passive.step(lost_joint(tau[s]), 10, torque=True)
            # the same sub-steps: the bodies' clearance to the obstacles where they are, and to the other arms
            np.testing.assert_allclose(rec.min_clearance, alone.min_clearance, rtol=0, atol=1e-12)
            assert np.isfinite(rec.min_clearance[0, 0])  # arm 0 can reach an obstacle
        for got, expected in zip(faulty.joint_state(), passive.joint_state(), strict=True):
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(faulty.passive_momentum()[0, 0], passive.passive_momentum()[0, 0], rtol=0,
                                   atol=1e-12)
        assert rec.tau[0, 0, 0] == 0.0 and np.isnan(rec.v_star[0, 0, 0])
        assert np.isfinite(rec.v_star[0, 0, 1:]).all() == whole_arm  # v* is filtered (unfiltered torque mode: NaN)
        assert faulty.faulted[0].tolist() == [True, False, False, False]
        acted += rec.qp_counts[0, :, 1:].sum()
    assert abs(faulty.passive_momentum()[0, 0]) > 1e-3, "the fault came while the arm moved"
    assert (acted > 0) == whole_arm, "the filter should act on the faulted team"
    faulty.step(tau[5], 10, torque=True)
    assert faulty.faulted[0].tolist() == [True, False, True, False]


def test_frictionless_fault_conserves_the_momentum_and_a_reset_restores_the_actuator() -> None:
    """b = 0: after a fault at 0.5 s into a shielded, speed-bounded velocity-mode run, p₁ = Σ_α M_1α q̇_α,
    from the engine's float64 joint state, stays what it was at the fault to 1e-9 relative over 100 s
    (10 ms sub-steps). A reset gives the arm its actuator back, and the fault comes again at its time."""
    team = _mixed([0.5, np.inf, np.inf, np.inf])
    engine = Engine(team, 1, physics=Physics(physics_dt=0.01, max_joint_speed=2.0), safety_filter=True)
    arm = team.arms[0]
    command = np.zeros((1, 4, 2))
    command[0, :3] = [1.5, -1.0]
    command[0, 3] = [1.0, 0.0]

    def momentum() -> float:
        q, qd = engine.joint_state()
        return float(mass_matrix(arm, q[0, 0, :2])[0] @ qd[0, 0, :2])

    engine.step(command, 50)
    assert engine.faulted[0, 0] and engine.elapsed[0] == pytest.approx(0.5)
    start = momentum()
    assert abs(start) > 0.05
    assert engine.passive_momentum()[0, 0] == pytest.approx(start, rel=1e-12)
    for _ in range(100):
        engine.step(command, 100)
        assert abs(momentum() - start) <= 1e-9 * abs(start)
    engine.reset()
    assert not engine.faulted.any() and np.isnan(engine.passive_momentum()[0, 0])
    rec = engine.step(command, 10)
    assert np.isfinite(rec.v_star[0, 0, 0]) and rec.tau[0, 0, 0] != 0.0, "actuated again after the reset"
    engine.step(command, 45)
    assert engine.faulted[0, 0], "the fault comes again at 0.5 s after the reset"


@pytest.mark.parametrize("threads", [False, True])
def test_copies_fault_on_their_own(threads: bool) -> None:
    """Whole-arm safety with other arms and moving obstacles, filter on: three copies of two teams, whose arms
    fault at different times (copy 1: none), each equal to its team alone in a one-copy engine, through a
    fault, another copy's fault and a reset of one copy."""
    times = ([0.05, np.inf, 0.13, np.inf], [np.inf] * 4, [0.0, 0.09, np.inf, 0.031])
    teams = [_whole_arm_team(7, times[0]), _whole_arm_team(8, times[1]), _whole_arm_team(7, times[2])]
    kw = dict(safety_filter=True, physics=Physics(max_joint_speed=3.0), threads=threads)
    batch = Engine(teams[0], 3, **kw)
    for b, team in enumerate(teams):
        batch.load_team(b, team)
    batch.reset()
    alone = [Engine(team, 1, **kw) for team in teams]
    rng = np.random.default_rng(9)
    for s in range(14):
        command = rng.uniform(-2.0, 2.0, (3, 4, 3))
        rec = batch.step(command, 10)
        recs = [engine.step(command[b: b + 1], 10) for b, engine in enumerate(alone)]
        for b, (engine, one) in enumerate(zip(alone, recs, strict=True)):
            for got, expected in zip(batch.joint_state(), engine.joint_state(), strict=True):
                np.testing.assert_allclose(got[b], expected[0], rtol=0, atol=1e-12)
            np.testing.assert_allclose(batch.passive_momentum()[b], engine.passive_momentum()[0], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(rec.qp_counts[b], one.qp_counts[0])
            np.testing.assert_allclose(rec.min_clearance[b], one.min_clearance[0], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(np.isnan(rec.v_star[b]), np.isnan(one.v_star[0]))
            np.testing.assert_array_equal(batch.faulted[b], engine.faulted[0])
        if s == 8:
            batch.reset(np.array([2]))
            alone[2].reset()
    assert batch.faulted[0, [0, 2]].all() and not batch.faulted[1].any()
    assert rec.qp_counts[:, :, 1:].sum() > 0, "the filter should act"


def test_the_geometry_follows_a_faulted_arm() -> None:
    """Whole-arm safety with other arms, one sub-step per step, the filter on: every step's smallest clearance
    of every arm, to the obstacles and to the other arms, is an independent geometry's at the joint angles
    the engine reports, before arm 0's fault, after it (arm 0's smallest is to another arm) and after a
    reset."""
    team = _whole_arm_team(15, [0.02, np.inf, np.inf, np.inf])
    engine = Engine(team, 1, physics=Physics(max_joint_speed=3.0), safety_filter=True)
    rng = np.random.default_rng(2)
    rho, binding = team.link_radius, 0
    for s in range(40):
        rec = engine.step(rng.uniform(-0.5, 0.5, (1, 4, 3)), 1, torque=True)
        q, _ = engine.joint_state()
        arms = [joints(q[0, i], arm.lengths, arm.base, arm.phi) for i, arm in enumerate(team.arms)]
        to_obstacles = [c.min() for c in obstacle_clearances(arms, engine.centers[0], engine.radii[0], rho)]
        between = inter_arm_clearances(arms, rho)
        to_arms = [min(c.min() for pair, c in between.items() if i in pair) for i in range(4)]
        np.testing.assert_allclose(rec.min_clearance[0], np.minimum(to_obstacles, to_arms), rtol=0, atol=1e-9)
        binding += engine.faulted[0, 0] and to_arms[0] < to_obstacles[0]
        if s == 25:
            engine.reset()
    assert binding >= 10, "arm 0's clearance to another arm should be its smallest after its fault"


def test_a_reset_after_a_fault_is_a_fresh_engine() -> None:
    """Whole-arm safety with other arms, velocity mode, filter on: after faults and a reset, the engine steps
    as a fresh one, bit for bit, through the faults that come again."""
    team = _whole_arm_team(15, [0.02, 0.05, np.inf, 0.0])
    kw = dict(safety_filter=True, physics=Physics(max_joint_speed=3.0))
    used, fresh = Engine(team, 2, **kw), Engine(team, 2, **kw)
    rng = np.random.default_rng(4)
    for _ in range(6):
        used.step(rng.uniform(-2.0, 2.0, (2, 4, 3)), 10)
    assert used.faulted.sum() == 6
    used.reset()
    for _ in range(6):
        command = rng.uniform(-2.0, 2.0, (2, 4, 3))
        rec, expected = used.step(command, 10), fresh.step(command, 10)
        for got, want in zip(used.joint_state(), fresh.joint_state(), strict=True):
            np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(rec.min_clearance, expected.min_clearance)
        np.testing.assert_array_equal(rec.qp_counts, expected.qp_counts)
    assert used.faulted.sum() == 6


def test_fault_times_are_checked() -> None:
    with pytest.raises(ValueError, match=r"fault_times\[3\]: arm 3's first joint is passive already"):
        _mixed([np.inf, np.inf, np.inf, 1.0])
    with pytest.raises(ValueError, match=r"fault_times\[0\] must lie within the episode, \[0, 100\] s"):
        _mixed([100.5, np.inf, np.inf, np.inf])
    with pytest.raises(ValueError, match=r"fault_times\[1\] must lie within the episode"):
        _mixed([np.inf, -0.1, np.inf, np.inf])
    with pytest.raises(ValueError, match="one time per arm"):
        _mixed([1.0])
    engine = Engine(scenario.load("paper_pa_mixed_square"), 2)
    with pytest.raises(ValueError, match="fault_times only if the engine's first team had them"):
        engine.load_team(1, _mixed([1.0, np.inf, np.inf, np.inf]))
    with pytest.raises(ValueError, match="qp_solver='piqp' does not step arms that lose an actuator"):
        Engine(_mixed([1.0, np.inf, np.inf, np.inf]), 1, physics=Physics(qp_solver="piqp"), safety_filter=True)
