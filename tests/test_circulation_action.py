"""``action_mode="circulation"``: the compiled circulation term (pan1_env/kernels/circulation.py) against its numpy
twin, the rule's :func:`~pan1_env.baselines.circulation.circulation_term` (itself checked by forward kinematics in
test_circulation_study.py); the zero action is the paper's law; entry 0 turns the command one way or the other;
every view gives each arm one entry more."""

import os
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from pan1_env.baselines.circulation import circulation_term
from pan1_env.centralized import CentralizedEnv
from pan1_env.engine import Engine
from pan1_env.environment import parallel_env
from pan1_env.random_scenario import RandomScenarioOptions, random_scenario
from pan1_env.vector import Pan1VectorEnv

WHOLE_ARM = "pan1_env/WholeArmStaticFormation-v1"


@pytest.mark.parametrize("bodies", ["end_effector", "links"])
def test_the_compiled_term_is_the_rules_numpy_term(bodies: str) -> None:
    """Random teams of two PA3 and two fully actuated 4-link arms (two arms per kind, so a kind's rows span copies
    and arms), one team per copy, at random joint angles with random commands; an activation of 3 m brings most
    (body point, obstacle) pairs into range."""
    rng = np.random.default_rng(11)
    options = RandomScenarioOptions(n_arms=4, links=(3, 3, 4, 4), bodies=bodies,
                                    link_radius=0.03 if bodies == "links" else 0.0, n_obstacles=3)
    teams = [random_scenario(rng, options) for _ in range(10)]
    engine = Engine(teams[0], len(teams))
    for b, team in enumerate(teams):
        engine.load_team(b, team)
        engine.set_state(b, [rng.uniform(-np.pi, np.pi, arm.n_links) for arm in team.arms],
                         [np.zeros(arm.n_links) for arm in team.arms])
    assert [kind.A for kind in engine.kinds] == [2, 2]
    pairs = 0
    for kind in engine.kinds:
        v0 = rng.uniform(-2.0, 2.0, (len(kind.q), kind.k))
        term = engine.circulation(kind, v0, 3.0)
        for row in range(len(kind.q)):
            b, arm_id = divmod(row, kind.A)
            team = teams[b]
            twin = circulation_term(team.arms[kind.ids[arm_id]], kind.q[row], v0[row], team.obstacles.centers,
                                    team.obstacles.radii, team.link_radius, bodies == "links", 1.0, 1.0, 3.0)
            np.testing.assert_allclose(term[row], twin, rtol=1e-9, atol=1e-12)
            pairs += bool(np.any(twin))
    assert pairs >= 10, "too few arms near an obstacle to check anything"


@pytest.mark.parametrize(("env_id", "options"), [
    ("pan1_env/WholeArmFormation-v2", {}),  # obstacles that move
    ("pan1_env/FaultFormation-v1", {"fault_probability": 1.0, "fault_time": (0.5, 2.0)})])  # arms that lose a joint
def test_the_envs_command_is_the_rules_term_on_the_gain_command(env_id: str, options: dict) -> None:
    """Through the env's own composition, with random gains and a random signed entry 0 per arm: the command is
    the gain command (entry 0 at zero) plus c times the rule's term computed from it, where the obstacles are now
    and, for an arm that lost its first actuator, as the PA arm it has become; then scaled to the speed bound."""
    env = parallel_env(env_id, action_mode="circulation", safety_filter=True, circulation_activation=0.6,
                       random_options=options or None)
    rng, speed = np.random.default_rng(3), env.config.max_joint_speed
    acted = lost_acted = 0
    env.reset(seed=2_000_001)
    for _ in range(80):
        sizes, team, engine = env.core.action_sizes, env.scenario, env.engine
        actions = {a: rng.uniform(-1, 1, k).astype(np.float32) for a, k in zip(env.agents, sizes, strict=True)}
        command, _ = env.commands(actions)
        gains, _ = env.commands({a: np.r_[0.0, act[1:]].astype(np.float32) for a, act in actions.items()})
        q, lost = engine.joint_state()[0][0], engine.faulted[0]
        for i, (agent, arm) in enumerate(zip(env.agents, team.arms, strict=True)):
            first = 1 if lost[i] else 0  # the command's columns of a PA arm made by a fault start at its second
            k = arm.n_actuated - first
            reduced = replace(arm, passive_first_joint=True) if lost[i] else arm
            v0 = gains[0, i, first:first + k]
            term = circulation_term(reduced, q[i, :arm.n_links], v0, engine.centers[0], engine.radii[0],
                                    team.link_radius, team.bodies == "links", 1.0, 1.0, 0.6)
            v = v0 + float(np.clip(actions[agent][0], -1, 1)) * term
            v /= max(1.0, np.abs(v).max() / speed)
            np.testing.assert_allclose(command[0, i, first:first + k], v, rtol=1e-9, atol=1e-12)
            acted += bool(np.any(term))
            lost_acted += bool(lost[i] and np.any(term))
        env.step(actions)
    assert acted >= 20 and (lost_acted >= 5 or not options), (acted, lost_acted)


