"""Trained policies against the paper's law over training seeds, as RL papers report them (needs the ``rl`` extra).

:func:`report` evaluates the final model of every run (``pan1-env train`` output) on held-out teams, groups the
runs that differ only in their seed, and gives per group, for each metric, the **interquartile mean over
training seeds** (the mean of the middle half, scipy's ``trim_mean(·, 0.25)``, rliable's IQM; below 4 seeds
it is the mean) and a **95 % percentile bootstrap interval** over the seeds (scipy's ``bootstrap``, as in
Agarwal et al. 2021, *Deep RL at the Edge of the Statistical Precipice*, and marl-eval). A row is one task,
so its bootstrap has one stratum; :func:`iqm_interval` takes one array of runs per task and resamples each
on its own (the stratified bootstrap) for scores pooled over tasks. One run gives one score per metric, each
over the held-out episodes:

* ``success``: the fraction of episodes the task's rule calls formed (the formation error below 1 cm at the end,
  held for the task's hold time on a moving formation);
* ``time_to_formation``: the mean time after which the error stayed below 1 cm, over the episodes it formed;
* ``time_ratio``: the same mean over the episodes that both the run and the reference formed, divided by the
  reference's over the same episodes (the issue's "on the teams both form");
* ``return`` (the mean episode return) and ``cost`` (arm-steps inside an obstacle, summed over episodes).

A run whose time is undefined (it formed no episode, or none that the reference formed too) is left out of
that metric's IQM, and the row says how many seeds it has. The reference is the zero action of the runs' own
env: the paper's law behind the same shield (runs trained with residual or gain actions; for others there is
no reference and no ratio). Every run is evaluated in the env it was trained in (its ``model.json``). Random
teams are evaluated on reset seeds ``first … first + teams − 1`` (default: docs/TRAINING.md's held-out teams
2,000,000–2,000,199, which no training or model choice saw), a paper scenario on its single start.

:func:`marl_eval_json` writes the episodes in marl-eval's raw-data layout (``env → task → algorithm →
run → absolute_metrics``, plus one ``step_k`` per row of the run's ``eval.csv``), for its plots and tests.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from .curves import group_labels, group_runs, run_arguments
from .evaluation import LAW_MODES, evaluate, law_policy, model_policy

__all__ = ["report", "iqm", "iqm_interval", "time_ratio", "markdown", "marl_eval_json", "marl_eval_data", "METRICS",
           "HELD_OUT_FIRST"]

METRICS = ("success", "time_to_formation", "time_ratio", "return", "cost")
HELD_OUT_FIRST, HELD_OUT_TEAMS = 2_000_000, 200


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """The interquartile mean: the mean of the scores left after cutting a quarter at each end."""
    return stats.trim_mean(scores, 0.25, axis=axis)


def iqm_interval(tasks: Sequence[np.ndarray], confidence: float = 0.95, reps: int = 2000,
                 seed: int = 0) -> tuple[float, float, float]:
    """The IQM of all scores and its stratified percentile bootstrap interval: each task's runs (one array per
    task) are resampled with replacement on their own, and the IQM taken over the pooled resample. A task of one
    run (or identical scores) gives a point interval; no scores or a NaN give NaN."""
    tasks = [np.asarray(t, dtype=float) for t in tasks]
    pooled = np.concatenate(tasks)
    if len(pooled) == 0 or not np.isfinite(pooled).all():
        return float("nan"), float("nan"), float("nan")
    point = float(iqm(pooled))
    if min(len(t) for t in tasks) < 2 or np.ptp(pooled) == 0:  # nothing to resample in some task
        return point, point, point

    def statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        return iqm(np.concatenate(samples, axis=axis), axis=axis)

    result = stats.bootstrap(tasks, statistic, n_resamples=reps, confidence_level=confidence, method="percentile",
                             vectorized=True, rng=np.random.default_rng(seed))
    return point, float(result.confidence_interval.low), float(result.confidence_interval.high)


def _held_out(meta: dict[str, Any], first: int, teams: int) -> list[int]:
    return list(range(first, first + teams)) if meta["scenario"] == "random" else [first]


def time_ratio(times: np.ndarray, reference_times: np.ndarray) -> float:
    """A run's mean time to formation over the episodes both it and the reference formed (a time per episode, NaN
    where not formed), over the reference's mean on those episodes; NaN if they formed none in common."""
    times, reference_times = np.asarray(times, float), np.asarray(reference_times, float)
    both = np.isfinite(times) & np.isfinite(reference_times)
    return float(np.mean(times[both]) / np.mean(reference_times[both])) if both.any() else float("nan")


