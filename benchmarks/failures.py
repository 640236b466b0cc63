"""Why the paper's law fails on random teams (what a learner has to beat).

    python benchmarks/failures.py [--episodes 200] [--seed 10000] [--max-steps 2000] [--out runs/failures]
                                  [--unshielded] [--no-progress] [--task pan1_env/RandomFormation-v1]

Runs the shielded reference, :class:`pan1_env.baselines.ReferencePolicy` behind
:class:`pan1_env.wrappers.SafetyShield`, on ``pan1_env.parallel_env(task)``: by default ``"random"`` with the
default random options (4 arms, default time steps, 2000 steps of 0.05 s = 100 s; the paper's filter), or a
random-team id such as ``pan1_env/RandomFormation-v1`` (its teams and filter), one episode per reset seed
``seed … seed + episodes − 1`` (from 10 000 up by default: seeds not used elsewhere), and sorts every
failed episode (final max edge error ≥ ``SUCCESS_TOL`` = 1 cm) into one class. Writes ``failures.md``
(counts and percentages per class, success rates at 1, 2 and 5 cm) and ``failures.json`` (one record per
episode: the summary below plus its class; the thresholds) to ``--out``, and prints the table.
``--unshielded`` also runs every seed without the shield and records its final error and cost (the
same law and team: what the shield changes).

Only public API is read: the infos (``formation_error``, ``min_clearance``, the ``shield_*`` keys),
``env.state()`` (per arm q, q̇, end-effector p), ``env.unwrapped.scenario`` (arms, formation, obstacles,
``obstacle_mask()``, κ, ε), :func:`pan1_env.cascade.reduced_jacobian`, :func:`pan1_env.dynamics.jacobian`
and :func:`pan1_env.safety.rcbf_constraints`.

Per-episode summary (what :func:`classify` reads; "window" = the last ``WINDOW_S`` = 10 s)
--------------------------------------------------------------------------------------------
* ``final_error``: max edge-length error |‖p_i − p_j‖ − d_ij| at the end (m); ``error_window_start``
  the same ``WINDOW_S`` earlier.
* ``sigma_min[i]``: smallest singular value of arm i's reduced Jacobian J̄_i = J_i g0_i at the end (m/rad).
* ``grad_norm[i]``: ‖ê_i‖, ê_i = Σ_j 2 (p_i − p_j)(‖p_i − p_j‖² − d_ij²), the gradient of V in arm i's
  end-effector position (what the nominal law v_i0 = −K_P J̄_iᵀ ê_i follows), at the end (m³).
* ``clearance[i]``: arm i's end-effector clearance to the nearest obstacle in the last step (m).
* ``blocked_fraction[i]``: fraction of the window's steps in which the shield changed arm i's action
  *substantially*: ‖applied − requested‖ ≥ ``ACTION_CHANGE_REL`` · ‖requested‖ and ≥ ``ACTION_CHANGE_ABS``
  (normalised action units; the report's ``intervened`` flag alone also counts tiny changes).
* ``criteria_met`` (JSON only): every class criterion below that holds for a failed episode, before the
  order picks one (e.g. a blocked arm that is also stretched: ``["shield_far", "singular_arm"]``).
* ``travel[i]``: ‖p_i(T) − p_i(T − WINDOW_S)‖, how far arm i's end-effector moved over the window (m).
  (Net displacement, not speed: some arms end in a fast bang-bang limit cycle of the saturated nominal
  action at the 0.05 s control step, which goes nowhere.)

Not used by the classifier, recorded as diagnostics: ``robust_ratio[i]`` = max over the obstacles in arm
i's reach of ‖L_g h‖² / (ε(h̃) κ h̃) of its end-effector's row at the end, in the filter's own barrier and
robust term (≥ 1: the RCBF row forbids any approach to that obstacle from there; behind the paper's filter
however far, see docs/PAPER_REPRODUCTION.md "Obstacles an arm can never reach"; links' rows, a sensing
range and a gate are not looked at), the end-effector speeds,
the nominal actions, ``cos_grad_to_obstacle`` (cosine between −ê_i and the direction to the nearest
obstacle: > 0 when V pulls the arm towards it), success at 1/2/5 cm, the cost.

Classes, evaluated in this order (the first that applies wins; a success is not classified)
---------------------------------------------------------------------------------------------
Let *blocked* arms be those with ``blocked_fraction`` ≥ ``BLOCKED_FRACTION`` (the shield keeps changing
their nominal action substantially over the last 10 s).

1. ``deadlock_obstacle`` — a blocked arm is at an obstacle: its clearance is below
   ``DEADLOCK_CLEARANCE`` at the end. The nominal direction points into the obstacle and the filter
   removes that component.
2. ``shield_far`` — a blocked arm, but every blocked arm is ≥ ``DEADLOCK_CLEARANCE`` from the
   obstacles. The filter stalls the arm far from any obstacle: the robust term (1/ε)‖L_g h‖² of the RCBF
   row exceeds κh, which happens at any distance once ‖J̄ᵀn‖ > √(κε)/2 (long, stretched arms). This class
   is not among the usual CBF failure modes; the deadlock class asks for a small clearance, and the frames show
   arms frozen 0.1–2 m from the obstacle that binds them (fully actuated arms, mostly stretched).
3. ``singular_arm`` — no arm blocked, but some arm i has σ_min(J̄_i) < ``SIGMA_SINGULAR`` at the end
   while it is still asked to move (‖ê_i‖ ≥ ``GRAD_ACTIVE``): its end-effector cannot move in one
   direction (stretched towards a target beyond its reach, or folded), so the nominal direction
   −J̄_iᵀ ê_i loses the component of ê_i that V needs.
4. ``local_minimum`` — no arm blocked or singular, the team has stopped: every end-effector moved less
   than ``STOP_TRAVEL`` over the window and the error fell by less than ``STOP_DECREASE`` (relative), yet
   the error is ≥ 1 cm: a wrong critical point of V (ê_i ≈ 0 for every arm, e.g. a reflected or
   collinear arrangement) or what is left of ê_i lies in the null space of J̄_iᵀ.
5. ``not_converged`` — everything else: still moving, or the error still decreasing, at the end.

Blocking is tested before singularity because a blocked arm is usually also fully stretched (the
stretched arm has the largest ‖J̄ᵀn‖), and it is the block, not the singularity, that decides the
outcome: with ``--unshielded`` the same teams nearly all converge.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter, deque
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from pan1_env.config import SUCCESS_TOLERANCE

# ----------------------------------------------------------------------------- thresholds
SUCCESS_TOL = SUCCESS_TOLERANCE  # m: success = final max edge error below this (the env's is_success)
WINDOW_S = 10.0  # s: final window over which motion, error decrease and shield activity are measured
ACTION_CHANGE_REL = 0.2  # the shield changed the action by ≥ 20 % of the requested action's norm ...
ACTION_CHANGE_ABS = 1e-3  # ... and by at least this much (normalised units): a "substantial" change
BLOCKED_FRACTION = 0.5  # substantial change in at least half of the window's steps: the arm is "blocked"
DEADLOCK_CLEARANCE = 0.05  # m: a blocked arm's end-effector clearance below this is "at an obstacle"
SIGMA_SINGULAR = 0.02  # m/rad: σ_min(J̄) below this is "singular"
GRAD_ACTIVE = 1e-4  # m³: ‖ê_i‖ at or above this means arm i is still asked to move
STOP_TRAVEL = 0.005  # m: every end-effector moved less than this over the window: "stopped"
STOP_DECREASE = 0.02  # ... and the error fell by less than 2 % (relative) over the window

THRESHOLDS = ("SUCCESS_TOL", "WINDOW_S", "ACTION_CHANGE_REL", "ACTION_CHANGE_ABS", "BLOCKED_FRACTION",
              "DEADLOCK_CLEARANCE", "SIGMA_SINGULAR", "GRAD_ACTIVE", "STOP_TRAVEL", "STOP_DECREASE")
CLASSES = ("deadlock_obstacle", "shield_far", "singular_arm", "local_minimum", "not_converged")
CLASS_TITLES = {
    "deadlock_obstacle": "deadlock at an obstacle (blocked arm < 5 cm from it)",
    "shield_far": "blocked by the shield far from obstacles (RCBF robust term)",
    "singular_arm": "singular arm",
    "local_minimum": "local minimum of V away from obstacles",
    "not_converged": "not converged in time",
}


def criteria(rec: Mapping) -> dict[str, bool]:
    """Which class criteria hold for one failed episode's summary (each on its own, before the order)."""
    blocked = np.asarray(rec["blocked_fraction"], float) >= BLOCKED_FRACTION
    near = np.asarray(rec["clearance"], float) < DEADLOCK_CLEARANCE
    sigma, grad = np.asarray(rec["sigma_min"], float), np.asarray(rec["grad_norm"], float)
    start = rec["error_window_start"]
    decrease = (start - rec["final_error"]) / start if start > 0 else 0.0
    return {
        "deadlock_obstacle": bool(np.any(blocked & near)),
        "shield_far": bool(np.any(blocked & ~near)),
        "singular_arm": bool(np.any((sigma < SIGMA_SINGULAR) & (grad >= GRAD_ACTIVE))),
        "local_minimum": bool(np.max(np.asarray(rec["travel"], float)) < STOP_TRAVEL and decrease < STOP_DECREASE),
        "not_converged": True,
    }


