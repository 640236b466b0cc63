"""What an arm's links face in the seconds before a contact: a step-by-step trace of one arm of one team.

For each step of a time window it prints, per link of the arm, its least clearance to the obstacles, how fast
the nearest obstacle closes on it and how fast the link could move away from it at most, and then what the
filter did (the QP's status, the command it applied as fractions of the speed bound) and the joint speeds the
arm reached. It is the tool behind the diagnosis of the law's contacts in docs/ENVIRONMENTS.md:

    python benchmarks/contact_trace.py --task pan1_env/WholeArmFormation-v1 --seed 2000178 --arm 1 \\
        --start 4.3 --stop 5.4 [--policy reference] [--no-shield]

**Closing and escape speeds** (:func:`escape_speeds`). For link ℓ and obstacle j, n is the unit vector from the
obstacle's centre to the link's nearest point x. The obstacle closes at ``n · ċ_j`` (m/s, > 0: approaching).
The link moves away at n · ẋ = (∇_q d)ᵀ g0 v for actuated joint speeds v (g0: a passive first joint follows the
others, docs/MODEL.md §2), and within the speed box |v_t| ≤ v_max the most it can is
``v_max Σ_t |(∇_q d)ᵀ g0|_t``. Where the closing speed exceeds that, no command can keep this pair's clearance
from shrinking at this instant; the filter's QP may still have an answer as long as the clearance lasts.
"""

from __future__ import annotations

import argparse
import sys
from typing import NamedTuple

import numpy as np

from pan1_env.bodies import link_obstacle_barrier
from pan1_env.dynamics import ArmParams
from pan1_env.safety import shaped_barrier

__all__ = ["LinkEscape", "escape_speeds"]

_STATUS = {0: "nominal", 1: "solved", 2: "fallback"}


class LinkEscape(NamedTuple):
    """Per link ``(n,)``, against its nearest obstacle."""

    clearance: np.ndarray  #: d − r − ρ (m)
    obstacle: np.ndarray  #: the nearest obstacle's index
    closing: np.ndarray  #: n · ċ: how fast that obstacle approaches the link's nearest point (m/s)
    escape: np.ndarray  #: v_max Σ_t |(∇_q d)ᵀ g0|_t: the fastest the point can move away along n (m/s)


def escape_speeds(arm: ArmParams, q: np.ndarray, centers: np.ndarray, velocities: np.ndarray, radii: np.ndarray,
                  link_radius: float, max_speed: float) -> LinkEscape:
    """:class:`LinkEscape` of each link of ``arm`` at joint angles ``q (n,)`` against obstacles ``centers``,
    ``velocities (O, 2)`` and ``radii (O,)``, with actuated joint speeds bounded by ``max_speed``."""
    q = np.asarray(q, dtype=float)
    radii = np.asarray(radii, dtype=float)
    if not max_speed > 0:
        raise ValueError(f"max_speed must be > 0, got {max_speed}")
    pairs = link_obstacle_barrier(arm, q, centers, radii, link_radius, velocities)  # h = d² − R², per (link, obstacle)
    # the distance barrier: the clearance d − R, (∇_q d)ᵀ g0 and ∂d/∂t = −n · ċ
    clear, row, dd_dt = shaped_barrier(pairs.h, radii + link_radius, "distance", pairs.row, pairs.dh_dt)
    nearest = np.argmin(clear, axis=1)
    links = np.arange(arm.n_links)
    return LinkEscape(clear[links, nearest], nearest, -dd_dt[links, nearest],
                      max_speed * np.abs(row[links, nearest]).sum(axis=-1))


def main(argv: list[str] | None = None) -> int:
    from pan1_env.baselines.policies import make_policy
    from pan1_env.environment import parallel_env
    from pan1_env.registration import env_arguments
    from pan1_env.wrappers import SafetyShield

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="pan1_env/WholeArmFormation-v1")
    parser.add_argument("--seed", type=int, required=True, help="the team's reset seed")
    parser.add_argument("--arm", type=int, required=True, help="the arm's index in the team")
    parser.add_argument("--start", type=float, default=0.0, help="s: the window's first step")
    parser.add_argument("--stop", type=float, default=5.0, help="s: the window's last step")
    parser.add_argument("--policy", default="reference")
    parser.add_argument("--no-shield", action="store_true", help="run the policy without the safety shield")
    args = parser.parse_args(argv)
    if not 0.0 <= args.start <= args.stop:
        parser.error(f"need 0 ≤ --start ≤ --stop, got {args.start} and {args.stop}")
    try:
        scenario, kwargs = env_arguments(args.task, {})
        env = parallel_env(scenario, **kwargs)
        env = env if args.no_shield else SafetyShield(env)
        policy = make_policy(args.policy, env, 0)
    except (TypeError, ValueError) as err:
        parser.error(str(err))
    obs, _ = env.reset(seed=args.seed)
    team = env.unwrapped
    drawn = team.scenario
    if not 0 <= args.arm < len(drawn.arms):
        parser.error(f"--arm must be in 0…{len(drawn.arms) - 1} for this team, got {args.arm}")
    arm, agent = drawn.arms[args.arm], team.possible_agents[args.arm]
    radii = drawn.obstacles.radii
    print(f"{args.task}, team {args.seed}, arm {args.arm}: {arm.n_links} links, "
          f"{'passive' if arm.passive_first_joint else 'actuated'} first joint; speed bound "
          f"{team.config.max_joint_speed} rad/s. Per link: clearance mm / closing m/s / escape m/s (nearest obstacle)")
    step, dt = 0, team.dt
    while env.agents and step * dt <= args.stop + 1e-9:
        now = step * dt
        q, qd = team.joint_state()
        obs, _, _, _, infos = env.step(policy(obs))
        step += 1
        if now < args.start - 1e-9:
            continue
        n = arm.n_links
        links = escape_speeds(arm, q[args.arm, :n], drawn.obstacle_centers(now), drawn.obstacle_velocities(now),
                              radii, drawn.link_radius, team.config.max_joint_speed)
        faced = "  ".join(f"L{ell}:{c * 1e3:+6.1f}/{v:+.2f}/{e:.2f}(o{o})"
                          for ell, (c, v, e, o) in enumerate(zip(links.clearance, links.closing, links.escape,
                                                                 links.obstacle, strict=True)))
        info = infos[agent]
        shield = "" if args.no_shield else (f" {_STATUS.get(int(info['shield_status']), '?'):8s} applied "
                                             f"{np.round(np.asarray(info['shield_applied'], float), 2)}")
        print(f"t={now:6.2f} {faced} |{shield} q̇ {np.round(qd[args.arm, :n], 2)} cost {info['cost']:.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