def _law_and_turns(env):
    """The command of the zero action, and of entry 0 at +1 and −1 (the others zero)."""
    sizes = env.core.action_sizes
    zero = {a: np.zeros(k, np.float32) for a, k in zip(env.agents, sizes, strict=True)}
    law, _ = env.commands(zero)
    turned = {}
    for sign in (1.0, -1.0):
        turned[sign], _ = env.commands({a: np.r_[sign, np.zeros(k - 1)].astype(np.float32)
                                        for a, k in zip(env.agents, sizes, strict=True)})
    return law, turned


def test_the_zero_action_is_the_law_and_entry_0_turns_either_way() -> None:
    env = parallel_env(WHOLE_ARM, action_mode="circulation", safety_filter=True)
    gains = parallel_env(WHOLE_ARM, action_mode="gain", safety_filter=True)
    turning = 0
    for seed in range(2_000_000, 2_000_040):
        env.reset(seed=seed)
        gains.reset(seed=seed)
        for _ in range(60):  # the law's first steps, towards the obstacles in its way
            law, turned = _law_and_turns(env)
            zero, _ = gains.commands({a: np.zeros(gains.action_space(a).shape, np.float32) for a in gains.agents})
            np.testing.assert_array_equal(law, zero)
            plus, minus = turned[1.0] - law, turned[-1.0] - law
            if np.abs(plus).max() > 1e-3:
                turning += 1
                peak = np.maximum(np.abs(turned[1.0]).max(axis=-1), np.abs(turned[-1.0]).max(axis=-1))
                free = peak < env.config.max_joint_speed * (1 - 1e-9)  # arms not scaled down to the speed bound
                np.testing.assert_allclose(plus[free], -minus[free], atol=1e-12)
            env.step({a: np.zeros(k, np.float32) for a, k in zip(env.agents, env.core.action_sizes, strict=True)})
            gains.step({a: np.zeros(gains.action_space(a).shape, np.float32) for a in gains.agents})
        if turning >= 20:
            break
    assert turning >= 20, "the law should drive some arm at an obstacle within reach of the term"


def test_every_view_gives_each_arm_one_entry_more() -> None:
    kw = {"action_mode": "circulation", "safety_filter": True}
    par = parallel_env(WHOLE_ARM, **kw)
    plain = parallel_env(WHOLE_ARM, action_mode="gain")
    assert [par.action_space(a).shape[0] for a in par.possible_agents] == \
           [plain.action_space(a).shape[0] + 1 for a in plain.possible_agents]
    total = sum(par.core.action_sizes)
    assert CentralizedEnv(WHOLE_ARM, **kw).action_space.shape == (total,)
    venv = Pan1VectorEnv(WHOLE_ARM, 2, **kw)
    assert venv.single_action_space.shape == (total,)
    venv.reset(seed=0)
    out = venv.step(np.zeros((2, total), np.float32))
    assert np.all(np.isfinite(out[1]))
    flat = np.arange(2 * total, dtype=float).reshape(2, total)
    np.testing.assert_array_equal(venv.core.flat_actions(venv.core.padded_actions(flat).copy()), flat)


@pytest.mark.parametrize("bad", [{"circulation_gain": 0.0}, {"circulation_activation": -0.1},
                                 {"circulation_gain": float("nan")}])
def test_bad_circulation_settings_are_refused(bad: dict) -> None:
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        parallel_env(WHOLE_ARM, action_mode="circulation", **bad)
    with pytest.raises(ValueError, match="they need action_mode='circulation', got action_mode='gain'"):
        parallel_env(WHOLE_ARM, action_mode="gain", circulation_activation=0.2)


def test_the_circulation_env_passes_the_api_tests() -> None:
    """PettingZoo's and Gymnasium's own API checks, on whole arms among still obstacles behind the filter."""
    from gymnasium.utils.env_checker import check_env
    from pettingzoo.test import parallel_api_test

    parallel_api_test(parallel_env(WHOLE_ARM, action_mode="circulation", safety_filter=True, max_steps=40),
                      num_cycles=40)
    check_env(CentralizedEnv(WHOLE_ARM, action_mode="circulation", safety_filter=True, max_steps=40),
              skip_render_check=True)


_COMPILE = """
import numpy as np
from pan1_env.kernels import group_circulation
group_circulation(np.ones((1, 3, 3)), np.ones((1, 3)), np.zeros((1, 2)), np.zeros(1), True, np.zeros((1, 3)),
                  np.zeros(1, np.int64), np.ones((1, 1, 2)), np.full((1, 1), 0.1), 0.03, True, 0.1, np.ones((1, 2)),
                  np.empty((1, 2)))
"""


def test_the_term_says_once_that_it_compiles(tmp_path) -> None:
    """Its first use compiles for a few seconds: one notice on an empty cache, none once it is cached."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    first = subprocess.run([sys.executable, "-c", _COMPILE], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr[-2000:]
    assert first.stderr.count("compiling the circulation term") == 1, first.stderr
    again = subprocess.run([sys.executable, "-c", _COMPILE], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0 and "compil" not in again.stderr, again.stderr[-2000:]
