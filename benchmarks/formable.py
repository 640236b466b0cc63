"""Which random teams can hold their shape at rest behind the paper's filter: a bound on any policy.

    python benchmarks/formable.py [--first 1000000] [--teams 64] [--cell 0.01] [--headings 180]
                                  [--slack M] [--out runs/formable.json]

Behind the paper's RCBF filter (docs/MODEL.md §5) an arm stays still only if the filter lets it:
either v = 0 satisfies every row, ``0 ≤ b_j = κ (h_j − margin) − ‖L_g0 h_j‖² / ε``, or the QP with the
speed box |v_t| ≤ ``max_joint_speed`` is infeasible and the filter brakes (v* = 0). Anywhere else the
filter demands ``ḣ_j ≥ −b_j > 0`` for some obstacle j and finds a velocity that does it, so the
end-effector moves whatever the policy asks for. A team can therefore end an episode formed and at
rest only at a placement of its shape where every arm's end-effector is in that arm's *resting set*.

For every team (the ``RandomFormation-v0`` team of each reset seed), this script

1. grids the plane in cells of ``--cell`` m and, for every arm, every cell within its reach and
   ``--headings`` sampled headings of its last link (both elbows), solves the arm's inverse
   kinematics to the cell's centre and asks the filter (``safety.project_velocity``, compiled) whether v = 0
   stays still there. A PA arm is allowed every first-joint angle, although from rest it reaches only
   those its zero passive momentum leads to: this can only enlarge the set;
2. widens each set by the slack a formed team needs (:func:`default_slack`: 2 cm for a formed team's
   distance from an exact placement plus the grid's roundings, 4.4 cm at 1 cm cells);
3. looks for one placement of the shape (every realisation of its edge lengths, including the
   folded ones, rotated in 0.5° steps, translated by whole cells) with every arm's vertex in its
   widened set.

A team with no such placement cannot end an episode formed and at rest behind this filter, whatever
the policy. The share of the others bounds from above the success of every policy whose formed teams
end at rest (a team could in principle pass through the shape, or creep through it as the filter
pushes it away, at the last step). The bound ignores whether a placement can be reached at all, so
the true ceiling is lower. It is numerical: the resting sets are sampled at cell centres and finitely
many headings (tests/test_formable.py checks them against joint-space samples and checks that the
teams the shielded reference forms are counted formable).

Prints the number of formable teams and writes one record per team to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from pan1_env.kernels import compiled_projection
from pan1_env.safety import QPStatus, rcbf_constraints

ROTATION_STEP = np.deg2rad(0.5)
#: how far a formed team (every edge within 1 cm of its length) can sit from an exact realisation of
#: the shape, per end-effector, after the best rigid alignment: 1.96 cm was the most an optimiser found
#: for RandomFormation-v0's shapes (tests/test_formable.py samples it)
FORMED_DEVIATION = 0.02


def default_slack(cell: float, shape_radius: float) -> float:
    """The widening the grid needs: a formed end-effector's distance from the exact placement, plus
    three roundings of cell/√2 each (a resting point to its cell's centre, the placement's centre to a
    cell, a vertex's shift to whole cells), plus half a rotation step at the shape's largest radius."""
    return FORMED_DEVIATION + 3.0 / np.sqrt(2.0) * cell + 0.5 * ROTATION_STEP * shape_radius


def _heading(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The package's link angle of a direction: (sin α, cos α) = (x, y)/‖·‖."""
    return np.arctan2(x, y)


def arm_ik(arm, points: np.ndarray, headings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Absolute link angles θ + φ ``(K, 3)`` of three-link configurations reaching ``points`` with the
    last link at each heading, both elbows, and the index of the point each row reaches."""
    if arm.lengths.shape[0] != 3:
        raise ValueError("formable.py handles three-link arms (RandomFormation-v0's default)")
    L1, L2, L3 = arm.lengths
    P = np.repeat(points, len(headings), axis=0)
    psi = np.tile(headings, len(points))
    idx = np.repeat(np.arange(len(points)), len(headings))
    wrist = P - L3 * np.stack([np.sin(psi), np.cos(psi)], axis=-1) - arm.base
    c = (np.sum(wrist * wrist, axis=-1) - L1**2 - L2**2) / (2 * L1 * L2)
    ok = np.abs(c) <= 1.0
    wrist, psi, idx, c = wrist[ok], psi[ok], idx[ok], c[ok]
    beta = _heading(wrist[:, 0], wrist[:, 1])
    out = []
    for sign in (1.0, -1.0):
        gamma = sign * np.arccos(c)  # the elbow: link 2's angle relative to link 1
        a1 = beta - np.arctan2(L2 * np.sin(gamma), L1 + L2 * np.cos(gamma))
        out.append(np.stack([a1, a1 + gamma, psi], axis=-1))
    return np.concatenate(out), np.concatenate([idx, idx])


def joint_angles(arm, angles: np.ndarray) -> np.ndarray:
    """Relative joint angles q of absolute link angles θ + φ."""
    return np.diff(angles - np.asarray(arm.phi, float), prepend=0.0, axis=-1)


def reduced_jacobian_at(arm, angles: np.ndarray) -> np.ndarray:
    """J̄ = J g0 ``(K, 2, k)`` from absolute link angles: the package's ``cascade.reduced_jacobian``
    (docs/MODEL.md §1–2) written for this many configurations, with only the mass matrix's first row
    (M_1β = Σ_a Σ_{b ≥ β} λ_ab cos(θ_b − θ_a)) that a passive first joint needs."""
    L = arm.lengths
    J = np.cumsum(np.stack([L * np.cos(angles), -L * np.sin(angles)], axis=-2)[..., ::-1], axis=-1)[..., ::-1]
    if not arm.passive_first_joint:
        return J
    X = arm.lam * np.cos(angles[..., None, :] - angles[..., :, None])  # X_ab = λ_ab cos(θ_b − θ_a)
    M0 = np.cumsum(X.sum(-2)[..., ::-1], axis=-1)[..., ::-1]
    return J[..., 1:] - J[..., :1] * (M0[..., None, 1:] / M0[..., None, :1])


def resting_cells(arm, cells: np.ndarray, centers: np.ndarray, radii: np.ndarray, kappa: float,
                  epsilon: float, margin: float, max_speed: float, headings: np.ndarray,
                  chunk: int = 400_000) -> np.ndarray:
    """Boolean per cell: some sampled configuration reaching the cell's centre can stay still behind
    the filter. That is the filter's own answer to v0 = 0 (``safety.project_velocity``, run compiled by
    ``kernels.compiled_projection``, on the RCBF rows
    and the speed box |v_t| ≤ ``max_speed``): v = 0 satisfies every row, or the QP is infeasible and
    the filter brakes (v* = 0) whatever the policy asks for."""
    near = np.linalg.norm(cells - arm.base, axis=-1) <= arm.lengths.sum()
    rest = np.zeros(len(cells), bool)
    pts = np.flatnonzero(near)
    per = max(1, chunk // (2 * len(headings)))
    for first in range(0, len(pts), per):
        block = cells[pts[first:first + per]]
        angles, i = arm_ik(arm, block, headings)
        if len(i) == 0:
            continue
        p = block[i]
        A, b, _ = rcbf_constraints(p, reduced_jacobian_at(arm, angles), centers, radii, kappa, epsilon,
                                   margin=margin)
        k = A.shape[-1]
        if np.isfinite(max_speed):
            box = np.concatenate([np.eye(k), -np.eye(k)])
            A = np.concatenate([A, np.broadcast_to(box, (len(p), 2 * k, k))], axis=1)
            b = np.concatenate([b, np.full((len(p), 2 * k), max_speed)], axis=1)
        still = compiled_projection(np.zeros((len(p), k)), A, b).status != QPStatus.SOLVED
        rest[pts[first:first + per][np.unique(i[still])]] = True
    return rest


def realisations(edges: np.ndarray, distances: np.ndarray, n: int) -> list[np.ndarray]:
    """Every planar realisation (up to rotation and translation) of a polygon-with-fan graph: each
    vertex j ≥ 2 lies on either side of the line through 0 and j − 1."""
    d = {tuple(sorted(map(int, e))): float(x) for e, x in zip(edges, distances, strict=True)}
    out = []
    for signs in np.ndindex(*(2,) * (n - 2)):
        pos = np.zeros((n, 2))
        pos[1] = [d[(0, 1)], 0.0]
        for j in range(2, n):
            a, b = d[(0, j)], d[(j - 1, j)]
            base = pos[j - 1]
            r = np.linalg.norm(base)
            x = (a * a - b * b + r * r) / (2 * r)
            y = np.sqrt(max(a * a - x * x, 0.0)) * (1 if signs[j - 2] == 0 else -1)
            u = base / r
            pos[j] = x * u + y * np.array([-u[1], u[0]])
        out.append(pos - pos.mean(0))
    return out


def _dilate(grid: np.ndarray, radius_cells: int) -> np.ndarray:
    from scipy.ndimage import binary_dilation

    r = radius_cells
    yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
    return binary_dilation(grid, structure=(xx * xx + yy * yy) <= r * r)


def formable(scenario, cell: float, headings: int, max_speed: float, slack: float | None = None) -> dict:
    """Whether some placement of the team's shape has every arm's vertex in its widened resting set
    (``slack`` None: :func:`default_slack`). ``scenario`` must protect end-effectors from still
    obstacles, as ``RandomFormation-v0``'s do; ``max_speed`` is the env's ``max_joint_speed``."""
    if scenario.bodies != "end_effector" or scenario.obstacle_paths is not None:
        raise ValueError("formable.py bounds the paper's filter: end-effectors among still obstacles")
    arms = scenario.arms
    bases = np.array([a.base for a in arms])
    shape = scenario.formation
    placements = realisations(shape.edges, shape.distances, len(arms))
    radius = max(np.linalg.norm(pos, axis=-1).max() for pos in placements)
    slack = default_slack(cell, radius) if slack is None else slack
    # room for every shift of a vertex, so that np.roll below never wraps a resting cell round
    pad = max(a.lengths.sum() for a in arms) + slack + radius
    lo = bases.min(0) - pad
    nx, ny = (np.ceil((bases.max(0) + pad - lo) / cell).astype(int) + 1)
    xs, ys = lo[0] + cell * np.arange(nx), lo[1] + cell * np.arange(ny)
    cells = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    psi = np.linspace(-np.pi, np.pi, headings, endpoint=False)
    mask = scenario.obstacle_mask()
    centers, radii = scenario.obstacles.centers, scenario.obstacles.radii
    sets = []
    for i, arm in enumerate(arms):
        f = scenario.filter
        rest = resting_cells(arm, cells, centers[mask[i]], radii[mask[i]], f.kappa, f.epsilon, f.margin, max_speed,
                             psi).reshape(nx, ny)
        sets.append(_dilate(rest, int(np.ceil(slack / cell))))
    for pos in placements:
        for rot in np.arange(0.0, 2 * np.pi, ROTATION_STEP):
            R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
            shift = np.rint(pos @ R.T / cell).astype(int)  # vertex i sits at the centre cell + shift_i
            all_rest = np.ones((nx, ny), bool)
            for (dx, dy), grid in zip(shift, sets, strict=True):
                all_rest &= np.roll(grid, (-dx, -dy), axis=(0, 1))  # centres whose shifted vertex rests
                if not all_rest.any():
                    break
            if all_rest.any():
                return {"formable": True, "slack": float(slack)}
    return {"formable": False, "slack": float(slack)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--first", type=int, default=1_000_000, help="first reset seed (default 1000000)")
    parser.add_argument("--teams", type=int, default=64, help="number of teams (default 64)")
    parser.add_argument("--cell", type=float, default=0.01, help="grid cell, m (default 0.01)")
    parser.add_argument("--headings", type=int, default=180, help="last-link headings per cell (default 180)")
    parser.add_argument("--slack", type=float, default=None,
                        help="widening of the resting sets, m (default: what the grid needs, see default_slack)")
    parser.add_argument("--out", type=Path, default=Path("runs/formable.json"))
    args = parser.parse_args(argv)
    if not (args.cell > 0 and args.headings >= 1 and args.teams >= 1):
        parser.error(f"--cell must be > 0 and --headings, --teams ≥ 1; got {args.cell}, {args.headings}, "
                     f"{args.teams}")
    if args.slack is not None and not args.slack >= 0:
        parser.error(f"--slack must be ≥ 0, got {args.slack}")
    import pan1_env

    print(f"formable.py: {args.teams} teams at {args.cell} m cells and {args.headings} headings, about 20 s "
          f"a team at the defaults ...", file=sys.stderr, flush=True)

    env = pan1_env.parallel_env("random")
    max_speed = env.unwrapped.config.max_joint_speed
    records = []
    for k, seed in enumerate(range(args.first, args.first + args.teams)):
        env.reset(seed=seed)
        t = time.perf_counter()
        rec = {"seed": seed, **formable(env.unwrapped.scenario, args.cell, args.headings, max_speed, args.slack)}
        records.append(rec)
        print(f"[{k + 1}/{args.teams}] seed {seed}: {'formable' if rec['formable'] else 'NOT formable'} "
              f"({time.perf_counter() - t:.1f} s)", file=sys.stderr, flush=True)
    n = sum(r["formable"] for r in records)
    print(f"formable at rest behind the filter: {n} of {len(records)} teams ({100 * n / len(records):.1f} %)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "teams": records}, indent=1))


if __name__ == "__main__":
    main()
