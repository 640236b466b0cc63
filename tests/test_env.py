"""The PettingZoo env and the Gymnasium view: API conformance, seeding, rendering, bad input."""

import inspect
import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test

import pan1_env
from pan1_env.baselines import ReferencePolicy
from pan1_env.environment import env as aec_env
from pan1_env.environment import parallel_env
from pan1_env.formation import edge_length_errors, edge_vectors
from pan1_env.registration import REACH_ENV_ID

MIXED = {"links": (2, 3, 4, 3), "passive_fraction": 0.5}


@pytest.mark.parametrize("scenario", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_parallel_api_paper(scenario: str) -> None:
    parallel_api_test(parallel_env(scenario), num_cycles=100)


def test_parallel_api_random_mixed_n() -> None:
    e = parallel_env("random", random_options=MIXED)
    assert len({e.action_space(a).shape for a in e.possible_agents}) > 1
    parallel_api_test(e, num_cycles=100)


@pytest.mark.parametrize("scenario", ["paper_pa_mixed_square", "random"])
def test_aec_api(scenario: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        api_test(aec_env(scenario), num_cycles=50)


@pytest.mark.parametrize("env_id,max_steps", [(i, 2000) for i in sorted(pan1_env.ENV_IDS)] + [(REACH_ENV_ID, 200)])
def test_gymnasium_check_env_no_warnings(env_id: str, max_steps: int) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = gymnasium.make(env_id)
        check_env(env.unwrapped)
    # Gymnasium's own nudge for an id with a newer version (RandomFormation-v0 now that v1 exists) is
    # its registry's rule, not the env's: v0 stays as it was for the models trained on it
    newer = f"The environment {env_id} is out of date"
    assert [str(w.message) for w in caught if newer not in str(w.message)] == []
    # the env's own clock truncates (one rule: max_steps); no TimeLimit that could disagree with it
    assert env.spec.max_episode_steps is None and env.unwrapped.config.max_steps == max_steps


def test_episode_length_follows_control_dt_through_gymnasium_make() -> None:
    """The episode lasts the scenario's horizon whatever control_dt is: 100 s = 1000 steps of 0.1 s."""
    env = gymnasium.make("pan1_env:pan1_env/PaperPA3Square-v0", control_dt=0.1, max_steps=None)
    env.reset(seed=0)
    steps, truncated = 0, False
    while not truncated:
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
        steps += 1
        assert not terminated
    assert steps == 1000 == env.unwrapped.config.max_steps


def test_make_in_fresh_interpreter(tmp_path) -> None:
    code = ("import gymnasium, numpy as np\n"
            "e = gymnasium.make('pan1_env:pan1_env/RandomFormation-v0')\n"
            "o, i = e.reset(seed=3)\n"
            "o, r, te, tr, i = e.step(e.action_space.sample())\n"
            "assert np.all(np.isfinite(o)) and 'cost' in i\n"
            "print('ok', o.shape)\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("ok")


def _rollout(seed: int, steps: int, action_seed: int = 0) -> list[np.ndarray]:
    e = parallel_env("random", random_options=MIXED)
    obs, _ = e.reset(seed=seed)
    rng = np.random.default_rng(action_seed)
    out = []
    for _ in range(steps):
        actions = {a: rng.uniform(-1, 1, e.action_space(a).shape).astype(np.float32) for a in e.agents}
        obs, _, _, _, _ = e.step(actions)
        out.append(np.concatenate([obs[a] for a in e.possible_agents]))
        if not e.agents:
            obs, _ = e.reset()
    return out


def test_same_seed_same_episode_for_1000_steps() -> None:
    a, b = _rollout(7, 1000), _rollout(7, 1000)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    c = _rollout(8, 5)
    assert not np.array_equal(a[0], c[0])


def test_reset_seed_redraws_random_team() -> None:
    e = parallel_env("random")
    e.reset(seed=1)
    bases1 = [a.base for a in e.scenario.arms]
    e.reset(seed=2)
    bases2 = [a.base for a in e.scenario.arms]
    assert not np.allclose(bases1, bases2)
    e.reset(seed=1)
    np.testing.assert_array_equal(bases1, [a.base for a in e.scenario.arms])


@pytest.mark.parametrize("scenario", ["paper_pa3_square", "paper_pa_mixed_square"])
def test_rgb_array_frame_shows_the_scene(scenario: str) -> None:
    e = parallel_env(scenario, render_mode="rgb_array")
    e.reset(seed=0)
    frame = e.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    red = (frame[..., 0] > 180) & (frame[..., 1] < 120) & (frame[..., 2] < 120)
    assert red.sum() > 20, "obstacles (red) should be drawn"
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20
    e.close()


@pytest.mark.parametrize("scenario", ["paper_pa3_square", "paper_pa_mixed_square", "random"])
def test_zero_velocity_keeps_arms_still(scenario: str) -> None:
    e = parallel_env(scenario)
    e.reset(seed=0)
    q0, _ = e.joint_state()
    for _ in range(50):
        e.step({a: np.zeros(e.action_space(a).shape, np.float32) for a in e.agents})
    q, qd = e.joint_state()
    np.testing.assert_allclose(q, q0, atol=1e-12, equal_nan=True)
    assert np.nanmax(np.abs(qd)) < 1e-12


@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_random_policy_never_produces_nan(mode: str) -> None:
    e = parallel_env("random", random_options=MIXED, action_mode=mode, max_steps=200)
    rng = np.random.default_rng(0)
    for seed in range(3):
        obs, _ = e.reset(seed=seed)
        while e.agents:
            obs, rew, _, _, infos = e.step(
                {a: rng.uniform(-1, 1, e.action_space(a).shape).astype(np.float32) for a in e.agents})
            assert all(np.all(np.isfinite(o)) for o in obs.values())
            assert all(np.isfinite(r) for r in rew.values())
            assert all("fault" not in i for i in infos.values())


def test_cost_marks_steps_inside_an_obstacle() -> None:
    # Section 5.2's nominal law drives the PA arm (arm_3) into the obstacle.
    e = parallel_env("paper_pa_mixed_square")
    policy = ReferencePolicy(e)
    obs, _ = e.reset(seed=0)
    costs, clears = [], []
    for _ in range(200):
        obs, _, _, _, infos = e.step(policy(obs))
        costs.append(infos["arm_3"]["cost"])
        clears.append(infos["arm_3"]["min_clearance"])
        assert infos["arm_0"]["cost"] == 0.0
    costs, clears = np.array(costs), np.array(clears)
    assert costs.sum() > 0
    np.testing.assert_array_equal(costs == 1.0, clears < 0)


def test_reference_policy_forms_the_square() -> None:
    e = parallel_env("paper_pa3_square")
    policy = ReferencePolicy(e)
    obs, infos = e.reset(seed=0)
    while e.agents:
        obs, _, _, _, infos = e.step(policy(obs))
    assert infos["arm_0"]["formation_error"] < 0.01 and infos["arm_0"]["is_success"]


def test_gym_view_cost_and_info() -> None:
    env = gymnasium.make("pan1_env/PaperMixedPA-v0")
    obs, info = env.reset(seed=0)
    assert info["cost"] == 0.0 and obs.shape == env.observation_space.shape
    obs, reward, term, trunc, info = env.step(np.zeros(env.action_space.shape, np.float32))
    assert {"cost", "formation_error", "min_clearance", "is_success", "reward_formation"} <= set(info)
    # reward = −mean_k |‖z_k‖ − d_k| (5 edges); formation_error is the max over the same edges
    err = info["formation_error"]
    assert err / 5 <= -reward <= err
    core = env.unwrapped.parallel
    f = core.scenario.formation  # the numpy reference formulas, not the env's compiled ones
    z = edge_length_errors(edge_vectors(f.incidence, core.end_effectors()), f.distances)
    assert reward == pytest.approx(-np.mean(np.abs(z)))
    assert info["formation_error"] == pytest.approx(np.abs(z).max())


# ---------------------------------------------------------------- bad input
def test_unknown_argument_suggests_the_right_one() -> None:
    with pytest.raises(TypeError, match="did you mean 'control_dt'"):
        parallel_env("paper_pa3_square", contol_dt=0.1)


def test_constructors_name_their_arguments() -> None:
    """help() and IDEs see the arguments; an unknown keyword still gets a "did you mean" hint."""
    from pan1_env.centralized import CentralizedEnv
    from pan1_env.environment import Pan1ParallelEnv

    named = {"action_mode", "control_dt", "physics_dt", "max_steps", "render_mode"}
    for init in (Pan1ParallelEnv.__init__, CentralizedEnv.__init__, parallel_env, aec_env):
        params = inspect.signature(init).parameters
        assert named <= set(params) and "qp_solver" in params, init
        assert params["control_dt"].default == 0.05 and params["max_steps"].default is None
        assert all(p.kind is not p.VAR_KEYWORD for p in params.values())
    with pytest.raises(TypeError, match="Pan1ParallelEnv got an unknown argument 'max_step'; did you mean 'max_steps'"):
        Pan1ParallelEnv("paper_pa3_square", max_step=10)
    with pytest.raises(TypeError, match="CentralizedEnv got an unknown argument 'contol_dt'; did you mean"):
        gymnasium.make("pan1_env/PaperPA3Square-v0", contol_dt=0.1)
    with pytest.raises(TypeError, match="did you mean 'max_steps'"):
        gymnasium.make(REACH_ENV_ID, max_step=10)
    assert gymnasium.make("pan1_env/PaperPA3Square-v0", max_steps=5).unwrapped.parallel.config.max_steps == 5


@pytest.mark.parametrize("kwargs, match", [
    ({"control_dt": 0.0015}, "divides control_dt=0.0015"),
    ({"control_dt": 0.0015, "physics_dt": 0.001}, "whole multiple"),
    ({"control_dt": -1.0}, "positive"),
    ({"physics_dt": 0.0}, "positive"),
    ({"action_mode": "acceleration"}, "action_mode"),
    ({"render_mode": "ansi"}, "render_mode"),
    ({"max_steps": 0}, "max_steps"),
    ({"n_obstacle_obs": -1}, "n_obstacle_obs"),
    ({"random_options": {"n_arms": 3}}, "random_options"),
])
def test_bad_constructor_arguments(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        parallel_env("paper_pa3_square", **kwargs)


def test_bad_actions_are_rejected_and_state_untouched() -> None:
    e = parallel_env("paper_pa_mixed_square")
    e.reset(seed=0)
    q0, _ = e.joint_state()
    good = {a: np.zeros(e.action_space(a).shape, np.float32) for a in e.agents}
    with pytest.raises(ValueError, match="NaN or inf"):
        e.step({**good, "arm_0": np.array([np.nan, 0.0], np.float32)})
    with pytest.raises(ValueError, match="shape"):
        e.step({**good, "arm_3": np.zeros(2, np.float32)})
    with pytest.raises(ValueError, match="missing"):
        e.step({a: v for a, v in good.items() if a != "arm_1"})
    with pytest.raises(ValueError, match="unexpected"):
        e.step({**good, "arm_9": np.zeros(1)})
    q1, _ = e.joint_state()
    np.testing.assert_array_equal(q0, q1)
    assert e.num_steps == 0


def test_actions_outside_the_box_are_clipped() -> None:
    a, b = parallel_env("paper_pa_mixed_square"), parallel_env("paper_pa_mixed_square")
    a.reset(seed=0)
    b.reset(seed=0)
    big = {ag: np.full(a.action_space(ag).shape, 7.0, np.float32) for ag in a.agents}
    one = {ag: np.ones(a.action_space(ag).shape, np.float32) for ag in a.agents}
    oa, *_ = a.step(big)
    ob, *_ = b.step(one)
    for ag in oa:
        np.testing.assert_array_equal(oa[ag], ob[ag])


def test_step_before_reset_raises() -> None:
    e = parallel_env("paper_pa3_square")
    with pytest.raises(RuntimeError, match="reset"):
        e.step({})
