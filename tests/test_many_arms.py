"""Teams of many arms: each arm's capsules list the other arms' links nearest first, and what the engine
measures and filters from that list is what the independent geometry (tests/geometry.py) measures over
every pair."""

import numpy as np
import pytest

RHO = 0.03
MANY = {"bodies": "links", "link_radius": RHO, "inter_arm": True, "shape": "ring", "arm_redraws": 20}


def _core(n_arms: int, n_obstacles: int, speed=(0.0, 0.0), extra: dict | None = None):
    from pan1_env.environment import parallel_env

    options = {**MANY, "n_arms": n_arms, "n_obstacles": n_obstacles, "obstacle_speed": speed, **(extra or {})}
    return parallel_env("random", random_options=options, control_dt=0.01, physics_dt=0.01, max_steps=400)


def test_other_arms_slots_are_nearest_first_and_active_where_reaches_meet() -> None:
    """In every arm's row: the world's obstacles first, then each other arm's links together, in order of
    the floor |b_i − b_j| − reach_i − reach_j − 2ρ, active exactly where it is ≤ 0, then unused slots; and
    of 24 arms, each arm's reach meets only a few others'."""
    from pan1_env.compiled import kernels
    from pan1_env.engine import FLOOR_SLACK

    K = kernels().capsules
    core = _core(24, 18)
    core.reset(seed=3)
    engine, team = core.engine, core.scenario
    bases = np.array([a.base for a in team.arms])
    reach = np.array([a.reach for a in team.arms])
    O = len(team.obstacles.radii)
    for kind in engine.kinds:
        for r, i in enumerate(kind.ids):
            row = kind.caps[r]
            assert np.all(row[:O, K.CAP_ARM] == -1.0)
            arms = row[O:, K.CAP_ARM].astype(int)
            used = arms >= 0
            assert used.sum() == sum(a.n_links for j, a in enumerate(team.arms) if j != i)
            assert not used[used.sum():].any(), "unused slots come last"
            floor = np.linalg.norm(bases[arms[used]] - bases[i], axis=-1) - reach[i] - reach[arms[used]] - 2 * RHO
            np.testing.assert_allclose(row[O:, K.CAP_FLOOR][used], floor - FLOOR_SLACK, atol=1e-12)
            assert np.all(np.diff(floor) >= -1e-12), "nearest first"
            np.testing.assert_array_equal(row[O:, K.CAP_ACTIVE][used] != 0.0, floor - FLOOR_SLACK <= 0.0)
            links = row[O:, K.CAP_LINK][used].astype(int)
            for j in np.unique(arms[used]):
                np.testing.assert_array_equal(links[arms[used] == j], np.arange(team.arms[j].n_links))
            assert len(np.unique(arms[used][floor <= 0.0])) <= 8


MIXED = {"links": (2, 3, 4, 3) * 4, "fault_probability": 0.5, "fault_time": (0.05, 0.4), "passive_damping": 0.5}


@pytest.mark.parametrize(("speed", "extra"), [((0.0, 0.0), {}), ((0.1, 0.3), {}), ((0.1, 0.3), MIXED)],
                         ids=["still", "moving", "mixed links and faults"])
def test_a_16_arm_teams_clearance_is_the_geometrys_and_the_shield_keeps_it(speed, extra) -> None:
    """A 16-arm ring team behind the whole-arm shield, one sub-step per step: every arm's reported
    clearance is its smallest to the obstacles and to every other arm, measured pair by pair from the
    state (also with arms of 2, 3 and 4 links, of which half lose an actuator within the first 0.4 s); with
    still obstacles no capsule ever enters another or an obstacle."""
    import geometry

    core = _core(16, 12, speed, extra)
    from pan1_env.wrappers import SafetyShield

    env = SafetyShield(core)
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    for t in range(60):
        _, _, _, _, infos = env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})
        arms, parts = geometry.arms_from_state(core.state(), core.scenario)
        to_obstacles = geometry.obstacle_clearances(arms, parts["centers"], parts["radii"], RHO)
        between = geometry.inter_arm_clearances(arms, RHO)
        expected = [min(to_obstacles[i].min(initial=np.inf),
                        *(c.min() for (a, b), c in between.items() if i in (a, b))) for i in range(len(arms))]
        reported = [infos[a]["min_clearance"] for a in core.possible_agents]
        np.testing.assert_allclose(reported, expected, atol=2e-5, err_msg=f"step {t}")
        if speed == (0.0, 0.0):
            assert min(expected) > -1e-5, f"step {t}: a capsule entered another or an obstacle"


@pytest.mark.parametrize("speed", [(0.0, 0.0), (0.1, 0.3)])
def test_a_step_of_sub_steps_reports_the_smallest_clearance_of_its_sub_steps(speed) -> None:
    """A step of 5 sub-steps reports the smallest clearance of its sub-steps: the same as 5 steps of one sub-step
    each (whose clearance the test above checks against the geometry), though within a call the skips start from
    the clearance of the call's earlier sub-steps."""
    from pan1_env.engine import Engine, Physics
    from pan1_env.random_scenario import RandomScenarioOptions, random_scenario

    team = random_scenario(np.random.default_rng(7), RandomScenarioOptions(
        **MANY, n_arms=12, n_obstacles=9, obstacle_speed=speed, physics_dt=0.01, control_dt=0.05))
    engines = [Engine(team, physics=Physics(max_joint_speed=2.0), safety_filter=True) for _ in range(2)]
    rng = np.random.default_rng(0)
    for _ in range(10):
        command = rng.uniform(-2, 2, (1, team.n_arms, 3))
        whole = engines[0].step(command, 5).min_clearance
        parts = np.min([engines[1].step(command, 1).min_clearance for _ in range(5)], axis=0)
        np.testing.assert_allclose(whole, parts, rtol=0, atol=1e-9)
