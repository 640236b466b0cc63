"""Placed formations (a motion with a ``centre``: a turn and a path): the arms' points against finite differences
and an independent rigid-motion fit, their workspace check, ``[formation.motion]``'s and the random options'
new keys with their bad inputs, the feed-forward and success of a placed copy beside a still one, and the
reference following a turn and a travel on the paper's arms."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
import tomllib
from pettingzoo.test import parallel_api_test
from rollouts import reference_and_law, reference_episode

from pan1_env import scenario
from pan1_env.environment import parallel_env
from pan1_env.motion import PLACEMENT_GAIN, PLACEMENT_SPEED, FormationMotion, MotionTable, check_motion
from pan1_env.random_scenario import RandomScenarioOptions, random_scenario
from pan1_env.registration import env_arguments
from pan1_env.simulation import Simulation

SQUARE = np.array([[0.0, 0.0], [0.7, 0.0], [0.7, 0.7], [0.0, 0.7]])
EDGES = np.array([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]])


def _placed(**kw) -> FormationMotion:
    args = {"scale_times": [0.0, 40.0], "scales": [1.0, 1.1], "centre": [1.25, 1.0], "turn_times": [0.0, 10.0, 30.0],
            "turns": [0.0, 0.0, 0.4], "path_times": [0.0, 20.0, 50.0], "path": [[0, 0], [0.05, 0.0], [0.05, 0.1]],
            "switch_shape": SQUARE * [1.0, 1.2], "switch_time": 35.0, "switch_duration": 10.0}
    return FormationMotion(**(args | kw))


def _fit_angle(points: np.ndarray, shape: np.ndarray) -> float:
    """The angle of the proper rotation taking the centred ``shape`` closest to the centred ``points``."""
    a, b = shape - shape.mean(0), points - points.mean(0)
    return float(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b)))


def test_placed_points_are_the_shape_turned_and_carried() -> None:
    """p*(t) has the shape's lengths, its centroid at centre + δ(t), and the rigid fit from the shape to it turns by
    θ(t); its velocity matches central differences through the scale, the turn, the path and the switch."""
    motion = _placed()
    t = np.array([0.0, 5.0, 15.0, 25.0, 37.0, 44.0, 60.0])
    points, velocity = motion.placement(SQUARE, t)
    shapes, _ = motion.shape(SQUARE, t)
    theta = np.interp(t, [0.0, 10.0, 30.0], [0.0, 0.0, 0.4])
    delta = np.stack([np.interp(t, [0.0, 20.0, 50.0], [0, 0.05, 0.05]), np.interp(t, [0.0, 20.0, 50.0], [0, 0, 0.1])],
                     axis=-1)
    for k in range(len(t)):
        np.testing.assert_allclose(np.linalg.norm(points[k][:, None] - points[k][None], axis=-1),
                                   np.linalg.norm(shapes[k][:, None] - shapes[k][None], axis=-1), atol=1e-12)
        np.testing.assert_allclose(points[k].mean(0), [1.25, 1.0] + delta[k], atol=1e-12)
        assert _fit_angle(points[k], shapes[k]) == pytest.approx(theta[k], abs=1e-12)
    h = 1e-6
    inner = np.array([5.0, 15.0, 25.0, 37.0, 44.0])
    ahead, behind = motion.placement(SQUARE, inner + h)[0], motion.placement(SQUARE, inner - h)[0]
    np.testing.assert_allclose((ahead - behind) / (2 * h), motion.placement(SQUARE, inner)[1], atol=1e-7)
    assert np.abs(velocity).max() > 1e-3


def test_a_placed_copy_is_pulled_to_its_points_and_a_still_one_is_not() -> None:
    """In one table, the placed copy's feed-forward is ṗ* + k_place (p* − p), its speed capped at PLACEMENT_SPEED, and
    its misplacement ‖p* − p‖; the copy without a centre keeps the lengths' feed-forward and no misplacement."""
    table = MotionTable(2, 4, 3)
    motion = _placed()
    table.load(0, SQUARE, motion)
    table.load(1, SQUARE, FormationMotion([0.0, 40.0], [1.0, 1.1]))
    t = np.array([12.0, 12.0])
    P = np.random.default_rng(0).normal(0.0, 0.1, (2, 4, 2)) + motion.placement(SQUARE, 12.0)[0]
    _, ff, misplacement = table.targets(t, EDGES, P)
    point, velocity = motion.placement(SQUARE, 12.0)
    pull = point[0] - P[0]
    distance = np.linalg.norm(pull, axis=-1, keepdims=True)
    assert distance.min() < PLACEMENT_SPEED / PLACEMENT_GAIN < distance.max()  # both sides of the pull's cap
    expected = velocity[0] + np.minimum(PLACEMENT_GAIN * distance, PLACEMENT_SPEED) * pull / distance
    np.testing.assert_allclose(ff[0], expected, atol=1e-12)
    np.testing.assert_allclose(misplacement[0], np.linalg.norm(point[0] - P[0], axis=-1), atol=1e-12)
    assert np.all(misplacement[1] == 0.0)
    scaling = MotionTable(1, 4, 2)
    scaling.load(0, SQUARE, FormationMotion([0.0, 40.0], [1.0, 1.1]))
    np.testing.assert_allclose(ff[1], scaling.targets(t[:1], EDGES, P[1:])[1][0], atol=1e-12)


