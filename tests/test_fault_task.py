"""Actuator faults as a task: scenario ``[[faults]]`` entries and random fault options, the fault flag in the
observation and the infos, the lost joint's action ignored, the reference law through a fault, and
``pan1_env/FaultFormation-v0`` checked by Gymnasium's and PettingZoo's own API tests."""

from __future__ import annotations

from importlib import resources

import gymnasium
import numpy as np
import pytest
import tomllib
from pettingzoo.test import parallel_api_test
from rollouts import reference_and_law

from pan1_env import scenario
from pan1_env.environment import parallel_env
from pan1_env.random_scenario import RandomScenarioOptions, random_scenario
from pan1_env.registration import env_arguments

EARLY = {"fault_probability": 1.0, "fault_time": (0.1, 0.3)}  # every full arm faults within the first 0.3 s


def _mixed_toml(faults: str) -> dict:
    text = resources.files("pan1_env.scenarios").joinpath("paper_pa_mixed_square.toml").read_text()
    text = faults + text if faults.startswith("faults =") else text + faults  # a top-level key goes first
    return tomllib.loads(text)


def test_faults_in_a_scenario_file() -> None:
    team = scenario.from_dict(_mixed_toml("[[faults]]\narm = 2\ntime = 1.5\n[[faults]]\narm = 0\ntime = 0\n"))
    np.testing.assert_array_equal(team.fault_times, [0.0, np.inf, 1.5, np.inf])
    assert scenario.from_dict(_mixed_toml("")).fault_times is None


@pytest.mark.parametrize(("faults", "message"), [
    ("[[faults]]\narm = 3\ntime = 1.0\n", r"faults\[0\]\.arm: arm 3's first joint is passive already"),
    ("[[faults]]\narm = 4\ntime = 1.0\n", r"faults\[0\]\.arm: expected an arm index from 0 to 3, got 4"),
    ("[[faults]]\narm = true\ntime = 1.0\n", r"faults\[0\]\.arm: expected an arm index"),
    ("[[faults]]\narm = 0\ntime = 101\n", r"faults\[0\]\.time: 101 s is after the episode's end"),
    ("[[faults]]\narm = 0\ntime = -1\n", r"faults\[0\]\.time: must be non-negative"),
    ("[[faults]]\narm = 0\n", r"faults\[0\]\.time: missing"),
    ("[[faults]]\narm = 0\ntime = 1\n[[faults]]\narm = 0\ntime = 2\n", r"faults\[1\]\.arm: arm 0 has a fault already"),
    ("[[faults]]\narm = 0\ntime = 1\nwhen = 2\n", r"faults\[0\]\.when: unknown key"),
    ("faults = 3\n", r"faults: expected an array of tables"),
], ids=["passive_arm", "arm_out_of_range", "arm_not_int", "time_after_horizon", "negative_time", "time_missing",
        "second_fault", "unknown_key", "not_tables"])
def test_bad_faults_in_a_scenario_file(faults: str, message: str) -> None:
    with pytest.raises(scenario.ScenarioError, match=message):
        scenario.from_dict(_mixed_toml(faults))


