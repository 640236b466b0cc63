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

sys.path.insert(0, str(Path(__file__).resolve().parent))  # filters.py and failures.py are scripts beside this one
import failures  # noqa: E402
import filters  # noqa: E402

from pan1_env.baselines import ReferencePolicy  # noqa: E402
from pan1_env.bodies import link_obstacle_barrier, link_point_jacobian  # noqa: E402
from pan1_env.cascade import passive_velocity_map  # noqa: E402
from pan1_env.dynamics import end_effector  # noqa: E402
from pan1_env.registration import env_arguments  # noqa: E402
from pan1_env.safety import clearance  # noqa: E402

SENSES = {"ccw": 1.0, "cw": -1.0}
PAUSE_S = 2.0  # a pause in an arm's term this long ends its spell of contact


def circulation(arm, q, v0, centers, radii, link_radius, links, gain, sense, activation):
    """The term added to one arm's velocity command ``v0 (k,)`` (rad/s) at joint angles ``q``."""
    if links:
        bar = link_obstacle_barrier(arm, q, centers, radii, link_radius)  # the closest point of each link
        gap = np.linalg.norm(bar.point - centers, axis=-1) - radii - link_radius
        pairs = [(link, o, bar.point[link, o], bar.t[link, o]) for link, o in
                 zip(*np.nonzero(gap < activation), strict=True)]
    else:
        p = end_effector(arm, q)
        pairs = [(arm.n_links - 1, o, p, 1.0) for o in np.flatnonzero(clearance(p, centers, radii) < activation)]
    g0 = passive_velocity_map(arm, q)
    term = np.zeros_like(v0)
    for link, o, x, t in pairs:
        Jx = link_point_jacobian(arm, q, link, t) @ g0
        rel = x - centers[o]
        a = rel @ Jx
        norm_a = np.linalg.norm(a)
        into = -(a @ v0)
        if norm_a < 1e-12 or into <= 0.0:
            continue
        tangent = sense * np.array([-rel[1], rel[0]]) @ Jx
        tangent -= (tangent @ a) / norm_a**2 * a
        norm_t = np.linalg.norm(tangent)
        if norm_t > 1e-12:
            term += gain * into / norm_a * tangent / norm_t
    return term


class CirculatingPolicy:
    """The paper's law (:class:`~pan1_env.baselines.ReferencePolicy`, velocity mode) plus :func:`circulation`
    for every arm, on a parallel env whose team it reads at every call.

    A spell of contact is the time an arm's term is non-zero without a pause of :data:`PAUSE_S`. ``delay``
    (s) holds the term back for the spell's first seconds, so that it acts only on an arm that stays
    blocked. ``flip_after`` > 0 (s) turns the arm's sense round once the term has acted that long, once per
    spell."""

    def __init__(self, env, gain: float, sense: str, activation: float, flip_after: float = 0.0,
                 delay: float = 0.0) -> None:
        self.env, self.law = env, ReferencePolicy(env)
        self.gain, self.sense, self.activation, self.flip_after = gain, SENSES[sense], activation, flip_after
        self.delay = delay
        self.arms: list[dict] = []

    def __call__(self, observations: dict) -> dict:
        actions = self.law(observations)
        env, dt = self.env, self.env.unwrapped.control_dt
        scenario, speed = env.scenario, env.max_joint_speed
        if env.unwrapped.num_steps == 0:  # a new episode
            self.arms = [{"sense": self.sense, "acting": 0.0, "pause": 0.0, "flipped": False}
                         for _ in env.possible_agents]
        qs = failures.team_state(env, scenario)[0]
        obstacles = scenario.obstacles
        for i, agent in enumerate(env.possible_agents):
            arm = self.arms[i]
            v0 = np.asarray(actions[agent], float) * speed
            term = circulation(scenario.arms[i], qs[i], v0, obstacles.centers, obstacles.radii, scenario.link_radius,
                               scenario.bodies == "links", self.gain, arm["sense"], self.activation)
            if np.any(term):
                arm["acting"] += dt
                arm["pause"] = 0.0
                if self.flip_after > 0 and arm["acting"] > self.delay + self.flip_after and not arm["flipped"]:
                    arm["sense"], arm["flipped"] = -arm["sense"], True
            else:
                arm["pause"] += dt
                if arm["pause"] > PAUSE_S:
                    arm["acting"], arm["flipped"] = 0.0, False
            v = v0 + term if arm["acting"] > self.delay else v0
            v /= speed * max(1.0, float(np.max(np.abs(v))) / speed)
            actions[agent] = v.astype(np.float32)
        return actions


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
