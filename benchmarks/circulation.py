"""Can a tangential term free the paper's law from its deadlocks at an obstacle? A study behind v1's filter.

    python benchmarks/circulation.py [--task whole_arm] [--teams 200] [--first 2000000] [--senses ccw,cw]
                                     [--gains 1] [--flip-after 0,15] [--delay 0] [--activation 0.1]
                                     [--max-steps N] [--out runs/circulation.json]

Behind ``WholeArmStaticFormation-v1``'s filter most of the law's failed teams are deadlocks at an obstacle
(``benchmarks/failures.py``): the law drives a link straight into an obstacle and the QP cancels the
motion. The usual remedy is a circulation term, a push along the obstacle's boundary. This script tries
a simple one, in the policy (the filter and its safety argument are untouched: whatever the policy asks,
the QP keeps the same rows). For every body point x of arm i within ``--activation`` m of obstacle o (the
end-effector on the end-effector task, each link's closest point on the whole-arm task), with J_x the
point's Jacobian through g0 (actuated velocities to ẋ):

    a = (x − o)ᵀ J_x                       the direction that moves x away from o (the barrier's row),
    t = (R (x − o))ᵀ J_x, less its part along a    the direction that moves x round o, R the quarter turn
                                                   anticlockwise (``ccw``) or clockwise (``cw``),
    v = v0 + γ max(0, −a·v0)/‖a‖ · t/‖t‖   summed over the pairs,

so the law's speed into an obstacle (what the QP cancels) becomes as fast a turn round it (equal norms
of joint velocity). The term reads the team's true state and every obstacle, not an agent's local
observation, and it acts on obstacles only, not on the other arms. v is scaled down as the law's action
is if an entry passes the speed bound. The sense is fixed, or (``--flip-after
S``) each arm's sense turns round once it has pushed round an obstacle for S seconds on end; ``--delay D``
holds the term back until an arm has been blocked for D seconds on end. Both are a memory per arm, which
the filter, a function of one instant, has not.

The law and the circulating law (both in velocity mode, each team alone on the parallel env, classified by
``benchmarks/failures.py``) run on the same held-out teams, behind the task's v1 filter
(``benchmarks/filters.py``'s ``v1`` setting). Per gain, flip time and first sense: teams formed at 1 cm,
the law's failures it forms, the law's successes it loses, the failure classes, the cost and the smallest
clearance; and, per gain and flip time, the teams formed by either sense (what a term that picked its
sense well could at best reach). Writes ``--out`` (JSON) and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # filters.py is a script beside this one
import filters  # noqa: E402

from pan1_env.baselines.circulation import SENSES, CirculatingPolicy  # noqa: E402
from pan1_env.registration import env_arguments  # noqa: E402


def run(task: str, seeds: list[int], senses: list[str], gains: list[float], flips: list[float], activation: float,
        max_steps: int | None, delay: float = 0.0) -> dict:
    """The law's outcome per team, then the circulating law's per gain, sense and ``flip_after`` (0: never);
    see the module docstring."""
    scenario, kwargs = env_arguments(filters.TASKS[task])
    if max_steps is not None:
        kwargs["max_steps"] = max_steps
    params = filters._filter(kwargs, filters.SETTINGS["v1"][1])
    print(f"circulation: the law on {len(seeds)} teams of {task} …", file=sys.stderr, flush=True)
    law = filters.failure_records(task, params, seeds, max_steps)  # the same path as the circulating law's
    law_formed = {r["seed"] for r in law if r["success_1cm"]}
    runs = []
    for gain, flip, sense in itertools.product(gains, flips, senses):
        print(f"circulation: gain {gain:g}, {sense}, flip after {flip:g} s …", file=sys.stderr, flush=True)
        records = filters.failure_records(task, params, seeds, max_steps, policy_for=lambda env, g=gain, s=sense,
                                          f=flip: CirculatingPolicy(env, g, s, activation, f, delay))
        formed = {r["seed"] for r in records if r["success_1cm"]}
        classes = dict(Counter(r["class"] for r in records if not r["success_1cm"]))
        runs.append({"gain": gain, "flip_after_s": flip, "sense": sense, "formed": sorted(formed),
                     "gained": sorted(formed - law_formed), "lost": sorted(law_formed - formed), "classes": classes,
                     "cost": float(sum(r["cost"] for r in records)),
                     "min_clearance_m": float(min(r["min_clearance_episode"] for r in records))})
    return {"task": task, "seeds": [seeds[0], seeds[-1]], "activation_m": activation, "delay_s": delay,
            "law_formed": sorted(law_formed), "runs": runs}


def _flip_text(flip_after: float) -> str:
    return f"{flip_after:g} s" if flip_after > 0 else "never"


def table(result: dict) -> str:
    n, law = result["seeds"][1] - result["seeds"][0] + 1, len(result["law_formed"])
    lines = [f"The law alone: {law} of {n} teams formed at 1 cm ({100 * law / n:.1f} %). The term acts within "
             f"{100 * result['activation_m']:g} cm of an obstacle, after {result['delay_s']:g} s blocked.", "",
             "| gain | flip after | first sense | formed | of the law's failures | of its successes lost "
             "| failure classes | cost | min clearance [mm] |", "|---:|---:|---|---:|---:|---:|---|---:|---:|"]
    either: dict[tuple, set] = {}
    for r in result["runs"]:
        either.setdefault((r["gain"], r["flip_after_s"]), set()).update(r["formed"])
        classes = ", ".join(f"{filters.CLASS_COLUMNS.get(k, k)} {v}" for k, v in sorted(r["classes"].items()))
        formed = len(r["formed"])
        lines.append(f"| {r['gain']:g} | {_flip_text(r['flip_after_s'])} | {r['sense']} "
                     f"| {formed} ({100 * formed / n:.1f} %) "
                     f"| {len(r['gained'])} of {n - law} | {len(r['lost'])} of {law} | {classes} | {r['cost']:g} "
                     f"| {1000 * r['min_clearance_m']:+.1f} |")
    for (gain, flip), formed in either.items():
        lines.append(f"| {gain:g} | {_flip_text(flip)} | either | {len(formed)} ({100 * len(formed) / n:.1f} %) "
                     "| | | | | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="whole_arm", choices=("end_effector", "whole_arm"),
                        help="the task's teams and v1 filter (default whole_arm)")
    parser.add_argument("--teams", type=int, default=200, help="held-out random teams (default 200)")
    parser.add_argument("--first", type=int, default=2_000_000, help="first reset seed (default 2000000)")
    parser.add_argument("--senses", default="ccw,cw", help="comma-separated: ccw, cw (default both)")
    parser.add_argument("--gains", default="1", help="comma-separated gains γ > 0 (default 1)")
    parser.add_argument("--flip-after", default="0,15",
                        help="comma-separated: seconds of contact after which an arm's sense turns round, 0 for "
                             "never (default 0,15: both)")
    parser.add_argument("--delay", type=float, default=0.0,
                        help="seconds an arm stays blocked before its term acts (default 0: at once)")
    parser.add_argument("--activation", type=float, default=0.1,
                        help="clearance (m) within which a pair circulates (default 0.1: v1's robust term holds "
                             "arms up to about 6 cm away)")
    parser.add_argument("--max-steps", type=int, default=None, help="control steps per episode (default the task's)")
    parser.add_argument("--out", type=Path, default=Path("runs/circulation.json"), help="output JSON")
    args = parser.parse_args(argv)
    senses = [s for s in args.senses.split(",") if s]
    if not senses or any(s not in SENSES for s in senses):
        parser.error(f"--senses: choose from {', '.join(SENSES)}, got {args.senses!r}")
    try:
        gains = [float(g) for g in args.gains.split(",") if g]
    except ValueError:
        parser.error(f"--gains: comma-separated numbers, got {args.gains!r}")
    if not gains or not all(np.isfinite(g) and g > 0 for g in gains):
        parser.error(f"--gains: every gain must be finite and > 0, got {args.gains!r}")
    try:
        flips = [float(f) for f in args.flip_after.split(",") if f]
    except ValueError:
        parser.error(f"--flip-after: comma-separated numbers, got {args.flip_after!r}")
    if not flips or not all(np.isfinite(f) and f >= 0 for f in flips):
        parser.error(f"--flip-after: every value must be finite and ≥ 0, got {args.flip_after!r}")
    if not (np.isfinite(args.delay) and args.delay >= 0):
        parser.error(f"--delay must be finite and ≥ 0, got {args.delay}")
    if not (np.isfinite(args.activation) and args.activation > 0):
        parser.error(f"--activation must be finite and > 0, got {args.activation}")
    if args.teams < 1:
        parser.error("--teams must be ≥ 1")
    if args.max_steps is not None and args.max_steps < 1:
        parser.error("--max-steps must be ≥ 1")
    seeds = list(range(args.first, args.first + args.teams))
    result = run(args.task, seeds, senses, gains, flips, args.activation, args.max_steps, args.delay)
    result["command"] = " ".join(["python benchmarks/circulation.py", *(sys.argv[1:] if argv is None else argv)])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1), encoding="utf-8")
    print(f"`{result['command']}`\n\n{table(result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