def classify(rec: Mapping) -> str | None:
    """The failure class of one episode summary (keys as in the module docstring), ``None`` on success:
    the first class in ``CLASSES`` whose criterion holds.

    A pure function of the summary, so the criteria are testable without running episodes.
    """
    if rec["final_error"] < SUCCESS_TOL:
        return None
    met = criteria(rec)
    return next(c for c in CLASSES if met[c])


# ----------------------------------------------------------------------------- running episodes
def team_state(env, scenario) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per-arm q, q̇ and the end-effector positions ``(N, 2)`` from ``env.state()``."""
    s = np.asarray(env.state(), dtype=float)
    n_max = max(arm.n_links for arm in scenario.arms)  # state() pads every arm's q and q̇ to n_max
    qs, qds, P, k = [], [], [], 0
    for arm in scenario.arms:
        n = arm.n_links
        qs.append(s[k : k + n])
        qds.append(s[k + n_max : k + n_max + n])
        P.append(s[k + 2 * n_max : k + 2 * n_max + 2])
        k += 2 * n_max + 2
    return qs, qds, np.array(P)


def _grad(scenario, P: np.ndarray) -> np.ndarray:
    """ê_i = Σ_j 2 (p_i − p_j)(‖p_i − p_j‖² − d_ij²) for every arm, ``(N, 2)``."""
    g = np.zeros_like(P)
    for (i, j), d in zip(scenario.formation.edges, scenario.formation.distances, strict=True):
        z = P[i] - P[j]
        term = 2.0 * z * (z @ z - d * d)
        g[i] += term
        g[j] -= term
    return g


def _edge_error(scenario, P: np.ndarray) -> float:
    f = scenario.formation
    z = P[f.edges[:, 0]] - P[f.edges[:, 1]]
    return float(np.max(np.abs(np.linalg.norm(z, axis=1) - f.distances)))


def _finite(x):
    """JSON-safe: non-finite floats become None."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x


