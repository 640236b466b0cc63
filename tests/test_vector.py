"""The batched vector env against independent copies of the single env it vectorises."""

import importlib.util
import inspect

import gymnasium
import numpy as np
import pytest

from pan1_env.centralized import CentralizedEnv
from pan1_env.vector import Pan1VectorEnv
from pan1_env.wrappers import GymSafetyShield


def _singles(scenario, B, shield=True, **kw):
    envs = [CentralizedEnv(scenario, **kw) for _ in range(B)]
    return [GymSafetyShield(e) for e in envs] if shield else envs


@pytest.mark.parametrize("scenario,threads", [("paper_pa3_square", False), ("paper_pa_mixed_square", False),
                                              ("paper_pa3_square", True)])
@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_vector_env_equals_independent_copies(scenario: str, threads: bool, mode: str) -> None:
    B, kw = 3, dict(max_steps=7, action_mode=mode, effort_weight=0.3, collision_penalty=2.0)
    venv = Pan1VectorEnv(scenario, B, threads=threads, **kw)
    singles = _singles(scenario, B, **kw)
    obs, info = venv.reset(seed=[5, 6, 7])
    assert isinstance(venv, gymnasium.vector.VectorEnv)
    assert venv.observation_space.contains(obs)
    for b, e in enumerate(singles):
        o, _ = e.reset(seed=[5, 6, 7][b])
        np.testing.assert_array_equal(obs[b], o)
    rng = np.random.default_rng(1)
    for t in range(10):  # crosses the end of the 7-step episodes: autoreset in the same step
        actions = rng.uniform(-1.2, 1.2, venv.action_space.shape)
        obs, rew, term, trunc, info = venv.step(actions)
        assert obs.dtype == np.float32 and obs.shape == venv.observation_space.shape
        for b, e in enumerate(singles):
            o, r, te, tr, i = e.step(actions[b])
            assert (te, tr) == (term[b], trunc[b])
            assert rew[b] == pytest.approx(r, rel=1e-12, abs=1e-12)
            assert info["cost"][b] == i["cost"]
            assert info["min_clearance"][b] == pytest.approx(i["min_clearance"], abs=1e-12)
            assert info["shield_intervened"][b] == i["shield_intervened"]
            assert info["shield_fallback"][b] == i["shield_fallback"]
            assert info["formation_error"][b] == pytest.approx(i["formation_error"], abs=1e-12)
            assert info["is_success"][b] == i["is_success"]
            if te or tr:
                np.testing.assert_array_equal(info["final_obs"][b], o)
                assert info["_final_obs"][b] and info["final_info"]["cost"][b] == i["cost"]
                o, _ = e.reset()
            else:
                assert not info.get("_final_obs", np.zeros(B, bool))[b]
            np.testing.assert_allclose(obs[b], o, rtol=1e-6, atol=1e-6, err_msg=f"copy {b} step {t}")
        assert (t == 6) == bool(trunc.all())


def test_unshielded_vector_env_charges_collisions_like_the_single_env() -> None:
    """Without the shield, arms driven at full speed hit obstacles: cost and the collision penalty
    in the reward agree with the single env's."""
    B, kw = 4, dict(max_steps=40, collision_penalty=2.0, effort_weight=0.1)
    venv = Pan1VectorEnv("paper_pa3_square", B, safety_filter=False, **kw)
    singles = _singles("paper_pa3_square", B, shield=False, **kw)
    venv.reset(seed=0)
    for b, e in enumerate(singles):
        e.reset(seed=b)
    rng = np.random.default_rng(7)
    hits = 0.0
    for _ in range(40):
        actions = np.sign(rng.uniform(-1.0, 1.0, venv.action_space.shape))
        _, rew, _, _, info = venv.step(actions)
        for b, e in enumerate(singles):
            _, r, _, _, i = e.step(actions[b])
            assert info["cost"][b] == i["cost"]
            assert rew[b] == pytest.approx(r, rel=1e-12, abs=1e-12)
        hits += info["cost"].sum()
    assert hits > 0


WHOLE_ARM_MOVING = {"bodies": "links", "link_radius": 0.03, "inter_arm": True, "obstacle_speed": (0.05, 0.2)}


@pytest.mark.parametrize("scenario, options", [("paper_pa3_square", None), ("paper_pa_mixed_square", None),
                                               ("random", WHOLE_ARM_MOVING)])
def test_threaded_and_serial_kernels_agree_bit_for_bit(scenario: str, options) -> None:
    runs = []  # the whole-arm case also measures the clearance between arms on threads
    for threads in (False, True):
        venv = Pan1VectorEnv(scenario, 12, threads=threads, max_steps=30, random_options=options)
        obs, _ = venv.reset(seed=2)
        venv.action_space.seed(2)
        trace = [obs]
        for _ in range(40):  # through an autoreset
            obs, reward, _, _, info = venv.step(venv.action_space.sample())
            trace += [obs, reward, info["min_clearance"], info["shield_intervened"]]
        runs.append(trace)
    for serial, threaded in zip(*runs, strict=True):
        np.testing.assert_array_equal(serial, threaded)