def _square(motion: dict | None, obstacles: bool = True) -> dict:
    data = tomllib.loads(resources.files("pan1_env.scenarios").joinpath("paper_pa3_square.toml").read_text())
    if not obstacles:
        data.pop("obstacles")
    if motion is not None:
        data["formation"]["motion"] = motion
    return data


TURN_AND_TRAVEL = {"centre": [1.25, 1.0], "turn": [[0, 0.0], [30, 0.0], [50, 0.2]],
                   "path": [[0, 0, 0], [60, 0, 0], [80, 0.1, 0.1]]}


def test_a_scenario_file_places_the_shape() -> None:
    team = scenario.from_dict(_square(TURN_AND_TRAVEL))
    written = scenario.from_dict(_square(TURN_AND_TRAVEL | {"turn": [[0, 0], [30, "-pi/16"], [50, "pi/16"]]}))
    np.testing.assert_allclose(written.motion.turns, [0.0, -np.pi / 16, np.pi / 16])
    np.testing.assert_array_equal(team.motion.centre, [1.25, 1.0])
    np.testing.assert_array_equal(team.motion.turn_times, [0, 30, 50])
    np.testing.assert_array_equal(team.motion.turns, [0, 0, 0.2])
    np.testing.assert_array_equal(team.motion.path[-1], [0.1, 0.1])
    np.testing.assert_array_equal(team.motion.scales, [1.0])


@pytest.mark.parametrize(("motion", "message"), [
    ({"turn": [[0, 0.0], [10, 0.2]]}, r"formation\.motion\.centre: a turn or a path places the shape: it needs centre"),
    ({"path": [[0, 0, 0]]}, r"formation\.motion\.centre: a turn or a path places the shape"),
    ({"centre": [1.25]}, r"formation\.motion\.centre: expected 2 numbers, got 1"),
    ({"centre": [1.25, 1.0], "turn": [[0, 0.0], [10]]}, r"formation\.motion\.turn\[1\]: expected 2 numbers"),
    ({"centre": [1.25, 1.0], "turn": 0.2}, r"formation\.motion\.turn: expected a list of \[time, angle\] pairs"),
    ({"centre": [1.25, 1.0], "turn": [[0, 0.0], [10, "quarter"]]}, r"formation\.motion\.turn\[1\]: cannot read angle"),
    ({"centre": [1.25, 1.0], "path": [[0, 0, 0], [0, 1, 1]]}, r"path_times must be finite, ≥ 0 and increasing"),
    ({"centre": [1.25, 1.0], "turn": [[0, 0.0], [150, 0.1]]}, r"the turn keyframes end at 150 s, after the episode's"),
    ({"centre": [1.6, 1.0]}, r"at t = 0 s the placed shape puts arm 0's point 1\.409 m from its base, farther from it "
                             r"than the arm reaches \(1\.400 m\)"),
    ({"centre": [1.25, 1.0], "path": [[0, 0, 0], [20, 0.4, 0]]}, r"at t = 1[0-9.]* s the placed shape puts arm"),
], ids=["turn_without_centre", "path_without_centre", "centre_one_number", "turn_keyframe_one_number",
        "turn_not_pairs", "turn_angle_unreadable", "path_not_increasing", "turn_after_horizon",
        "centre_out_of_reach", "path_out_of_reach"])
