"""Moving formations: the shape's lengths and their rates against finite differences and an independent
geometry, the feed-forward against the edge rates it must realise, ``[formation.motion]`` and the random
options with their bad inputs, the tracking success, the reference law from observations against the env's,
the feed-forward's effect on tracking, and ``pan1_env/MovingFormation-v0`` under Gymnasium's, PettingZoo's and
TorchRL's API tests."""

from __future__ import annotations

from importlib import resources

import gymnasium
import numpy as np
import pytest
import tomllib
from pettingzoo.test import parallel_api_test
from rollouts import reference_and_law, reference_episode

from pan1_env import scenario
from pan1_env.baselines import ReferencePolicy
from pan1_env.environment import parallel_env
from pan1_env.formation import Formation
from pan1_env.motion import FEED_FORWARD_DAMPING, MIN_EDGE, FormationMotion, MotionTable, edge_rates, feed_forward
from pan1_env.random_scenario import RandomScenarioOptions, random_scenario
from pan1_env.registration import env_arguments

RECTANGLE = [0.7, 0.8, 0.7, 0.8, float(np.hypot(0.7, 0.8))]  # the square's edges (sides, then the diagonal 0–2)


def _square(motion: dict | None) -> dict:
    data = tomllib.loads(resources.files("pan1_env.scenarios").joinpath("paper_pa3_square.toml").read_text())
    if motion is not None:
        data["formation"]["motion"] = motion
    return data


def _moving_square(**motion) -> scenario.Scenario:
    return scenario.from_dict(_square({"scale": [[0, 1.0], [50, 1.0], [70, 1.2]], "switch_distances": RECTANGLE,
                                       "switch_time": 80.0, "switch_duration": 10.0} | motion))


def test_the_shape_scales_and_switches_as_its_keyframes_say() -> None:
    team = _moving_square()
    start = team.formation.target
    r, _ = team.motion.shape(start, [0.0, 25.0, 50.0, 60.0, 70.0, 79.9, 90.0, 100.0])
    d = np.linalg.norm(r[:, team.formation.edges[:, 0]] - r[:, team.formation.edges[:, 1]], axis=-1)
    np.testing.assert_allclose(d[:3], np.tile(team.formation.distances, (3, 1)), rtol=1e-12)
    np.testing.assert_allclose(d[3], 1.1 * team.formation.distances, rtol=1e-12)
    np.testing.assert_allclose(d[4:6], np.tile(1.2 * team.formation.distances, (2, 1)), rtol=1e-12)
    # after the switch: the rectangle's lengths, scaled; not its folded twin (arms 1 and 3 on one side)
    np.testing.assert_allclose(d[6:], np.tile(1.2 * np.array(RECTANGLE), (2, 1)), rtol=1e-9)
    assert np.linalg.norm(r[-1, 1] - r[-1, 3]) > 1.0
    step = _moving_square(switch_duration=0.0).motion.shape(start, [79.99, 80.0])[0]
    assert np.linalg.norm(step[0, 1] - step[0, 2]) == pytest.approx(0.84) and \
        np.linalg.norm(step[1, 1] - step[1, 2]) == pytest.approx(0.96)


@pytest.mark.parametrize("t", [10.0, 55.0, 69.0, 83.0, 89.5])
def test_the_rates_are_the_lengths_derivatives(t: float) -> None:
    """d ⊙ ḋ from the shape's velocity equals a central difference of ½ d² (d from numpy's norm of the shape)."""
    team = _moving_square()
    h = 1e-5
    r, r_dot = team.motion.shape(team.formation.target, [t - h, t, t + h])
    edges = team.formation.edges
    d, rates = edge_rates(edges, r, r_dot)
    half_square = 0.5 * np.sum((r[:, edges[:, 0]] - r[:, edges[:, 1]]) ** 2, axis=-1)
    np.testing.assert_allclose(d[1], np.sqrt(2 * half_square[1]), rtol=1e-12)
    np.testing.assert_allclose(rates[1], (half_square[2] - half_square[0]) / (2 * h), atol=1e-8)


