"""Could any admissible command have avoided a contact? A judge of avoidability, independent of the filter.

A contact with a moving obstacle, or after a fault, is the filter's fault only if some command the arm was
allowed to give could have avoided it. :func:`judge` answers that for one arm and its obstacles from the state
some horizon before the contact: it searches command sequences and reports one that keeps every link capsule
clear through the whole window, if it finds one.

**What is admissible.** The commands are the actuated joints' velocities, each within ±``max_speed`` (the env's
``max_joint_speed``), held piecewise constant over ``pieces`` equal parts of the window. The actuated joints
follow them exactly; a passive first joint follows from its momentum, q̇ = g₀(q) v + e₁ p₁ / M₁₁ (Eq. 12), and the
momentum decays through the joint's damping, ṗ₁ = −b q̇₁ (a faulted arm carries the momentum it had when its
actuator failed). The obstacles follow their known paths (:func:`pan1_env.bodies.obstacle_centers`).

**How far to trust a verdict.** The torque loop's lag is ignored, so an escape found here may need perfect
tracking: "avoidable" is generous to the arm, which makes it strict on the filter. "No escape found" means none
among the sequences tried (every constant corner command of the speed box, then random bang-bang sequences, then
random uniform ones): a search, not a proof. Other arms are not in the way here: only obstacles count.

    from benchmarks.avoidability import judge
    verdict = judge(arm, q, p1, centers, path_ends, speeds, radii, link_radius=0.03, max_speed=2.0,
                    t0=12.0, window=3.0)
    verdict.avoidable, verdict.best_clearance

**Classing a task's contacts.** Run as a script, it runs a policy (default: the paper's law) behind the task's
filter on held-out teams, one team at a time, and judges every spell of contact (an arm's consecutive steps with
cost) from the state ``--horizon`` s before the spell began (or the episode's start, or the arm's fault if that came
later: :func:`judged_from`), over a window that lasts
``--after`` s past the contact:

    python benchmarks/avoidability.py --task pan1_env/WholeArmFormation-v1 --teams 200 [--first 2000000]
        [--seeds S,S,…] [--horizon 1.0] [--after 2.0] [--samples 400] [--policy reference]
        [--env-kwargs JSON] [--out runs/avoidability.json]

It writes every spell (team, arm, time, verdict, the best clearance found) and prints the counts.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
from collections import deque
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pan1_env.bodies import link_clearance, obstacle_centers
from pan1_env.cascade import joint_velocity, passive_momentum, rk4_step
from pan1_env.dynamics import ArmParams

__all__ = ["Verdict", "judge", "judged_from", "rollout"]


class Verdict(NamedTuple):
    """What :func:`judge` found."""

    avoidable: bool  #: some sequence kept every link clear through the window
    best_clearance: float  #: the largest, over the sequences tried, of the least clearance along the window (m)
    witness: np.ndarray | None  #: the best sequence's commands ``(pieces, k)`` (rad/s)
    tried: int  #: sequences tried


def rollout(arm: ArmParams, q: np.ndarray, p1: float, commands: np.ndarray, window: float,
            dt: float) -> np.ndarray:
    """Joint angles ``(S, steps + 1, n)`` of S command sequences ``(S, pieces, k)`` over ``window`` s (RK4 steps
    of ``dt``), all from (q, p₁)."""
    S, pieces, _ = commands.shape
    steps = int(np.ceil(window / dt - 1e-9))
    h = window / steps
    passive = arm.passive_first_joint
    b = arm.passive_damping if passive else 0.0
    qs = np.broadcast_to(np.asarray(q, float), (S, arm.n_links)).copy()
    p = np.full(S, float(p1))
    out = [qs]

    def rhs(qq: np.ndarray, pp: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        qd = joint_velocity(arm, qq, v, pp) if passive else v
        return qd, (-b * qd[:, 0] if passive else np.zeros_like(pp))

    for k in range(steps):
        v = commands[:, min(int(k * h / window * pieces), pieces - 1)]
        qs, p = rk4_step(lambda qq, pp, v=v: rhs(qq, pp, v), qs, p, h)
        out.append(qs)
    return np.stack(out, axis=1)


def _candidates(k: int, pieces: int, samples: int, max_speed: float, rng: np.random.Generator) -> np.ndarray:
    corners = np.array(list(itertools.product((-1.0, 0.0, 1.0), repeat=k)))  # held for the whole window
    constant = np.repeat(corners[:, None, :], pieces, axis=1)
    bang = rng.choice([-1.0, 0.0, 1.0], size=(samples // 2, pieces, k))
    uniform = rng.uniform(-1.0, 1.0, size=(samples - samples // 2, pieces, k))
    return max_speed * np.concatenate([constant, bang, uniform])


def judge(arm: ArmParams, q: np.ndarray, p1: float, centers: np.ndarray, path_ends: np.ndarray, speeds: np.ndarray,
          radii: np.ndarray, *, link_radius: float, max_speed: float, t0: float, window: float, pieces: int = 6,
          samples: int = 400, dt: float = 0.01, seed: int = 0) -> Verdict:
    """Whether some admissible command sequence, from joint angles ``q`` and passive momentum ``p1`` (0 for a fully
    actuated arm) at time ``t0``, keeps every link capsule of ``arm`` clear of the obstacles (their start centres,
    path ends, speeds and radii, as the scenario holds them) for ``window`` s."""
    if not (max_speed > 0 and window > 0 and dt > 0 and pieces >= 1 and samples >= 2):
        raise ValueError(f"max_speed, window and dt must be > 0, pieces ≥ 1 and samples ≥ 2; got {max_speed}, "
                         f"{window}, {dt}, {pieces}, {samples}")
    if not (np.all(np.isfinite(q)) and np.isfinite(p1) and np.isfinite(t0)):
        raise ValueError(f"the state must be finite: q={np.asarray(q).tolist()}, p1={p1}, t0={t0}")
    commands = _candidates(arm.n_actuated, pieces, samples, max_speed, np.random.default_rng(seed))
    paths = rollout(arm, q, p1, commands, window, dt)  # (S, T, n)
    times = t0 + np.linspace(0.0, window, paths.shape[1])
    where = obstacle_centers(centers, path_ends, speeds, times)  # (T, O, 2)
    least = np.full(len(commands), np.inf)
    for k, t_centers in enumerate(where):
        least = np.minimum(least, link_clearance(arm, paths[:, k], t_centers, radii, link_radius).min(axis=(-2, -1)))
    best = int(np.argmax(least))
    return Verdict(bool(least[best] >= 0.0), float(least[best]), commands[best], len(commands))


def judged_from(past, arm: int) -> tuple:
    """The recorded step a contact of ``arm`` is judged from: the oldest of ``past`` (the steps' starts, each
    ``(time, q, qd, lost)``, oldest first), or the first at which the arm had lost its actuator if that came later:
    before the fault the arm was whole, and no command then could plan for a fault it could not know of."""
    return next((entry for entry in past if entry[3][arm]), past[0])


def _spells(env, policy, seed: int, horizon: float, after: float, samples: int) -> list[dict]:
    """Every spell of contact of one team's episode, judged from the state :func:`judged_from` picks. An arm whose
    actuator failed within the very step of the contact has no state after its fault before the contact: its
    spell is recorded, not judged (``avoidable`` None)."""
    team = env.unwrapped
    obs, _ = env.reset(seed=seed)
    scenario, dt = team.scenario, team.dt
    centers, radii = scenario.obstacles.centers, scenario.obstacles.radii
    moving = scenario.obstacle_paths is not None
    path_ends = scenario.obstacle_paths if moving else centers
    speeds = scenario.obstacle_speeds if moving else np.zeros(len(radii))
    past: deque = deque(maxlen=int(round(horizon / dt)) + 1)  # (time, q, qd, lost) at the start of each step
    lost = np.zeros(len(team.possible_agents), dtype=bool)
    touching = np.zeros(len(team.possible_agents), dtype=bool)
    out, step = [], 0
    while env.agents:
        past.append((step * dt, *team.joint_state(), lost.copy()))
        obs, _, _, _, infos = env.step(policy(obs))
        step += 1
        cost = np.array([infos[a]["cost"] for a in team.possible_agents]) > 0
        lost = np.array([bool(infos[a].get("actuator_lost", False)) for a in team.possible_agents])
        for i in np.flatnonzero(cost & ~touching):
            t0, q, qd, was_lost = judged_from(past, i)
            if lost[i] and not was_lost[i]:  # the fault and the contact in one step
                out.append({"team": seed, "arm": int(i), "contact_s": step * dt, "from_s": None, "faulted": True,
                            "avoidable": None, "best_clearance_m": None})
                continue
            arm = scenario.arms[i]
            arm = dataclasses.replace(arm, passive_first_joint=True) if was_lost[i] else arm
            n = arm.n_links
            p1 = float(passive_momentum(arm, q[i, :n], qd[i, :n])) if arm.passive_first_joint else 0.0
            window = step * dt - t0 + after
            verdict = judge(arm, q[i, :n], p1, centers, path_ends, speeds, radii, link_radius=scenario.link_radius,
                            max_speed=team.config.max_joint_speed, t0=t0, window=window, samples=samples, seed=seed)
            out.append({"team": seed, "arm": int(i), "contact_s": step * dt, "from_s": t0,
                        "faulted": bool(was_lost[i]), "avoidable": verdict.avoidable,
                        "best_clearance_m": verdict.best_clearance})
        touching = cost
    return out


def main(argv: list[str] | None = None) -> int:
    from pan1_env.baselines.policies import make_policy
    from pan1_env.cli import json_object
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments
    from pan1_env.wrappers import SafetyShield

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="pan1_env/WholeArmFormation-v1")
    parser.add_argument("--teams", type=int, default=200)
    parser.add_argument("--first", type=int, default=2_000_000)
    parser.add_argument("--seeds", default=None, help="comma-separated reset seeds instead of --first/--teams")
    parser.add_argument("--horizon", type=float, default=1.0, help="s before a spell's first contact to judge from")
    parser.add_argument("--after", type=float, default=2.0, help="s past the contact the escape must hold")
    parser.add_argument("--samples", type=int, default=400, help="random command sequences per spell")
    parser.add_argument("--policy", default="reference")
    parser.add_argument("--env-kwargs", type=json_object, default={}, metavar="JSON",
                        help="the env's arguments over the task's (random_options merged key by key), e.g. the soak's "
                             "shorter steps and earlier faults")
    parser.add_argument("--out", type=Path, default=Path("runs/avoidability.json"))
    args = parser.parse_args(argv)
    if args.teams < 1 or not (args.horizon > 0 and args.after >= 0) or args.samples < 2:
        parser.error("--teams ≥ 1, --horizon > 0, --after ≥ 0 and --samples ≥ 2")
    overrides = args.env_kwargs
    if "scenario" in overrides:
        parser.error("--env-kwargs cannot set the scenario: name it in --task")
    try:
        scenario, kwargs = env_arguments(args.task, overrides)
        env = SafetyShield(parallel_env(scenario, **kwargs))
        policy = make_policy(args.policy, env, 0)
    except (TypeError, ValueError) as err:
        parser.error(str(err))
    try:
        seeds = ([int(x) for x in args.seeds.split(",") if x.strip()] if args.seeds
                 else list(range(args.first, args.first + args.teams)))
    except ValueError:
        parser.error(f"--seeds: comma-separated integers, got {args.seeds!r}")
    spells = []
    for seed in seeds:
        spells += _spells(env, policy, seed, args.horizon, args.after, args.samples)
        print(f"team {seed}: {len(spells)} spells so far", file=sys.stderr, flush=True)
    avoidable = sum(s["avoidable"] is True for s in spells)
    unjudged = sum(s["avoidable"] is None for s in spells)
    summary = {"task": args.task, "env_kwargs": overrides, "policy": args.policy, "seeds": seeds,
               "horizon_s": args.horizon, "after_s": args.after, "samples": args.samples, "spells": len(spells),
               "avoidable": avoidable, "no_escape_found": len(spells) - avoidable - unjudged,
               "fault_in_the_contact_step": unjudged,
               "command": " ".join(["python", *sys.argv])}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary | {"events": spells}, indent=1) + "\n")
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
