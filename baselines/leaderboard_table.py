"""The leaderboard's numbers and pages: a row per task and entry of
:func:`~pan1_env.baselines.leaderboard.run_suite`'s data, as a Markdown table and as the whole of docs/BENCHMARK.md
(generated, so that the page and its JSON cannot drift apart)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from .report import iqm_interval, time_ratio

__all__ = ["leaderboard_rows", "markdown", "benchmark_page", "success_scores"]


def success_scores(data: dict[str, Any], task_id: str, entry: str) -> np.ndarray:
    """One success rate per run of an entry on a task (empty if it has none)."""
    runs = data["raw"]["pan1_env"].get(task_id, {}).get(entry, {})
    return np.array([np.mean(r["absolute_metrics"]["success"]) for r in runs.values()], float)


def _team_interval(formed: np.ndarray) -> tuple[float, float, float]:
    """The success rate of one run over its teams and its 95 % Wilson score interval (which, unlike a bootstrap of
    0s and 1s, does not shrink to a point when every team or none formed); a point for one team."""
    k, n = int(formed.sum()), len(formed)
    if n < 2:
        return float(k), float(k), float(k)
    ci = stats.binomtest(k, n).proportion_ci(method="wilson")
    return k / n, float(ci.low), float(ci.high)


def _time_ratio(mine: dict[str, list], law: dict[str, list]) -> float:
    """A run's mean time to formation over the teams both it and the law formed, over the law's on those teams."""
    def times(metrics: dict[str, list]) -> np.ndarray:
        return np.array([np.nan if t is None else t for t in metrics["time_to_formation"]], float)

    return time_ratio(times(mine), times(law))


def leaderboard_rows(data: dict[str, Any], reps: int = 2000) -> list[dict[str, Any]]:
    """Per task and entry with runs: ``runs``, ``sources``, ``success`` (IQM, low, high) and ``over`` (``runs``, or
    ``teams`` for an entry of one run), ``time`` (IQM over the runs of each one's mean time to formation over its
    formed teams; None if none formed), ``time_ratio`` (IQM over the runs of each one's mean time over the teams both
    it and the law formed, over the law's: the targets' measure; None without the law), ``cost`` (IQM over runs of
    the summed cost), ``min_clearance`` (m, over every run and team) and ``interventions`` (mean fraction of steps in
    which the shield changed some arm's command; None unshielded)."""
    rows = []
    for task in data["tasks"]:
        for e in data["entries"]:
            runs = data["raw"]["pan1_env"].get(task["env_id"], {}).get(e["name"])
            if not runs:
                continue
            metrics = [r["absolute_metrics"] for r in runs.values()]
            success = np.array([np.mean(m["success"]) for m in metrics])
            if len(metrics) > 1:
                over, interval = "runs", iqm_interval([success], reps=reps)
            else:
                over, interval = "teams", _team_interval(np.asarray(metrics[0]["success"], float))
            law = data["raw"]["pan1_env"].get(task["env_id"], {}).get("law")
            ratios = np.array([_time_ratio(m, next(iter(law.values()))["absolute_metrics"]) for m in metrics]
                              if law and e["name"] != "law" else [])
            ratios = ratios[np.isfinite(ratios)]
            times = [np.mean([t for t in m["time_to_formation"] if t is not None]) for m in metrics
                     if any(t is not None for t in m["time_to_formation"])]
            clearances = [c for m in metrics for c in m["min_clearance"] if c is not None]
            rates = [np.mean(m["intervention_rate"]) for m in metrics if "intervention_rate" in m]
            rows.append({
                "task": task["name"], "env_id": task["env_id"], "entry": e["name"], "runs": len(metrics),
                "sources": [r["source"] for r in data["runs"][task["env_id"]][e["name"]]],
                "success": interval, "over": over,
                "time": iqm_interval([np.array(times)], reps=reps) if times else None,
                "time_runs": len(times),
                "time_ratio": iqm_interval([ratios], reps=reps) if len(ratios) else None,
                "cost": iqm_interval([np.array([np.sum(m["cost"]) for m in metrics])], reps=reps),
                "cost_max": float(max(np.sum(m["cost"]) for m in metrics)),
                "min_clearance": min(clearances) if clearances else None,
                "interventions": float(np.mean(rates)) if rates else None})
    return rows


def _cell(interval: tuple[float, float, float] | None, scale: float = 1.0, fmt: str = "{:.1f}") -> str:
    if interval is None or not np.isfinite(interval[0]):
        return "–"
    point, low, high = (scale * v for v in interval)
    return fmt.format(point) if low == high else f"{fmt.format(point)} [{fmt.format(low)}, {fmt.format(high)}]"


def markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as one Markdown table: IQM [95 % interval]; the interval of an entry of one run is over its teams."""
    lines = ["| task | entry | runs | success [%] | interval over | time to formation [s] | time ÷ the law's, "
             "teams both form | cost | min clearance [mm] | steps the shield changed |",
             "|---|---|---:|---|---|---|---|---|---:|---:|"]
    for r in rows:
        some = r["time_runs"] not in (0, r["runs"])  # runs that formed no team have no time
        time = _cell(r["time"]) + (f" ({r['time_runs']} of {r['runs']} runs)" if some else "")
        clearance = "–" if r["min_clearance"] is None else f"{1000 * r['min_clearance']:+.1f}"
        rate = "–" if r["interventions"] is None else f"{r['interventions']:.1%}"
        lines.append(f"| {r['task']} | {r['entry']} | {r['runs']} | {_cell(r['success'], 100)} | {r['over']} "
                     f"| {time} | {_cell(r['time_ratio'], fmt='{:.2f}')} | {_cell(r['cost'], fmt='{:g}')} "
                     f"| {clearance} | {rate} |")
    return "\n".join(lines)


def meets(row: dict[str, Any], goal: dict[str, Any], law_success: float | None) -> bool:
    """Whether a leaderboard row (:func:`leaderboard_rows`) reaches a task's goal (the suite's ``Target`` as a dict):
    its IQM success and time ratio against the goal's bounds, its IQM success against the law's on the task (a team
    formed at least: where the law forms none, forming none is not reaching it), and every run's cost within the
    goal's."""
    if not goal:
        return False
    success = row["success"][0]
    if goal.get("success") is not None and success < goal["success"]:
        return False
    if goal.get("vs_law") is not None:
        if law_success is None or success <= 0.0 or success < law_success:
            return False
        if goal["vs_law"] == "above" and success == law_success:
            return False
    if goal.get("time_ratio") is not None and (row["time_ratio"] is None or row["time_ratio"][0] > goal["time_ratio"]):
        return False
    return _within_cost(row, goal)


