"""SB3MixedArmVecEnv: teams of several sizes as one SB3 VecEnv, for one network the arms share (--team-sizes),
checked against one SB3ArmVecEnv per size stepped beside it, and through a short training run."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from pan1_env.baselines.arm_vec_env import SB3ArmVecEnv  # noqa: E402
from pan1_env.baselines.mixed_vec_env import SB3MixedArmVecEnv, sized_options  # noqa: E402
from pan1_env.core import copy_generator  # noqa: E402
from pan1_env.random_scenario import RandomScenarioOptions  # noqa: E402
from pan1_env.registration import ENV_IDS  # noqa: E402
from pan1_env.team_draw import draw_teams  # noqa: E402

RING = "pan1_env/RandomFormation-v2"


def test_each_size_is_its_own_arm_view_and_every_copy_draws_its_own_stream() -> None:
    """Sub-envs are the arms of the 3-arm copies, then of the 5-arm ones; stepped with the same actions, each
    block is what an SB3ArmVecEnv of that size gives when its copies are numbered where the block starts. Copy b
    of size k draws from copy_generator(seed, k·B + b): no two copies of the batch share a team stream. Each size
    has the task's three obstacles per four arms, rounded half up."""
    B, sizes, seed = 2, (3, 5), 7
    assert [sized_options(RING, {}, n) for n in sizes] == [{"n_arms": 3, "n_obstacles": 2},
                                                           {"n_arms": 5, "n_obstacles": 4}]
    mixed = SB3MixedArmVecEnv(RING, sizes, B, max_steps=4, action_mode="gain")
    assert mixed.dt == 0.05  # every view says its step
    alone = [SB3ArmVecEnv(RING, B, random_options=sized_options(RING, {}, n), max_steps=4, action_mode="gain")
             for n in sizes]
    assert mixed.num_envs == B * sum(sizes) and [list(t) for t in mixed.team_envs[:3]] == [[0, 1, 2], [3, 4, 5],
                                                                                       [6, 7, 8, 9, 10]]
    for k, part in enumerate(alone):
        part.venv.core.first_copy = k * B
        part.seed(seed)
    mixed.seed(seed)
    obs = mixed.reset()
    blocks = np.cumsum([0, *(B * n for n in sizes)])
    rng = np.random.default_rng(0)
    expected = [part.reset() for part in alone]
    for _ in range(6):  # through the episodes' end at step 4 and the next teams' draw
        for k in range(len(sizes)):
            np.testing.assert_array_equal(obs[blocks[k]:blocks[k + 1]], expected[k])
        actions = rng.uniform(-1, 1, (mixed.num_envs, 3)).astype(np.float32)
        mixed.step_async(actions)
        obs, rewards, dones, infos = mixed.step_wait()
        expected = []
        for k, part in enumerate(alone):
            part.step_async(actions[blocks[k]:blocks[k + 1]])
            o, r, d, _ = part.step_wait()
            np.testing.assert_array_equal(rewards[blocks[k]:blocks[k + 1]], r)
            np.testing.assert_array_equal(dones[blocks[k]:blocks[k + 1]], d)
            expected.append(o)
        assert len(infos) == mixed.num_envs
    for k, n in enumerate(sizes):  # the first teams: each copy's own spawned stream
        options = RandomScenarioOptions(**(ENV_IDS[RING]["random_options"] | sized_options(RING, {}, n)))
        first = draw_teams([copy_generator(seed, k * B + b) for b in range(B)], options)
        again = SB3ArmVecEnv(RING, B, random_options=sized_options(RING, {}, n))
        again.venv.core.first_copy = k * B
        again.seed(seed)
        again.reset()
        np.testing.assert_array_equal(again.venv.core.engine.bases, first.bases)


def test_sizes_whose_observations_differ_are_refused_with_the_way_out() -> None:
    with pytest.raises(ValueError, match="use a ring"):
        SB3MixedArmVecEnv("pan1_env/RandomFormation-v1", (3, 5), 1)
    with pytest.raises(ValueError, match="distinct team sizes"):
        SB3MixedArmVecEnv(RING, (3, 3), 1)
    with pytest.raises(ValueError, match="centralised-critic"):
        SB3MixedArmVecEnv(RING, (3, 4), 1, critic_state=True)
    with pytest.raises(ValueError, match="team_sizes only"):
        SB3MixedArmVecEnv(RING, (3, 4), 1, random_options={"n_arms": 5})
    with pytest.raises(ValueError, match="obstacles per arm"):
        SB3MixedArmVecEnv(RING, (3, 4), 1, random_options={"n_obstacles": 5})


def test_training_on_mixed_sizes_logs_one_row_per_team_episode(tmp_path) -> None:
    """--team-sizes 2,3 with 2 copies each and 20-step episodes: 4 teams end every 20 steps, one row each
    (each team's arms end together); the run records its sizes and the model then acts on a 6-arm team."""
    from pan1_env.baselines.training import train

    kwargs = {"seed": 3, "out": tmp_path / "run", "n_envs": 2, "param_sharing": True, "progress": False,
              "env_kwargs": {"max_steps": 20, "action_mode": "gain"}, "algo_kwargs": {"n_steps": 20, "batch_size": 50}}
    summary = train("ppo", RING, timesteps=400, team_sizes=[2, 3], eval_every=200, checkpoint_every=200, **kwargs)
    assert summary["team_sizes"] == [2, 3] and summary["timesteps"] == 400
    with (tmp_path / "run" / "episodes.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 * (400 // (20 * 10)) and {int(r["length"]) for r in rows} == {20}
    with (tmp_path / "run" / "eval.csv").open() as fh:  # on the id's own 4-arm teams
        assert [int(r["timesteps"]) for r in csv.DictReader(fh)] == [0, 200]  # at the rollouts that start there
    for other in ([3, 2], None):  # a resume on other sizes is refused before anything is built
        with pytest.raises(ValueError, match="--team-sizes"):
            train("ppo", RING, timesteps=600, team_sizes=other, resume=True, **kwargs)
    from pan1_env.baselines.benchmark import run_benchmark

    rows = run_benchmark([RING], [f"sb3:{tmp_path / 'run' / 'model.zip'}"], episodes=1, seed=0,
                         shield_settings=(True,), max_steps=3, env_kwargs={"random_options": {"n_arms": 6}})
    assert rows[0]["episodes"] == 1
    from pan1_env.baselines.report import _at_size, report

    rows = report([tmp_path / "run"], first=7, teams=2, reps=100, team_size=6)  # the run and the law at 6 arms
    for row in rows:
        options = json.loads(row["task"])[1]["random_options"]  # the env it was evaluated in
        assert (options["n_arms"], options["n_obstacles"]) == (6, 5)  # 3 obstacles per 4 arms, rounded half up
        assert len(next(iter(row["episodes"].values()))["success"]) == 2
    with pytest.raises(ValueError, match="a team size is a random-team option; this run's scenario is 'paper"):
        _at_size("paper_pa3_square", {}, 6)


def test_the_cli_refuses_bad_team_sizes_in_one_line(capsys) -> None:
    from pan1_env.cli import main

    for bad in ("3,3", "1,4", "three"):
        with pytest.raises(SystemExit) as exit_info:
            main(["train", "--scenario", RING, "--param-sharing", "--team-sizes", bad, "--out", "x"])
        assert exit_info.value.code == 2
        assert "team-sizes" in capsys.readouterr().err