@pytest.mark.parametrize("edges,distances", [
    ([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2]], RECTANGLE),  # minimally rigid
    ([[0, 1], [1, 2], [2, 3], [0, 3], [0, 2], [1, 3]], [0.7] * 4 + [float(np.hypot(0.7, 0.7))] * 2),  # one to spare
])
def test_the_feed_forward_changes_every_edge_at_its_rate(edges, distances) -> None:
    """At a realisation, z_k · (ṗ_i − ṗ_j) = d_k ḋ_k for the scaling's and a morph's rates, up to the damping μ."""
    form = Formation.from_edges(edges, distances, 4)
    E = np.asarray(form.edges)
    rng = np.random.default_rng(0)
    P = form.target + rng.uniform(-1, 1, 2)  # anywhere in the plane
    target_rate = rng.normal(size=(4, 2))  # a velocity of every vertex: its edge rates are realisable
    rates = np.sum((P[E[:, 0]] - P[E[:, 1]]) * (target_rate[E[:, 0]] - target_rate[E[:, 1]]), axis=-1)
    ff = feed_forward(E, P[None], rates[None])[0]
    realised = np.sum((P[E[:, 0]] - P[E[:, 1]]) * (ff[E[:, 0]] - ff[E[:, 1]]), axis=-1)
    # the damping's bias is of order μ / σ²(R) relative: 1e-3 of the largest rate holds for μ = 1e-4 (not 1e-2)
    assert FEED_FORWARD_DAMPING <= 1e-4
    np.testing.assert_allclose(realised, rates, atol=1e-3 * np.abs(rates).max())
    # the least such velocity: no more than the vertices' own
    assert np.linalg.norm(ff) <= np.linalg.norm(target_rate - target_rate.mean(0)) + 1e-9
    np.testing.assert_array_equal(feed_forward(E, P[None], np.zeros((1, len(E)))), 0.0)


def test_a_table_of_copies_gives_each_its_own_motion() -> None:
    team = _moving_square()
    table = MotionTable(3, 4, 5)
    table.load(0, team.formation.target, team.motion)
    table.load(1, team.formation.target, None)
    table.load(2, team.formation.target, team.motion)
    r, r_dot = table.shape(np.array([60.0, 60.0, 85.0]))
    one, one_dot = team.motion.shape(team.formation.target, [60.0, 85.0])
    np.testing.assert_allclose(r[[0, 2]], one, rtol=1e-12)
    np.testing.assert_allclose(r_dot[[0, 2]], one_dot, rtol=1e-12)
    np.testing.assert_allclose(r[1], team.formation.target)
    np.testing.assert_array_equal(r_dot[1], 0.0)
    with pytest.raises(ValueError, match="a motion with 3 scale keyframes does not fit this env's 2"):
        MotionTable(1, 4, 2).load(0, team.formation.target, team.motion)


@pytest.mark.parametrize(("motion", "message"), [
    ({"scale": [[0, 1.0], [150, 1.1]]}, r"formation\.motion: the scale keyframes end at 150 s, after the episode's"),
    ({"scale": [[0, 1.0], [0, 1.1]]}, r"formation\.motion: .*scale_times must be finite, ≥ 0 and increasing"),
    ({"scale": [[0, -1.0]]}, r"formation\.motion: .*scales must be positive"),
    ({"scale": "fast"}, r"formation\.motion\.scale: expected a list of \[time, scale\] pairs"),
    ({"scale": [[0, 1.0]], "speed": 2}, r"formation\.motion\.speed: unknown key"),
    ({"switch_time": 3.0}, r"formation\.motion\.switch_time: a switch needs switch_distances"),
    ({"switch_distances": [0.7, 0.8]}, r"formation\.motion\.switch_distances: got 5 edges but 2 distances"),
    ({"switch_distances": [0.7, 0.7, 0.7, 0.7, 3.0], "switch_time": 1.0},
     r"formation\.motion\.switch_distances: no planar placement"),
    ({"switch_distances": RECTANGLE}, r"formation\.motion\.switch_time: missing"),
    ({"switch_distances": RECTANGLE, "switch_time": 120.0}, r"the switch at 120 s comes after the episode's 100 s"),
    ({"switch_distances": RECTANGLE, "switch_time": 1.0, "switch_duration": -1.0},
     r"formation\.motion\.switch_duration: must be non-negative"),
    ({"scale": [[0, 1.0], [10, 8.0]]}, r"at t = \d.* s the shape puts arms \d and \d .* m apart, farther apart than"),
    ({"scale": [[0, 1.0], [10, 0.3]]}, r"the shape puts arms \d and \d .* closer than their reach allows"),
    ({"scale": [[0, 10**400]]}, r"formation\.motion\.scale\[0\]: an integer of 401 digits is out of range"),
    ({"scale": [[0, 1e300]]}, r"formation\.motion\.scale\[0\]: 1e\+300 is out of range"),
    ({"scale": [[0]]}, r"formation\.motion\.scale\[0\]: expected 2 numbers, got 1"),
], ids=["keyframe_after_horizon", "keyframes_not_increasing", "negative_scale", "scale_not_pairs", "unknown_key",
        "switch_without_shape", "switch_distances_count", "switch_unrealisable", "switch_time_missing",
        "switch_after_horizon", "negative_duration", "out_of_reach_far", "out_of_reach_near", "huge_integer_scale",
        "scale_out_of_range", "keyframe_one_number"])
