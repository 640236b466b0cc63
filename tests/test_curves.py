"""Learning curves over seeds (pan1_env.baselines.curves, pan1-env plot) on hand-written run directories."""

import csv
import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from pan1_env.baselines.curves import learning_curves, load_run, plot_curves
from pan1_env.cli import main

META = {"algo": "ppo", "scenario": "paper_pa3_square", "shield": True, "timesteps": 1000, "seed": 0, "n_envs": 4,
        "param_sharing": False, "env_kwargs": {}, "algo_kwargs": {}}


def write_run(path: Path, returns, *, steps=None, success=None, cost=None, **meta) -> Path:
    """A run directory as pan1-env train writes it: episode i ends at env step 100 (i + 1) unless ``steps``."""
    path.mkdir(parents=True)
    (path / "run.json").write_text(json.dumps(META | meta, indent=2) + "\n")
    n = len(returns)
    steps = [100 * (i + 1) for i in range(n)] if steps is None else steps
    success = [0] * n if success is None else success
    cost = [0.0] * n if cost is None else cost
    with (path / "episodes.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["timesteps", "return", "length", "cost", "success"])
        w.writerows([s, r, 100, c, int(ok)] for s, r, c, ok in zip(steps, returns, cost, success, strict=True))
    return path


def three_seeds(tmp_path: Path) -> list[Path]:
    """Seed k: return (k + 1) * i and cost k * i for episode i; success from episode 5 + k on."""
    i = np.arange(10)
    return [write_run(tmp_path / f"s{k}", list((k + 1) * i), cost=list(k * i), success=list(i >= 5 + k), seed=k)
            for k in range(3)]


def test_the_mean_is_the_hand_computed_mean_of_running_means(tmp_path) -> None:
    runs = three_seeds(tmp_path)
    (g,) = learning_curves(runs, window=3, points=19).values()
    assert g["n_seeds"] == 3 and g["seeds"] == [0, 1, 2]
    assert list(g["x"]) == list(range(100, 1001, 50))
    at = {int(x): j for j, x in enumerate(g["x"])}
    # at 100 steps one episode (returns 0); at 200 two: (0+1)/2 * (1+2+3)/3; at 550 episodes 2,3,4 count;
    # at 1000 episodes 7, 8, 9: means 8, 16, 24 over the seeds -> 16
    assert g["return"]["mean"][at[100]] == 0.0
    assert g["return"]["mean"][at[200]] == pytest.approx(1.0)
    assert g["return"]["mean"][at[550]] == pytest.approx(6.0)
    assert g["return"]["mean"][at[1000]] == pytest.approx(16.0)
    assert g["return"]["per_seed"][:, at[1000]] == pytest.approx([8, 16, 24])
    assert g["cost"]["mean"][at[1000]] == pytest.approx((0 + 8 + 16) / 3)
    # success at 1000 over episodes 7..9: seed 0 all three, seed 1 all three, seed 2 (from episode 7) all three
    assert g["success"]["mean"][at[1000]] == pytest.approx(1.0)
    # at 700 over episodes 4..6: seed 0 has 5, 6 -> 2/3; seed 1 has 6 -> 1/3; seed 2 none
    assert g["success"]["mean"][at[700]] == pytest.approx((2 / 3 + 1 / 3 + 0) / 3)


def test_window_one_reads_the_last_episode_and_episodes_axis(tmp_path) -> None:
    runs = three_seeds(tmp_path)
    (g,) = learning_curves(runs, window=1, points=10).values()
    assert g["return"]["mean"] == pytest.approx(2.0 * np.arange(10))  # (1 + 2 + 3) / 3 * i
    (e,) = learning_curves(runs, x="episodes", window=1, points=10).values()
    assert list(e["x"]) == list(range(1, 11))
    assert e["return"]["mean"] == pytest.approx(g["return"]["mean"])


def test_the_grid_is_the_range_every_seed_covers(tmp_path) -> None:
    a = write_run(tmp_path / "a", [1, 2, 3], steps=[300, 600, 900], seed=0)
    b = write_run(tmp_path / "b", [1, 2, 3, 4], steps=[100, 400, 700, 1000], seed=1)
    c = write_run(tmp_path / "c", [5, 6], steps=[50, 800], seed=2)
    (g,) = learning_curves([a, b, c], points=5).values()
    assert g["x"][0] == 300 and g["x"][-1] == 800
    shuffled = load_run(write_run(tmp_path / "shuffled", [3, 1, 2], steps=[300, 100, 200]))
    assert list(shuffled["timesteps"]) == [100, 200, 300] and list(shuffled["return"]) == [1, 2, 3]
    late = write_run(tmp_path / "late", [1], steps=[5000], seed=3)
    with pytest.raises(ValueError, match="do not overlap"):
        learning_curves([a, late])


def test_the_band_holds_the_mean_and_shrinks_when_seeds_agree(tmp_path) -> None:
    base = np.linspace(-100, 0, 20)
    spread = [write_run(tmp_path / f"spread{k}", list(base + 10 * d), seed=k) for k, d in enumerate((-2, 0, 1, 3))]
    close = [write_run(tmp_path / f"close{k}", list(base + 0.1 * d), seed=k, scenario="random")
             for k, d in enumerate((-2, 0, 1, 3))]
    same = [write_run(tmp_path / f"same{k}", list(base + 0.1), seed=k, scenario="same") for k in range(3)]
    curves = learning_curves(spread + close + same, window=5)
    s, c, z = curves.values()
    for g in curves.values():
        for metric in ("return", "success", "cost"):
            assert np.all(g[metric]["lo"] <= g[metric]["mean"]) and np.all(g[metric]["mean"] <= g[metric]["hi"])
    width_spread = s["return"]["hi"] - s["return"]["lo"]
    width_close = c["return"]["hi"] - c["return"]["lo"]
    assert np.all(width_spread > 0) and np.all(width_close < width_spread / 10)
    assert z["return"]["hi"] - z["return"]["lo"] == pytest.approx(np.zeros(len(z["x"])), abs=1e-12)
    assert z["return"]["mean"][-1] == pytest.approx(np.mean(base[-5:] + 0.1))


def test_the_band_is_a_bootstrap_of_the_mean_not_the_spread_of_the_seeds(tmp_path) -> None:
    runs = [write_run(tmp_path / f"s{k}", [float(k)] * 3, seed=k) for k in range(10)]
    (g,) = learning_curves(runs, points=3).values()
    # seeds 0..9: mean 4.5, standard error sqrt(8.25 / 10) = 0.908; 95 % interval about 4.5 -+ 1.78
    assert g["return"]["mean"] == pytest.approx([4.5] * 3)
    assert g["return"]["lo"] == pytest.approx([4.5 - 1.78] * 3, abs=0.15)
    assert g["return"]["hi"] == pytest.approx([4.5 + 1.78] * 3, abs=0.15)
    again = next(iter(learning_curves(runs, points=3).values()))
    np.testing.assert_array_equal(again["return"]["lo"], g["return"]["lo"])  # seeded: reproducible


def test_runs_differing_only_in_seed_form_one_group(tmp_path) -> None:
    shielded = [write_run(tmp_path / f"on{k}", [1.0, 2.0], seed=k) for k in range(3)]
    bare = [write_run(tmp_path / f"off{k}", [3.0, 4.0], seed=k, shield=False) for k in range(2)]
    other = write_run(tmp_path / "rnd", [5.0, 6.0], seed=0, scenario="random")
    with pytest.warns(UserWarning, match=r"seed\(s\): plotted without a confidence band, which needs >= 3") as got:
        curves = learning_curves([shielded[0], bare[0], *shielded[1:], bare[1], other])
    assert sorted(str(w.message).split(" has ")[1][0] for w in got) == ["1", "2"]
    assert list(curves) == ["ppo shield, scenario=paper_pa3_square", "ppo no shield, scenario=paper_pa3_square",
                            "ppo shield, scenario=random"]
    on, off, rnd = curves.values()
    assert on["seeds"] == [0, 1, 2] and off["seeds"] == [0, 1] and rnd["n_seeds"] == 1
    assert {Path(p).name for p in off["runs"]} == {"off0", "off1"}
    assert np.isnan(off["return"]["lo"]).all() and not np.isnan(on["return"]["lo"]).any()
    assert off["return"]["mean"][-1] == pytest.approx(3.5)  # window 100: both episodes of both seeds
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # three seeds: no warning
        (only,) = learning_curves(shielded)
    assert only == "ppo shield"
    with pytest.warns(UserWarning, match="group 'B' has 2 seed"):
        named = learning_curves(shielded + bare, labels=["A", "B"])
    assert list(named) == ["A", "B"]
    with pytest.raises(ValueError, match="1 label"):
        learning_curves(shielded + bare, labels=["A"])
    twin = write_run(tmp_path / "twin", [1.0], seed=1)
    with pytest.raises(ValueError, match="same run"):
        learning_curves([*shielded, twin])


def test_plot_writes_the_png_and_the_long_csv_beside_it(tmp_path) -> None:
    runs = three_seeds(tmp_path / "a") + [write_run(tmp_path / "b" / "s0", [1.0, 2.0], seed=0, algo="sac")]
    with pytest.warns(UserWarning):
        png, table = plot_curves(runs, tmp_path / "out" / "curves.png", points=4, window=2)
    assert png == tmp_path / "out" / "curves.png" and table == tmp_path / "out" / "curves.csv"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with table.open(newline="") as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames == ["group", "metric", "timesteps", "mean", "lo", "hi", "n_seeds"]
        rows = list(reader)
    assert len(rows) == 2 * 3 * 4
    assert {(r["group"], r["n_seeds"]) for r in rows} == {("ppo shield", "3"), ("sac shield", "1")}
    last = next(r for r in rows if r["group"] == "ppo shield" and r["metric"] == "return" and r["timesteps"] == "1000")
    assert float(last["mean"]) == pytest.approx((8.5 + 17 + 25.5) / 3)  # episodes 8, 9 of each seed
    assert float(last["lo"]) <= float(last["mean"]) <= float(last["hi"])
    sac = [r for r in rows if r["group"] == "sac shield"]
    assert {r["timesteps"] for r in sac} == {"100", "133", "167", "200"}
    assert all(r["lo"] == "" and r["hi"] == "" for r in sac)
    with pytest.raises(ValueError, match=r"\.png"):
        plot_curves(runs[:3], tmp_path / "curves.svg")


def test_missing_or_empty_files_are_named(tmp_path) -> None:
    good = write_run(tmp_path / "good", [1.0], seed=0)
    with pytest.raises(FileNotFoundError, match="nowhere: no such run directory"):
        load_run(tmp_path / "nowhere")
    (tmp_path / "bare").mkdir()
    with pytest.raises(FileNotFoundError, match=r"bare: not a training run directory, missing run\.json and episodes"):
        load_run(tmp_path / "bare")
    no_csv = write_run(tmp_path / "no_csv", [1.0])
    (no_csv / "episodes.csv").unlink()
    with pytest.raises(FileNotFoundError, match=r"no_csv: .*missing episodes\.csv"):
        learning_curves([good, no_csv])
    no_json = write_run(tmp_path / "no_json", [1.0])
    (no_json / "run.json").unlink()
    with pytest.raises(FileNotFoundError, match=r"no_json: .*missing run\.json"):
        load_run(no_json)
    header_only = write_run(tmp_path / "header_only", [])
    with pytest.raises(ValueError, match=r"header_only.episodes\.csv: empty"):
        load_run(header_only)
    (header_only / "episodes.csv").write_text("")
    with pytest.raises(ValueError, match="the file is empty"):
        load_run(header_only)
    (header_only / "episodes.csv").write_text("timesteps,return\n100,1\n")
    with pytest.raises(ValueError, match="missing column.*length, cost, success"):
        load_run(header_only)


def test_the_command_line(tmp_path, capsys) -> None:
    runs = [str(p) for p in three_seeds(tmp_path)]
    out = tmp_path / "curves.png"
    assert main(["plot", *runs[:2], "--out", str(out), "--window", "2", "--label", "mine"]) == 0
    captured = capsys.readouterr()
    assert "warning: group 'mine' has 2 seed(s)" in captured.err
    assert str(out) in captured.out and out.exists() and out.with_suffix(".csv").exists()
    assert main(["plot", runs[0], str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert "missing: no such run directory" in capsys.readouterr().err
    (Path(runs[0]) / "episodes.csv").write_text("timesteps,return,length,cost,success\n")
    assert main(["plot", runs[0], "--out", str(out)]) == 2
    assert "empty, no finished episode" in capsys.readouterr().err


def test_importing_the_package_does_not_import_matplotlib() -> None:
    code = "import sys, pan1_env, pan1_env.baselines.curves; assert 'matplotlib' not in sys.modules"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_a_run_without_episodes_is_drawn_from_its_evaluations(tmp_path, capsys) -> None:
    run = write_run(tmp_path / "short", [], seed=0)
    with (run / "eval.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["timesteps", "success_1cm", "success_2cm", "success_5cm", "median_final_error_m", "mean_return",
                    "cost", "mean_time_to_formation_s"])
        w.writerows([[1000, 0.0, 0.1, 0.2, 0.3, -50.0, 0.0, ""], [2000, 0.25, 0.5, 0.6, 0.02, -20.0, 1.0, 12.5]])
    with pytest.warns(UserWarning, match="plotting its evaluations"):
        loaded = load_run(run)
    assert loaded["source"] == "eval.csv" and list(loaded["return"]) == [-50.0, -20.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (curves,) = learning_curves([run], window=100, points=3).values()
    # each evaluation read as it is, not averaged with the ones before (the window is for episodes)
    assert list(curves["x"]) == [1000, 1500, 2000]
    assert list(curves["return"]["mean"]) == [-50.0, -50.0, -20.0]
    assert list(curves["success"]["mean"]) == [0.0, 0.0, 0.25]
    out = tmp_path / "c.png"
    assert main(["plot", str(run), "--out", str(out)]) == 0 and out.exists()
    assert "warning:" in capsys.readouterr().err
    (run / "eval.csv").unlink()
    with pytest.raises(ValueError, match="no finished episode logged yet; the first episodes end after"):
        load_run(run)