def robust_ratio(lg2: float, h_tilde: float, kappa: float, epsilon: float, decay: float = 0.0) -> float:
    """‖L_g0 h‖² / (ε(h̃) κ h̃) of one row (docs/MODEL.md §5a): ≥ 1 where the row forbids any approach, so an
    arm pushed straight at the obstacle rests where it is 1; infinite at or inside the tightened boundary."""
    from pan1_env.safety import robust_epsilon

    if h_tilde <= 0.0:
        return math.inf
    return lg2 / (float(robust_epsilon(np.asarray(h_tilde), epsilon, decay)) * kappa * h_tilde)


def run_episode(env, policy, seed: int) -> dict:
    """One shielded reference episode from ``reset(seed=seed)``; returns its summary (and class)."""
    from pan1_env.cascade import reduced_jacobian
    from pan1_env.dynamics import jacobian
    from pan1_env.safety import rcbf_constraints

    obs, infos = env.reset(seed=seed)
    core = env.unwrapped
    scenario = core.scenario
    agents = list(core.possible_agents)
    n_arms = len(agents)
    window = max(1, round(WINDOW_S / core.dt))
    positions = deque(maxlen=window + 1)
    errors = deque(maxlen=window + 1)
    blocked = deque(maxlen=window)  # per step: (N,) substantial shield change
    P = team_state(env, scenario)[2]
    positions.append(P)
    errors.append(_edge_error(scenario, P))
    min_clearance = np.full(n_arms, np.inf)
    cost = 0.0
    steps = 0
    while env.agents:
        actions = policy(obs)
        obs, _, _, _, infos = env.step(actions)
        steps += 1
        flags = np.zeros(n_arms, dtype=bool)
        for i, a in enumerate(agents):
            info = infos[a]
            min_clearance[i] = min(min_clearance[i], info["min_clearance"])
            cost += info["cost"]
            if info.get("shield_intervened"):
                req = np.asarray(actions[a], float)
                change = np.linalg.norm(np.asarray(info["shield_applied"], float) - req)
                flags[i] = change >= ACTION_CHANGE_ABS and change >= ACTION_CHANGE_REL * np.linalg.norm(req)
        blocked.append(flags)
        positions.append(team_state(env, scenario)[2])
        errors.append(infos[agents[0]]["formation_error"])

    qs, qds, P = team_state(env, scenario)
    grad = _grad(scenario, P)
    params = core.safety_filter or scenario.filter
    kappa, epsilon, margin, barrier, decay = params.kappa, params.epsilon, params.margin, params.barrier, params.decay
    mask = scenario.obstacle_mask()
    obstacles = scenario.obstacles
    sigma, ee_speed, cos_into, robust = [], [], [], []
    for i, arm in enumerate(scenario.arms):
        Jbar = reduced_jacobian(arm, qs[i])
        sigma.append(float(np.linalg.svd(Jbar, compute_uv=False)[-1]))
        ee_speed.append(float(np.linalg.norm(jacobian(arm, qs[i]) @ qds[i])))
        to_obs = obstacles.centers - P[i]
        k = int(np.argmin(np.linalg.norm(to_obs, axis=1) - obstacles.radii))
        u, g = to_obs[k], -grad[i]
        denom = np.linalg.norm(u) * np.linalg.norm(g)
        cos_into.append(float(u @ g / denom) if denom > 0 else 0.0)
        A, _, h = rcbf_constraints(P[i], Jbar, obstacles.centers, obstacles.radii, kappa, epsilon, mask[i], margin,
                                   barrier=barrier, decay=decay)
        ratios = [robust_ratio(float(np.sum(A[j] ** 2)), float(h[j] - margin), kappa, epsilon, decay)
                  for j in np.flatnonzero(mask[i])]
        robust.append(max(ratios, default=0.0))
    err = float(errors[-1])
    rec = {
        "seed": int(seed),
        "steps": steps,
        "final_error": err,
        "error_window_start": float(errors[0]),
        "success_1cm": err < SUCCESS_TOL,
        "success_2cm": err < 0.02,
        "success_5cm": err < 0.05,
        "sigma_min": sigma,
        "grad_norm": np.linalg.norm(grad, axis=1).tolist(),
        "clearance": [float(infos[a]["min_clearance"]) for a in agents],
        "min_clearance_episode": float(np.min(min_clearance)),
        "cost": float(cost),
        "blocked_fraction": np.mean(np.array(blocked), axis=0).tolist(),
        "intervened_final": [bool(infos[a].get("shield_intervened", False)) for a in agents],
        "nominal_action": [float(np.max(np.abs(actions[a]))) if "shield_applied" in infos[a] else 0.0
                           for a in agents],
        "robust_ratio": robust,
        "travel": np.linalg.norm(positions[-1] - positions[0], axis=1).tolist(),
        "ee_speed": ee_speed,
        "cos_grad_to_obstacle": cos_into,
        "passive": [bool(arm.passive_first_joint) for arm in scenario.arms],
    }
    rec["class"] = classify(rec)
    rec["criteria_met"] = [c for c, ok in criteria(rec).items() if ok and c != "not_converged"] if rec["class"] else []
    return rec