def test_bad_motions_in_a_scenario_file(motion: dict, message: str) -> None:
    with pytest.raises(scenario.ScenarioError, match=message):
        scenario.from_dict(_square(motion))


def test_a_moving_shape_may_not_shrink_an_edge_to_nothing() -> None:
    """:data:`MIN_EDGE` is checked on a team whose reach would allow the arms to meet."""
    data = _square({"scale": [[0, 1.0], [10, MIN_EDGE / 0.8]]})
    for arm, base in zip(data["arms"], ([0, 0], [1, 0], [1, 1], [0, 1]), strict=True):
        arm["base"] = base
    with pytest.raises(scenario.ScenarioError, match=r"an edge of the moving shape is shorter than 0\.01 m"):
        scenario.from_dict(data)


def test_a_scenario_checks_the_motion_it_is_given() -> None:
    team = _moving_square()
    import dataclasses

    with pytest.raises(ValueError, match=r"Scenario\.motion: the switch shape has 3 vertices for 4 arms"):
        dataclasses.replace(team, motion=FormationMotion([0.0], [1.0], team.motion.switch_shape[:3], 1.0))
    with pytest.raises(ValueError, match="Scenario.motion must be a FormationMotion or None"):
        dataclasses.replace(team, motion={"scale": [[0, 1]]})


def test_random_motion_draws_after_the_team_and_stays_in_reach() -> None:
    """A moving team is, for most seeds, the seed's still team plus scale keyframes; every arm reaches its scaled
    vertex of the drawn placement at each keyframe (checked from the arm's own kinematics: the end-effector can be
    anywhere within its reach annulus), and the keyframes follow the options."""
    opts = RandomScenarioOptions(formation_scale=(0.8, 1.2), scale_period=20.0)
    same = 0
    for seed in range(6):
        team = random_scenario(np.random.default_rng(seed), opts)
        still = random_scenario(np.random.default_rng(seed), RandomScenarioOptions())
        same += all(a == b for a, b in zip(team.arms, still.arms, strict=True))
        np.testing.assert_array_equal(team.motion.scale_times, [0.0, 20.0, 40.0, 60.0, 80.0, 100.0])
        assert team.motion.scales[0] == 1.0 and np.all((team.motion.scales >= 0.8) & (team.motion.scales <= 1.2))
        assert team.motion.switch_shape is None
    assert same >= 4
    assert random_scenario(np.random.default_rng(0), RandomScenarioOptions()).motion is None


