"""PPO-Lagrangian (baselines/lagrangian.py): the penalised reward, the multiplier's update, its state, a run."""

from __future__ import annotations

import csv
import math
import pickle

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch  # noqa: E402
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor  # noqa: E402

from pan1_env.baselines.lagrangian import CostPenalisedVecEnv, LagrangianCallback  # noqa: E402

EPISODE = 10


class Toy(gym.Env):
    """Constant observation; reward 0.5 and cost 1 when the action is positive, else 0 and 0; 10 steps."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action):
        self.t += 1
        positive = float(action[0]) > 0
        return (np.zeros(1, np.float32), 0.5 if positive else 0.0, False, self.t >= EPISODE,
                {"cost": 1.0 if positive else 0.0})


def _env(n: int = 2, **kwargs) -> CostPenalisedVecEnv:
    return CostPenalisedVecEnv(VecMonitor(DummyVecEnv([Toy] * n)), **kwargs)


def _run(venv: CostPenalisedVecEnv, action: float, steps: int):
    out = []
    for _ in range(steps):
        out.append(venv.step(np.full((venv.num_envs, 1), action, np.float32)))
    return out


def test_the_penalised_reward_is_the_formula() -> None:
    venv = _env(lagrangian_lr=0.1, initial_lambda=3.0)
    venv.reset()
    (_, rewards, _, infos), = _run(venv, 1.0, 1)
    assert rewards == pytest.approx([(0.5 - 3.0 * 1.0) / 4.0] * 2)
    assert [i["reward_unpenalised"] for i in infos] == [0.5, 0.5]
    (_, rewards, _, infos), = _run(venv, -1.0, 1)
    assert rewards == pytest.approx([0.0, 0.0]) and [i["reward_unpenalised"] for i in infos] == [0.0, 0.0]
    venv.lagrange_multiplier = 0.0  # λ = 0: the task reward unchanged
    (_, rewards, _, _), = _run(venv, 1.0, 1)
    assert rewards == pytest.approx([0.5, 0.5])


def test_lambda_rises_above_the_limit_and_falls_to_zero_below_it(tmp_path) -> None:
    venv = _env(cost_limit=1.0, lagrangian_lr=0.125, initial_lambda=0.0)  # steps exact in binary
    venv.reset()
    steps = _run(venv, 1.0, EPISODE)  # one costly episode per copy: J_c = 10
    assert [i["episode_cost"] for i in steps[-1][3]] == [10.0, 10.0]
    assert venv.update_multiplier() == 10.0
    assert venv.lagrange_multiplier == 0.125 * (10.0 - 1.0)
    for k in range(1, 11):  # cost-free episodes: J_c = 0 < 1, λ falls by 0.125 per update down to 0
        _run(venv, -1.0, EPISODE)
        assert venv.update_multiplier() == 0.0
        assert venv.lagrange_multiplier == max(0.0, 1.125 - 0.125 * k)
    assert venv.lagrange_multiplier == 0.0  # clipped, never negative
    assert venv.update_multiplier() is None and venv.lagrange_multiplier == 0.0  # nothing measured: unchanged


def test_without_ended_episodes_the_estimate_is_cost_per_step_times_episode_length() -> None:
    venv = _env(cost_limit=0.0, lagrangian_lr=1.0)
    venv.reset()
    _run(venv, 1.0, 3)
    assert venv.update_multiplier() is None  # no episode has ended yet: no length to scale by
    _run(venv, -1.0, EPISODE - 3)  # episodes end (cost 3 each)
    venv.update_multiplier()
    lam = venv.lagrange_multiplier
    assert lam == pytest.approx(3.0)
    _run(venv, 1.0, 4)  # half a window... no episode ends: cost rate 1 per step × mean length 10
    assert venv.update_multiplier() == pytest.approx(10.0)
    assert venv.lagrange_multiplier == pytest.approx(lam + 10.0)
    assert venv.update_multiplier() is None  # an empty window: nothing to estimate


def test_before_any_episode_ends_episode_length_scales_the_cost_per_step() -> None:
    venv = _env(cost_limit=0.0, lagrangian_lr=1.0, episode_length=40)
    venv.reset()
    _run(venv, 1.0, 2)
    _run(venv, -1.0, 2)  # cost 2 in 4 steps per copy, × 40
    assert venv.update_multiplier() == pytest.approx(20.0) and venv.lagrange_multiplier == pytest.approx(20.0)
    _run(venv, 1.0, EPISODE - 4)  # episodes of 10 steps end: their own mean length replaces 40
    _run(venv, 1.0, 5)
    assert venv.update_multiplier() == pytest.approx(8.0)  # the ended episodes' mean cost (10 steps, cost 8)
    _run(venv, 1.0, 4)
    assert venv.update_multiplier() == pytest.approx(1.0 * 10)  # none ended: rate 1 × ended length 10


def test_state_dict_round_trips_through_pickle() -> None:
    venv = _env(cost_limit=2.0, lagrangian_lr=0.25, initial_lambda=1.5, episode_length=7)
    venv.reset()
    _run(venv, 1.0, EPISODE + 3)
    state = pickle.loads(pickle.dumps(venv.state_dict()))
    other = _env()
    other.load_state_dict(state)
    assert other.lagrange_multiplier == 1.5 and other.cost_limit == 2.0 and other.lagrangian_lr == 0.25
    assert other.episode_length == 7
    assert other.episode_cost_estimate() == venv.episode_cost_estimate() == 10.0
    assert other.update_multiplier() == venv.update_multiplier()
    assert other.lagrange_multiplier == venv.lagrange_multiplier == pytest.approx(1.5 + 0.25 * 8.0)
    other.reset()  # the running episode costs came along: (3 arm-steps so far) + 7 more = 10
    np.testing.assert_array_equal(other.state_dict()["episode_costs"], [0.0, 0.0])
    np.testing.assert_array_equal(venv.state_dict()["episode_costs"], [3.0, 3.0])
    with pytest.raises(ValueError, match="copies"):
        _env(n=3).load_state_dict(state)


@pytest.mark.parametrize("bad", [{"cost_limit": -1.0}, {"lagrangian_lr": 0.0}, {"initial_lambda": math.nan},
                                 {"episode_length": 0}, {"episode_length": 2.5}])
def test_bad_parameters_are_refused(bad) -> None:
    with pytest.raises(ValueError):
        _env(**bad)


def test_a_missing_cost_is_an_error() -> None:
    class NoCost(Toy):
        def step(self, action):
            obs, r, term, trunc, _ = super().step(action)
            return obs, r, term, trunc, {}

    venv = CostPenalisedVecEnv(DummyVecEnv([NoCost]))
    venv.reset()
    with pytest.raises(KeyError, match="cost"):
        _run(venv, 1.0, 1)


def _positive_rate(model: PPO) -> float:
    obs = np.zeros((256, 1), np.float32)
    torch.manual_seed(0)
    actions, _ = model.predict(obs, deterministic=False)
    return float((actions > 0).mean())


@pytest.mark.parametrize("initial_lambda, lower", [(0.0, False), (10.0, True)])
def test_ppo_with_a_high_lambda_learns_to_lower_the_cost(initial_lambda: float, lower: bool, tmp_path) -> None:
    """With λ = 10 (r' < 0 when costly) PPO moves its actions negative; with λ = 0 it keeps them positive."""
    torch.set_num_threads(1)
    venv = _env(n=4, cost_limit=0.0, lagrangian_lr=1e-9, initial_lambda=initial_lambda)  # λ ~ held
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=4, learning_rate=3e-3, seed=0, device="cpu")
    model.learn(3072, callback=LagrangianCallback(venv, log_dir=tmp_path))
    rate = _positive_rate(model)
    assert (rate < 0.2) if lower else (rate > 0.8), rate
    with (tmp_path / "lagrangian.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3072 // 256 and [int(r["timesteps"]) for r in rows] == list(range(256, 3073, 256))
    assert all(float(r["lambda"]) == pytest.approx(initial_lambda, abs=1e-6) for r in rows)


def test_the_full_loop_meets_the_limit_and_then_lowers_lambda(tmp_path) -> None:
    """λ from 0 with d = 2 per episode: unconstrained PPO would pay ~10; λ rises while J_c > d, the
    policy's cost falls below d, and λ then falls again (the usual overshoot of the Lagrangian)."""
    torch.set_num_threads(1)
    venv = _env(n=4, cost_limit=2.0, lagrangian_lr=0.05, initial_lambda=0.0)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=4, learning_rate=3e-3, seed=0, device="cpu")
    model.learn(6144, callback=LagrangianCallback(venv, log_dir=tmp_path))
    with (tmp_path / "lagrangian.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    lam, cost = [float(r["lambda"]) for r in rows], [float(r["episode_cost"]) for r in rows]
    assert cost[0] > 2.0 and lam[0] > 0.0 and max(lam) > 1.0
    assert max(cost[-3:]) < 2.0 and lam[-1] < max(lam) and lam[-1] == venv.lagrange_multiplier
    assert _positive_rate(model) < 0.2


def test_smoke_on_the_real_env_without_the_shield(tmp_path) -> None:
    from pan1_env.baselines.vec_env import SB3VecEnv

    torch.set_num_threads(1)
    venv = CostPenalisedVecEnv(VecMonitor(SB3VecEnv("paper_pa3_square", num_envs=4, safety_filter=False,
                                                    max_steps=20)), lagrangian_lr=0.05, initial_lambda=1.0)
    venv.seed(0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=2, seed=0, device="cpu")
    model.learn(384, callback=LagrangianCallback(venv, log_dir=tmp_path))
    assert math.isfinite(venv.lagrange_multiplier) and venv.lagrange_multiplier >= 0.0
    with (tmp_path / "lagrangian.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 and all(r["episode_cost"] != "" for r in rows)  # 20-step episodes end every rollout
    venv.close()


def test_import_pan1_env_does_not_import_the_lagrangian_layer() -> None:
    import subprocess
    import sys

    code = "import sys, pan1_env, pan1_env.baselines; print('pan1_env.baselines.lagrangian' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.stdout.strip() == "False", done.stderr


def test_train_ppo_lagrangian_resumes_exactly_with_its_multiplier(tmp_path) -> None:
    """``train("ppo-lagrangian")`` without the shield: λ rises, is checkpointed, and an interrupted run
    resumed with the same arguments ends where the uninterrupted one does (model, episodes, λ log)."""
    from stable_baselines3.common.callbacks import BaseCallback

    from pan1_env.baselines.training import latest_checkpoint, train

    kwargs = dict(algo="ppo-lagrangian", scenario="paper_pa_mixed_square", shield=False, timesteps=4 * 256, seed=3,
                  checkpoint_every=256, progress=False, n_envs=2, env_kwargs={"max_steps": 100},
                  algo_kwargs={"n_steps": 128, "batch_size": 64, "n_epochs": 2}, cost_limit=0.0, lagrangian_lr=0.5)

    class Interrupt(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps >= 640:  # in the third rollout, after the 512-step checkpoint
                raise KeyboardInterrupt
            return True

    whole, cut = tmp_path / "whole", tmp_path / "cut"
    summary = train(out=whole, **kwargs)
    assert summary["cost_limit"] == 0.0 and summary["total_cost"] > 0 and summary["lambda"] > 0
    with pytest.raises(KeyboardInterrupt):
        train(out=cut, extra_callbacks=[Interrupt()], **kwargs)
    assert latest_checkpoint(cut)[1] == 512
    resumed = train(out=cut, resume=True, **kwargs)
    assert resumed["resumed_from"] == 512 and resumed["lambda"] == summary["lambda"]
    a, b = (PPO.load(p / "model.zip", device="cpu").policy.state_dict() for p in (whole, cut))
    for key in a:
        assert torch.equal(a[key], b[key]), key

    def rows(path):
        with path.open() as fh:
            return list(csv.DictReader(fh))

    assert rows(whole / "episodes.csv") == rows(cut / "episodes.csv")
    log = rows(whole / "lagrangian.csv")
    assert log == rows(cut / "lagrangian.csv") and [int(r["timesteps"]) for r in log] == [256, 512, 768, 1024]
    assert float(log[-1]["lambda"]) == summary["lambda"]



def test_ppo_lagrangian_with_parameter_sharing_prices_each_arms_own_cost(tmp_path) -> None:
    """IPPO-Lagrangian: one network shared by the arms, each arm's reward penalised by its own cost. Unshielded
    arms collide, so the multiplier rises from 0 above a zero cost limit."""
    from pan1_env.baselines.training import train

    summary = train("ppo-lagrangian", "paper_pa_mixed_square", shield=False, timesteps=2 * 256, seed=1, n_envs=2,
                    param_sharing=True, out=tmp_path, progress=False, env_kwargs={"max_steps": 16},
                    algo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1}, cost_limit=0.0, lagrangian_lr=0.5)
    assert summary["total_cost"] > 0 and summary["lambda"] > 0
