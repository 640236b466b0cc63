"""The envs' batched draw of random teams (pan1_env.team_draw, compiled in pan1_env.draw_kernel) against the
reference, random_scenario: the same teams from the same generators (up to rounding), each generator left in the
same state, a copy's team independent of the other copies drawn with it, every guarantee of random_scenario's
docstring on a few hundred draws (by the independent geometry of tests/geometry.py), and the engine and task
loaded as load_team loads the reference's teams."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from geometry import inter_arm_clearances, joints, obstacle_clearances, point_segment_distance, segment_segment_distance

from pan1_env.cascade import reduced_jacobian
from pan1_env.random_scenario import BASE_MARGIN, DrawError, RandomScenarioOptions, random_scenario
from pan1_env.registration import ENV_IDS
from pan1_env.team_draw import draw_teams

OPTIONS = {
    "v1": ENV_IDS["pan1_env/RandomFormation-v1"]["random_options"],
    "whole_arm": ENV_IDS["pan1_env/WholeArmStaticFormation-v1"]["random_options"],
    "moving_obstacles": ENV_IDS["pan1_env/WholeArmFormation-v1"]["random_options"],
    "faults": ENV_IDS["pan1_env/FaultFormation-v0"]["random_options"],
    "clear_paths": ENV_IDS["pan1_env/WholeArmFormation-v1"]["random_options"] | {"clear_paths": True},
    # end-effectors only: the path's clearance from the starting end-effectors is the check that acts
    "clear_paths_end_effector": ENV_IDS["pan1_env/RandomFormation-v1"]["random_options"]
    | {"obstacle_speed": (0.05, 0.2), "clear_paths": True},
    # odd numbers of signs per arm leave a 32-bit half in the generator's buffer between arms and attempts
    "mixed": {"n_arms": 5, "links": (2, 3, 4, 3, 2), "passive_fraction": 0.6, "n_obstacles": 4},
    "square": {"shape": "square", "links": 2, "passive_fraction": 0.25},
    # arms drawn again alone: the ring's larger teams, and with whole-arm clearances between the arms
    "ring_redraws": ENV_IDS["pan1_env/RandomFormation-v1"]["random_options"] | {"shape": "ring", "n_arms": 8,
                                                                               "n_obstacles": 6, "arm_redraws": 20},
    "whole_arm_redraws": ENV_IDS["pan1_env/WholeArmStaticFormation-v1"]["random_options"]
    | {"shape": "ring", "n_arms": 6, "arm_redraws": 5},
    # one redraw only: arms that use it up send the draw to a new attempt, often
    "one_redraw": ENV_IDS["pan1_env/WholeArmStaticFormation-v1"]["random_options"]
    | {"shape": "ring", "n_arms": 8, "arm_redraws": 1},
}


def _assert_same_team(ours, ref) -> None:
    """Same structure and choices exactly; the drawn numbers to rounding (the geometry sums in another order)."""
    assert len(ours.arms) == len(ref.arms) and ours.formation.edges.tolist() == ref.formation.edges.tolist()
    for a, b, qa, qb in zip(ours.arms, ref.arms, ours.q0, ref.q0, strict=True):
        assert a.passive_first_joint == b.passive_first_joint and a.passive_damping == b.passive_damping
        for name in ("masses", "lengths", "com", "inertias", "base", "lam"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(qa, qb, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours.formation.distances, ref.formation.distances, rtol=1e-12)
    np.testing.assert_allclose(ours.obstacles.centers, ref.obstacles.centers, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours.obstacles.radii, ref.obstacles.radii, rtol=1e-12)
    assert (ours.obstacle_paths is None) == (ref.obstacle_paths is None)
    if ref.obstacle_paths is not None:
        np.testing.assert_allclose(ours.obstacle_paths, ref.obstacle_paths, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ours.obstacle_speeds, ref.obstacle_speeds, rtol=1e-12)
    assert (ours.fault_times is None) == (ref.fault_times is None)
    if ref.fault_times is not None:
        np.testing.assert_allclose(ours.fault_times, ref.fault_times, rtol=1e-12)
    assert (ours.bodies, ours.link_radius, ours.inter_arm, ours.filter) == \
        (ref.bodies, ref.link_radius, ref.inter_arm, ref.filter)


@pytest.mark.parametrize("case", list(OPTIONS))
def test_the_batched_draw_is_the_references_draw(case: str) -> None:
    options = RandomScenarioOptions(**OPTIONS[case])
    seeds = range(60)
    rngs = [np.random.default_rng(seed) for seed in seeds]
    draws = draw_teams(rngs, options)
    for c, seed in enumerate(seeds):
        reference_rng = np.random.default_rng(seed)
        _assert_same_team(draws.scenario(c), random_scenario(reference_rng, options))
        # no more and no fewer numbers drawn, down to the half of a 64-bit draw the generator keeps
        assert rngs[c].bit_generator.state == reference_rng.bit_generator.state


def test_a_moving_formation_is_the_references_too() -> None:
    options = RandomScenarioOptions(**ENV_IDS["pan1_env/MovingFormation-v0"]["random_options"])
    rngs = [np.random.default_rng(seed) for seed in range(12)]
    draws = draw_teams(rngs, options)
    for c in range(12):
        reference_rng = np.random.default_rng(c)
        ref, ours = random_scenario(reference_rng, options), draws.scenario(c)
        _assert_same_team(ours, ref)
        np.testing.assert_allclose(ours.motion.scales, ref.motion.scales, rtol=1e-12)
        assert rngs[c].bit_generator.state == reference_rng.bit_generator.state


def test_a_copys_team_depends_on_its_generator_only() -> None:
    options = RandomScenarioOptions(**OPTIONS["whole_arm"])
    alone = draw_teams([np.random.default_rng(5)], options)
    among = draw_teams([np.random.default_rng(s) for s in (9, 5, 2)], options)
    again = draw_teams([np.random.default_rng(5)], options)
    for name in ("lengths", "masses", "com", "inertias", "lam", "bases", "q0", "centers", "radii", "fault_times"):
        assert np.array_equal(getattr(alone, name)[0], getattr(among, name)[1]), name  # reproducible, bit for bit
        assert np.array_equal(getattr(alone, name), getattr(again, name)), name
    assert not np.array_equal(among.bases[0], among.bases[1])


@pytest.mark.parametrize("case", ["moving_obstacles", "clear_paths", "clear_paths_end_effector"])
def test_the_guarantees_hold_on_hundreds_of_draws_by_independent_geometry(case: str) -> None:
    """Start clearances, σ_min, reachable vertices and paths clear of the bases; with ``clear_paths`` every path's
    swept capsule clear of the starting end-effectors (and links) and 5 cm from every vertex, by the tests' own
    geometry."""
    options = RandomScenarioOptions(**OPTIONS[case])
    rho, clear = options.link_radius, options.start_clearance
    draws = draw_teams([np.random.default_rng(1000 + s) for s in range(300)], options)
    for c in range(300):
        team = draws.scenario(c)
        arm_joints = [joints(q, a.lengths, a.base, a.phi) for a, q in zip(team.arms, team.q0, strict=True)]
        centers, radii = team.obstacles.centers, team.obstacles.radii
        if options.bodies == "links":
            assert min(cl.min() for cl in obstacle_clearances(arm_joints, centers, radii, rho)) >= clear - 1e-9
            assert min(cl.min() for cl in inter_arm_clearances(arm_joints, rho).values()) >= clear - 1e-9
        else:  # end-effectors only
            tips = np.array([p[-1] for p in arm_joints])
            assert np.min(np.linalg.norm(tips[:, None] - centers, axis=-1) - radii) >= clear - 1e-9
        for arm, q in zip(team.arms, team.q0, strict=True):
            assert np.linalg.svd(reduced_jacobian(arm, q), compute_uv=False).min() >= options.min_sigma - 1e-9
        # every vertex is reachable: the target configuration put the end-effector on it
        targets = draws.targets[c]
        for arm, target in zip(team.arms, targets, strict=True):
            assert arm.inner_reach - 1e-9 <= np.linalg.norm(target - arm.base) <= arm.reach + 1e-9
        for centre, end, r in zip(centers, team.obstacle_paths, radii, strict=True):
            assert np.min(np.linalg.norm(targets - centre, axis=-1)) >= r + 0.05 - 1e-9
            for arm in team.arms:
                sweep = arm.lengths[0] if arm.passive_first_joint else 0.0
                assert point_segment_distance(arm.base, centre, end) >= r + BASE_MARGIN + rho + sweep - 1e-9
            if options.clear_paths:
                assert min(point_segment_distance(x, centre, end) for x in targets) >= r + 0.05 - 1e-9
                assert min(point_segment_distance(p[-1], centre, end) for p in arm_joints) - r >= clear - 1e-9
                assert options.bodies != "links" or min(
                    segment_segment_distance(p[a], p[a + 1], centre, end) for p in arm_joints
                    for a in range(len(p) - 1)) - r - rho >= clear - 1e-9


@pytest.mark.parametrize("env_id", ["pan1_env/RandomFormation-v2", "pan1_env/WholeArmStaticFormation-v1"])
def test_teams_of_32_arms_draw_when_arms_are_redrawn_alone(env_id: str) -> None:
    """Drawing the whole team again while any arm fails its checks finds no 32-arm team in 200 attempts; redrawing
    only the failing arm does, and the teams keep the guarantees (independent geometry)."""
    base = ENV_IDS[env_id]["random_options"] | {"n_arms": 32, "n_obstacles": 24, "shape": "ring"}
    with pytest.raises(DrawError):
        draw_teams([np.random.default_rng(0)], RandomScenarioOptions(**(base | {"arm_redraws": 0})))
    options = RandomScenarioOptions(**(base | {"arm_redraws": 20}))
    draws = draw_teams([np.random.default_rng(500 + s) for s in range(8)], options)
    rho, clear = options.link_radius, options.start_clearance
    for c in range(8):
        team = draws.scenario(c)
        arm_joints = [joints(q, a.lengths, a.base, a.phi) for a, q in zip(team.arms, team.q0, strict=True)]
        if options.bodies == "links":
            assert min(cl.min() for cl in inter_arm_clearances(arm_joints, rho).values()) >= clear - 1e-9
        tips = np.array([j[-1] for j in arm_joints])
        centers, radii = team.obstacles.centers, team.obstacles.radii
        assert len(radii) == 24
        assert (np.linalg.norm(tips[:, None] - centers[None], axis=-1) - radii).min() >= clear - 1e-9
        for arm, q in zip(team.arms, team.q0, strict=True):
            assert np.linalg.svd(reduced_jacobian(arm, q), compute_uv=False).min() >= options.min_sigma - 1e-9


def test_options_no_team_satisfies_raise_a_draw_error() -> None:
    options = RandomScenarioOptions(min_sigma=5.0)
    with pytest.raises(DrawError, match="no valid random scenario in 3 draws"):
        draw_teams([np.random.default_rng(0), np.random.default_rng(1)], options, max_tries=3)


@pytest.mark.parametrize("env_id", ["pan1_env/WholeArmFormation-v1", "pan1_env/FaultFormation-v0",
                                    "pan1_env/MovingFormation-v0"])
def test_the_engine_and_task_hold_what_load_team_gives_the_references_teams(env_id: str) -> None:
    from pan1_env.vector import Pan1VectorEnv

    batched, single = Pan1VectorEnv(env_id, 6), Pan1VectorEnv(env_id, 6)
    batched.core.seed(list(range(40, 46)))
    single.core.rngs = copy.deepcopy(batched.core.rngs)
    batched.core.reset()
    for b in range(6):
        team = random_scenario(single.core.rngs[b], single.core.config.random_options)
        single.core.engine.load_team(b, team)
        single.core.task.load_team(b, team)
    single.core.engine.reset()  # as the batched reset does after its load
    ours, ref = batched.core.engine, single.core.engine
    for kind, kind_ref in zip(ours.kinds, ref.kinds, strict=True):
        for name in ("lam", "lengths", "base", "phi", "damping", "q0", "centers", "radii"):
            np.testing.assert_allclose(getattr(kind, name), getattr(kind_ref, name), rtol=1e-9, atol=1e-10,
                                       err_msg=name)
        assert np.array_equal(kind.mask, kind_ref.mask)
        if ref.whole_arm:
            np.testing.assert_allclose(kind.caps, kind_ref.caps, rtol=1e-9, atol=1e-10)
    for name in ("fault_times", "bases", "centers", "radii", "start_centers", "path_ends", "speeds", "velocities"):
        np.testing.assert_allclose(getattr(ours, name), getattr(ref, name), rtol=1e-9, atol=1e-10, err_msg=name)
    np.testing.assert_allclose(batched.core.task.distances, single.core.task.distances, rtol=1e-12)
    np.testing.assert_array_equal(batched.core.task.kp, single.core.task.kp)
    if single.core.task.motion is not None:  # a moving formation's shape mid-episode, as the reference's motion
        t = np.full(6, 7.5)
        for ours_shape, ref_shape in zip(batched.core.task.motion.shape(t), single.core.task.motion.shape(t),
                                         strict=True):
            np.testing.assert_allclose(ours_shape, ref_shape, rtol=1e-9, atol=1e-12)
    for b in range(6):  # a copy's Scenario, built when read, is the reference's team
        _assert_same_team(ours.teams[b], ref.teams[b])


def test_the_kernel_draws_as_this_numpy_and_refuses_a_numpy_that_does_not(monkeypatch) -> None:
    """The once-per-process check passes here, and fails when the kernel's stream parts from numpy's."""
    from pan1_env import draw_kernel, team_draw

    team_draw.check_numpy_streams.__wrapped__()
    kernel = draw_kernel.stream_sample

    def shifted(gen, uniforms, signs, doubles):  # a kernel whose uniform rounds otherwise
        kernel(gen, uniforms, signs, doubles)
        uniforms[0] += 1e-12

    monkeypatch.setattr(draw_kernel, "stream_sample", shifted)
    with pytest.raises(RuntimeError, match="draws uniform, choice or random differently"):
        team_draw.check_numpy_streams.__wrapped__()
