"""Learning curves over seeds: return, success rate and cost against environment steps.

Reads the run directories :func:`~pan1_env.baselines.training.train` (``pan1-env train``) writes, each
with ``run.json`` (the training arguments) and ``episodes.csv`` (one row per finished episode:
``timesteps, return, length, cost, success``), and summarises them the way RL papers do:

1. **Groups.** Runs whose ``run.json`` differ only in ``seed`` form one group. A group's label is
   the algorithm and shield setting plus every other argument that differs between the groups
   (e.g. ``ppo shield, scenario=random``), unless ``labels`` names the groups.
2. **Per seed.** Each run's episodes are smoothed with a running mean over its last ``window``
   episodes (SB3 logs ``rollout/ep_rew_mean`` the same way, over 100) and that mean is read off on a
   grid of ``points`` env steps shared by the group: from the latest first episode to the earliest
   last episode of its runs, so every seed has a value at every point. (A running mean rather than
   bins: with many env copies, episodes end in bursts and most bins of a fine grid would be empty.)
3. **Over seeds.** At each grid point: the mean over seeds and a 95 % percentile bootstrap
   confidence band of that mean: the seeds are resampled with replacement ``n_boot`` times, the mean
   of each resample taken, and the band runs from the 2.5th to the 97.5th percentile of those means.
   It says how well the seeds pin down the mean curve, not how spread the seeds are. The resampling
   is seeded, so the same runs give the same numbers. A group of fewer than 3 seeds gets no band
   (``lo``/``hi`` are NaN) and a warning.

A run with no finished episode (shorter than one episode of every copy) is drawn from its evaluation
log, ``eval.csv`` (``--eval-every``), if it has one: one point per evaluation, not smoothed (each is
already a mean over held-out episodes), and a warning says so. Without one, :func:`load_run` raises a
``ValueError`` that gives the ``pan1-env train … --resume`` command that continues the run to its
first episodes.

Only numpy here; matplotlib is imported by :func:`plot_curves` (Agg backend) and nowhere else.
"""

from __future__ import annotations

import csv
import json
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["group_runs", "group_labels", "run_arguments", "load_run", "learning_curves", "plot_curves", "METRICS",
           "COLUMNS"]

COLUMNS = ("timesteps", "return", "length", "cost", "success")
METRICS = ("return", "success", "cost")  # the panels, top to bottom
MIN_SEEDS_FOR_BAND = 3
_TITLES = {"return": "episode return", "success": "success rate (formation error < 1 cm at the end)",
           "cost": "cost per episode (arm-steps inside an obstacle)"}


