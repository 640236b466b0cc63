"""The leaderboard's figures, drawn by rliable (Agarwal et al. 2021) from the suite's success scores (needs the
``suite`` extra): the IQM over runs and tasks with 95 % stratified bootstrap intervals, the performance profiles,
and the probability that an entry forms more of a task's teams than the law.

A score is one run's success rate on one task (already in [0, 1], so nothing is normalised). rliable compares
entries over one set of tasks, so the IQM and the profiles take the entries that have every task of the suite's
data; the probability of improvement takes each entry against the law over the tasks both have (its label says how
many). An entry of one
run per task (the law, the circulation rule, a shipped model) has no spread over runs: its intervals are points.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from .leaderboard_table import success_scores

__all__ = ["leaderboard_figures", "score_matrices"]

FIGURES = ("leaderboard_iqm.png", "leaderboard_profiles.png", "leaderboard_improvement.png")


def score_matrices(data: dict[str, Any]) -> tuple[list[str], dict[str, np.ndarray]]:
    """The tasks, and for each entry with the same number of runs on every task a (runs × tasks) matrix of success
    rates (an entry missing a task, or with fewer runs on one, is left out rather than cut down)."""
    tasks = [t["env_id"] for t in data["tasks"]]
    matrices = {}
    for e in data["entries"]:
        per_task = [success_scores(data, task, e["name"]) for task in tasks]
        if all(len(s) for s in per_task) and len({len(s) for s in per_task}) == 1:
            matrices[e["name"]] = np.stack(per_task, axis=1)
    return tasks, matrices


def leaderboard_figures(data: dict[str, Any], out: str | Path, reps: int = 2000) -> list[Path]:
    """Write the figures under ``out`` and return their paths (those that have something to show)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=FutureWarning, module="arch")  # rliable hands arch a RandomState
        return _draw(data, Path(out), reps)


def _draw(data: dict[str, Any], out: Path, reps: int) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from rliable import library as rly
    from rliable import metrics, plot_utils

    from pan1_env.figures import save_figure

    state = np.random.RandomState(0)
    paths = []
    _, matrices = score_matrices(data)
    if matrices:
        def iqm(scores: np.ndarray) -> np.ndarray:
            return np.array([metrics.aggregate_iqm(scores)])

        points, intervals = rly.get_interval_estimates(matrices, iqm, reps=reps, random_state=state)
        names = list(matrices)
        fig, ax = plt.subplots(figsize=(6, 1.2 + 0.5 * len(names)))
        low, high = (np.array([intervals[n][k, 0] for n in names]) for k in (0, 1))
        middle = np.array([points[n][0] for n in names])
        ax.barh(names, high - low, left=low, height=0.5, alpha=0.6)
        ax.plot(middle, names, "k|", markersize=14)
        ax.set(xlim=(0, 1), xlabel="IQM of success over runs and tasks (95 % stratified bootstrap)")
        fig.tight_layout()
        paths.append(save_figure(fig, out / FIGURES[0]))
        thresholds = np.linspace(0.0, 1.0, 41)
        saved = np.random.get_state()  # noqa: NPY002 - rliable's profile bootstrap draws from the global generator
        np.random.seed(0)  # noqa: NPY002 - so that the bands are the same at every render
        try:
            profiles, bands = rly.create_performance_profile(matrices, thresholds, reps=reps)
        finally:
            np.random.set_state(saved)  # noqa: NPY002
        fig, ax = plt.subplots(figsize=(6, 4))
        plot_utils.plot_performance_profiles(profiles, thresholds, performance_profile_cis=bands, ax=ax,
                                             xlabel=r"success rate $\tau$",
                                             ylabel=r"fraction of runs with success > $\tau$")
        ax.legend(ax.get_lines()[:len(profiles)], list(profiles), loc="lower left")  # the lines, not the bands
        fig.tight_layout()
        paths.append(save_figure(fig, out / FIGURES[1]))
    pairs = _pairs_with_law(data)
    if pairs:
        points, intervals = rly.get_interval_estimates(pairs, metrics.probability_of_improvement, reps=reps,
                                                       random_state=state)
        ax = plot_utils.plot_probability_of_improvement(points, intervals, figsize=(7, 1.5 + 0.6 * len(pairs)),
                                                        xticks=[0.0, 0.25, 0.5, 0.75, 1.0], left_ylabel="entry X",
                                                        right_ylabel="")
        ax.figure.tight_layout()
        paths.append(save_figure(ax.figure, out / FIGURES[2]))
    return paths


def _pairs_with_law(data: dict[str, Any]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Entry against the law, over the tasks both have: {"entry,law": (entry's runs × tasks, law's runs × tasks)}."""
    tasks = [t["env_id"] for t in data["tasks"]]
    law = {task: success_scores(data, task, "law") for task in tasks}
    pairs = {}
    for e in data["entries"]:
        if e["name"] == "law":
            continue
        mine = {task: success_scores(data, task, e["name"]) for task in tasks}
        shared = [task for task in tasks if len(mine[task]) and len(law[task])]
        if shared:
            if len({len(mine[t]) for t in shared}) > 1 or len({len(law[t]) for t in shared}) > 1:
                continue  # as many runs on every task, or none of the entry's rows
            label = f"{e['name']} ({len(shared)} task{'s' if len(shared) > 1 else ''})"
            pairs[f"{label},law"] = (np.stack([mine[t] for t in shared], axis=1),
                                     np.stack([law[t] for t in shared], axis=1))
    return pairs