def test_random_teams_follow_per_copy_seeds_and_redraw_on_autoreset() -> None:
    B = 4
    venv = Pan1VectorEnv("random", B, max_steps=3)
    obs, _ = venv.reset(seed=[10, 11, None, 13])
    for b in (0, 1, 3):
        single = CentralizedEnv("random")
        o, _ = single.reset(seed=[10, 11, None, 13][b])
        np.testing.assert_array_equal(obs[b], o)
    first = obs.copy()
    for _ in range(3):
        obs, *_ = venv.step(np.zeros(venv.action_space.shape))
    # every copy ended at step 3 and drew a new team from its own generator
    assert not np.allclose(obs[[0, 1, 3]], first[[0, 1, 3]])
    again, _ = Pan1VectorEnv("random", B, max_steps=3).reset(seed=[10, 11, None, 13])
    np.testing.assert_array_equal(again[[0, 1, 3]], first[[0, 1, 3]])


def test_shielded_vector_env_stays_out_of_obstacles() -> None:
    venv = Pan1VectorEnv("paper_pa3_square", 16, max_steps=200)
    venv.reset(seed=0)
    venv.action_space.seed(0)
    total_cost, intervened = 0.0, 0
    for _ in range(200):
        _, _, _, _, info = venv.step(venv.action_space.sample())
        total_cost += info["cost"].sum()
        intervened += info["shield_intervened"].sum()
        assert np.all(info["min_clearance"] >= 0)
    assert total_cost == 0 and intervened > 0


def test_a_numerical_fault_truncates_only_its_copy() -> None:
    venv = Pan1VectorEnv("paper_pa3_square", 2, action_mode="torque", max_torque=1e300, safety_filter=False)
    venv.reset(seed=0)
    actions = np.zeros((2, 12))
    actions[1] = 1.0
    obs, _, term, trunc, info = venv.step(actions)
    assert list(trunc) == [False, True] and not term.any()
    assert list(info["_fault"]) == [False, True] and info["fault"][1].startswith("non-finite state")
    assert info["_final_obs"][1] and np.isfinite(obs).all()  # copy 1 was reset in the same step


@pytest.mark.parametrize("bad,error", [
    (np.zeros((2, 5)), "shape"),
    (np.full((2, 12), np.nan), "NaN"),
    pytest.param({"arm_0": np.zeros(3)}, r"actions must be an array of numbers of shape \(2, 12\), got dict",
                 id="dict"),
    pytest.param("zeros", r"actions must be an array of numbers of shape \(2, 12\), got str 'zeros'", id="string"),
])
def test_bad_actions_are_refused(bad, error) -> None:
    venv = Pan1VectorEnv("paper_pa3_square", 2)
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros((2, 12)))
    venv.reset()
    with pytest.raises(ValueError, match=error):
        venv.step(bad)


@pytest.mark.parametrize("kwargs,error", [
    (dict(num_envs=0), "num_envs"),
    (dict(num_envs=2, render_mode="rgb_array"), "render_mode"),
    (dict(num_envs=2, threads="sometimes"), "threads"),
    (dict(num_envs=2, control_dt=-1.0), "control_dt"),
])
def test_bad_arguments_are_refused(kwargs, error) -> None:
    with pytest.raises((ValueError, TypeError), match=error):
        Pan1VectorEnv("paper_pa3_square", **kwargs)


def test_vector_constructor_names_its_arguments() -> None:
    """The team env's arguments in the signature (less render_mode, qp_solver); a typo gets a hint."""
    params = inspect.signature(Pan1VectorEnv.__init__).parameters
    assert {"num_envs", "safety_filter", "threads", "action_mode", "control_dt", "physics_dt",
            "max_steps"} <= set(params)
    assert not {"render_mode", "qp_solver"} & set(params)
    assert all(p.kind is not p.VAR_KEYWORD for p in params.values())
    with pytest.raises(TypeError, match="Pan1VectorEnv got an unknown argument 'safety_fliter'; did you mean "
                                        "'safety_filter'"):
        Pan1VectorEnv("paper_pa3_square", 2, safety_fliter=False)
    if importlib.util.find_spec("stable_baselines3"):
        from pan1_env.baselines.vec_env import SB3VecEnv

        assert set(params) - {"self"} <= set(inspect.signature(SB3VecEnv).parameters)
        with pytest.raises(TypeError, match="did you mean 'max_steps'"):
            SB3VecEnv("paper_pa3_square", 2, max_step=3)


def test_sb3_adapter_runs_ppo_and_reports_terminal_observations() -> None:
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from pan1_env.baselines.vec_env import SB3VecEnv

    venv = SB3VecEnv("paper_pa3_square", num_envs=4, max_steps=5)
    venv.seed(3)
    obs = venv.reset()
    assert obs.shape == (4, venv.observation_space.shape[0])
    for _ in range(5):
        obs, rewards, dones, infos = venv.step(np.zeros((4, 12)))
    assert dones.all() and all(i["TimeLimit.truncated"] and "terminal_observation" in i for i in infos)
    assert all(i["cost"] == 0.0 for i in infos)
    model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0)
    model.learn(64)
    assert model.num_timesteps >= 64


def test_the_filter_is_on_by_default_and_switched_by_safety_filter() -> None:
    """0.1.0's ``shield=`` is gone (CHANGELOG): it is refused like any unknown argument."""
    with pytest.raises(TypeError, match="unknown argument 'shield'"):
        Pan1VectorEnv("paper_pa3_square", 2, shield=False, max_steps=5)
    assert Pan1VectorEnv("paper_pa3_square", 2, safety_filter=False, max_steps=5).safety_filter is None
    assert Pan1VectorEnv("paper_pa3_square", 2, max_steps=5).safety_filter is not None
