"""Random teams (pan1_env.random_scenario): what the generator draws for a seed, the starts it gives
(clear of the obstacles and of the other arms, by the independent checker in tests/geometry.py), and
its options' validation."""

from __future__ import annotations

import hashlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from geometry import (
    arms_from_state,
    inter_arm_clearances,
    inter_arm_penetration,
    joints,
    obstacle_clearances,
    obstacle_penetration,
    point_segment_distance,
)

from pan1_env.dynamics import end_effector
from pan1_env.environment import parallel_env
from pan1_env.random_scenario import BASE_MARGIN, RandomScenarioOptions, random_scenario

ROOT = Path(__file__).resolve().parents[1]
WHOLE_ARM = {"bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.05, 0.2),
             "links": (2, 3, 4, 3)}


DIGEST_CASES = {
    "default": ({}, "40c33cb34f617a926e57019ce1255d6678697f52d556cbeb1cf08c2a995bb0fb"),
    "mixed": ({"links": (2, 3, 4, 3), "passive_fraction": 0.5, "n_obstacles": 4},
              "1660d9d16402be35e3393599576651fa74ee5cca0c97ef0ce01ffc5af120f0c5"),
    "square": ({"shape": "square", "links": 2, "passive_fraction": 0.25},
               "0f46a45d5ef5920f5e6132904f2c2fe4b80f4e72472cdcc43920b7d73e1772dd"),
    "no_obstacles": ({"n_arms": 3, "n_obstacles": 0, "links": 4, "passive_fraction": 1.0},
                     "91637b73333a060ba0c117d9b1cdbde7f2611efe5e12715b25a0357b0049efa5"),
}
# the last commit before the whole-arm options, whose generator the default path must reproduce
BEFORE_WHOLE_ARM = "803ea7e5e924f2f9539f16754ab7065821c3eea4"


def _team_digest(sc) -> str:
    h = hashlib.sha256()
    parts = []
    for arm, q in zip(sc.arms, sc.q0, strict=True):
        parts += [arm.masses, arm.lengths, arm.com, arm.inertias, arm.base,
                  [arm.phi, float(arm.passive_first_joint)], q]
    parts += [sc.obstacles.centers.ravel(), sc.obstacles.radii, sc.formation.distances,
              np.asarray(sc.formation.edges, float).ravel()]
    for p in parts:
        h.update(np.round(np.asarray(p, dtype=np.float64), 10).tobytes())
    return h.hexdigest()


def _draws_digest(generate, options) -> str:
    h = hashlib.sha256()
    for seed in range(20):
        rng = np.random.default_rng(seed)
        for _ in range(2):
            h.update(_team_digest(generate(rng, options)).encode())
        h.update(rng.bit_generator.state["state"]["state"].to_bytes(16, "little"))  # no extra numbers drawn
    return h.hexdigest()


@pytest.mark.parametrize("case", list(DIGEST_CASES))
def test_default_options_draw_the_same_teams_as_before(case: str) -> None:
    options, digest = DIGEST_CASES[case]
    assert _draws_digest(random_scenario, RandomScenarioOptions(**options)) == digest