def test_random_fault_options_draw_after_the_team() -> None:
    """A team drawn with faults is the same seed's team without them, plus fault times for its full arms only,
    within ``fault_time`` (bad options: tests/test_random_scenario.py)."""
    plain = random_scenario(np.random.default_rng(3), RandomScenarioOptions())
    faulty = random_scenario(np.random.default_rng(3), RandomScenarioOptions(fault_probability=1.0,
                                                                             fault_time=(2.0, 4.0)))
    assert plain.fault_times is None
    for a, b in zip(faulty.arms, plain.arms, strict=True):
        assert a == b
    for a, b in zip(faulty.q0, plain.q0, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(faulty.obstacles.centers, plain.obstacles.centers)
    full = np.array([not arm.passive_first_joint for arm in faulty.arms])
    assert full.any() and (~full).any()
    assert np.all((faulty.fault_times[full] >= 2.0) & (faulty.fault_times[full] <= 4.0))
    assert np.all(np.isinf(faulty.fault_times[~full]))


def _fault_env(**kw):
    name, args = env_arguments("pan1_env/FaultFormation-v0", {"random_options": EARLY} | kw)
    return parallel_env(name, **args)


def test_the_fault_flag_the_infos_and_the_ignored_action() -> None:
    """The flag (last observation entry) and ``actuator_lost`` turn on at an arm's fault and stay on; from then
    on the first entry of its action changes nothing."""
    envs = [_fault_env(), _fault_env()]
    for env in envs:
        env.reset(seed=11)
    env = envs[0]
    full = [i for i, arm in enumerate(env.scenario.arms) if not arm.passive_first_joint]
    layout = env.observation_layout
    rng = np.random.default_rng(0)
    seen = np.zeros(env.num_agents, dtype=bool)
    for _ in range(12):
        actions = {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}
        other = {a: act.copy() for a, act in actions.items()}
        for i in full:
            if seen[i]:  # the lost joint's entry differs between the two envs
                other[env.agents[i]][0] = -actions[env.agents[i]][0]
        results = [e.step(acts) for e, acts in zip(envs, (actions, other), strict=True)]
        obs, infos = results[0][0], results[0][4]
        for i, agent in enumerate(env.agents):
            flag = obs[agent][layout.segments(layout.n[i])["actuator_lost"]][0]
            assert flag == float(infos[agent]["actuator_lost"])
            assert infos[agent]["actuator_lost"] >= seen[i]
            seen[i] = bool(infos[agent]["actuator_lost"])
            np.testing.assert_array_equal(obs[agent], results[1][0][agent])
    assert seen[full].all() and not seen[[i for i in range(env.num_agents) if i not in full]].any()


def test_the_flag_shows_a_fault_from_its_sub_step() -> None:
    """An observation shows an arm's fault once the sub-step that contains its time has begun: a fault at
    0 s in the reset's observation, others at the first observation at most one sub-step before their time;
    behind the shield, the lost joint's ``shield_applied`` entry reads 0, and a reset gives the actuator back."""
    from pan1_env.wrappers import SafetyShield

    env = SafetyShield(_fault_env(random_options={"fault_probability": 1.0, "fault_time": (0.0, 0.4)}))
    for seed in (3, 4):
        obs, infos = env.reset(seed=seed)
        times, dt = env.unwrapped.scenario.fault_times, env.unwrapped.engine.physics_dt
        for step in range(12):
            now = step * env.unwrapped.dt
            for i, agent in enumerate(env.agents):
                assert infos[agent]["actuator_lost"] == (times[i] < now + dt - 1e-9), (seed, step, i, times[i])
                applied = infos[agent]["shield_applied"]
                if step and infos[agent]["actuator_lost"]:
                    assert applied[0] == 0.0 and np.isfinite(applied).all()
            obs, _, _, _, infos = env.step({a: np.full(env.action_space(a).shape, 0.5, np.float32) for a in env.agents})
    zero = _fault_env(random_options={"fault_probability": 1.0, "fault_time": (0.0, 0.0)})
    obs, infos = zero.reset(seed=5)
    full = [i for i, arm in enumerate(zero.scenario.arms) if not arm.passive_first_joint]
    assert all(infos[zero.agents[i]]["actuator_lost"] for i in full)


def test_the_reference_law_through_a_fault_is_the_tasks() -> None:
    """After the faults, the reference policy from observations (the PAn−1 law minus J̄⁺ of the drift, p₁
    from the observed speeds) equals the env's own law from its state, as the residual mode's zero action."""
    env, obs, pairs, ref = reference_and_law(_fault_env, seed=12, steps=10, action_seed=1)
    assert env.engine.faulted.any()
    assert np.abs(env.engine.passive_momentum()[env.engine.faulted]).min() > 1e-3
    for i, (agent, (law, reference)) in enumerate(zip(env.agents, pairs, strict=True)):
        np.testing.assert_allclose(law, reference, rtol=1e-4, atol=1e-5)
        if env.engine.faulted[0, i]:
            assert law[0] == 0.0
            # a gain per action entry (as a gain-trained model gives): the lost joint's is dropped
            ones = np.ones(env.n_actuated[i])
            np.testing.assert_allclose(ref.act(agent, obs[agent], ones), ref.act(agent, obs[agent]))


@pytest.mark.parametrize("env_id", ["pan1_env/FaultFormation-v0", "pan1_env/FaultFormation-v1"])
def test_the_fault_env_passes_the_api_tests(env_id: str) -> None:
    """Both fault tasks (v1: behind the fault margin, in the whole-arm rows) pass PettingZoo's and Gymnasium's own
    API checks, with faults early in the episode."""
    name, args = env_arguments(env_id, {"random_options": EARLY, "max_steps": 40})
    parallel_api_test(parallel_env(name, **args), num_cycles=40)
    env = gymnasium.make(f"pan1_env:{env_id}", random_options=EARLY, max_steps=40)
    from gymnasium.utils.env_checker import check_env

    check_env(env.unwrapped, skip_render_check=True)