def _scores(result: dict[str, np.ndarray], reference: dict[str, np.ndarray] | None) -> dict[str, float]:
    formed = result["success"]  # the task's own rule: on a moving formation, the error held below 1 cm
    times = np.where(formed, result["time_to_formation"], np.nan)
    out = {"success": float(formed.mean()),
           "time_to_formation": float(np.mean(times[formed])) if formed.any() else float("nan"),
           "return": float(np.mean(result["return"])), "cost": float(np.sum(result["cost"])),
           "time_ratio": float("nan")}
    if reference is not None:
        out["time_ratio"] = time_ratio(times, np.where(reference["success"], reference["time_to_formation"], np.nan))
    return out


def report(run_dirs: Sequence[str | Path], *, first: int = HELD_OUT_FIRST, teams: int = HELD_OUT_TEAMS,
           reps: int = 2000, team_size: int | None = None,
           progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """One row per group of runs (and one per task for its reference): ``label``, ``task``, ``runs`` (paths),
    ``scores`` (metric → one score per run), ``episodes`` (run path → :func:`~pan1_env.baselines.evaluation.evaluate`'s
    arrays), and ``<metric>`` → (IQM, low, high) over the runs where it is defined. ``progress`` is told what is
    being evaluated. ``team_size`` evaluates every run, and the law, on teams of that many arms of the run's task
    (random teams; the obstacles at the task's density per arm: a model trained on a ring task such as
    ``pan1_env/RandomFormation-v2``). ValueError for a run directory that is not a finished ``pan1-env train``
    run."""
    if first < 0:
        raise ValueError(f"first must be a reset seed ≥ 0, got {first}")
    runs = [_finished_run(Path(path), team_size) for path in run_dirs]
    groups = group_runs(runs, same_budget=True)
    rows, references = [], {}
    for label, group in zip(group_labels(groups, same_budget=True), groups, strict=True):
        meta = group[0]["meta"]
        scenario, shield, seeds = meta["scenario"], meta.get("shield", True), _held_out(meta, first, teams)
        kwargs = group[0]["env_kwargs"]  # the env the models were trained in (model.json), defaults resolved
        task = json.dumps([scenario, kwargs, shield], sort_keys=True)
        if task not in references and kwargs.get("action_mode") in LAW_MODES:
            if progress:
                progress(f"the paper's law on {len(seeds)} held-out episodes of {scenario} …")
            references[task] = evaluate(law_policy(scenario, kwargs), scenario, seeds, shield=shield, env_kwargs=kwargs)
        reference = references.get(task)
        episodes = {}
        for run in group:
            if run["env_kwargs"] != kwargs:
                raise ValueError(f"{run['path']} and {group[0]['path']} have the same run.json but were trained in "
                                 f"different envs (model.json): {run['env_kwargs']} against {kwargs}")
            if progress:
                progress(f"{run['path']} on {len(seeds)} held-out episodes …")
            episodes[str(run["path"])] = evaluate(run["policy"], scenario, seeds, shield=shield, env_kwargs=kwargs)
        rows.append(_row(label, task, meta, episodes, reference, reps))
    for k, (task, reference) in enumerate(references.items()):
        scenario, kwargs, shield = json.loads(task)
        meta = {"scenario": scenario, "env_kwargs": kwargs, "shield": shield, "algo": "reference"}
        label = "reference (the paper's law)" + (f", task {k + 1}" if len(references) > 1 else "")
        rows.append(_row(label, task, meta, {"reference": reference}, reference, reps))
    return rows


def _finished_run(path: Path, team_size: int | None = None) -> dict[str, Any]:
    missing = [name for name in ("run.json", "model.zip", "model.json") if not (path / name).is_file()]
    if missing:
        raise ValueError(f"{path}: not a finished training run, no {' or '.join(missing)} (pan1-env train writes "
                         "run.json at its start, model.zip and model.json at its end)")
    meta = run_arguments(path)
    kwargs = json.loads((path / "model.json").read_text()).get("env_kwargs", {})
    if team_size is not None:
        kwargs = _at_size(meta["scenario"], kwargs, team_size)
    policy, env_kwargs = model_policy(path / "model.zip", kwargs)
    return {"path": path, "meta": meta, "policy": policy, "env_kwargs": env_kwargs}


def _at_size(scenario: str, kwargs: dict[str, Any], size: int) -> dict[str, Any]:
    """A run's env arguments for teams of ``size`` arms with the obstacles at its task's density."""
    from .mixed_vec_env import sized_options

    if scenario != "random":
        raise ValueError(f"a team size is a random-team option; this run's scenario is {scenario!r}")
    options = dict(kwargs.get("random_options", {}))
    return kwargs | {"random_options": options | sized_options(scenario, options, size)}


def _row(label: str, task: str, meta: dict, episodes: dict, reference: dict | None, reps: int) -> dict[str, Any]:
    per_run = [_scores(result, reference) for result in episodes.values()]
    scores = {m: np.array([run[m] for run in per_run]) for m in METRICS}
    row = {"label": label, "task": task, "meta": meta, "runs": list(episodes), "scores": scores, "episodes": episodes}
    for metric in METRICS:
        defined = scores[metric][np.isfinite(scores[metric])]
        row[metric] = iqm_interval([defined], reps=reps)
        row[f"{metric}_runs"] = len(defined)
    return row


def markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as a Markdown table: IQM [95 % CI] of each metric, per group."""
    def cell(row: dict, metric: str, scale: float = 1.0, fmt: str = "{:.1f}") -> str:
        point, low, high = (scale * v for v in row[metric])
        if not np.isfinite(point):
            return "–"
        text = fmt.format(point) if low == high else f"{fmt.format(point)} [{fmt.format(low)}, {fmt.format(high)}]"
        defined, runs = row[f"{metric}_runs"], len(row["runs"])
        return text if defined == runs else f"{text} ({defined} of {runs} seeds)"

    lines = ["| task | policy | runs | success [%] | time to formation [s] | time ÷ reference's, teams both form "
             "| return | cost |", "|---|---|---:|---|---|---|---|---|"]
    for row in rows:
        scenario = row["meta"]["scenario"]
        lines.append(f"| {scenario} | {row['label']} | {len(row['runs'])} | {cell(row, 'success', 100)} "
                     f"| {cell(row, 'time_to_formation')} | {cell(row, 'time_ratio', fmt='{:.2f}')} "
                     f"| {cell(row, 'return')} | {cell(row, 'cost', fmt='{:g}')} |")
    return "\n".join(lines)


def marl_eval_json(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Write the episodes in marl-eval's raw-data layout: ``{"pan1_env": {task: {label: {"seed_<s>": {...}}}}}``,
    each run with ``absolute_metrics`` (one value per held-out episode) and a ``step_<k>`` per evaluation of its
    ``eval.csv`` (marl-eval's per-episode lists hold the evaluation's mean there). Unshielded groups are a task of
    their own (``<scenario> (no shield)``)."""
    entries = []
    for row in rows:
        shielded = row["meta"].get("shield", True)
        task = row["meta"]["scenario"] + ("" if shielded else " (no shield)")
        for i, (run, result) in enumerate(row["episodes"].items()):
            formed = result["success"]
            record: dict[str, Any] = {}
            evaluations = Path(run) / "eval.csv"
            if run != "reference" and evaluations.is_file():
                with evaluations.open(newline="") as fh:
                    for k, r in enumerate(csv.DictReader(fh)):
                        record[f"step_{k}"] = {"step_count": int(r["timesteps"]),
                                               "success": [float(r["success_1cm"])],
                                               "return": [float(r["mean_return"])], "cost": [float(r["cost"])]}
            record["absolute_metrics"] = {
                "success": formed.astype(float).tolist(), "return": result["return"].tolist(),
                "cost": result["cost"].tolist()}  # no time: undefined where an episode did not form
            seed = json.loads((Path(run) / "run.json").read_text()).get("seed", i) if run != "reference" else 0
            entries.append((task, row["label"], seed, record))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(marl_eval_data(entries), indent=1) + "\n")
    return path


def marl_eval_data(entries: Iterable[tuple[str, str, int, dict[str, Any]]]) -> dict[str, Any]:
    """marl-eval's raw-data layout, ``{"pan1_env": {task: {algorithm: {"seed_<s>": record}}}}``, of ``(task,
    algorithm, seed, record)`` entries; a record holds ``absolute_metrics`` (metric → one value per episode)
    and, for a trained run, ``step_<k>`` evaluations."""
    data: dict[str, Any] = {"pan1_env": {}}
    for task, algorithm, seed, record in entries:
        data["pan1_env"].setdefault(task, {}).setdefault(algorithm, {})[f"seed_{seed}"] = record
    return data

