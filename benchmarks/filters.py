"""The conservatism study: how the safety filter's design trades safety against what the paper's law can form.

    python benchmarks/filters.py [--teams 200] [--first 2000000] [--out runs/filters] [--tasks end_effector,whole_arm]
                                 [--settings paper,radius,...] [--policies reference,random,adversarial]
                                 [--no-classes] [--max-steps N]

For each task (``end_effector``: RandomFormation's teams, each end-effector kept out of the obstacles;
``whole_arm``: WholeArmStaticFormation's teams, every link a capsule kept out of the obstacles and off the
other arms; ``whole_arm_moving``: WholeArmFormation's, the same with the obstacles moving) and each filter
setting of :data:`SETTINGS`, it runs on the same held-out random teams (reset seeds
``first … first + teams − 1``; the defaults are docs/TRAINING.md's held-out teams, on which no filter
setting was tuned) two policies behind the filter, all teams of a setting batched in one vector env:

* ``reference``: the paper's law (the zero action in residual mode), which measures what the filter lets a
  good controller form;
* ``random``: uniform random velocity actions held for 1 s each (persistent, so that arms travel and
  meet the obstacles), which measures how close the filter lets a careless policy come;
* ``adversarial``: every arm driven at full action straight at its nearest obstacle
  (:class:`pan1_env.baselines.VectorAdversary`), which measures what the filter lets through when a policy
  tries to collide.

Per row: success at 1 / 2 / 5 cm, mean time to formation (formed teams), intervention and fallback rates
(the fraction of steps in which the filter changed, or fell back for, some arm's command), the smallest
clearance over every sub-step (m; ≥ 0 is safe) and the cost (arm-steps inside an obstacle). For the
reference, each team it fails is run again, alone, through ``benchmarks/failures.py``'s classifier (the
law in velocity mode, :class:`pan1_env.baselines.ReferencePolicy`, on the parallel env behind the same
filter), and the row counts the failure classes, the freeze (``shield_far``: an arm held by the filter far
from any obstacle) first; ``--no-classes`` skips this, the slow part. Writes ``filters.md`` (the tables),
``filters.json`` and ``filters.png``: the reference's success against the smallest clearance any policy
reached, one point per setting and task, the Pareto front (no other setting both forms more and keeps
farther) marked.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from pan1_env.baselines import ReferencePolicy, VectorAdversary
from pan1_env.baselines.evaluation import TOLERANCES, evaluate, law_policy
from pan1_env.registration import env_arguments
from pan1_env.safety import FilterParams

TASKS = {"end_effector": "pan1_env/RandomFormation-v0", "whole_arm": "pan1_env/WholeArmStaticFormation-v0",
         "whole_arm_moving": "pan1_env/WholeArmFormation-v0", "whole_arm_clear_paths": "pan1_env/WholeArmFormation-v2",
         "faults": "pan1_env/FaultFormation-v0"}
# κ and ε are the random teams' (0.5, 5); the paper's filter first, then RandomFormation-v1's, then the smooth
# gate (5 cm past the sensing range) on the hard-range settings, then v1 with the whole-arm last resort measured
# by the barrier's rate (FilterParams.fallback). Key: (label, FilterParams fields).
SETTINGS = {
    "paper": ("paper (squared, constant ε)", {}),
    "radius": ("paper + 0.1 m sensing radius", {"sensing_radius": 0.1}),
    "distance": ("distance barrier", {"barrier": "distance"}),
    "decay20": ("distance, ε decaying λ = 20", {"barrier": "distance", "decay": 20.0}),
    "v1": ("distance, ε decaying λ = 50 (v1)", {"barrier": "distance", "decay": 50.0}),
    "radius_gate": ("paper + 0.1 m sensing radius, 5 cm gate", {"sensing_radius": 0.1, "gate": 0.05}),
    "v1_gate": ("v1 + 5 cm gate past the whole-arm range", {"barrier": "distance", "decay": 50.0, "gate": 0.05}),
    "v1_rate": ("v1, last resort by barrier rate", {"barrier": "distance", "decay": 50.0, "fallback": "barrier_rate"}),
    "v1_ahead1": ("v1, obstacles' next 1 s of path kept out", {"barrier": "distance", "decay": 50.0, "lookahead": 1.0}),
    "v1_ahead3": ("v1, obstacles' next 3 s of path kept out", {"barrier": "distance", "decay": 50.0, "lookahead": 3.0}),
    "v1_path": ("v1, obstacles' whole paths kept out", {"barrier": "distance", "decay": 50.0,
                                                         "lookahead": float("inf")}),
    "v1_radius": ("v1 + 0.1 m sensing radius", {"barrier": "distance", "decay": 50.0, "sensing_radius": 0.1}),
    "v1_fault": ("v1 + the fault margin", {"barrier": "distance", "decay": 50.0, "fault_margin": True}),
}
POLICIES = ("reference", "random", "adversarial")
HOLD_STEPS = 20  # the random policy's action is held this many control steps (1 s)


def _filter(scenario_kwargs: dict, setting: dict) -> FilterParams:
    """The setting on the task's teams: their κ and ε; the whole-arm task keeps its own sensing radius
    (:data:`pan1_env.engine.SENSING_RADIUS`) when the setting names none."""
    options = scenario_kwargs.get("random_options", {})
    return FilterParams(kappa=options.get("kappa", 0.5), epsilon=options.get("epsilon", 5.0), margin=0.0,
                        sensing_radius=setting.get("sensing_radius"), barrier=setting.get("barrier", "squared"),
                        decay=setting.get("decay", 0.0), gate=setting.get("gate", 0.0),
                        fallback=setting.get("fallback", "command"), lookahead=setting.get("lookahead", 0.0),
                        fault_margin=setting.get("fault_margin", False))


def _persistent_random(size: int, teams: int, seed: int):
    rng = np.random.default_rng(seed)
    state = {"t": 0, "action": rng.uniform(-1, 1, (teams, size)).astype(np.float32)}

    def policy(obs: np.ndarray) -> np.ndarray:
        if state["t"] % HOLD_STEPS == 0:
            state["action"] = rng.uniform(-1, 1, (len(obs), size)).astype(np.float32)
        state["t"] += 1
        return state["action"]

    return policy


def _failures():
    """benchmarks/failures.py, a script beside this one."""
    if str(Path(__file__).resolve().parent) not in sys.path:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
    import failures

    return failures


def failure_records(task: str, params: FilterParams, seeds: list[int], max_steps: int | None = None,
                    progress: bool = True, policy_for=ReferencePolicy) -> list[dict]:
    """Each of ``seeds`` run alone on the parallel env behind ``params`` by ``policy_for(env)`` (a velocity-mode
    policy; default the paper's law): ``benchmarks/failures.py``'s summary of every episode, its class included."""
    from tqdm import tqdm

    import pan1_env

    failures = _failures()
    env = pan1_env.parallel_env(TASKS[task], safety_filter=params, max_steps=max_steps)
    policy = policy_for(env)
    records = [failures.run_episode(env, policy, seed)
               for seed in tqdm(seeds, desc="teams alone", disable=not progress or not seeds, leave=False)]
    env.close()
    return records


def failure_classes(task: str, params: FilterParams, seeds: list[int], max_steps: int | None = None,
                    progress: bool = True) -> dict[str, int]:
    """How many of ``seeds`` (teams the reference failed) fall in each class of ``benchmarks/failures.py``
    (``formed`` for a team the law forms when run again in velocity mode)."""
    counts = dict.fromkeys((*_failures().CLASSES, "formed"), 0)
    for record in failure_records(task, params, seeds, max_steps, progress):
        counts[record["class"] or "formed"] += 1
    return counts


def run(tasks: list[str], teams: int, first: int, settings: list[str] | None = None, classes: bool = True,
        policies: tuple[str, ...] = POLICIES, max_steps: int | None = None) -> list[dict]:
    from pan1_env.vector import Pan1VectorEnv

    seeds = range(first, first + teams)
    rows = []
    for task in tasks:
        scenario, kwargs = env_arguments(TASKS[task])
        if max_steps is not None:
            kwargs["max_steps"] = max_steps
        size = Pan1VectorEnv(scenario, 1, **kwargs).single_action_space.shape[0]
        law = law_policy(scenario, {**kwargs, "action_mode": "residual"})
        for key in settings or list(SETTINGS):
            name, setting = SETTINGS[key]
            if task.startswith("whole_arm") and "sensing_radius" in setting:
                continue  # the whole-arm filter has its sensing radius already
            whole_arm_only = "gate" in setting or "fallback" in setting or "lookahead" in setting
            if task == "end_effector" and whole_arm_only and "sensing_radius" not in setting:
                continue  # a gate widens a sensing range; the fallback's measure and the look-ahead are whole-arm rows'
            if task not in ("whole_arm_moving", "whole_arm_clear_paths") and "lookahead" in setting:
                continue  # the look-ahead is along moving obstacles' paths
            params = _filter(kwargs, setting)
            chosen = {"reference": ({"action_mode": "residual"}, law),
                      "random": ({}, _persistent_random(size, teams, first)), "adversarial": ({}, VectorAdversary())}
            for policy_name in policies:
                mode, policy = chosen[policy_name]
                print(f"filters: {task}, {name}, {policy_name} on {teams} teams …", file=sys.stderr, flush=True)
                t0 = time.perf_counter()
                result = evaluate(policy, scenario, seeds, shield=params, env_kwargs={**kwargs, **mode})
                row = _row(task, name, policy_name, result, time.perf_counter() - t0)
                if classes and policy_name == "reference":
                    failed = [seed for seed, error in zip(seeds, result["final_error"], strict=True)
                              if error >= TOLERANCES[0]]
                    row["failure_classes"] = failure_classes(task, params, failed, max_steps)
                rows.append(row)
    return rows


def _row(task: str, setting: str, policy: str, result: dict, seconds: float) -> dict:
    formed = result["final_error"] < TOLERANCES[0]
    return {"task": task, "setting": setting, "policy": policy,
            **{f"success_{round(100 * tol)}cm": float(np.mean(result["final_error"] < tol)) for tol in TOLERANCES},
            "time_to_formation_s": float(np.mean(result["time_to_formation"][formed])) if formed.any() else None,
            "intervention_rate": float(np.mean(result["intervention_rate"])),
            "fallback_rate": float(np.mean(result["fallback_rate"])),
            "min_clearance_m": float(np.min(result["min_clearance"])), "cost": float(np.sum(result["cost"])),
            "seconds": seconds}


def table(rows: list[dict]) -> str:
    lines = ["| task | filter setting | policy | success 1 / 2 / 5 cm [%] | time to formation [s] | interventions "
             "| fallbacks | min clearance [mm] | cost |", "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        rates = " / ".join(f"{100 * r[f'success_{k}cm']:.1f}" for k in (1, 2, 5))
        t = "–" if r["time_to_formation_s"] is None or r["policy"] != "reference" else f"{r['time_to_formation_s']:.1f}"
        lines.append(f"| {r['task']} | {r['setting']} | {r['policy']} | {rates if r['policy'] == 'reference' else '–'} "
                     f"| {t} | {100 * r['intervention_rate']:.1f} % | {100 * r['fallback_rate']:.2f} % "
                     f"| {1000 * r['min_clearance_m']:+.1f} | {r['cost']:g} |")
    return "\n".join(lines)


CLASS_COLUMNS = {"shield_far": "freeze (held far from obstacles)", "deadlock_obstacle": "deadlock at an obstacle",
                 "singular_arm": "singular arm", "local_minimum": "local minimum", "not_converged": "not converged",
                 "formed": "formed on the re-run"}


def class_table(rows: list[dict]) -> str:
    """The reference's failed teams per setting, by class (rows that were classified)."""
    mine = [r for r in rows if "failure_classes" in r]
    if not mine:
        return ""
    lines = ["| task | filter setting | failed teams | " + " | ".join(CLASS_COLUMNS.values()) + " |",
             "|---|---|---:|" + "---:|" * len(CLASS_COLUMNS)]
    for r in mine:
        counts = r["failure_classes"]
        lines.append(f"| {r['task']} | {r['setting']} | {sum(counts.values())} | "
                     + " | ".join(str(counts[key]) for key in CLASS_COLUMNS) + " |")
    return "\n".join(lines)


def pareto(points: list[tuple[float, float]]) -> list[bool]:
    """Which (success, clearance) points no other point beats in both (≥ in both, > in one)."""
    return [not any(a >= x and b >= y and (a > x or b > y) for a, b in points) for x, y in points]


def figure(rows: list[dict], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = len({r["task"] for r in rows})
    fig, axes = plt.subplots(1, tasks, figsize=(5.5 * tasks, 4.5), squeeze=False)
    for ax, task in zip(axes[0], dict.fromkeys(r["task"] for r in rows), strict=True):
        mine = [r for r in rows if r["task"] == task]
        settings = list(dict.fromkeys(r["setting"] for r in mine))
        points = [(next(r["success_1cm"] for r in mine if r["setting"] == s and r["policy"] == "reference"),
                   min(r["min_clearance_m"] for r in mine if r["setting"] == s)) for s in settings]
        front = pareto(points)
        for (success, clearance), name, best in zip(points, settings, front, strict=True):
            ax.scatter(1000 * clearance, 100 * success, marker="*" if best else "o", s=120 if best else 40,
                       color="tab:red" if best else "tab:gray")
            ax.annotate(name, (1000 * clearance, 100 * success), fontsize=7, xytext=(4, 4), textcoords="offset points")
        ax.set_xlabel("smallest clearance, any policy, any sub-step [mm]")
        ax.set_ylabel("paper's law: success at 1 cm [%]")
        ax.set_title(f"{task} (stars: Pareto front)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teams", type=int, default=200, help="held-out random teams per setting (default 200)")
    parser.add_argument("--first", type=int, default=2_000_000, help="first reset seed (default 2000000)")
    parser.add_argument("--tasks", default="end_effector,whole_arm",
                        help="comma-separated: end_effector, whole_arm, whole_arm_moving (default: the first two)")
    parser.add_argument("--settings", default=",".join(SETTINGS),
                        help=f"comma-separated filter settings (default: all): {', '.join(SETTINGS)}")
    parser.add_argument("--policies", default=",".join(POLICIES),
                        help=f"comma-separated: {', '.join(POLICIES)} (default: all three)")
    parser.add_argument("--no-classes", action="store_true",
                        help="skip the failure classes of the reference's failed teams (each is run again alone)")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="control steps per episode (default: the tasks' own, 2000 = 100 s)")
    parser.add_argument("--out", type=Path, default=Path("runs/filters"), help="output directory")
    args = parser.parse_args(argv)
    if args.max_steps is not None and args.max_steps < 1:
        parser.error("--max-steps must be ≥ 1")
    policies = tuple(p for p in args.policies.split(",") if p)
    unknown_policies = [p for p in policies if p not in POLICIES]
    if unknown_policies or not policies:
        parser.error(f"--policies: unknown {', '.join(unknown_policies) or '(none given)'}; "
                     f"choose from {', '.join(POLICIES)}")
    settings = [k for k in args.settings.split(",") if k]
    unknown_settings = [k for k in settings if k not in SETTINGS]
    if unknown_settings or not settings:
        parser.error(f"--settings: unknown {', '.join(unknown_settings) or '(none given)'}; "
                     f"choose from {', '.join(SETTINGS)}")
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in tasks if t not in TASKS]
    if unknown or not tasks:
        parser.error(f"--tasks: unknown {', '.join(unknown) or '(none given)'}; choose from {', '.join(TASKS)}")
    if args.teams < 1:
        parser.error("--teams must be ≥ 1")
    rows = run(tasks, args.teams, args.first, settings, classes=not args.no_classes, policies=policies,
               max_steps=args.max_steps)
    args.out.mkdir(parents=True, exist_ok=True)
    command = " ".join(["python benchmarks/filters.py", *(sys.argv[1:] if argv is None else argv)])
    text = (f"# Filter settings on held-out random teams\n\n`{command}`: seeds {args.first}…"
            f"{args.first + args.teams - 1}\n\n{table(rows)}\n")
    classes = class_table(rows)
    if classes:
        text += ("\nThe reference's failed teams by class (benchmarks/failures.py, each team run again alone):\n\n"
                 f"{classes}\n")
    (args.out / "filters.md").write_text(text, encoding="utf-8")
    (args.out / "filters.json").write_text(json.dumps({"command": command, "rows": rows}, indent=1), encoding="utf-8")
    if "reference" in policies:  # the figure's success axis is the reference's
        figure(rows, args.out / "filters.png")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