@pytest.mark.parametrize(("options", "message"), [
    ({"formation_scale": (1.2, 0.8)}, r"formation_scale must have low ≤ high"),
    ({"formation_scale": (0.0, 1.2)}, r"formation_scale\[0\] must be positive"),
    ({"formation_scale": 1.1}, r"formation_scale must be a range"),
    ({"scale_period": 0.0}, r"scale_period must be positive"),
])
def test_bad_random_motion_options(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RandomScenarioOptions(**options)


def test_success_needs_the_error_held_below_the_tolerance() -> None:
    """With ``success_hold``, ``is_success`` turns on exactly ``success_hold`` seconds after the error last was at
    or above the tolerance, and never without it."""
    team = _moving_square()
    plain, held = parallel_env(team), parallel_env(team, success_hold=5.0)
    errors, plain_success, held_success = [], [], []
    for env, out in ((plain, plain_success), (held, held_success)):
        obs, _ = env.reset(seed=0)
        policy = ReferencePolicy(env)
        for _ in range(1000):
            obs, _, _, _, infos = env.step(policy(obs))
            out.append(infos["arm_0"]["is_success"])
            if env is plain:
                errors.append(infos["arm_0"]["formation_error"])
    below = np.array(errors) < 0.01
    assert below.any() and not below.all()
    first = int(np.argmax(below))
    np.testing.assert_array_equal(plain_success, below)
    # the error was last at or above the tolerance at step `first − 1`: success 5 s (100 steps of 0.05 s) later
    assert not any(held_success[: first + 99]) and held_success[first + 99]
    held.reset(seed=0)  # a new episode starts its hold afresh, even where the error stays below
    assert held.task.below_since[0] == 0.0
    with pytest.raises(ValueError, match="success_hold must be non-negative"):
        parallel_env(team, success_hold=-1.0)
    with pytest.warns(UserWarning, match=r"success_hold=200 s is longer than the episode .* no episode can succeed"):
        parallel_env(team, success_hold=200.0)


def test_the_feed_forward_keeps_the_moving_shape() -> None:
    """Behind the shield, the reference holds the paper square within 1 mm while it grows by a fifth over 20 s and
    morphs into a rectangle over 10 s; with its feed-forward zeroed the same motion opens errors of more than
    1 cm (the formation law alone lags the moving lengths)."""
    team = _moving_square()
    worst = {}
    for with_ff in (True, False):
        def zero_feed_forward(env):
            env.task.motion.targets = _without_feed_forward(env.task.motion.targets)
        env, obs, _, t, errors = reference_episode(team, None if with_ff else zero_feed_forward)
        worst[with_ff] = np.max(errors[t > 52.0])
        if with_ff:
            assert np.abs(env.task.distances[0] - 1.2 * np.array(RECTANGLE)).max() < 1e-12
            assert np.all(obs["arm_0"][-2:] == 0.0)  # still again: no feed-forward
    assert worst[True] < 1e-3 < 1e-2 < worst[False]


def _without_feed_forward(targets):
    def zero(t, edges, P):
        d, ff, misplacement = targets(t, edges, P)
        return d, np.zeros_like(ff), misplacement
    return zero


def _moving_env(**kw):
    name, args = env_arguments("pan1_env/MovingFormation-v0", kw)
    return parallel_env(name, **args)


def test_the_reference_from_observations_is_the_tasks_law_with_the_feed_forward() -> None:
    """While the shape moves, the reference policy from observations (its own J̄, the neighbours' errors and the
    observed ṗ_ff) equals the env's own law from its state, as the residual mode's zero action."""
    env, obs, pairs, _ = reference_and_law(lambda **kw: _moving_env(random_options={"scale_period": 1.0}, **kw),
                                        seed=4, steps=12, action_seed=2)
    assert np.abs(env.task.feed_forward).max() > 1e-2
    segment = env.observation_layout.segments(env.scenario.arms[0].n_links)["formation_velocity"]
    np.testing.assert_allclose(obs["arm_0"][segment], env.task.feed_forward[0, 0], rtol=1e-6)
    for law, reference in pairs:
        np.testing.assert_allclose(law, reference, rtol=1e-4, atol=1e-5)


def test_reproduce_measures_and_follows_a_moving_formation() -> None:
    """``pan1-env reproduce``'s loop (:class:`~pan1_env.simulation.Simulation`) records each edge's error against
    the moving length at the sample's time (recomputed here from the motion and the recorded end-effectors), and
    its law is the env's: the same lengths and feed-forward at the same clock and state."""
    from pan1_env.experiment import run
    from pan1_env.simulation import Simulation

    team = _moving_square(scale=[[0, 1.0], [3, 1.2]], switch_time=4.0, switch_duration=2.0)
    traj = run(team, "nominal", horizon=8.0, record_dt=1.0).trajectory
    r, _ = team.motion.shape(team.formation.target, traj["time"])
    edges, P = team.formation.edges, traj["p_end"]
    lengths = np.linalg.norm(r[:, edges[:, 0]] - r[:, edges[:, 1]], axis=-1)
    np.testing.assert_allclose(traj["edge_error"], np.linalg.norm(P[:, edges[:, 0]] - P[:, edges[:, 1]], axis=-1)
                               - lengths, atol=1e-12)
    assert traj["time"][-1] == pytest.approx(8.0) and not np.allclose(lengths[-1], team.formation.distances)
    sim, env = Simulation(team, safety_filter=False), parallel_env(team)
    env.reset(seed=0)
    sim.engine.elapsed[:], env.engine.elapsed[:] = 4.5, 4.5  # within the switch: the shape morphs (one clock each)
    ff = sim.targets()[1]
    assert np.abs(ff).max() > 1e-3
    v_sim, v_env = sim.nominal_velocity(), env.task.nominal_velocity(env.engine)[0]
    np.testing.assert_allclose(env.task.feed_forward[0], ff, rtol=1e-12)
    peak = np.maximum(np.nanmax(np.abs(v_sim), axis=1) / env.config.max_joint_speed, 1.0)  # the env scales to its speed
    np.testing.assert_allclose(v_env, v_sim / peak[:, None], rtol=1e-10, atol=1e-12)


def test_the_moving_env_passes_the_api_tests() -> None:
    parallel_api_test(_moving_env(max_steps=40, success_hold=1.0), num_cycles=40)
    env = gymnasium.make("pan1_env:pan1_env/MovingFormation-v0", max_steps=40, success_hold=1.0)
    from gymnasium.utils.env_checker import check_env

    check_env(env.unwrapped, skip_render_check=True)
    assert env.unwrapped.observation_layout.motion


def test_every_copy_of_the_vector_env_follows_its_own_moving_team() -> None:
    """In the vector env each copy's desired lengths are its own team's moving shape at its own clock (copies
    reset at different times by autoreset), and its observations carry its feed-forward."""
    from pan1_env.vector import Pan1VectorEnv

    venv = Pan1VectorEnv("pan1_env/MovingFormation-v0", 3, max_steps=7, success_hold=0.1,
                         random_options={"scale_period": 1.0})
    venv.reset(seed=5)
    venv.step(np.zeros((3, venv.single_action_space.shape[0]), np.float32))
    venv.core.reset(np.array([1]))  # copy 1 starts a new episode: its clock is behind the others'
    obs, *_ = venv.step(np.zeros((3, venv.single_action_space.shape[0]), np.float32))
    core = venv.core
    clock = core.engine.elapsed
    assert clock[1] < clock[0] == clock[2]
    layout = core.layout
    segment = layout.segments(venv.teams[0].arms[0].n_links)["formation_velocity"]
    for b, team in enumerate(venv.teams):
        r, _ = team.motion.shape(team.formation.target, clock[b])
        lengths = np.linalg.norm(r[0, team.formation.edges[:, 0]] - r[0, team.formation.edges[:, 1]], axis=-1)
        np.testing.assert_allclose(core.task.distances[b], lengths, rtol=1e-12)
        np.testing.assert_allclose(obs[b, segment], core.task.feed_forward[b, 0], rtol=1e-6)
    assert len({tuple(team.motion.scales) for team in venv.teams}) == 3


def _signed_areas(shape: np.ndarray) -> np.ndarray:
    """The square graph's two triangles (0, 1, 2) and (0, 2, 3): their signed areas."""
    def area(a, b, c):
        u, v = shape[b] - shape[a], shape[c] - shape[a]
        return u[0] * v[1] - u[1] * v[0]
    return np.array([area(0, 1, 2), area(0, 2, 3)])


@pytest.mark.parametrize("lengths", [RECTANGLE, [0.796, 0.981, 1.545, 1.595, 1.695], [0.6, 0.9, 1.0, 0.8, 1.2]])
def test_a_switch_keeps_every_triangle_the_way_round_it_was(lengths) -> None:
    """The switch shape realises the lengths with no triangle turned over (a local search from the formation alone
    finds the folded twin of the second set), so the blend never passes through a flat triangle."""
    team = scenario.from_dict(_square({"switch_distances": lengths, "switch_time": 10.0, "switch_duration": 5.0}))
    end, start = team.motion.switch_shape, team.formation.target
    edges = team.formation.edges
    np.testing.assert_allclose(np.linalg.norm(end[edges[:, 0]] - end[edges[:, 1]], axis=-1), lengths, rtol=1e-9)
    for lam in np.linspace(0.0, 1.0, 101):
        assert np.all(np.sign(_signed_areas(start + lam * (end - start))) == np.sign(_signed_areas(start)))


def test_a_folded_switch_is_refused() -> None:
    """A switch shape with a triangle turned over (vertex 3 mirrored across the diagonal 0–2: the same lengths)
    blends through a flat triangle: Scenario refuses it, and :func:`blend_degenerates` says where."""
    import dataclasses

    from pan1_env.motion import blend_degenerates

    team = _moving_square()
    start = team.formation.target
    folded = start.copy()
    folded[3] = start[1]  # the square's vertex 3 mirrored across its diagonal 0–2 lands on vertex 1
    folded[3] += [0.05, -0.05]
    edges = team.formation.edges
    lam = blend_degenerates(edges, start, folded)
    assert lam is not None and 0.0 < lam < 1.0
    flat = start + lam * (folded - start)
    assert np.abs(_signed_areas(flat)[1]) < 0.1 * np.abs(_signed_areas(start)[1])
    with pytest.raises(ValueError, match=r"Scenario\.motion: the edges stop holding the shape rigid \d+% of the way"):
        dataclasses.replace(team, motion=FormationMotion([0.0], [1.0], folded, 1.0, 2.0))
    assert blend_degenerates(edges, start, team.motion.switch_shape) is None


def test_a_long_episode_checks_its_motion_at_its_keyframes() -> None:
    """The reach check samples the keyframes and the switch, where a length's extremes lie: a 10⁶ s episode with
    a keyframe at its end loads (samples every 0.05 s of it would not fit in memory)."""
    for keyframes in ([[0, 1.0], [10, 1.1]], [[0, 1.0], [1e6, 1.1]]):
        data = _square({"scale": keyframes})
        data["simulation"]["horizon"] = 1e6
        assert scenario.from_dict(data).motion.scales[-1] == 1.1


def test_the_frame_measures_the_moving_lengths() -> None:
    """Rendered while the square grows (by 12 % at 60 s) and the reference tracks it, every edge is drawn formed
    (green) and the fitted grey shape is the one at that time."""
    from matplotlib.colors import to_rgb

    from pan1_env.render import Renderer

    team = _moving_square(scale=[[0, 1.0], [100, 1.2]], switch_time=99.0)  # still growing at 60 s
    env = parallel_env(team, render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    policy = ReferencePolicy(env)
    for _ in range(1200):
        obs, _, _, _, infos = env.step(policy(obs))
    assert np.abs(env.task.feed_forward).max() > 0
    assert infos["arm_0"]["formation_error"] < 0.005
    renderer = Renderer()
    try:
        renderer.draw(env)
        edges = [line.get_color() for line in renderer.ax.lines  # the edges: solid, 1.5 pt
                 if line.get_linestyle() == "-" and line.get_linewidth() == 1.5]
        assert len(edges) == len(team.formation.edges)
        assert all(to_rgb(c) == to_rgb("tab:green") for c in edges)
        grey = [line.get_xydata() for line in renderer.ax.lines if line.get_linestyle() == "--"]
        side = np.linalg.norm(grey[0][0] - grey[0][1])
        assert side == pytest.approx(1.12 * 0.7, rel=1e-6)  # s(60 s) = 1.12
    finally:
        renderer.close()
        env.close()


def test_the_state_carries_the_moving_target() -> None:
    """A centralised critic's state ends, for a moving formation, with the desired lengths now and every arm's
    feed-forward; a still formation's state is as before."""
    env = parallel_env(_moving_square())
    env.reset(seed=0)
    for _ in range(1100):  # into the growth (50–70 s)
        env.step({a: np.zeros(env.action_space(a).shape, np.float32) for a in env.agents})
    state = env.state()
    E, N = len(env.task.edges), 4
    team = env.scenario
    r, _ = team.motion.shape(team.formation.target, env.engine.elapsed[0])
    lengths = np.linalg.norm(r[0, team.formation.edges[:, 0]] - r[0, team.formation.edges[:, 1]], axis=-1)
    np.testing.assert_allclose(state[-(E + 2 * N):-2 * N], lengths, rtol=1e-6)
    assert lengths[0] > 1.0001 * 0.7
    assert state.shape == env.state_space.shape
    np.testing.assert_allclose(state[-(E + 2 * N):-2 * N], env.task.distances[0], rtol=1e-6)
    np.testing.assert_allclose(state[-2 * N:], env.task.feed_forward[0].ravel(), rtol=1e-5, atol=1e-7)
    assert np.abs(state[-2 * N:]).max() > 0
    still = parallel_env("paper_pa3_square")
    assert still.state_space.shape[0] == env.state_space.shape[0] - E - 2 * N


def test_a_team_that_faults_and_moves_observes_both_and_the_reference_is_the_law() -> None:
    """Faults and a moving formation together: the feed-forward comes before the fault flag, and the reference
    from observations equals the env's law through both (the drift's cancellation and the feed-forward)."""
    options = {"fault_probability": 1.0, "fault_time": (0.1, 0.3), "passive_damping": 0.5, "scale_period": 1.0}
    env, obs, pairs, _ = reference_and_law(lambda **kw: _moving_env(random_options=options, **kw), seed=3, steps=12,
                                        action_seed=4)
    assert env.engine.faulted.any() and np.abs(env.task.feed_forward).max() > 1e-3
    for i, agent in enumerate(env.agents):
        seg = env.observation_layout.segments(env.scenario.arms[i].n_links)
        assert seg["formation_velocity"].stop == seg["actuator_lost"].start == len(obs[agent]) - 1
        np.testing.assert_allclose(obs[agent][seg["formation_velocity"]], env.task.feed_forward[0, i], rtol=1e-6)
        assert obs[agent][-1] == float(env.engine.faulted[0, i])
    for law, reference in pairs:
        np.testing.assert_allclose(law, reference, rtol=1e-4, atol=1e-5)


def test_a_new_episode_holds_its_success_afresh() -> None:
    """A team that starts formed succeeds 5 s into every episode (held still), even after an episode whose error
    was above the tolerance at 3 s: the hold's clock restarts at the reset."""
    import dataclasses

    from pan1_env.dynamics import end_effector

    team = scenario.load("paper_pa3_square")
    starts = np.array([end_effector(arm, q) for arm, q in zip(team.arms, team.q0, strict=True)])
    edges = team.formation.edges
    formed = Formation.from_edges(edges.tolist(), np.linalg.norm(starts[edges[:, 0]] - starts[edges[:, 1]], axis=-1), 4)
    env = parallel_env(dataclasses.replace(team, formation=formed), success_hold=5.0)
    still = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    errors = [env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})[4]["arm_0"]
              ["formation_error"] for _ in range(60)]
    assert max(errors) >= 0.01
    for _ in range(2):  # the first episode ended unformed; the second is interrupted formed
        _, infos = env.reset(seed=0)
        assert infos["arm_0"]["formation_error"] < 1e-9 and not infos["arm_0"]["is_success"]
        success = [env.step(still)[4]["arm_0"]["is_success"] for _ in range(120)]
        assert not any(success[:99]) and all(success[99:])


