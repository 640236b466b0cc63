"""The policy benchmark: every policy meets the same seeded starts, with the shield on and off.

Policies are named in the registry of :mod:`pan1_env.baselines.policies` (:func:`make_policy`,
re-exported here): ``reference`` (the paper's nominal law on local observations; behind the shield
it is the paper's full controller), ``zero``, ``random`` (uniform actions), ``adversarial`` (every
arm heads for its nearest obstacle), ``sb3:PATH`` (a Stable-Baselines3 model trained on the
Gymnasium view of the same scenario, run deterministically) and any name added with
:func:`~pan1_env.baselines.policies.register_policy`; each is built on the (shielded or plain) env.

A scenario is a built-in name, a ``.toml`` path, ``random`` or one of the Gymnasium ids
(``pan1_env/WholeArmStaticFormation-v0`` runs random teams with that id's options).
For each scenario × policy × shield setting, episodes ``seed, seed+1, …`` are run to their end
(``max_steps``). Per row: ``success_rate`` (formation error < 1 cm at the end), ``mean_time_to_formation_s``
(over successful episodes, the time after which the error stays below 1 cm, as ``reproduce``'s
``time_to_edge_error_1cm_s``), ``mean_return`` (sum over steps of
the mean agent reward), ``total_cost`` (arm-steps inside an obstacle), ``min_clearance_m`` (over every
sub-step), ``intervention_rate`` (fraction of arm-steps where the shield changed the action; in torque mode
this includes speed limiting) and ``fallback_steps``; on a task whose arms lose actuators, ``fault_episodes``
(episodes in which some arm lost one), ``fault_success_rate`` (the success rate over those) and
``mean_time_from_fault_s`` (over those that end formed: from the step that showed the episode's last fault to
the formation, 0 if the shape held through it); on a moving formation ``mean_tracking_error_m`` (the formation
error averaged over each episode's steps, then over episodes; success there is the error below 1 cm for the
env's ``success_hold`` seconds at the end). A model
trained with ``--param-sharing`` acts for each arm on the arm's own observation. :func:`run_benchmark`
returns the rows; :func:`markdown_table` and :func:`plot_benchmark` present them.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .policies import BUILTIN_POLICIES, check_policy_name, make_policy

__all__ = ["run_benchmark", "run_episode", "markdown_table", "marl_eval_rows", "plot_benchmark", "benchmark_figure",
           "make_policy", "BUILTIN_POLICIES"]


def run_episode(env, policy, seed: int, shield: bool) -> dict[str, Any]:
    """One episode of a policy on a parallel env (shielded or not) from ``reset(seed=seed)``, to its end: success,
    time to formation (None if not formed), return, cost, smallest clearance, arm-steps, steps, and behind the
    shield the arm-steps it changed, the steps in which it changed some arm, and its fallbacks; the time (s) at which
    the last actuator fault showed, and the mean formation error."""
    core = env.unwrapped
    obs, _ = env.reset(seed=seed)
    ret, cost, steps, arm_steps, interventions, fallbacks, intervened_steps = 0.0, 0.0, 0, 0, 0, 0, 0
    clearance = math.inf
    last_failure = 0.0  # the last time the formation error was ≥ the tolerance (1 cm)
    lost, last_fault = 0, None  # arms that have lost an actuator, and when the last one showed
    tracking = 0.0  # the formation error summed over the steps
    infos: dict = {}
    while env.agents:
        obs, rewards, _, _, infos = env.step(policy(obs))
        steps += 1
        ret += float(np.mean(list(rewards.values())))
        for info in infos.values():
            cost += info["cost"]
            clearance = min(clearance, info["min_clearance"])
            arm_steps += 1
            if shield:
                interventions += int(info["shield_intervened"])
                fallbacks += int(info["shield_fallback"])
        if shield:  # the steps in which the filter changed some arm's command, as the batched evaluation counts
            intervened_steps += any(info["shield_intervened"] for info in infos.values())
        team = next(iter(infos.values()))
        tracking += team["formation_error"]
        if team["formation_error"] >= core.config.success_tolerance:  # not is_success, which lags by success_hold
            last_failure = steps * core.dt
        now_lost = sum(bool(info.get("actuator_lost", False)) for info in infos.values())
        if now_lost > lost:
            lost, last_fault = now_lost, steps * core.dt
    final = next(iter(infos.values())) if infos else {"is_success": False}
    success = bool(final["is_success"])
    return {"success": success, "time_to_formation": last_failure if success else None, "return": ret,
            "cost": cost, "min_clearance": clearance, "arm_steps": arm_steps, "interventions": interventions,
            "steps": steps, "intervened_steps": intervened_steps,
            "fallbacks": fallbacks, "last_fault": last_fault, "tracking_error": tracking / max(steps, 1)}


def run_benchmark(scenarios: Sequence[str], policies: Sequence[str], episodes: int = 5, seed: int = 0,
                  shield_settings: Sequence[bool] = (True, False), max_steps: int | None = None,
                  env_kwargs: dict[str, Any] | None = None,
                  progress: Callable[[str], None] | None = None, bar: bool | None = False) -> list[dict[str, Any]]:
    """Run every scenario × policy × shield combination on episodes seeded ``seed … seed+episodes−1``.

    ``progress`` receives a line before and after each row; ``bar`` shows a tqdm bar of a row's episodes
    on stderr (``None``: only when stderr is a terminal)."""
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments
    from pan1_env.wrappers import SafetyShield

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be a positive integer, got {episodes!r}")
    for name in policies:
        check_policy_name(name)
    rows = []
    kwargs = dict(env_kwargs or {})
    if max_steps is not None:
        kwargs["max_steps"] = max_steps
    # every env and policy is built before the first episode, so that a bad name or a missing model
    # fails at once rather than after the rows before it have run for minutes
    runs = []
    for scenario in scenarios:
        name_or_path, scenario_kwargs = env_arguments(scenario, kwargs)
        for name in policies:
            for shield in shield_settings:
                base = parallel_env(name_or_path, **scenario_kwargs)
                env = SafetyShield(base) if shield else base
                runs.append((scenario, name, shield, env, make_policy(name, env, seed)))
    for scenario, name, shield, env, policy in runs:
        if progress is not None:  # a row can take minutes: say what runs
            progress(f"{scenario} / {name} / shield {'on' if shield else 'off'}: {episodes} episodes …")
        label = f"{scenario} / {name} / shield {'on' if shield else 'off'}"
        with tqdm(total=episodes, desc=label, unit="episode", file=sys.stderr, leave=False,
                  disable=None if bar is None else not bar) as ticks:
            results = []
            for k in range(episodes):
                results.append(run_episode(env, policy, seed + k, shield))
                ticks.update()
        times = [r["time_to_formation"] for r in results if r["success"]]
        arm_steps = sum(r["arm_steps"] for r in results)
        row = {
            "scenario": scenario, "policy": name, "shield": shield, "episodes": episodes,
            "success_rate": float(np.mean([r["success"] for r in results])),
            "mean_time_to_formation_s": float(np.mean(times)) if times else None,
            "mean_return": float(np.mean([r["return"] for r in results])),
            "total_cost": float(sum(r["cost"] for r in results)),
            "min_clearance_m": _finite_or_none(min(r["min_clearance"] for r in results)),
            "intervention_rate": (sum(r["interventions"] for r in results) / arm_steps) if shield else None,
            "fallback_steps": sum(r["fallbacks"] for r in results) if shield else None,
        }
        faulted = [r for r in results if r["last_fault"] is not None]
        if faulted:
            recovered = [max(0.0, r["time_to_formation"] - r["last_fault"]) for r in faulted if r["success"]]
            row["fault_episodes"] = len(faulted)
            row["fault_success_rate"] = len(recovered) / len(faulted)
            row["mean_time_from_fault_s"] = float(np.mean(recovered)) if recovered else None
        if env.unwrapped.observation_layout.motion:
            row["mean_tracking_error_m"] = float(np.mean([r["tracking_error"] for r in results]))
        row["per_episode"] = {key: [_finite_or_none(float(r[key])) for r in results]
                              for key in ("success", "return", "cost", "min_clearance")}
        rows.append(row)
        if progress is not None:
            progress(f"{scenario} / {name} / shield {'on' if shield else 'off'}: "
                     f"success {row['success_rate']:.0%}, cost {row['total_cost']:g}")
    return rows


def marl_eval_rows(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The rows' episodes in marl-eval's raw-data layout (:func:`~pan1_env.baselines.report.marl_eval_data`): a
    task per scenario (``<scenario> (no shield)`` unshielded), an algorithm per policy, one ``seed_0`` (a
    benchmark row is one policy, not a set of training seeds) whose ``absolute_metrics`` hold one value per
    episode: success (0/1), return, cost (arm-steps inside an obstacle) and min clearance (m; left out where an
    episode has none: no obstacle)."""
    from .report import marl_eval_data

    return marl_eval_data((r["scenario"] + ("" if r["shield"] else " (no shield)"), r["policy"], 0,
                           {"absolute_metrics": _numeric(r["per_episode"])}) for r in rows)