def load_run(path: str | Path) -> dict[str, Any]:
    """One training run: ``{"path", "meta", "timesteps", "return", "length", "cost", "success"}``.

    ``meta`` is ``run.json`` as a dict; the other entries are float arrays, one value per episode,
    sorted by ``timesteps`` (the env steps done when the episode ended, over all copies).
    Raises FileNotFoundError naming the directory and what it lacks, ValueError for an empty or
    malformed ``episodes.csv``.
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such run directory")
    missing = [name for name in ("run.json", "episodes.csv") if not (path / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{path}: not a training run directory, missing {' and '.join(missing)} "
                                "(pan1-env train writes both)")
    meta = run_arguments(path)
    csv_path = path / "episodes.csv"
    with csv_path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None:
            raise ValueError(f"{csv_path}: the file is empty (no header, no episodes)")
        lacking = [c for c in COLUMNS if c not in reader.fieldnames]
        if lacking:
            raise ValueError(f"{csv_path}: missing column(s) {', '.join(lacking)}; expected {', '.join(COLUMNS)}")
        try:
            rows = [[_number(row[c]) for c in COLUMNS] for row in reader]
        except (TypeError, ValueError) as err:
            raise ValueError(f"{csv_path}, line {reader.line_num}: {err}") from None
    source = "episodes.csv"
    if not rows:
        rows = _evaluations(path / "eval.csv")
        if not rows:
            raise ValueError(f"{csv_path}: empty, no finished episode logged yet; {_what_to_run(path, meta)}")
        source = "eval.csv"
        warnings.warn(f"{path}: no finished training episode; plotting its evaluations (eval.csv) instead, "
                      "one point per evaluation, not smoothed", UserWarning, stacklevel=2)
    table = np.array(rows, dtype=float)
    table = table[np.argsort(table[:, 0], kind="stable")]
    return {"path": path, "meta": meta, "source": source} | {c: table[:, i] for i, c in enumerate(COLUMNS)}


def _evaluations(path: Path) -> list[list[float]]:
    """The rows of ``eval.csv`` (written with ``--eval-every``) as episode rows: each evaluation, a mean
    over held-out episodes, stands for one point (return: mean return, success: success at 1 cm, cost:
    mean cost, length unknown). Empty if there is no such file or it has no row."""
    if not path.is_file():
        return []
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        try:
            return [[_number(r["timesteps"]), _number(r["mean_return"]), float("nan"), _number(r["cost"]),
                     _number(r["success_1cm"])] for r in reader]
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{path}, line {reader.line_num}: not an evaluation log ({err})") from None


def _what_to_run(path: Path, meta: dict[str, Any]) -> str:
    """What to run to get a run with no finished episode to its first episodes: the ``pan1-env train``
    command that resumes it to the step at which every copy has finished one."""
    from .commands import training_command
    from .training import DEFAULT_N_ENVS, first_episode_end

    try:
        end = first_episode_end(meta["scenario"], meta.get("env_kwargs") or {}, int(meta.get("n_envs", DEFAULT_N_ENVS)),
                                bool(meta.get("param_sharing")))
        command = training_command(meta, path, timesteps=max(end, int(meta.get("timesteps", 0))), resume=True)
    except (KeyError, TypeError, ValueError):  # a hand-written or foreign run.json: no command to give
        return ("train it longer: pan1-env train --resume --out DIR --timesteps N with the run's own options, "
                "or with a smaller --max-steps")
    return f"the first episodes end after {end:,} steps; continue the run with: {command}"


def _number(text: str | None) -> float:
    if text is None:
        raise ValueError("row has fewer fields than the header")
    low = text.strip().lower()
    return {"true": 1.0, "false": 0.0}[low] if low in ("true", "false") else float(text)


def run_arguments(path: Path) -> dict[str, Any]:
    """A run's ``run.json``: the training arguments (ValueError naming the file if it is not their object)."""
    try:
        meta = json.loads((path / "run.json").read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path / 'run.json'}: not valid JSON ({err})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("scenario"), str):
        raise ValueError(f"{path / 'run.json'}: expected a JSON object of the training arguments, with a scenario")
    return meta


def group_runs(runs: Sequence[dict[str, Any]], same_budget: bool = False) -> list[list[dict[str, Any]]]:
    """Runs with the same arguments apart from ``seed`` and ``timesteps`` (with ``same_budget``, apart from
    ``seed`` only: final models of different budgets are different results), in the order the groups first
    appear."""
    groups: dict[str, list[dict[str, Any]]] = {}
    ignored = ("seed",) if same_budget else ("seed", "timesteps")  # a curve resumed further is the same setting
    for run in runs:
        key = json.dumps({k: v for k, v in run["meta"].items() if k not in ignored}, sort_keys=True, default=str)
        group = groups.setdefault(key, [])
        twin = next((r for r in group if r["meta"].get("seed") == run["meta"].get("seed")), None)
        if twin is not None:
            raise ValueError(f"{twin['path']} and {run['path']} are the same run (same arguments and seed "
                             f"{run['meta'].get('seed')}): pass each run once")
        group.append(run)
    return list(groups.values())


