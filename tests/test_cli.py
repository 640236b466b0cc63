"""The pan1-env command line: outputs, metrics keys, errors."""

import json
import subprocess
import sys

import numpy as np

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