def _triangles(edges: np.ndarray, N: int) -> list[tuple[int, int, int]]:
    linked = {tuple(sorted(e)) for e in edges.tolist()}
    return [(i, j, k) for i in range(N) for j in range(i + 1, N) for k in range(j + 1, N)
            if {(i, j), (i, k), (j, k)} <= linked]


def _area(shape: np.ndarray, i: int, j: int, k: int) -> float:
    u, v = shape[j] - shape[i], shape[k] - shape[i]
    return float(u[0] * v[1] - u[1] * v[0])


def test_a_pentagons_switch_turns_no_triangle_over() -> None:
    """Five arms, a regular pentagon switching to lengths whose folded realisation turns triangle (0, 3, 4) over
    through a dip in the rigidity too narrow for the samples: the switch shape kept has every triangle the way
    round it was along the whole blend, and the folded one is refused (its triangle found exactly)."""
    import dataclasses

    from pan1_env.motion import blend_degenerates

    data = _square(None)
    angles = 2 * np.pi * np.arange(5) / 5
    data["arms"] = [{"base": [float(1.2 * np.cos(a)), float(1.2 * np.sin(a))], "q0": [float(a + np.pi), 0.3, -0.3, 0.2]}
                    for a in angles]
    data["formation"] = {"shape": "polygon", "size": 0.5, "motion": {
        "switch_distances": [0.7004147806421304, 0.23738579930593617, 0.23773842976314924, 0.2883466786229976,
                             0.5082233790821523, 0.46344275689276887, 0.6159534189974551],
        "switch_time": 10.0, "switch_duration": 5.0}}
    data["obstacles"] = [{"center": [5.0, 5.0], "radius": 0.05}]
    team = scenario.from_dict(data)
    start, end, edges = team.formation.target, team.motion.switch_shape, team.formation.edges
    triangles = _triangles(edges, 5)
    assert (0, 3, 4) in triangles
    for lam in np.linspace(0.0, 1.0, 2001):
        blend = start + lam * (end - start)
        assert all(np.sign(_area(blend, *t)) == np.sign(_area(start, *t)) for t in triangles)
    folded = end.copy()  # vertex 4 mirrored across the line 0–3: the same lengths, triangle (0, 3, 4) turned over
    axis = (end[3] - end[0]) / np.linalg.norm(end[3] - end[0])
    offset = end[4] - end[0]
    folded[4] = end[0] + 2 * np.dot(offset, axis) * axis - offset
    np.testing.assert_allclose(np.linalg.norm(folded[edges[:, 0]] - folded[edges[:, 1]], axis=-1),
                               np.linalg.norm(end[edges[:, 0]] - end[edges[:, 1]], axis=-1), rtol=1e-12)
    lam = blend_degenerates(edges, start, folded)
    assert lam is not None
    assert abs(_area(start + lam * (folded - start), 0, 3, 4)) < 1e-9
    with pytest.raises(ValueError, match="the edges stop holding the shape rigid"):
        dataclasses.replace(team, motion=FormationMotion([0.0], [1.0], folded, 10.0, 5.0))