def group_labels(groups: list[list[dict[str, Any]]], same_budget: bool = False) -> list[str]:
    """algo + shield + every other argument (not the seed) whose value differs between the groups."""
    metas = [g[0]["meta"] for g in groups]
    keys = sorted({k for m in metas for k in m} - {"algo", "shield", "seed", *(() if same_budget else ("timesteps",))})
    differ = [k for k in keys if len({json.dumps(m.get(k), sort_keys=True, default=str) for m in metas}) > 1]
    labels = []
    for m in metas:
        parts = [str(m["algo"])] if "algo" in m else []
        if "shield" in m:
            parts.append("shield" if m["shield"] else "no shield")
        head = " ".join(parts) or "runs"
        extra = [f"{k}={json.dumps(m[k], sort_keys=True) if isinstance(m.get(k), dict | list) else m.get(k)}"
                 for k in differ if m.get(k) is not None]  # a setting the run does not have is not a label
        labels.append(", ".join([head, *extra]))
    return labels


def _running_mean(x: np.ndarray, y: np.ndarray, grid: np.ndarray, window: int) -> np.ndarray:
    """At each grid point g: the mean of y over the last ``window`` episodes with x <= g."""
    csum = np.concatenate([[0.0], np.cumsum(y)])
    k = np.searchsorted(x, grid, side="right")  # episodes finished by g (>= 1 on the group's grid)
    start = np.maximum(k - window, 0)
    return (csum[k] - csum[start]) / (k - start)