def test_default_options_draw_what_the_generator_before_whole_arm_options_drew(tmp_path: Path) -> None:
    try:
        old = subprocess.run(["git", "show", f"{BEFORE_WHOLE_ARM}:pan1_env/random_scenario.py"], cwd=ROOT,
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("no git history here")
    # its draws are what is compared; the Scenario it builds from them takes the filter's settings as one group now
    built = "kappa=opt.kappa, epsilon=opt.epsilon,"
    assert built in old
    old = old.replace(built, "filter=__import__('pan1_env.safety').safety.FilterParams(opt.kappa, opt.epsilon),")
    path = tmp_path / "random_scenario_before.py"
    path.write_text(old)
    spec = importlib.util.spec_from_file_location("pan1_env._random_scenario_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    for options, _ in DIGEST_CASES.values():
        assert (_draws_digest(random_scenario, RandomScenarioOptions(**options))
                == _draws_digest(module.random_scenario, module.RandomScenarioOptions(**options)))


@pytest.mark.parametrize("moving", [False, True], ids=["still", "moving"])
def test_whole_arm_random_starts_are_clear_by_the_independent_checker(moving: bool) -> None:
    from pan1_env.environment import parallel_env

    options = dict(WHOLE_ARM, obstacle_speed=(0.05, 0.2) if moving else (0.0, 0.0))
    env = parallel_env("random", random_options=options, control_dt=0.01, physics_dt=0.01)
    rho = options["link_radius"]
    for seed in range(25):
        env.reset(seed=seed)
        sc = env.scenario
        assert (sc.bodies, sc.link_radius, sc.inter_arm) == ("links", rho, True)
        arm_joints, parts = arms_from_state(env.state(), sc)
        clear = obstacle_clearances(arm_joints, parts["centers"], parts["radii"], rho)
        assert min(c.min() for c in clear) >= 0.05 - 1e-5  # start_clearance, in float32 state()
        assert all(np.all(p == 0) for p in obstacle_penetration(arm_joints, parts["centers"], parts["radii"], rho))
        assert min(c.min() for c in inter_arm_clearances(arm_joints, rho).values()) >= 0.05 - 1e-5
        assert all(np.all(p == 0) for p in inter_arm_penetration(arm_joints, rho).values())
        if not moving:
            assert sc.obstacle_paths is None
            continue
        assert np.all((sc.obstacle_speeds >= 0.05) & (sc.obstacle_speeds <= 0.2))
        lengths = np.linalg.norm(sc.obstacle_paths - sc.obstacles.centers, axis=-1)
        assert np.all((lengths >= 0.2) & (lengths <= 0.6))
        for c, e, r in zip(sc.obstacles.centers, sc.obstacle_paths, sc.obstacles.radii, strict=True):
            for arm in sc.arms:  # every point of the path keeps the obstacle BASE_MARGIN + ρ off every base
                assert point_segment_distance(arm.base, c, e) >= r + BASE_MARGIN + rho - 1e-12


def test_whole_arm_random_links_start_clear_of_obstacles() -> None:
    """bodies="links" without inter_arm: every link capsule starts start_clearance outside every obstacle."""
    for seed in range(40):
        sc = random_scenario(np.random.default_rng(seed), RandomScenarioOptions(bodies="links", link_radius=0.03))
        arm_joints = [joints(q, a.lengths, a.base, a.phi) for a, q in zip(sc.arms, sc.q0, strict=True)]
        np.testing.assert_allclose([P[-1] for P in arm_joints], [end_effector(a, q) for a, q in
                                                                  zip(sc.arms, sc.q0, strict=True)], atol=1e-12)
        assert all(c.min() >= 0.05 - 1e-12 for c in obstacle_clearances(arm_joints, sc.obstacles.centers,
                                                                         sc.obstacles.radii, 0.03))


def test_inter_arm_keeps_crowded_random_arms_apart() -> None:
    """Six 4-link arms on a small hexagon: without inter_arm many starts bring two arms' capsules within
    start_clearance (by the independent checker); with it none do."""
    crowded = {"n_arms": 6, "links": 4, "size": (0.3, 0.4), "bodies": "links", "link_radius": 0.03}
    close = {False: 0, True: 0}
    for inter_arm in (False, True):
        options = RandomScenarioOptions(**crowded, inter_arm=inter_arm)
        for seed in range(20):
            sc = random_scenario(np.random.default_rng(seed), options)
            arm_joints = [joints(q, a.lengths, a.base, a.phi) for a, q in zip(sc.arms, sc.q0, strict=True)]
            close[inter_arm] += min(c.min() for c in inter_arm_clearances(arm_joints, 0.03).values()) < 0.05
    assert close[False] >= 5 and close[True] == 0, close


@pytest.mark.parametrize(("options", "message"), [
    ({"bodies": "link"}, "RandomScenarioOptions.bodies must be one of ('end_effector', 'links'), got 'link'"),
    ({"bodies": "links", "link_radius": -0.01}, "RandomScenarioOptions.link_radius must be non-negative"),
    ({"link_radius": 0.03}, "RandomScenarioOptions.link_radius > 0 and inter_arm=True need bodies='links'"),
    ({"inter_arm": True}, "RandomScenarioOptions.link_radius > 0 and inter_arm=True need bodies='links'"),
    ({"inter_arm": 1}, "RandomScenarioOptions.inter_arm must be True or False, got 1"),
    ({"obstacle_speed": (0.2, 0.1)}, "RandomScenarioOptions.obstacle_speed must have low ≤ high"),
    ({"obstacle_speed": (-0.1, 0.1)}, "RandomScenarioOptions.obstacle_speed[0] must be non-negative"),
    ({"obstacle_speed": 0.1}, "RandomScenarioOptions.obstacle_speed must be a range (low, high)"),
    ({"obstacle_path_length": (0.0, 0.5)}, "RandomScenarioOptions.obstacle_path_length[0] must be positive"),
    ({"passive_damping": -0.5}, "RandomScenarioOptions.passive_damping must be non-negative"),
    ({"fault_probability": 1.5}, "RandomScenarioOptions.fault_probability must lie in [0, 1], got 1.5"),
    ({"fault_probability": -0.1}, "RandomScenarioOptions.fault_probability must be non-negative"),
    ({"fault_probability": 0.5, "fault_time": (3.0, 2.0)},
     "RandomScenarioOptions.fault_time must have low ≤ high ≤ horizon (100 s)"),
    ({"fault_probability": 0.5, "fault_time": (1.0, 200.0)},
     "RandomScenarioOptions.fault_time must have low ≤ high ≤ horizon (100 s)"),
    ({"fault_time": 3.0}, "RandomScenarioOptions.fault_time must be a range (low, high) in seconds, got 3.0"),
    ({"arm_redraws": -1}, "RandomScenarioOptions.arm_redraws must be an integer ≥ 0, got -1"),
    ({"arm_redraws": 1.5}, "RandomScenarioOptions.arm_redraws must be an integer ≥ 0, got 1.5"),
    ({"shape": "rng"}, "RandomScenarioOptions.shape must be one of ('square', 'polygon', 'ring'), got 'rng'"),
    ({"clear_paths": "yes"}, "RandomScenarioOptions.clear_paths must be True or False, got 'yes'"),
    ({"fallback": "brake"}, "RandomScenarioOptions.fallback must be one of ('command', 'barrier_rate'), got 'brake'"),
    ({"lookahead": -1.0}, "RandomScenarioOptions.lookahead must be non-negative"),
    ({"lookahead": float("nan")}, "RandomScenarioOptions.lookahead must be finite"),
    ({"fault_margin": "yes"}, "RandomScenarioOptions.fault_margin must be True or False, got 'yes'"),
], ids=["bodies_misspelt", "negative_link_radius", "link_radius_without_links", "inter_arm_without_links",
        "inter_arm_not_bool", "speed_range_reversed", "negative_speed", "speed_not_a_range", "zero_path_length",
        "negative_damping", "fault_probability_above_1", "negative_fault_probability", "fault_time_reversed",
        "fault_time_after_horizon", "fault_time_not_a_range", "negative_redraws", "fractional_redraws",
        "shape_misspelt", "clear_paths_not_bool", "fallback_misspelt", "negative_lookahead", "nan_lookahead",
         "fault_margin_not_bool"])
def test_random_options_bad_input(options: dict, message: str) -> None:
    with pytest.raises(ValueError) as err:
        RandomScenarioOptions(**options)
    assert str(err.value).startswith(message), str(err.value)


def test_passive_damping_changes_no_draw() -> None:
    """A damped team is the undamped one's, seed for seed, with b on every arm."""
    plain = random_scenario(np.random.default_rng(4), RandomScenarioOptions())
    damped = random_scenario(np.random.default_rng(4), RandomScenarioOptions(passive_damping=0.7))
    assert [a.passive_damping for a in damped.arms] == [0.7] * 4
    for arm, arm_plain in zip(damped.arms, plain.arms, strict=True):
        for name in ("masses", "lengths", "com", "inertias", "base"):
            np.testing.assert_array_equal(getattr(arm, name), getattr(arm_plain, name))
        assert (arm.phi, arm.passive_first_joint) == (arm_plain.phi, arm_plain.passive_first_joint)
    for q, q_plain in zip(damped.q0, plain.q0, strict=True):
        np.testing.assert_array_equal(q, q_plain)


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


def test_a_seed_draws_one_team_and_the_next_draw_another() -> None:
    options = RandomScenarioOptions(links=(2, 3, 4, 3), n_obstacles=4)
    first, again = (random_scenario(np.random.default_rng(7), options) for _ in range(2))
    rng = np.random.default_rng(7)
    random_scenario(rng, options)
    other = random_scenario(rng, options)
    for a, b in zip(first.arms, again.arms, strict=True):
        np.testing.assert_array_equal(a.lengths, b.lengths)
        np.testing.assert_array_equal(a.base, b.base)
    np.testing.assert_array_equal(first.obstacles.centers, again.obstacles.centers)
    assert not np.allclose([a.base for a in first.arms], [a.base for a in other.arms])


@pytest.mark.parametrize("fraction, passive", [(0.0, [False] * 4), (0.5, [True, True, False, False]),
                                               (1.0, [True] * 4)])
def test_the_options_fix_the_team_structure(fraction: float, passive: list[bool]) -> None:
    options = RandomScenarioOptions(links=(2, 3, 4, 3), passive_fraction=fraction, n_obstacles=2)
    for seed in range(5):
        sc = random_scenario(np.random.default_rng(seed), options)
        assert [arm.n_links for arm in sc.arms] == [2, 3, 4, 3]
        assert [arm.passive_first_joint for arm in sc.arms] == passive
        assert [q.shape for q in sc.q0] == [(2,), (3,), (4,), (3,)]
        assert len(sc.obstacles.radii) == 2
        assert np.all((sc.obstacles.radii >= 0.05) & (sc.obstacles.radii <= 0.12))


def test_end_effectors_start_clear_of_every_obstacle() -> None:
    options = RandomScenarioOptions(n_obstacles=4)
    for seed in range(30):
        sc = random_scenario(np.random.default_rng(seed), options)
        for arm, q in zip(sc.arms, sc.q0, strict=True):
            gaps = np.linalg.norm(end_effector(arm, q) - sc.obstacles.centers, axis=1) - sc.obstacles.radii
            assert gaps.min() >= options.start_clearance - 1e-12


def test_options_too_tight_to_draw_raise_runtime_error() -> None:
    # obstacles at least 2 m wide cannot leave four 3-link arms' end-effectors 5 cm clear
    options = RandomScenarioOptions(n_obstacles=6, obstacle_radius=(2.0, 2.5))
    with pytest.raises(RuntimeError):
        random_scenario(np.random.default_rng(0), options, max_tries=5)


def test_a_short_horizon_needs_no_fault_time_without_faults() -> None:
    """The default ``fault_time`` (1–10 s) is checked against the horizon only where faults are drawn: a 0.6 s
    episode without faults is fine, and its moving formation's keyframes stay within it."""
    team = random_scenario(np.random.default_rng(0), RandomScenarioOptions(horizon=0.6, formation_scale=(0.9, 1.1),
                                                                           scale_period=0.2))
    assert team.motion.scale_times.tolist() == [0.0, 0.2, 0.4, 0.6] and team.fault_times is None
    with pytest.raises(ValueError, match=r"fault_time must have low ≤ high ≤ horizon \(0.6 s\)"):
        RandomScenarioOptions(horizon=0.6, fault_probability=0.5)