def run_unshielded(env, policy, seed: int) -> tuple[float, float]:
    """Final max edge error and total cost of the same seed's episode without the shield."""
    obs, infos = env.reset(seed=seed)
    cost = 0.0
    while env.agents:
        obs, _, _, _, infos = env.step(policy(obs))
        cost += sum(info["cost"] for info in infos.values())
    return float(next(iter(infos.values()))["formation_error"]), cost


def make_env(max_steps: int | None = None, render_mode: str | None = None, shield: bool = True,
             task: str = "random"):
    """The random-team env of ``task`` (``random`` or a random-team id; shielded by default) and the reference
    policy on it."""
    import pan1_env
    from pan1_env.baselines import ReferencePolicy
    from pan1_env.wrappers import SafetyShield

    env = pan1_env.parallel_env(task, max_steps=max_steps, render_mode=render_mode)
    if shield:
        env = SafetyShield(env)
    return env, ReferencePolicy(env.unwrapped)


# ----------------------------------------------------------------------------- report
def _pct(count: int, n: int) -> str:
    return f"{100.0 * count / n:.1f} %" if n else "–"


def table(records: list[dict]) -> str:
    """Markdown: counts and shares per class (with how many also have a singular arm, and, if recorded,
    how many the unshielded law solves), then success rates at 1, 2 and 5 cm."""
    n = len(records)
    counts = Counter(r["class"] for r in records)
    unshielded = n > 0 and all("unshielded_final_error" in r for r in records)
    rows = ["| outcome | episodes | share | also a singular arm |" + (" succeed unshielded |" if unshielded else ""),
            "|---|---:|---:|---:|" + ("---:|" if unshielded else "")]
    for key, title in [(None, "success (final max edge error < 1 cm)"), *CLASS_TITLES.items()]:
        mine = [r for r in records if r["class"] == key]
        also = sum("singular_arm" in r.get("criteria_met", ()) for r in mine)
        singular = "" if key in (None, "singular_arm") else str(also)
        row = f"| {title} | {counts[key]} | {_pct(counts[key], n)} | {singular} |"
        if unshielded:
            row += f" {sum(r['unshielded_final_error'] < SUCCESS_TOL for r in mine)} |"
        rows.append(row)
    rows.append(f"| **total** | {n} | | |" + (f" {sum(r['unshielded_final_error'] < SUCCESS_TOL for r in records)} |"
                                              if unshielded else ""))
    rows += ["", "| success at | 1 cm | 2 cm | 5 cm |", "|---|---:|---:|---:|"]
    rates = [_pct(sum(r[f"success_{k}cm"] for r in records), n) for k in (1, 2, 5)]
    rows.append(f"| shielded reference | {' | '.join(rates)} |")
    if unshielded:
        rates = [_pct(sum(r["unshielded_final_error"] < k / 100 for r in records), n) for k in (1, 2, 5)]
        rows.append(f"| same teams, unshielded | {' | '.join(rates)} |")
        hit = sum(r["unshielded_cost"] > 0 for r in records)
        rows += ["", f"Unshielded, {hit} of {n} episodes ({_pct(hit, n)}) enter an obstacle."]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    from tqdm import tqdm

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=200, help="number of random teams (default 200)")
    parser.add_argument("--seed", type=int, default=10_000, help="first reset seed (default 10000)")
    parser.add_argument("--max-steps", type=int, default=None, help="steps per episode (default: the env's, 2000)")
    parser.add_argument("--out", type=Path, default=Path("runs/failures"), help="output directory")
    parser.add_argument("--unshielded", action="store_true", help="also run every seed without the shield")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--task", default="random",
                        help="random (the default options, v0's filter) or a random-team id such as "
                             "pan1_env/RandomFormation-v1 (its teams and filter)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error("--episodes must be ≥ 1")
    try:
        env, policy = make_env(args.max_steps, task=args.task)
    except ValueError as err:
        parser.error(str(err))
    if not env.unwrapped.config.random:
        parser.error(f"--task {args.task}: not random teams (random, or an id such as pan1_env/RandomFormation-v1)")
    bare = make_env(args.max_steps, shield=False, task=args.task) if args.unshielded else None
    records = []
    t0 = time.perf_counter()
    for seed in tqdm(range(args.seed, args.seed + args.episodes), desc="episodes", disable=args.no_progress):
        rec = run_episode(env, policy, seed)
        if bare is not None:
            rec["unshielded_final_error"], rec["unshielded_cost"] = run_unshielded(*bare, seed)
        records.append(rec)
    elapsed = time.perf_counter() - t0
    env.close()

    args.out.mkdir(parents=True, exist_ok=True)
    command = " ".join(["python benchmarks/failures.py", *(sys.argv[1:] if argv is None else argv)])
    report = (f"# Failures of the shielded reference on random teams ({args.task})\n\n`{command}`: seeds "
              f"{args.seed}…{args.seed + args.episodes - 1}, {elapsed:.0f} s\n\n{table(records)}\n")
    (args.out / "failures.md").write_text(report, encoding="utf-8")
    payload = {"command": command, "task": args.task, "seed": args.seed, "episodes": args.episodes,
               "max_steps": args.max_steps,
               "thresholds": {name: globals()[name] for name in THRESHOLDS},
               "records": [{k: _finite(v) for k, v in r.items()} for r in records]}
    (args.out / "failures.json").write_text(json.dumps(payload, indent=1, allow_nan=False), encoding="utf-8")
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
