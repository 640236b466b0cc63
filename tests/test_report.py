"""pan1-env report: the interquartile mean over seeds, its stratified bootstrap interval, and marl-eval JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from pan1_env.baselines.report import iqm, iqm_interval, markdown, marl_eval_json, report  # noqa: E402
from pan1_env.baselines.training import train  # noqa: E402
from pan1_env.cli import main  # noqa: E402


def test_the_interquartile_mean_drops_a_quarter_at_each_end() -> None:
    assert iqm(np.array([1.0, 2, 3, 4, 100, 200, 300, 400])) == pytest.approx((3 + 4 + 100 + 200) / 4)


def test_the_bootstrap_resamples_each_task_on_its_own() -> None:
    """Two tasks whose runs agree within each task: every stratified resample has the same pooled scores, so
    the interval is a point. Pooling the tasks before resampling would spread it."""
    point, low, high = iqm_interval([np.zeros(5), np.ones(5)], reps=500)
    assert point == low == high == pytest.approx(0.5)
    point, low, high = iqm_interval([np.arange(10.0)], reps=2000)
    assert low < point < high and 0 <= low and high <= 9


def test_report_ranks_a_gain_model_against_the_law_and_writes_marl_eval_json(tmp_path, capsys) -> None:
    kwargs = dict(scenario="random", shield=True, timesteps=256, n_envs=2, progress=False, param_sharing=True,
                  env_kwargs={"action_mode": "gain", "max_steps": 40, "random_options": {"links": (2, 3, 4, 3)}},
                  algo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1})
    runs = [tmp_path / f"s{s}" for s in (0, 1)]
    for seed, out in enumerate(runs):
        train("ppo", seed=seed, out=out, **kwargs)
    rows = report(runs, first=7, teams=3, reps=200)
    assert [row["label"].startswith("reference") for row in rows] == [False, True]
    learned, reference = rows
    assert len(learned["runs"]) == 2 and reference["runs"] == ["reference"]
    assert learned["cost"][0] == reference["cost"][0] == 0.0
    assert reference["return"][0] == reference["return"][1] == reference["return"][2]  # one deterministic run
    assert "| random | reference (the paper's law) | 1 |" in markdown(rows)
    data = json.loads(marl_eval_json(rows, tmp_path / "marl.json").read_text())
    runs_json = data["pan1_env"]["random"][learned["label"]]
    assert set(runs_json) == {"seed_0", "seed_1"}
    assert len(runs_json["seed_0"]["absolute_metrics"]["return"]) == 3
    assert main(["report", str(runs[0]), "--teams", "2", "--first", "7", "--reps", "100"]) == 0
    assert "| random |" in capsys.readouterr().out
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "not a finished training run" in capsys.readouterr().err


def test_bad_report_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys) -> None:
    run = tmp_path / "run"
    run.mkdir()
    for name in ("model.zip", "model.json"):
        (run / name).write_text("")
    (run / "run.json").write_text('{"algo": "ppo"}')  # no scenario: not written by pan1-env train
    json_out = tmp_path / "out.json"
    for argv, text in ((["report", str(run), "--json", str(json_out)], "run.json: expected a JSON object"),
                       (["report", str(run), "--first", "-1"], "first must be a reset seed ≥ 0")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert text in err and len(err.strip().splitlines()) == 1, err
    assert not json_out.exists()