def _within_cost(row: dict[str, Any], goal: dict[str, Any]) -> bool:
    """Every run's cost within the goal's (a row without its runs' largest cost: its IQM's)."""
    return goal.get("cost") is None or row.get("cost_max", row["cost"][0]) <= goal["cost"]


def targets_table(data: dict[str, Any], rows: Sequence[dict[str, Any]]) -> str:
    """Per task, its target, the learners (entries with a recipe) that reach it, and the learner that forms the most
    of its teams at no more than the target's cost (of those that form as many: one that reaches the target, then the
    lowest time ratio)."""
    learners = {e["name"] for e in data["entries"] if e.get("recipe")}
    lines = ["| task | target | reached by | the learner forming the most teams within the cost: success [%], time ÷ "
             "the law's |", "|---|---|---|---|"]
    for task in data["tasks"]:
        goal = task.get("goal") or {}
        mine = [r for r in rows if r["env_id"] == task["env_id"]]
        law = next((r["success"][0] for r in mine if r["entry"] == "law"), None)
        ours = [r for r in mine if r["entry"] in learners]
        reached = [r["entry"] for r in ours if meets(r, goal, law)]
        within = [r for r in ours if _within_cost(r, goal)]
        # the most teams; among equals the one that reaches the target, then the faster
        best = max(within, key=lambda r: (r["success"][0], r["entry"] in reached,
                                          -(r["time_ratio"] or [np.inf])[0]), default=None)
        nearest = "–" if best is None else (f"{best['entry']}: {_cell(best['success'], 100)}, "
                                            f"{_cell(best['time_ratio'], fmt='{:.2f}')}")
        lines.append(f"| {task['name']} | {task['target']} | {', '.join(reached) or 'none yet'} | {nearest} |")
    return "\n".join(lines)


