"""Batched evaluation (baselines/evaluation.py) against episodes run one by one in the parallel env."""

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from pan1_env.baselines import ReferencePolicy  # noqa: E402
from pan1_env.baselines.evaluation import evaluate, summarise  # noqa: E402
from pan1_env.environment import parallel_env  # noqa: E402
from pan1_env.wrappers import SafetyShield  # noqa: E402


def test_batched_evaluation_matches_episodes_run_one_by_one() -> None:
    seeds, steps = [5, 6, 9], 150
    kwargs = {"action_mode": "residual", "max_steps": steps}
    k = sum(parallel_env("random").n_actuated)
    result = evaluate(lambda obs: np.zeros((len(obs), k), np.float32), "random", seeds, env_kwargs=kwargs)
    for b, seed in enumerate(seeds):
        env = SafetyShield(parallel_env("random", max_steps=steps))
        policy = ReferencePolicy(env)
        obs, _ = env.reset(seed=seed)
        ret, cost = 0.0, 0.0
        while env.agents:
            obs, rewards, _, _, infos = env.step(policy(obs))
            ret += np.mean(list(rewards.values()))
            cost += sum(i["cost"] for i in infos.values())
        final = next(iter(infos.values()))["formation_error"]
        # the reference reads float32 observations, the residual env the exact state: close, not equal
        assert result["final_error"][b] == pytest.approx(final, rel=1e-3)
        assert result["return"][b] == pytest.approx(ret, rel=1e-3)
        assert result["cost"][b] == cost == 0.0


def test_summary_counts_success_at_each_tolerance_and_times_only_successes() -> None:
    result = {"final_error": np.array([0.005, 0.015, 0.03, 0.2]), "return": np.array([-1.0, -2.0, -3.0, -4.0]),
              "cost": np.array([0.0, 1.0, 0.0, 2.0]), "time_to_formation": np.array([12.0, np.nan, np.nan, np.nan])}
    s = summarise(result)
    assert (s["success_1cm"], s["success_2cm"], s["success_5cm"]) == (0.25, 0.5, 0.75)
    assert s["cost"] == 3.0 and s["mean_return"] == -2.5 and s["mean_time_to_formation_s"] == 12.0
    assert s["median_final_error_m"] == pytest.approx(0.0225)


def test_training_writes_deterministic_evaluations(tmp_path) -> None:
    import csv

    from pan1_env.baselines.training import train

    train("ppo", "random", shield=True, timesteps=512, seed=0, out=tmp_path, checkpoint_every=256, progress=False,
          n_envs=4, env_kwargs={"max_steps": 40, "action_mode": "residual"}, eval_every=256,
          algo_kwargs={"n_steps": 64, "batch_size": 128, "n_epochs": 1})
    rows = list(csv.DictReader((tmp_path / "eval.csv").open()))
    assert [int(r["timesteps"]) for r in rows] == [0, 256]
    assert all(0.0 <= float(r["success_5cm"]) <= 1.0 and float(r["cost"]) == 0.0 for r in rows)