def test_bad_placements_in_a_scenario_file(motion: dict, message: str) -> None:
    with pytest.raises(scenario.ScenarioError, match=message):
        scenario.from_dict(_square(motion))


def test_a_point_inside_an_arms_inner_reach_is_refused() -> None:
    """An arm whose longest link is longer than the others together cannot bring its end-effector near its base."""
    bases = SQUARE + [[-0.8, -0.2], [0.8, -0.2], [0.8, 0.2], [-0.8, 0.2]]
    bases[0] = SQUARE[0] + [0.1, 0.0]
    motion = FormationMotion([0.0], [1.0], centre=SQUARE.mean(0))
    check_motion(motion, SQUARE, EDGES, bases, np.full(4, 1.2), 10.0)  # no inner reach given: 0
    with pytest.raises(ValueError, match=r"at t = 0 s the placed shape puts arm 0's point 0\.100 m from its base, "
                                         r"closer to it than the arm reaches \(0\.300 m\)"):
        check_motion(motion, SQUARE, EDGES, bases, np.full(4, 1.2), 10.0, inner=np.array([0.3, 0.0, 0.0, 0.0]))


@pytest.mark.parametrize(("kw", "message"), [
    ({"turns": [0.0, 0.2], "turn_times": [0.0, 10.0], "centre": None}, r"a turn or a path places the shape, so it "
                                                                       r"needs a centre"),
    ({"centre": [1.0, np.nan]}, r"centre must be a finite point"),
    ({"turn_times": [0.0, 10.0], "turns": [0.0]}, r"turn_times and turns need K ≥ 1 keyframes"),
    ({"path_times": [0.0, 5.0], "path": [[0.0, 0.0], [np.inf, 0.0]]}, r"FormationMotion\.path must be finite"),
], ids=["turn_without_centre", "centre_not_finite", "turns_count", "path_not_finite"])
def test_bad_placements_in_python(kw: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        _placed(**kw)


def test_random_placed_teams_keep_their_seed_and_start_at_the_drawn_placement() -> None:
    """A turn or a travel keeps each seed's still team (most seeds) and adds a placed motion whose points at 0 s have
    the formation's lengths and whose turns and travels stay in the options' ranges."""
    opts = RandomScenarioOptions(formation_turn=(-0.3, 0.3), formation_travel=(0.0, 0.05), scale_period=25.0)
    same = 0
    for seed in range(5):
        team = random_scenario(np.random.default_rng(seed), opts)
        still = random_scenario(np.random.default_rng(seed), RandomScenarioOptions())
        same += all(a == b for a, b in zip(team.arms, still.arms, strict=True))
        m = team.motion
        np.testing.assert_array_equal(m.centre, [0.0, 0.0])
        assert np.all(np.abs(m.turns - m.turns[0]) <= 0.3) and np.all(np.linalg.norm(m.path, axis=-1) <= 0.05 + 1e-12)
        assert np.all(m.scales == 1.0)
        points = m.placement(team.formation.target, 0.0)[0][0]
        lengths = np.linalg.norm(points[team.formation.edges[:, 0]] - points[team.formation.edges[:, 1]], axis=-1)
        np.testing.assert_allclose(lengths, team.formation.distances, atol=1e-12)
    assert same >= 3


@pytest.mark.parametrize(("options", "message"), [
    ({"formation_turn": (0.3, -0.3)}, r"formation_turn must have low ≤ high"),
    ({"formation_travel": (-0.1, 0.1)}, r"formation_travel\[0\] must be non-negative"),
    ({"formation_travel": 0.1}, r"formation_travel must be a range \(low, high\) in m"),
    ({"formation_turn": (-4.0, 0.0)}, r"formation_turn must lie within ±π"),
], ids=["turn_reversed", "travel_negative", "travel_not_a_range", "turn_beyond_half_a_revolution"])
def test_bad_random_placement_options(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RandomScenarioOptions(**options)


def test_the_reference_follows_a_turn_and_a_travel() -> None:
    """Behind the shield, on the paper's arms without obstacles, the reference keeps every end-effector within 2 mm
    of its point while the square turns by 0.2 rad over 20 s and travels 14 cm over 20 s, and succeeds; with the
    points' velocity zeroed (the pull alone) it lags by more than 3 mm."""
    team = scenario.from_dict(_square(TURN_AND_TRAVEL, obstacles=False))

    def still_points(env):  # the points where they are, their velocity zero (what the feed-forward reads)
        placed = env.task.motion._placed
        env.task.motion._placed = lambda *args: (placed(*args)[0], np.zeros((1, 4, 2)))
    worst = {}
    for with_velocity in (True, False):
        _, _, infos, t, errors = reference_episode(team, None if with_velocity else still_points)
        worst[with_velocity] = np.max(errors[(t > 25.0) & (t < 85.0)])
        if with_velocity:
            assert infos["arm_0"]["is_success"]
    assert worst[True] < 2e-3 and worst[False] > 3e-3


def _placed_env(**kw):
    name, args = env_arguments("pan1_env/MovingFormation-v0",
                               {"random_options": {"formation_turn": (-0.3, 0.3), "formation_travel": (0.0, 0.05),
                                                   "scale_period": 10.0}} | kw)
    return parallel_env(name, **args)


def test_the_reference_from_observations_is_the_law_on_a_placed_team() -> None:
    env, _, pairs, _ = reference_and_law(_placed_env, seed=1, steps=12, action_seed=2)
    assert env.task.motion.placed.all() and env.task.misplacement.max() > 1e-3
    for law, reference in pairs:
        np.testing.assert_allclose(law, reference, rtol=1e-4, atol=1e-5)


def test_a_placed_team_passes_pettingzoos_api_test() -> None:
    parallel_api_test(_placed_env(max_steps=40, success_hold=1.0), num_cycles=40)


def test_the_frame_draws_a_placed_shape_where_it_stands() -> None:
    """A frame draws a placed shape at its points (not fitted to the end-effectors): while the arms are still far
    from them, the grey edges join the points p*(t)."""
    from pan1_env.render import Renderer

    env = parallel_env(scenario.from_dict(_square(TURN_AND_TRAVEL, obstacles=False)), render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    points = env.task.motion.placement(env.engine.elapsed)[0][0]
    assert env.task.misplacement.max() > 0.1
    renderer = Renderer()
    try:
        renderer.draw(env)
        grey = [line.get_xydata() for line in renderer.ax.lines if line.get_linestyle() == "--"]
        drawn = np.concatenate([g for g in grey if len(g) == 2])
        edges = np.concatenate([points[[a, b]] for a, b in env.scenario.formation.edges])
        np.testing.assert_allclose(drawn[: len(edges)], edges, atol=1e-12)
    finally:
        renderer.close()
        env.close()


def test_a_formed_shape_away_from_its_points_is_not_a_success() -> None:
    """With the placed feed-forward zeroed, the paper's law forms the square where the arms meet it, away from the
    placed points: every edge is within 1 mm, yet the formation error is the arms' distance from their points, the
    formation term pays it, and the episode does not succeed."""
    team = scenario.from_dict(_square({"centre": [1.25, 1.0]}, obstacles=False))
    env = parallel_env(team, action_mode="residual")
    env.reset(seed=0)
    targets = env.task.motion.targets

    def no_pull(t, edges, P):
        d, ff, misplacement = targets(t, edges, P)
        return d, np.zeros_like(ff), misplacement
    env.task.motion.targets = no_pull
    env.task._tracked = None  # computed again, by the patched targets
    while env.agents:
        _, rewards, _, _, infos = env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    P = env.engine.positions()[0]
    edges = team.formation.edges
    assert np.abs(np.linalg.norm(P[edges[:, 0]] - P[edges[:, 1]], axis=-1) - team.formation.distances).max() < 1e-3
    misplacement = env.task.misplacement[0]
    assert misplacement.max() > 0.05
    info = infos["arm_0"]
    assert info["formation_error"] == pytest.approx(misplacement.max(), rel=1e-6)
    assert info["reward_formation"] < -misplacement.mean() + 1e-3 and not info["is_success"]


@pytest.mark.parametrize(("motion", "obstacles"), [
    ({"centre": [1.25, 1.0]}, True),
    ({"centre": [1.25, 1.0], "path": [[0, 0, 0], [10, 0, 0], [10.4, 0.18, 0.0], [14, 0.18, 0.0]]}, False),
], ids=["far_from_its_point", "a_fast_path"])
def test_reproduce_keeps_its_joints_bounded(motion: dict, obstacles: bool) -> None:
    """``Simulation`` (``pan1-env reproduce``) runs the paper's law, which has no speed bound, through the filter and
    backstepping. Far from its point (0.8 m, pulled at 0.8 m/s before the pull was capped) an arm ran its joints
    away within 0.2 s; on a path at 0.45 m/s, one passed 100 rad/s at 13 s. With a moving formation the law's
    command is bounded as the envs' is, and 14 s keep every joint below 5 rad/s."""
    team = scenario.from_dict(_square(motion, obstacles=obstacles))
    sim = Simulation(team, safety_filter=True)
    fastest = 0.0
    for _ in range(14000):
        sim.step(sim.nominal_velocity(), 1)
        fastest = max(fastest, float(np.abs(sim.joint_state()[1]).max()))
    assert fastest < 5.0


def test_keyframes_too_close_together_are_refused() -> None:
    for motion in ({"centre": [1.25, 1.0], "path": [[0, 0, 0], [5e-324, 0.01, 0]]},
                   {"scale": [[0, 1.0], [5e-324, 1.01]]}):
        with pytest.raises(scenario.ScenarioError, match=r"the motion's rate is not finite at t = 0 s: two keyframes "
                                                         r"are too close together"):
            scenario.from_dict(_square(motion))


def test_a_placed_random_team_may_have_a_horizon_shorter_than_its_period() -> None:
    team = random_scenario(np.random.default_rng(0), RandomScenarioOptions(horizon=10.0, formation_turn=(-0.3, 0.3)))
    np.testing.assert_array_equal(team.motion.turn_times, [0.0])


def test_a_long_turn_is_checked_all_the_way_round() -> None:
    """Turning 32 times in 240 s, a point passes as far from its arm's base as the centroid's distance plus its own
    radius: a reach 1 mm short of that is refused, and one just beyond it passes (the samples lie at most 0.02 rad
    of turn apart, so they miss the farthest point by 25 µm at most)."""
    bases = SQUARE + [[-0.3, -0.3], [0.3, -0.3], [0.3, 0.3], [-0.3, 0.3]]
    motion = FormationMotion([0.0], [1.0], centre=SQUARE.mean(0), turn_times=[0.0, 240.0], turns=[0.0, 64 * np.pi])
    farthest = np.linalg.norm(SQUARE.mean(0) - bases[0]) + np.linalg.norm(SQUARE[0] - SQUARE.mean(0))
    check_motion(motion, SQUARE, EDGES, bases, np.full(4, farthest + 1e-6), 300.0)
    with pytest.raises(ValueError, match=r"the placed shape puts arm \d's point 1\.41\d m from its base, farther"):
        check_motion(motion, SQUARE, EDGES, bases, np.full(4, farthest - 1e-3), 300.0)


@pytest.mark.parametrize(("kw", "message"), [
    ({"turn_times": [0.0, 1.0], "turns": [0.0, 1e9]}, r"the placed shape turns at 1e\+09 rad/s from t = 0 s, faster "
                                                      r"than 1 rad/s"),
    ({"turn_times": [0.0, 2e5], "turns": [0.0, 1e5]}, r"checking where the placed shape's points go takes 5e\+06 "
                                                      r"samples \(2 keyframes, 1e\+05 rad of turn\)"),
    ({"path_times": np.arange(20000.0), "path": np.zeros((20000, 2))}, r"takes 6\.6e\+05 samples \(20000 keyframes, "
                                                                       r"0 rad of turn\), more than 500000"),
    ({"path_times": [0.0, 1e-6], "path": [[0.0, 0.0], [0.01, 0.0]]}, r"at t = 0 s the moving shape's points move at "
                                                                     r"1e\+04 m/s, faster than 0\.5 m/s"),
    ({"scale_times": [0.0, 1e-3], "scales": [1.0, 1.01], "centre": None}, r"points move at 4\.95 m/s, faster"),
], ids=["turn_too_fast", "turn_too_long", "too_many_keyframes", "path_too_fast", "scale_too_fast"])
def test_motions_faster_than_arms_follow_are_refused(kw: dict, message: str) -> None:
    """Keyframes close together ask for speeds no arm follows: ``reproduce``, whose law has no joint-speed cap, ran
    its joints up to 1e152 rad/s on a path of 1 cm in 1 µs. Turning too far is refused before it is sampled."""
    base = {"scale_times": [0.0], "scales": [1.0], "centre": SQUARE.mean(0)}
    bases = SQUARE * 2.0 - SQUARE.mean(0)
    with pytest.raises(ValueError, match=message):
        check_motion(FormationMotion(**(base | kw)), SQUARE, EDGES, bases, np.full(4, 1.5), 1e6)


def test_a_speed_peaking_at_a_keyframe_is_caught_just_before_it() -> None:
    """Growing threefold while turning 0.6 rad in a second, a square of side 0.263 m has its points' speed peak at the
    segment's end (0.5004 m/s), where the next segment's rate already holds: the check looks just before it."""
    side = np.array([[0.0, 0.0], [0.263, 0.0], [0.263, 0.263], [0.0, 0.263]])
    motion = FormationMotion([0.0, 1.0], [1.0, 3.0], centre=side.mean(0), turn_times=[0.0, 1.0], turns=[0.0, 0.6])
    with pytest.raises(ValueError, match=r"at t = 1 s the moving shape's points move at 0\.5 m/s, faster than 0\.5"):
        check_motion(motion, side, EDGES, side * 5.0, np.full(4, 3.0), 10.0)


def test_a_switch_too_short_is_refused_and_a_step_is_not() -> None:
    """A switch's blend moves the points at (its lengths' change) / T_s: refused when that passes 0.5 m/s, with a hint
    to lengthen it; a step (T_s = 0) asks for no motion at all and loads."""
    bases = SQUARE * 2.0 - SQUARE.mean(0)
    switch = {"switch_shape": SQUARE * [1.0, 1.2], "switch_time": 1.0}
    for duration in (0.0, 10.0):
        check_motion(FormationMotion([0.0], [1.0], switch_duration=duration, **switch), SQUARE, EDGES, bases,
                     np.full(4, 1.5), 20.0)
    with pytest.raises(ValueError, match=r"faster than 0\.5 m/s: spread its keyframes further apart, or lengthen its "
                                         r"switch"):
        check_motion(FormationMotion([0.0], [1.0], switch_duration=0.05, **switch), SQUARE, EDGES, bases,
                     np.full(4, 1.5), 20.0)


def test_moving_formation_v1_is_v0_with_the_shape_placed_turning_and_travelling() -> None:
    """The id of the row where the law forms half the teams: v0's options and success hold, plus a turn within
    ±0.5 rad and a travel up to 0.1 m; every copy's arms are placed."""
    _, v0 = env_arguments("pan1_env/MovingFormation-v0")
    _, v1 = env_arguments("pan1_env/MovingFormation-v1")
    assert v1["random_options"] == v0["random_options"] | {"formation_turn": (-0.5, 0.5),
                                                           "formation_travel": (0.0, 0.1)}
    assert v1["success_hold"] == v0["success_hold"]
    env = parallel_env("pan1_env/MovingFormation-v1")
    env.reset(seed=2_000_000)
    assert env.task.motion.placed.all()