def benchmark_page(data: dict[str, Any], figures: Sequence[str] = (), reps: int = 2000) -> str:
    """docs/BENCHMARK.md from the leaderboard's JSON: the tasks, the entries and their commands, the table, what is
    missing, and the figures (paths relative to the page)."""
    rows = leaderboard_rows(data, reps)
    out = ["# The benchmark", "",
           "Generated by `pan1-env suite` from `docs/leaderboard.json`; do not edit by hand. Every number below is "
           "reproduced by `pan1-env suite --out runs/leaderboard` (the held-out teams of every task, every entry "
           "found), and re-rendered without evaluating by `pan1-env suite --from docs/leaderboard.json --docs "
           "docs/BENCHMARK.md`." + (" **This is a quick run (a few teams per task): not the leaderboard's numbers.**"
                                    if data.get("quick") else ""),
           "", "## Tasks", "", "| task | id | held-out teams (reset seeds) | training seeds | arm-steps per run "
           "| the law's success, as recorded | target |", "|---|---|---|---|---:|---:|---|"]
    for t in data["tasks"]:
        first, n = t["held_out"]
        law = "–" if t["law_success_recorded"] is None else f"{t['law_success_recorded']:.1%}"
        out.append(f"| {t['name']} | `{t['env_id']}` | {t['teams']} ({first}–{first + t['teams'] - 1}) "
                   f"| {', '.join(map(str, t['train_seeds']))} | {t['train_steps']:,} | {law} | {t['target']} |")
    out += ["", "## Entries", ""]
    for e in data["entries"]:
        where = f" on `{e['trained_on']}`'s seeds, whichever task is named" if e.get("trained_on") else ""
        how = (f"the policy `{e['policy']}` of `pan1-env benchmark --policies`" if e["policy"] else
               f"trained with `pan1-env suite --train {e['name']} TASK`{where} (recipe: `{_recipe(e['recipe'])}`)")
        out.append(f"- **{e['name']}**: {e['description']}; {how}.")
    out += ["", "## Leaderboard", "",
            "Success is the task's own rule on the held-out teams (the formation error below 1 cm at the end; held "
            "for the task's hold time on a moving formation). A cell is the interquartile mean over the runs with its "
            "95 % bootstrap interval; for an entry of one run (the law, the rule, a shipped model) it is the Wilson "
            "interval over the teams. The time to formation is over the teams each run formed; the ratio to the "
            "law's is over the teams both formed, the targets' measure. The cost counts arm-steps inside an obstacle; "
            "the last column is the fraction of steps in which the shield changed some arm's command.", "",
            markdown(rows), ""]
    if all("goal" in t for t in data["tasks"]):
        out += ["## Targets", "",
                "Each task's target for a learner, checked on the table above (`pan1_env.baselines.suite.Target`): the "
                "IQM success against the target's floor and against the law's success on the same teams (forming no "
                "team does not reach the law's none), the IQM time ratio, and the cost of every run, 0 on every task "
                "(behind the shield). A target over several tasks, such as the rings' at every team size, is judged "
                "on each task's row. Where no learner reaches it yet, the last column says how near the best learner "
                "within the target's cost comes.", "", targets_table(data, rows), ""]
    shipped = sorted({(r["entry"], r["task"], s) for r in rows for s in r["sources"] if s.startswith("shipped:")})
    if shipped:
        out += ["Rows scored by a shipped model (one training seed) until the entry's runs are trained: "
                + "; ".join(f"{e} on {t} ({s.removeprefix('shipped:')})" for e, t, s in shipped) + ".", ""]
    if data.get("missing"):
        out += ["## Not yet on the board", "", "No run and no shipped model: "
                + "; ".join(f"{e} on `{t}`" for t, e in data["missing"]) + ".", ""]
    if figures:
        out += ["## Figures", "",
                "Made with rliable: the IQM of success with 95 % stratified bootstrap intervals and the "
                "performance profiles, over the entries with as many runs on every task; and the probability that an "
                "entry forms more of a task's teams than the law, over the tasks both have (the label says how many).",
                ""]
        out += [f"![{name}]({name})" for name in figures] + [""]
    return "\n".join(out)


def _recipe(recipe: dict[str, Any]) -> str:
    import json

    return json.dumps(recipe, sort_keys=True)