def learning_curves(run_dirs: Sequence[str | Path], *, x: str = "timesteps", window: int = 100, points: int = 50,
                    labels: Sequence[str] | None = None, confidence: float = 0.95, n_boot: int = 2000,
                    seed: int = 0) -> dict[str, dict[str, Any]]:
    """The curves' numbers, one entry per group keyed by its label (see the module docstring).

    ``x``: ``"timesteps"`` (env steps, all copies counted) or ``"episodes"`` (episodes finished).
    ``labels``: one name per group, in the order the groups first appear in ``run_dirs``.
    Each group: ``{"runs": [paths], "seeds": [...], "n_seeds": n, "x": grid (P,),
    "return"|"success"|"cost": {"mean", "lo", "hi": (P,), "per_seed": (n, P)}}``.
    """
    if x not in ("timesteps", "episodes"):
        raise ValueError(f"x must be 'timesteps' or 'episodes', got {x!r}")
    for name, value in (("window", window), ("points", points), ("n_boot", n_boot)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be between 0 and 1, got {confidence!r}")
    if not run_dirs:
        raise ValueError("no run directory given")
    runs = list({Path(p).resolve(): load_run(p) for p in run_dirs}.values())  # each directory once
    groups = group_runs(runs)
    names = group_labels(groups) if labels is None else [str(s) for s in labels]
    if len(names) != len(groups):
        raise ValueError(f"{len(names)} label(s) for {len(groups)} group(s) of runs: {names}")
    if len(set(names)) != len(names):
        raise ValueError(f"two groups share a label ({names}): name them with labels")
    out: dict[str, dict[str, Any]] = {}
    tail = (1 - confidence) / 2 * 100
    for name, group in zip(names, groups, strict=True):
        xs = [r["timesteps"] if x == "timesteps" else np.arange(1.0, len(r["timesteps"]) + 1) for r in group]
        first, last = max(v[0] for v in xs), min(v[-1] for v in xs)
        if first > last:
            raise ValueError(f"group {name!r}: its runs' episodes do not overlap in {x} "
                             f"(one ends at {last:g}, another starts at {first:g})")
        grid = np.unique(np.linspace(first, last, points).round())
        n = len(group)
        entry: dict[str, Any] = {"runs": [r["path"] for r in group], "seeds": [r["meta"].get("seed") for r in group],
                                 "n_seeds": n, "x": grid,
                                 "from_evaluations": any(r.get("source") == "eval.csv" for r in group)}
        # the same resampled seeds for every metric; a group's band does not depend on the other groups
        idx = np.random.default_rng(seed).integers(0, n, size=(n_boot, n))
        for metric in METRICS:
            # an evaluation is already a mean over held-out episodes: read off as it is
            per_seed = np.stack([_running_mean(v, r[metric], grid, 1 if r.get("source") == "eval.csv" else window)
                                 for v, r in zip(xs, group, strict=True)])
            mean = per_seed.mean(axis=0)
            if n >= MIN_SEEDS_FOR_BAND:
                lo, hi = np.percentile(per_seed[idx].mean(axis=1), [tail, 100 - tail], axis=0)
            else:
                lo = hi = np.full_like(mean, np.nan)
            entry[metric] = {"mean": mean, "lo": lo, "hi": hi, "per_seed": per_seed}
        if n < MIN_SEEDS_FOR_BAND:
            warnings.warn(f"group {name!r} has {n} seed(s): plotted without a confidence band, which needs "
                          f">= {MIN_SEEDS_FOR_BAND} seeds", UserWarning, stacklevel=2)
        out[name] = entry
    return out


def write_csv(curves: dict[str, dict[str, Any]], path: str | Path, x: str = "timesteps") -> Path:
    """The long-format table: ``group, metric, <x>, mean, lo, hi, n_seeds`` (no band: empty lo, hi)."""
    from pan1_env.experiment import atomic_write

    def fmt(v: float) -> str:
        return "" if np.isnan(v) else repr(float(v))

    def write(fh) -> None:
        w = csv.writer(fh)
        w.writerow(["group", "metric", x, "mean", "lo", "hi", "n_seeds"])
        for name, g in curves.items():
            for metric in METRICS:
                c = g[metric]
                for i, at in enumerate(g["x"]):
                    w.writerow([name, metric, int(at), fmt(c["mean"][i]), fmt(c["lo"][i]), fmt(c["hi"][i]),
                                g["n_seeds"]])

    atomic_write(Path(path), write, mode="w")
    return Path(path)


def plot_curves(run_dirs: Sequence[str | Path], out: str | Path = "runs/curves.png", *, x: str = "timesteps",
                window: int = 100, **kwargs: Any) -> tuple[Path, Path]:
    """Draw return, success rate and cost (three panels, shared x axis) for the groups of
    ``run_dirs`` and write ``out`` (a .png) and the numbers beside it (same name, .csv).
    Other keyword arguments go to :func:`learning_curves`. Returns ``(png_path, csv_path)``."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"out must end in .png, got {out}")
    curves = learning_curves(run_dirs, x=x, window=window, **kwargs)
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from pan1_env.figures import save_figure

    fig, axes = plt.subplots(len(METRICS), 1, sharex=True, figsize=(8, 9))
    for k, (name, g) in enumerate(curves.items()):
        color = f"C{k % 10}"
        for ax, metric in zip(axes, METRICS, strict=True):
            c = g[metric]
            ax.plot(g["x"], c["mean"], color=color, label=f"{name} ({g['n_seeds']} seed{'s' * (g['n_seeds'] > 1)})")
            if not np.isnan(c["lo"]).all():
                ax.fill_between(g["x"], c["lo"], c["hi"], color=color, alpha=0.25, linewidth=0)
    for ax, metric in zip(axes, METRICS, strict=True):
        ax.set_title(_TITLES[metric], fontsize=10)
        ax.grid(alpha=0.3)
    axes[1].set_ylim(-0.05, 1.05)
    axes[0].legend(fontsize=8)
    axes[-1].set_xlabel("environment steps" if x == "timesteps" else "episodes")
    evaluated = [name for name, g in curves.items() if g["from_evaluations"]]
    fig.suptitle(f"mean over seeds of the running mean of the last {window} episodes; band: "
                 f"{kwargs.get('confidence', 0.95):.0%} bootstrap confidence interval of that mean"
                 + (f"\n{', '.join(evaluated)}: runs without a finished episode are drawn from their evaluations "
                    "(eval.csv)" if evaluated else ""), fontsize=9)
    fig.tight_layout()
    csv_path = write_csv(curves, out.with_suffix(".csv"), x=x)
    return save_figure(fig, out), csv_path
