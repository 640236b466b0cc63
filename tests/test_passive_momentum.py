"""The compiled engine with a passive momentum p₁ ≠ 0 and a damped passive joint (docs/MODEL.md §7),
checked against the numpy reference (`pan1_env.cascade`, itself checked against Pinocchio in
tests/test_fault_dynamics.py) and, for the filter's drift term, against the geometry: a PAn−1 arm
whose passive joint still turns keeps out of the obstacle its end-effector drifts into."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from geometry import joints, obstacle_clearances

from pan1_env import cascade, scenario
from pan1_env.dynamics import end_effector, jacobian, mass_matrix
from pan1_env.engine import Engine, Physics
from pan1_env.safety import Obstacles

DAMPINGS = (0.0, 0.2, 1.0, 3.0)  # N·m·s/rad, one per arm of the paper's team


def _team(dampings=DAMPINGS, obstacles: Obstacles | None = None, **fields) -> scenario.Scenario:
    team = scenario.load("paper_pa3_square")
    arms = tuple(dataclasses.replace(arm, passive_damping=b) for arm, b in zip(team.arms, dampings, strict=True))
    return dataclasses.replace(team, arms=arms, obstacles=obstacles or team.obstacles, **fields)


def _moving_state(team: scenario.Scenario, rng: np.random.Generator) -> tuple[list, list]:
    """Every arm at its start, its joints turning (the passive one too): p₁ ≠ 0."""
    q = [np.array(q0, dtype=float) for q0 in team.q0]
    qd = [rng.uniform(-1.5, 1.5, arm.n_links) for arm in team.arms]
    return q, qd


def test_damped_passive_joints_follow_the_reference() -> None:
    """Torque mode, no filter: after 300 sub-steps of 1 ms under random torques, q, v and p₁ of the engine's
    RK4 agree with cascade.momentum_cascade_rk4_step's, for dampings from 0 to 3 N·m·s/rad, with p₁ ≠ 0 from
    the start; a reset puts p₁ back to 0."""
    team = _team()
    engine = Engine(team, 1, physics=Physics(physics_dt=1e-3))
    rng = np.random.default_rng(3)
    q, qd = _moving_state(team, rng)
    engine.set_state(0, q, qd)
    state = [(qi, qdi[1:], mass_matrix(arm, qi)[0] @ qdi) for arm, qi, qdi in zip(team.arms, q, qd, strict=True)]
    start = np.array([s[2] for s in state])
    np.testing.assert_allclose(engine.passive_momentum()[0], start, rtol=0, atol=1e-14)
    for _ in range(300):
        tau = rng.uniform(-1.0, 1.0, (1, 4, 3))
        engine.step(tau, 1, torque=True)
        state = [cascade.momentum_cascade_rk4_step(arm, *s, tau[0, i], 1e-3) for i, (arm, s) in
                 enumerate(zip(team.arms, state, strict=True))]
    q_eng, qd_eng = engine.joint_state()
    for i, (arm, (qi, vi, p1)) in enumerate(zip(team.arms, state, strict=True)):
        np.testing.assert_allclose(q_eng[0, i], qi, rtol=0, atol=1e-10)
        np.testing.assert_allclose(qd_eng[0, i, 1:], vi, rtol=0, atol=1e-9)
        np.testing.assert_allclose(engine.passive_momentum()[0, i], p1, rtol=0, atol=1e-10)
        np.testing.assert_allclose(cascade.joint_velocity(arm, qi, vi, p1), qd_eng[0, i], rtol=0, atol=1e-9)
    momenta = engine.passive_momentum()[0]
    assert abs(momenta[0] - start[0]) < 1e-12, "b = 0: p₁ is constant"
    assert np.all(np.abs(momenta[1:] - start[1:]) > 1e-3), "with damping p₁ changes"
    engine.reset()
    assert np.all(engine.passive_momentum() == 0.0) and np.all(engine.joint_state()[1] == 0.0)


def test_momentum_without_damping_is_conserved_for_100_s() -> None:
    """b = 0 after the passive joint was set turning: p₁ read back from q and q̇ (Engine.joint_state, float64) stays
    p₁(0) to 1e-9 relative over 100 s of the shielded velocity mode, while the arms move."""
    team = _team(dampings=(0.0,) * 4)
    engine = Engine(team, 1, physics=Physics(physics_dt=0.01, max_joint_speed=2.0), safety_filter=True)
    q, qd = _moving_state(team, np.random.default_rng(5))
    engine.set_state(0, q, qd)
    p0 = np.array([mass_matrix(arm, qi)[0] @ qdi for arm, qi, qdi in zip(team.arms, q, qd, strict=True)])
    rng = np.random.default_rng(6)
    start = engine.joint_state()[0].copy()
    for _ in range(2000):  # 2,000 steps of 5 sub-steps of 10 ms
        engine.step(rng.uniform(-1.0, 1.0, (1, 4, 3)), 5)
    q_end, qd_end = engine.joint_state()
    assert np.abs(q_end - start).max() > 1.0, "the arms should have moved"
    p_end = np.array([mass_matrix(arm, q_end[0, i])[0] @ qd_end[0, i] for i, arm in enumerate(team.arms)])
    np.testing.assert_allclose(p_end, p0, rtol=1e-9, atol=0)


def _drifting_team(bodies: str) -> tuple[scenario.Scenario, list, list]:
    """The paper's team with its passive joints turning and no command: each end-effector drifts at
    d = J₁ p₁ / M_11; one obstacle per arm sits 4 cm ahead of it on that drift."""
    team = _team(dampings=(0.0,) * 4)
    rng = np.random.default_rng(11)
    q = [np.array(q0, dtype=float) for q0 in team.q0]
    qd = []
    centers, radii = [], []
    for arm, qi in zip(team.arms, q, strict=True):
        M = mass_matrix(arm, qi)
        qdi = np.concatenate([[rng.choice([-1.0, 1.0]) * 1.2], np.zeros(arm.n_links - 1)])
        p1 = M[0] @ qdi
        # at rest in the actuated joints the drift is q̇₁'s own motion: J₁ p₁ / M_11
        drift = jacobian(arm, qi)[:, 0] * p1 / M[0, 0]
        tip = cascade.end_effector_drift(arm, qi, p1)
        np.testing.assert_allclose(tip, drift, rtol=1e-12, atol=1e-15)
        centers.append(end_effector(arm, qi) + (0.04 + 0.03) * drift / np.linalg.norm(drift))
        radii.append(0.03)
        qd.append(qdi)
    team = dataclasses.replace(team, obstacles=Obstacles(np.array(centers), np.array(radii)), bodies=bodies)
    return team, q, qd


def _clearances(team: scenario.Scenario, q: np.ndarray, bodies: str) -> np.ndarray:
    """Every arm's smallest clearance to the obstacles, from tests/geometry.py's own kinematics."""
    out = []
    for i, arm in enumerate(team.arms):
        P = joints(q[i], arm.lengths, arm.base, arm.phi)
        if bodies == "end_effector":
            out.append((np.linalg.norm(P[-1] - team.obstacles.centers, axis=-1) - team.obstacles.radii).min())
        else:
            out.append(obstacle_clearances([P], team.obstacles.centers, team.obstacles.radii)[0].min())
    return np.array(out)


@pytest.mark.parametrize("bodies", ["end_effector", "links"])
def test_the_filter_takes_the_drift_into_account(bodies: str) -> None:
    """Each arm's end-effector drifts straight at an obstacle 4 cm away and the command is to hold still.
    The filter's rows include the drift, so the actuated joints cancel it: without a speed bound no body
    enters an obstacle in 3 s (the independent clearance of tests/geometry.py after every sub-step),
    through the end-effector rows and the whole-arm rows. With a speed bound of 5 rad/s the joints cannot
    cancel it for ever (b = 0: p₁ stays): an arm enters an obstacle first in a sub-step whose QP reported a
    fallback, and that fallback does not brake (v* = 0 would leave the drift acting) but pulls against it."""
    team, q, qd = _drifting_team(bodies)
    for max_speed in (np.inf, 5.0):
        engine = Engine(team, 1, physics=Physics(max_joint_speed=max_speed), safety_filter=True)
        engine.set_state(0, q, qd)
        solved, entered, fallbacks = np.zeros(4, dtype=int), np.zeros(4, dtype=bool), 0
        for _ in range(300):  # 0.3 s of 1 ms sub-steps
            rec = engine.step(np.zeros((1, 4, 3)), 1)
            solved += rec.qp_counts[0, :, 1]
            inside = _clearances(team, engine.joint_state()[0][0], bodies) < -1e-9
            if max_speed == np.inf:
                assert not inside.any(), f"arms {np.flatnonzero(inside)} entered an obstacle"
            first = inside & ~entered
            assert np.all(rec.qp_counts[0, first, 2] > 0), "an arm entered an obstacle in a sub-step with no fallback"
            entered |= inside
            fell_back = rec.qp_counts[0, :, 2] > 0
            fallbacks += int(fell_back.sum())
            assert np.all(np.abs(rec.v_star[0, fell_back]).max(axis=-1) > 0.1), "a drifting arm's fallback braked"
        assert np.all(solved > 0), "the filter should have changed every arm's command to cancel its drift"
        assert fallbacks > 0 or bodies == "links" or max_speed == np.inf, "the speed bound should leave no way out"
        assert np.all(np.abs(engine.passive_momentum()) > 0.5), "the passive joints keep their momentum"


def test_set_state_checks_its_input() -> None:
    engine = Engine(scenario.load("paper_pa3_square"), 2)
    good = [np.zeros(4)] * 4
    with pytest.raises(ValueError, match="copy must be"):
        engine.set_state(2, good, good)
    with pytest.raises(ValueError, match="every arm"):
        engine.set_state(0, good[:3], good)
    with pytest.raises(ValueError, match=r"qd\[1\] must be 4 finite joint speeds"):
        engine.set_state(0, good, [np.zeros(4), np.array([0.0, np.nan, 0.0, 0.0]), np.zeros(4), np.zeros(4)])
