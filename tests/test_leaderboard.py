"""The leaderboard (pan1-env suite): its statistics on made-up scores, where it finds a learner's runs, its
errors, the quick pipeline end to end, and that docs/BENCHMARK.md is the rendering of the shipped JSON."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pan1_env.baselines import leaderboard as board
from pan1_env.baselines.leaderboard_table import benchmark_page, leaderboard_rows, markdown
from pan1_env.baselines.suite import suite_task
from pan1_env.cli import main

DOCS = Path(__file__).resolve().parents[1] / "docs"
RANDOM = "pan1_env/RandomFormation-v1"


def _data(runs_by_entry: dict[str, list[dict]]) -> dict:
    """Leaderboard data of one made-up task: entry → one dict of per-team lists per run."""
    raw = {name: {f"seed_{k}": {"absolute_metrics": m} for k, m in enumerate(runs)}
           for name, runs in runs_by_entry.items()}
    return {"tasks": [{"name": "made up", "env_id": RANDOM, "env_kwargs": {}, "train_steps": 1, "train_seeds": [0],
                       "held_out": [0, 4], "teams": 4, "target": "", "law_success_recorded": None}],
            "entries": [{"name": n, "description": n, "policy": None, "recipe": {}, "tasks": None}
                        for n in runs_by_entry],
            "runs": {RANDOM: {n: [{"seed": k, "source": "made up"} for k in range(len(r))]
                              for n, r in runs_by_entry.items()}},
            "missing": [], "raw": {"pan1_env": {RANDOM: raw}}}


def _run(formed: list[int], time: float = 10.0) -> dict:
    return {"success": [float(f) for f in formed], "time_to_formation": [time if f else None for f in formed],
            "cost": [0.0] * len(formed), "min_clearance": [0.02] * len(formed),
            "intervention_rate": [0.1] * len(formed)}


def test_a_learner_is_the_iqm_over_its_runs_and_a_policy_is_bootstrapped_over_its_teams() -> None:
    teams = 10
    rates = [0.7, 0.8, 0.9, 0.9, 1.0]
    learner = [_run([1] * round(r * teams) + [0] * (teams - round(r * teams))) for r in rates]
    law = [_run([1, 0, 1, 1, 0, 1, 1, 1, 1, 0], time=20.0)]
    nothing = [_run([0] * teams)]
    sparse = [_run([0] * teams), _run([1] + [0] * (teams - 1), time=55.0)]  # one run of two forms a team
    data = _data({"ippo": learner, "law": law, "none": nothing, "sparse": sparse})
    rows = {r["entry"]: r for r in leaderboard_rows(data, reps=500)}
    point, low, high = rows["ippo"]["success"]
    assert rows["ippo"]["over"] == "runs" and rows["ippo"]["runs"] == 5
    assert point == pytest.approx((0.8 + 0.9 + 0.9) / 3)  # the middle three of five
    assert 0.7 <= low <= point <= high <= 1.0
    point, low, high = rows["law"]["success"]
    assert rows["law"]["over"] == "teams" and point == pytest.approx(0.7) and 0.0 <= low < point < high <= 1.0
    point, low, high = rows["none"]["success"]  # no team formed: the Wilson interval still has width
    assert rows["none"]["time"] is None and point == low == 0.0 and 0.2 < high < 0.35
    assert rows["ippo"]["time"][0] == pytest.approx(10.0) and rows["ippo"]["min_clearance"] == pytest.approx(0.02)
    # on the teams both formed the learner takes 10 s where the law takes 20
    assert rows["ippo"]["time_ratio"][0] == pytest.approx(0.5) and rows["law"]["time_ratio"] is None
    assert rows["none"]["time_ratio"] is None
    table = markdown(list(rows.values()))
    assert "| made up | ippo | 5 | 86.7 [" in table and "| made up | none | 1 | 0.0 [0.0, " in table
    assert "| 55.0 (1 of 2 runs) |" in table  # a mean time over the runs that formed a team says how many did


def test_docs_benchmark_is_the_rendering_of_the_shipped_leaderboard() -> None:
    data = json.loads((DOCS / "leaderboard.json").read_text())
    figures = [f"figures/{name}" for name in ("leaderboard_iqm.png", "leaderboard_profiles.png",
                                               "leaderboard_improvement.png") if (DOCS / "figures" / name).exists()]
    assert (DOCS / "BENCHMARK.md").read_text() == benchmark_page(data, figures)
    for task in data["tasks"]:
        assert task["teams"] == task["held_out"][1], "the shipped leaderboard is scored on every held-out team"
    assert not data.get("quick")


def test_unknown_names_fail_at_the_boundary(capsys) -> None:
    with pytest.raises(ValueError, match="no leaderboard entry 'nope'; the entries: law, circulation, ippo"):
        board.resolve(None, "law,nope")
    with pytest.raises(ValueError, match="no suite task 'nope'"):
        board.resolve("nope", None)
    assert main(["suite", "--entries", "nope"]) == 2
    assert "pan1-env: error: no leaderboard entry 'nope'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="entry 'law' is not trained"):
        board.train_entry(board.entry("law"), suite_task(RANDOM))
    with pytest.raises(ValueError, match=r"seeds \[7\] are not pan1_env/RandomFormation-v1's training seeds"):
        board.train_entry(board.entry("ippo"), suite_task(RANDOM), seeds=[0, 7])
    assert main(["suite", "--seeds", "1"]) == 2 and "--seeds goes with --train" in capsys.readouterr().err


def test_a_leaderboard_that_cannot_be_read_is_named_in_one_line(tmp_path, capsys) -> None:
    (tmp_path / "shape.json").write_text('{"a": 1}')
    (tmp_path / "text.json").write_text("not json")
    for path, why in ((tmp_path / "none.json", "cannot read"), (tmp_path, "cannot read"),
                      (tmp_path / "shape.json", "not a pan1-env suite leaderboard.json"),
                      (tmp_path / "text.json", "cannot read")):
        assert main(["suite", "--from", str(path), "--out", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(path) in err and why in err
    assert main(["suite", "--from", str(tmp_path / "shape.json"), "--quick"]) == 2
    assert "--from re-renders a leaderboard as it is" in capsys.readouterr().err


def test_train_entry_runs_each_seed_once_and_resumes_from_a_checkpoint(tmp_path, monkeypatch) -> None:
    import pan1_env.baselines.training as training

    calls = []
    monkeypatch.setattr(training, "train", lambda **kwargs: calls.append(kwargs) or {"seed": kwargs["seed"]})
    task, ippo = suite_task(RANDOM), board.entry("ippo")
    where = board.task_dir(tmp_path, ippo, task)
    (where / "seed_0").mkdir(parents=True)
    (where / "seed_0" / "model.zip").write_bytes(b"")  # finished
    (where / "seed_1" / "checkpoints").mkdir(parents=True)
    (where / "seed_1" / "checkpoints" / "model_512000_steps.zip").write_bytes(b"")
    (where / "seed_1" / "checkpoints" / "state_512000_steps.pkl").write_bytes(b"")
    board.train_entry(ippo, task, runs=tmp_path, seeds=[0, 1, 2], say=lambda text: None)
    assert [c["seed"] for c in calls] == [1, 2]
    assert [c["resume"] for c in calls] == [True, False]
    first = calls[0]
    assert first["scenario"] == RANDOM and first["timesteps"] == task.train_steps and first["param_sharing"]
    assert first["env_kwargs"]["action_mode"] == "gain" and first["shield"] is True
    assert first["out"] == where / "seed_1"


def test_an_entry_for_any_team_size_trains_once_and_is_judged_at_each_size(tmp_path, monkeypatch) -> None:
    """ippo-sizes trains on RandomFormation-v2's seeds with teams of 3-8 arms, whichever of its tasks is named, and
    its runs there score both the 4-arm and the 16-arm task; a run of another recipe does not."""
    import pan1_env.baselines.training as training

    calls = []
    monkeypatch.setattr(training, "train", lambda **kwargs: calls.append(kwargs) or {"seed": kwargs["seed"]})
    sizes, large, small = board.entry("ippo-sizes"), suite_task("pan1_env/LargeFormation-v0"), \
        suite_task("pan1_env/RandomFormation-v2")
    assert sizes.enters(large) and sizes.enters(small) and not sizes.enters(suite_task(RANDOM))
    assert not any(board.entry(e).enters(large) for e in ("ippo", "mappo", "mappo-lagrangian", "ippo-unshielded"))
    with pytest.raises(ValueError, match="'ippo-sizes' is not judged on pan1_env/PaperPA3Square-v0"):
        board.train_entry(sizes, suite_task("pan1_env/PaperPA3Square-v0"), runs=tmp_path, say=lambda text: None)
    board.train_entry(sizes, large, runs=tmp_path, seeds=[2], say=lambda text: None)
    (call,) = calls
    assert call["scenario"] == "pan1_env/RandomFormation-v2" and call["team_sizes"] == [3, 4, 5, 6, 7, 8]
    assert call["timesteps"] == small.train_steps and call["out"] == board.task_dir(tmp_path, sizes, small) / "seed_2"
    assert board.task_dir(tmp_path, sizes, large) == board.task_dir(tmp_path, sizes, small)
    run = {"algo": "ppo", "shield": True, "param_sharing": True, "n_envs": 4, "seed": 2, "normalize": True,
           "algo_kwargs": sizes.recipe["algo_kwargs"], "team_sizes": [3, 4, 5, 6, 7, 8], "timesteps": 16_368_000,
           "env_kwargs": {"success_bonus": 1.0, "action_mode": "gain",
                          "random_options": {"shape": "ring", "arm_redraws": 20}}}
    trained = sizes.training_task(large)
    assert board._recipe_of(run, trained) == board._recipe_of(sizes.recipe, trained)
    assert board._recipe_of(run | {"team_sizes": [4]}, trained) != board._recipe_of(sizes.recipe, trained)


def test_a_model_for_any_team_size_is_scored_on_the_tasks_teams(monkeypatch) -> None:
    """The shipped model trained on 3-8 arms stands in for ippo-sizes and is scored on LargeFormation-v0's 16-arm
    teams (the task's options), with its own action and reward arguments."""
    pytest.importorskip("stable_baselines3")
    import pan1_env.baselines.evaluation as evaluation

    seen = []

    def fake_evaluate(policy, scenario, seeds, *, shield, env_kwargs):
        seen.append((scenario, env_kwargs))
        return {"success": np.zeros(len(seeds))}

    monkeypatch.setattr(evaluation, "evaluate", fake_evaluate)
    sizes, large = board.entry("ippo-sizes"), suite_task("pan1_env/LargeFormation-v0")
    assert board.shipped_model(sizes, large) == "random_formation_v2_ippo_sizes"
    board.run_suite([large], [sizes], runs="/nonexistent", teams=1, max_steps=5)
    ((scenario, kwargs),) = seen
    assert scenario == "random" and kwargs["max_steps"] == 5 and kwargs["action_mode"] == "gain"
    assert (kwargs["random_options"]["n_arms"], kwargs["random_options"]["n_obstacles"]) == (16, 12)


def test_a_learners_runs_come_before_its_shipped_model(tmp_path) -> None:
    pytest.importorskip("stable_baselines3")
    from pan1_env.baselines.shipped import PRETRAINED_DIR

    task, ippo, mappo = suite_task(RANDOM), board.entry("ippo"), board.entry("mappo")
    assert board.shipped_model(ippo, task) == "random_formation_v1_ippo"
    assert board.shipped_model(ippo, suite_task("pan1_env/WholeArmStaticFormation-v1")) is None
    data = board.run_suite([task], [ippo, mappo], runs=tmp_path, teams=1, max_steps=5)
    assert data["runs"][RANDOM]["ippo"] == [{"seed": 0, "source": "shipped:random_formation_v1_ippo"}]
    assert [RANDOM, "mappo"] in data["missing"]
    run = board.task_dir(tmp_path, ippo, task) / "seed_3"
    run.mkdir(parents=True)
    shutil.copyfile(PRETRAINED_DIR / "random_formation_v1_ippo.zip", run / "model.zip")
    shutil.copyfile(PRETRAINED_DIR / "random_formation_v1_ippo.json", run / "model.json")
    recorded = json.loads((PRETRAINED_DIR / "random_formation_v1_ippo.json").read_text())["provenance"]["run"]
    (run / "run.json").write_text(json.dumps(recorded | {"seed": 3}))  # as if trained with seed 3
    data = board.run_suite([task], [ippo], runs=tmp_path, teams=1, max_steps=5)
    assert data["runs"][RANDOM]["ippo"] == [{"seed": 3, "source": str(run)}]
    episodes = data["raw"]["pan1_env"][RANDOM]["ippo"]["seed_3"]["absolute_metrics"]
    assert len(episodes["success"]) == 1 and set(episodes) >= {"success", "cost", "min_clearance"}
    (run / "run.json").write_text(json.dumps(recorded | {"seed": 3, "shield": False}))  # another recipe
    with pytest.raises(ValueError, match="seed_3: not a run of ippo's recipe with seed 3"):
        board.run_suite([task], [ippo], runs=tmp_path, teams=1, max_steps=5)


def test_the_batched_law_and_the_law_one_team_at_a_time_score_alike() -> None:
    """The law is scored batched (the zero action of the gain mode), the circulation rule one team at a time on the
    parallel env: the same teams give the same success, steps changed by the shield and time, near enough."""
    task = suite_task(RANDOM)
    seeds = list(task.held_out)[:2]
    batched = board._law(task, seeds, {})
    alone = board._per_team(task, "reference", seeds, {}, workers=1, tick=lambda n: None)
    assert batched["success"] == alone["success"]
    assert np.allclose(batched["intervention_rate"], alone["intervention_rate"], atol=0.02)
    for t, u in zip(batched["time_to_formation"], alone["time_to_formation"], strict=True):
        assert (t is None) == (u is None) and (t is None or abs(t - u) <= 0.5)


def test_the_worker_pool_scores_the_circulation_rule_as_one_process_does(monkeypatch) -> None:
    """The rule runs one team at a time; with --workers > 1 spawned processes share the teams. Two teams in two
    workers (the pool is lowered to start at 2 teams) give what one process gives, team for team and in order."""
    from concurrent import futures

    from pan1_env.cli import QUICK_STEPS, QUICK_TEAMS

    task, circulation = suite_task("pan1_env/WholeArmStaticFormation-v1"), board.entry("circulation")
    pools = []

    class Pool(futures.ProcessPoolExecutor):  # the real pool, counted: the test must reach it
        def __init__(self, workers, **kwargs) -> None:
            pools.append(workers)
            super().__init__(workers, **kwargs)

    monkeypatch.setattr(futures, "ProcessPoolExecutor", Pool)
    monkeypatch.setattr(board, "_POOL_MIN_TEAMS", QUICK_TEAMS)

    def scores(workers: int) -> dict[str, list]:
        data = board.run_suite([task], [circulation], teams=QUICK_TEAMS, max_steps=QUICK_STEPS, workers=workers,
                               bar=False)
        return data["raw"]["pan1_env"][task.env_id]["circulation"]["seed_0"]["absolute_metrics"]

    alone = scores(1)
    assert pools == []
    pooled = scores(2)
    assert pools == [2]
    assert set(pooled) == set(alone) and all(len(v) == QUICK_TEAMS for v in pooled.values())
    assert pooled["success"] == alone["success"]
    for key in board.EPISODE_METRICS[1:]:
        for p, a in zip(pooled[key], alone[key], strict=True):
            assert (p is None) == (a is None), key
            assert p is None or p == pytest.approx(a, abs=1e-9), key


@pytest.mark.slow
def test_the_quick_suite_writes_its_table_json_figures_and_page(tmp_path) -> None:
    pytest.importorskip("rliable")
    page = tmp_path / "docs" / "BENCHMARK.md"
    assert main(["suite", "--quick", "--out", str(tmp_path / "board"), "--docs", str(page)]) == 0
    raw = json.loads((tmp_path / "board" / "leaderboard_marl_eval.json").read_text())["pan1_env"]
    data = json.loads((tmp_path / "board" / "leaderboard.json").read_text())
    assert data["quick"] and len(raw) == len(data["tasks"])
    for task in data["tasks"]:
        law = raw[task["env_id"]]["law"]["seed_0"]["absolute_metrics"]
        assert len(law["success"]) == task["teams"] == min(2, task["held_out"][1])
        assert all(np.isfinite(c) for c in law["min_clearance"]) and all(c >= 0 for c in law["cost"])
    assert "circulation" in raw["pan1_env/WholeArmStaticFormation-v1"]
    for name in ("leaderboard_iqm.png", "leaderboard_profiles.png", "leaderboard_improvement.png"):
        assert (tmp_path / "docs" / "figures" / name).stat().st_size > 0
    text = page.read_text()
    assert "quick run" in text and all(task["name"] in text for task in data["tasks"])


def test_a_row_reaches_a_target_only_when_every_bound_holds() -> None:
    """meets: the IQM success against the floor and the law's (at least, or above), the time ratio and the cost; a
    bound the target does not set is not checked, and a row without a time ratio misses a time target."""
    from pan1_env.baselines.leaderboard_table import meets

    row = {"success": (0.80, 0.78, 0.82), "time_ratio": (0.90, 0.88, 0.93), "cost": (0.0, 0.0, 0.0)}
    assert meets(row, {"success": 0.65, "vs_law": "above", "time_ratio": None, "cost": 0.0}, law_success=0.745)
    assert not meets(row, {"success": 0.90, "vs_law": None, "time_ratio": None, "cost": 0.0}, law_success=0.745)
    assert not meets(row, {"success": None, "vs_law": "above", "time_ratio": None, "cost": 0.0}, law_success=0.80)
    assert meets(row, {"success": None, "vs_law": "at least", "time_ratio": None, "cost": 0.0}, law_success=0.80)
    assert not meets(row, {"success": None, "vs_law": "at least", "time_ratio": None, "cost": 0.0}, law_success=None)
    assert not meets(row, {"success": None, "vs_law": None, "time_ratio": 0.75, "cost": 0.0}, law_success=0.8)
    assert not meets(row | {"time_ratio": None}, {"time_ratio": 1.0, "cost": None}, law_success=None)
    assert not meets(row | {"cost": (3.0, 1.0, 5.0)}, {"success": 0.5, "cost": 0.0}, law_success=None)
    assert meets(row | {"cost": (3.0, 1.0, 5.0)}, {"success": 0.5, "cost": None}, law_success=None)
    nothing = row | {"success": (0.0, 0.0, 0.0)}
    assert not meets(nothing, {"vs_law": "at least", "cost": 0.0}, law_success=0.0)  # forming none reaches nothing
    assert not meets(row | {"cost_max": 12.0}, {"success": 0.5, "cost": 0.0}, law_success=None)  # one run's cost
    assert not meets(row, {}, law_success=0.5)  # a task without a goal is reached by nobody


def test_every_suite_task_has_a_goal_the_page_checks() -> None:
    """The suite's tasks carry their targets as numbers, and the shipped leaderboard's page has the targets' table."""
    from pan1_env.baselines.suite import SUITE, Target

    assert all(isinstance(task.goal, Target) and task.goal != Target(cost=None) for task in SUITE)
    assert "## Targets" in (DOCS / "BENCHMARK.md").read_text()


def test_the_targets_nearest_learner_among_equals_is_the_one_that_reaches_the_target() -> None:
    """Two learners form every team; the one within the time target is named, whichever is listed first."""
    from pan1_env.baselines.leaderboard_table import targets_table

    task = {"name": "square", "env_id": RANDOM, "target": "time ≤ 0.25×",
            "goal": {"success": None, "vs_law": None, "time_ratio": 0.25, "cost": 0.0}}
    rows = [{"env_id": RANDOM, "entry": "law", "success": (1.0, 1.0, 1.0), "time_ratio": None, "cost": (0, 0, 0)},
            {"env_id": RANDOM, "entry": "slow", "success": (1.0, 1.0, 1.0), "time_ratio": (0.9, 0.7, 1.1),
             "cost": (0, 0, 0)},
            {"env_id": RANDOM, "entry": "fast", "success": (1.0, 1.0, 1.0), "time_ratio": (0.2, 0.1, 0.3),
             "cost": (0, 0, 0)}]
    learner = {"algo": "ppo"}
    entries = [{"name": "law"}, {"name": "slow", "recipe": learner}, {"name": "fast", "recipe": learner}]
    line = targets_table({"tasks": [task], "entries": entries}, rows).splitlines()[-1]
    assert line.split("|")[3].strip() == "fast" and line.split("|")[4].strip().startswith("fast:")


def _cell(data: dict, env_id: str, name: str) -> dict:
    return data["raw"]["pan1_env"][env_id][name]


def test_an_entry_scored_alone_is_merged_into_the_shipped_board(tmp_path, capsys) -> None:
    """A board of the law and one new entry on one task (what ``pan1-env suite --tasks T --entries law,E`` writes)
    merged after the shipped board: its cells replace the shipped ones, every other cell is kept, the new entry is
    declared, and what is missing is worked out again; a board on other held-out teams is refused."""
    shipped = board.load_leaderboard(DOCS / "leaderboard.json")
    assert board.merge_leaderboards([shipped]) == {**shipped, "quick": shipped.get("quick", False)}
    task = next(t for t in shipped["tasks"] if t["env_id"] == "pan1_env/FaultFormation-v1")
    law = _cell(shipped, task["env_id"], "law")
    new = {"name": "made-up", "description": "made up", "policy": None, "recipe": {}, "tasks": [task["env_id"]],
           "trained_on": None}
    flipped = {"seed_0": {"absolute_metrics": {**law["seed_0"]["absolute_metrics"],
                                               "success": [1.0] * task["teams"]}}}
    alone = {"tasks": [task], "entries": [shipped["entries"][0], new],
             "runs": {task["env_id"]: {"law": shipped["runs"][task["env_id"]]["law"],
                                       "made-up": [{"seed": 0, "source": "made up"}]}},
             "missing": [], "raw": {"pan1_env": {task["env_id"]: {"law": law, "made-up": flipped}}}, "quick": False}
    merged = board.merge_leaderboards([shipped, alone])
    assert _cell(merged, task["env_id"], "made-up") == flipped
    assert [e["name"] for e in merged["entries"]] == [e["name"] for e in shipped["entries"]] + ["made-up"]
    for env_id, cells in shipped["raw"]["pan1_env"].items():
        for name, cell in cells.items():
            assert _cell(merged, env_id, name) == cell
    assert merged["missing"] == shipped["missing"]
    (tmp_path / "alone.json").write_text(json.dumps(alone))
    out = tmp_path / "out"
    assert main(["suite", "--from", str(DOCS / "leaderboard.json"), "--from", str(tmp_path / "alone.json"),
                 "--out", str(out), "--no-figures", "--reps", "50"]) == 0
    assert "made-up" in (out / "leaderboard.md").read_text()
    assert json.loads((out / "leaderboard.json").read_text()) == merged
    other = {**alone, "tasks": [{**task, "held_out": [task["held_out"][0] + 1, task["held_out"][1]]}]}
    with pytest.raises(ValueError, match="different held-out teams"):
        board.merge_leaderboards([shipped, other])
    capsys.readouterr()


def test_a_circulation_run_is_scored_in_its_own_action_mode(tmp_path) -> None:
    """The suite scores a run in the mode it was trained in: a circulation model (trained for a few steps, its
    run.json then the entry's recipe, as if trained with it) is a run of mappo-circulation on its task."""
    pytest.importorskip("stable_baselines3")
    from pan1_env.baselines.training import train

    circulation, task = board.entry("mappo-circulation"), suite_task("pan1_env/WholeArmStaticFormation-v1")
    run = board.task_dir(tmp_path, circulation, task) / "seed_1"
    recipe = circulation.recipe
    train("ppo", task.env_id, shield=True, timesteps=128, seed=1, out=run, checkpoint_every=128, progress=False,
          n_envs=2, param_sharing=True, centralised_critic=True, env_kwargs={"max_steps": 16, **recipe["env_kwargs"]},
          algo_kwargs={"n_steps": 32, "batch_size": 64, "n_epochs": 1})
    recorded = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps(recorded | {k: v for k, v in recipe.items() if k != "checkpoint_every"}
                                             | {"timesteps": task.train_steps, "seed": 1}))
    data = board.run_suite([task], [circulation], runs=tmp_path, teams=1, max_steps=5)
    assert data["runs"][task.env_id]["mappo-circulation"] == [{"seed": 1, "source": str(run)}]
    assert len(data["raw"]["pan1_env"][task.env_id]["mappo-circulation"]["seed_1"]["absolute_metrics"]["success"]) == 1