def _numeric(per_episode: dict[str, list]) -> dict[str, list]:
    """The metrics every episode has a number for: a team with no obstacle has no clearance (None), and
    marl-eval's aggregation takes numbers only."""
    return {key: values for key, values in per_episode.items() if None not in values}


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The benchmark rows as a Markdown table (with a column for the time from a fault to the formation
    when some row had actuator faults, and one for the mean tracking error when some row's formation moved)."""
    faults = any("fault_episodes" in r for r in rows)
    moving = any("mean_tracking_error_m" in r for r in rows)
    head = ("| scenario | policy | shield | success | time to formation [s] | mean return | cost "
            "| min clearance [mm] | interventions |"
            + (" episodes with a fault (success): time from fault to formation [s] |" if faults else "")
            + (" mean tracking error [mm] |" if moving else ""))
    lines = [head, "|" + "---|" * (9 + faults + moving)]
    for r in rows:
        t = r["mean_time_to_formation_s"]
        iv = r["intervention_rate"]
        clear = r["min_clearance_m"]
        lines.append(
            f"| {r['scenario']} | {r['policy']} | {'on' if r['shield'] else 'off'} | {r['success_rate']:.0%} "
            f"| {'—' if t is None else f'{t:.1f}'} | {r['mean_return']:.1f} | {r['total_cost']:g} "
            f"| {'—' if clear is None else f'{1000 * clear:+.1f}'} | {'—' if iv is None else f'{iv:.1%}'} |"
            + (f" {_fault_cell(r)} |" if faults else "")
            + (f" {_tracking_cell(r)} |" if moving else ""))
    return "\n".join(lines)


def _tracking_cell(row: dict[str, Any]) -> str:
    return "—" if "mean_tracking_error_m" not in row else f"{1000 * row['mean_tracking_error_m']:.1f}"


def _fault_cell(row: dict[str, Any]) -> str:
    if "fault_episodes" not in row:
        return "—"
    t = row["mean_time_from_fault_s"]
    return f"{row['fault_episodes']} ({row['fault_success_rate']:.0%}): {'—' if t is None else f'{t:.1f}'}"


def benchmark_figure(rows: Sequence[dict[str, Any]]):
    """The table as bar charts, one bar per row: success rate, time to formation (over successful
    episodes; "never" where none succeeded) and total cost, with every axis from 0."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    labels = [f"{r['scenario']}\n{r['policy']} ({'shield' if r['shield'] else 'no shield'})" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(1, 3, figsize=(max(10, 1.5 * len(rows)), 5))
    colors = ["tab:green" if r["shield"] else "tab:gray" for r in rows]
    ax[0].bar(x, [r["success_rate"] for r in rows], color=colors)
    ax[0].set(title="success rate (formation error < 1 cm at the end)", ylim=(0, 1.05))
    times = [r["mean_time_to_formation_s"] for r in rows]
    ax[1].bar(x, [0.0 if t is None else t for t in times], color=colors)
    top = max([t for t in times if t is not None], default=0.0)
    ax[1].set(title="time to formation [s] (mean over successes)", ylim=(0, 1.1 * top if top > 0 else 1.0))
    for i, t in enumerate(times):
        if t is None:  # no bar would read as "instant": say it
            ax[1].text(i, 0, "never", ha="center", va="bottom", rotation=90, fontsize=8)
    costs = [r["total_cost"] for r in rows]
    ax[2].bar(x, costs, color=colors)
    # counts are never negative: without an explicit top, all-zero bars get a −0.04…0.04 axis
    ax[2].set(title="total cost (arm-steps inside an obstacle)", ylim=(0, 1.1 * max(costs) if max(costs) > 0 else 1.0))
    for a in ax:
        a.set_xticks(x, labels, rotation=90, fontsize=7)
    fig.tight_layout()
    return fig


def plot_benchmark(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """:func:`benchmark_figure` written to ``path``."""
    from pan1_env.figures import save_figure

    return save_figure(benchmark_figure(rows), path)
