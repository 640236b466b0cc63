"""The pan1-env command line: outputs, metrics keys, errors."""

import json
import subprocess
import sys

import numpy as np
import pytest

from pan1_env.cli import main

REQUIRED = {"scenario", "controller", "horizon_s", "physics_dt", "control_dt", "steps", "wall_time_s",
            "arms", "min_clearance_m", "collided", "final_max_edge_error_m", "time_to_edge_error_1cm_s",
            "max_tracking_error", "max_momentum_drift"}


def test_reproduce_writes_metrics_trajectory_and_figures(tmp_path) -> None:
    out = tmp_path / "run"
    code = main(["reproduce", "paper_pa_mixed_square", "--controller", "safe", "--out", str(out),
                 "--horizon", "0.5", "--no-progress"])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert REQUIRED <= set(metrics)
    assert metrics["steps"] == 500 and metrics["horizon_s"] == 0.5
    assert len(metrics["arms"]) == 4
    assert {"min_clearance_m", "collided"} <= set(metrics["arms"][0])
    with np.load(out / "trajectory.npz") as traj:
        assert {"time", "q", "qd", "p_end", "v_star", "tau"} <= set(traj.files)
        assert traj["q"].shape == (len(traj["time"]), 4, 2)
        assert np.isclose(traj["time"][-1], 0.5)
        # every recorded clearance is at least the reported minimum (which covers all sub-steps)
        assert traj["clearance"].min() >= metrics["min_clearance_m"] - 1e-12
    for png in ("figure.png", "obstacle_distance.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_paper_command_prints_table(tmp_path, capsys) -> None:
    code = main(["paper", "--out", str(tmp_path), "--horizon", "0.2", "--no-progress", "--no-figures"])
    assert code == 0
    table = (tmp_path / "summary.md").read_text()
    assert table.count("\n") == 2 + 4  # header, rule, four runs
    assert "paper_pa3_square | nominal" in capsys.readouterr().out


def test_python_dash_m_reports_bad_scenario() -> None:
    proc = subprocess.run([sys.executable, "-m", "pan1_env", "reproduce", "no_such_scenario",
                           "--controller", "safe", "--out", "unused"], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "no_such_scenario" in proc.stderr and "not a built-in scenario" in proc.stderr


def test_bad_horizon_is_rejected(capsys) -> None:
    import pytest

    with pytest.raises(SystemExit):
        main(["reproduce", "paper_pa3_square", "--controller", "safe", "--out", "x", "--horizon", "-1"])
    assert "positive" in capsys.readouterr().err


def test_animate_writes_a_gif_with_the_shielded_reference(tmp_path, capsys) -> None:
    out = tmp_path / "episode.gif"
    assert main(["animate", "paper_pa_mixed_square", "--out", str(out), "--steps", "40", "--frames", "5"]) == 0
    assert out.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    text = capsys.readouterr().out
    assert "shield on" in text and "cost (arm-steps in obstacles) 0" in text
    assert main(["animate", "paper_pa3_square", "--out", str(tmp_path / "x.mp4")]) == 2


def _subcommands() -> dict:
    import argparse

    from pan1_env.cli import _parser

    (commands,) = [a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return commands.choices


def test_every_option_of_every_subcommand_has_help_and_shows_its_default() -> None:
    import argparse

    commands = _subcommands()
    assert {"reproduce", "paper", "scenarios", "animate", "train", "benchmark"} <= set(commands)
    for name, parser in commands.items():
        formatter = parser._get_formatter()
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            what = f"pan1-env {name} {'/'.join(action.option_strings) or action.dest}"
            assert action.help and action.help.strip(), f"{what} has no help text"
            shown = formatter._expand_help(action)  # the text `--help` prints for it
            if not action.option_strings or action.required or action.default in (None, False):
                continue  # positionals, required options, off-by-default flags: no value to show
            assert f"default: {action.default}" in shown, f"{what}: default not shown: {shown!r}"


def test_train_and_benchmark_help_show_defaults(capsys) -> None:
    import pytest

    for command, expected in (("train", "(default: 100000)"), ("benchmark", "(default: both)")):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert expected in " ".join(capsys.readouterr().out.split())


def test_console_summary_is_formatted_for_people(capsys) -> None:
    import re

    from pan1_env.cli import _print_summary

    metrics = {
        "scenario": "paper_pa3_square", "controller": "nominal", "steps": 100_000, "physics_dt": 0.001,
        "wall_time_s": 54.123456789,
        "arms": [{"index": 0, "min_clearance_m": -0.022198765432, "collided": True},
                 {"index": 1, "min_clearance_m": 0.55983210987, "collided": False},
                 {"index": 2, "min_clearance_m": None, "collided": False}],
        "final_max_edge_error_m": 0.000168912345678, "time_to_edge_error_1cm_s": 31.551000000015577,
        "max_momentum_drift": 1.8734e-16, "qp_solved_steps": 0, "qp_fallback_steps": 0,
    }
    _print_summary(metrics)
    out = capsys.readouterr().out
    assert "100,000 steps of 0.001 s in 54.1 s wall time" in out
    assert "arm 1: min clearance -22.2 mm  COLLIDED" in out
    assert "arm 2: min clearance +559.8 mm\n" in out
    assert "arm 3: min clearance —" in out
    assert "final max edge error 1.69e-04 m" in out
    assert "time to 1 cm: 31.55 s" in out
    assert "max momentum drift: 1.9e-16" in out
    assert not re.search(r"\d\.\d{4,}", out), f"raw floats in {out!r}"
    _print_summary({**metrics, "time_to_edge_error_1cm_s": None, "max_momentum_drift": None})
    out = capsys.readouterr().out
    assert "time to 1 cm: never" in out and "max momentum drift: —" in out


def test_train_rejects_json_options_that_are_not_objects(capsys) -> None:
    import pytest

    for option, text in (("--env-kwargs", "[1]"), ("--algo-kwargs", "{gamma: 1}")):
        with pytest.raises(SystemExit) as exit_info:
            main(["train", "--out", "unused", option, text])
        assert exit_info.value.code == 2
        assert f"argument {option}: expected a JSON object" in capsys.readouterr().err


def test_train_offers_every_action_mode_of_the_env() -> None:
    from pan1_env.config import ACTION_MODES

    (mode,) = [a for a in _subcommands()["train"]._actions if a.dest == "action_mode"]
    assert tuple(mode.choices) == ACTION_MODES


def test_help_names_every_algorithm_and_policy_the_code_has(capsys) -> None:
    import pytest

    from pan1_env.baselines.training import ALGOS

    with pytest.raises(SystemExit):
        main(["--help"])
    top = " ".join(capsys.readouterr().out.split()).lower()
    for algo in ALGOS:  # the top-level line of train names each algorithm
        assert algo in top.replace("- ", "-"), (algo, top)  # argparse may wrap after a hyphen
    (policy,) = [a for a in _subcommands()["animate"]._actions if a.dest == "policy"]
    assert "pretrained" in policy.help and "pretrained:NAME" in policy.help


def test_scenarios_lists_random_and_every_gymnasium_id_in_good_english(capsys) -> None:
    import re

    from pan1_env.registration import ENV_IDS, REACH_ENV_ID

    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    assert "paper_pa_mixed_square: 4 arms, 1 obstacle," in out
    assert not re.search(r"\b1 (obstacles|arms)\b", out), out
    assert re.search(r"^\s+random: ", out, re.MULTILINE)
    for env_id in [*ENV_IDS, REACH_ENV_ID]:
        assert f"  {env_id}: " in out, env_id


def test_benchmark_shows_a_progress_bar_per_row(tmp_path, capsys) -> None:
    code = main(["benchmark", "--scenarios", "paper_pa_mixed_square", "--policies", "zero", "--shield", "on",
                 "--episodes", "3", "--max-steps", "5", "--out", str(tmp_path)])
    assert code == 0
    err = capsys.readouterr().err
    assert "paper_pa_mixed_square / zero / shield on" in err and "0/3" in err and "episode/s" in err


def test_benchmark_passes_env_arguments_on_top_of_a_team_ids(tmp_path, capsys) -> None:
    """``--env-kwargs`` reaches every env (a placed random team's row reports its tracking error), and an option the
    random teams do not have is one line and exit 2."""
    import json

    options = ('{"random_options": {"formation_turn": [-0.2, 0.2], "formation_travel": [0, 0.05]}, "max_steps": 5, '
               '"success_hold": 0.1}')
    code = main(["benchmark", "--scenarios", "pan1_env/MovingFormation-v0", "--policies", "zero", "--shield", "on",
                 "--episodes", "1", "--env-kwargs", options, "--out", str(tmp_path)])
    assert code == 0
    (row,) = json.loads((tmp_path / "benchmark.json").read_text())
    assert row["mean_tracking_error_m"] > 0.0
    capsys.readouterr()
    code = main(["benchmark", "--scenarios", "pan1_env/MovingFormation-v0", "--policies", "zero", "--episodes", "1",
                 "--env-kwargs", '{"random_options": {"formation_spin": 1}}', "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "random_options: unknown option 'formation_spin'" in err


@pytest.mark.parametrize(("kwargs", "message"), [
    ('{"frobnicate": 1}', "Pan1ParallelEnv got an unknown argument 'frobnicate'"),
    ('{"scenario": "random"}', "--env-kwargs cannot set the scenario: name it in --scenarios"),
    ('{"random_options": {"formation_travel": [3, 4]}}', "no valid random scenario in 200 draws; loosen the options"),
], ids=["unknown_argument", "scenario", "options_too_tight"])
def test_benchmark_reports_bad_env_arguments_in_one_line(tmp_path, capsys, kwargs: str, message: str) -> None:
    code = main(["benchmark", "--scenarios", "pan1_env/MovingFormation-v0", "--policies", "zero", "--episodes", "1",
                 "--env-kwargs", kwargs, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err


def test_benchmark_writes_its_episodes_in_marl_evals_layout(tmp_path, capsys) -> None:
    import json

    code = main(["benchmark", "--scenarios", "paper_pa_mixed_square", "--policies", "zero,reference",
                 "--shield", "both", "--episodes", "2", "--max-steps", "5", "--out", str(tmp_path)])
    assert code == 0 and "benchmark_marl_eval.json" in capsys.readouterr().out
    rows = json.loads((tmp_path / "benchmark.json").read_text())
    tasks = json.loads((tmp_path / "benchmark_marl_eval.json").read_text())["pan1_env"]
    assert set(tasks) == {"paper_pa_mixed_square", "paper_pa_mixed_square (no shield)"}
    for row in rows:
        task = row["scenario"] + ("" if row["shield"] else " (no shield)")
        metrics = tasks[task][row["policy"]]["seed_0"]["absolute_metrics"]
        assert set(metrics) == {"success", "return", "cost", "min_clearance"}
        assert all(len(values) == 2 for values in metrics.values())
        assert np.mean(metrics["success"]) == row["success_rate"] and sum(metrics["cost"]) == row["total_cost"]
        assert np.mean(metrics["return"]) == pytest.approx(row["mean_return"])


def test_a_policy_whose_extra_is_missing_exits_2_in_one_line(tmp_path, capsys, monkeypatch) -> None:
    """``--policies marl`` (a shipped SB3 model) in a venv without Stable-Baselines3: one line naming the extra."""
    import sys

    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import stable_baselines3 now fails
    code = main(["benchmark", "--scenarios", "paper_pa3_square", "--policies", "marl", "--episodes", "1",
                 "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "rl extra" in err, err
    assert not (tmp_path / "benchmark.json").exists()