def test_the_benchmarks_time_to_formation_is_the_errors_not_the_holds() -> None:
    """A team that starts formed and is held still: the time to formation is 0 with a 5 s hold as without one,
    though ``is_success`` turns on only 5 s in."""
    import dataclasses

    from pan1_env.baselines.benchmark import run_episode
    from pan1_env.dynamics import end_effector

    team = scenario.load("paper_pa3_square")
    starts = np.array([end_effector(arm, q) for arm, q in zip(team.arms, team.q0, strict=True)])
    edges = team.formation.edges
    formed = Formation.from_edges(edges.tolist(), np.linalg.norm(starts[edges[:, 0]] - starts[edges[:, 1]], axis=-1), 4)
    for hold in (0.0, 5.0):
        env = parallel_env(dataclasses.replace(team, formation=formed), success_hold=hold, max_steps=120)
        still = {a: np.zeros(env.action_space(a).shape, np.float32) for a in env.possible_agents}
        result = run_episode(env, lambda obs, still=still: still, 0, False)
        assert result["success"] and result["time_to_formation"] == 0.0


def test_the_targets_are_computed_once_for_a_clock_and_state(monkeypatch) -> None:
    """A gain-mode step asks for a moving formation's targets twice at the same clock and end-effectors (the law
    at its start, the observation at its end: the next step's law asks at the same) and a critic's state a third
    time: they are computed once per clock and state, and again after new teams are loaded, where they equal a
    fresh computation."""
    from pan1_env.motion import MotionTable
    from pan1_env.vector import Pan1VectorEnv

    calls = []
    targets = MotionTable.targets
    monkeypatch.setattr(MotionTable, "targets", lambda self, *args: calls.append(1) or targets(self, *args))
    env = Pan1VectorEnv("pan1_env/MovingFormation-v1", 3, action_mode="gain", max_steps=50)
    env.reset(seed=1)
    calls.clear()
    for _ in range(10):
        env.step(np.zeros(env.action_space.shape, np.float32))
        env.core.state()
    assert len(calls) == 10  # one per step (the observation's), shared by the next law and the state
    task, engine = env.core.task, env.core.engine
    env.reset(seed=2)  # new teams and motions, the clocks back at 0
    fresh = targets(task.motion, engine.elapsed, task.edges, engine.positions())
    np.testing.assert_array_equal(task.distances, fresh[0])
    np.testing.assert_array_equal(task.feed_forward, fresh[1])
