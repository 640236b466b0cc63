"""Random scenarios: teams of arms, formations and obstacles drawn from a seeded generator.

:func:`random_scenario` draws a :class:`~pan1_env.scenario.Scenario` from ``numpy`` randomness only,
so the same generator state gives the same scenario. Every draw is checked to be

* **reachable** – the formation is placed in the plane first and every arm is built around a
  *target configuration* whose end-effector sits on its vertex; the start is joined to the target
  by a straight path in the actuated joints, along which the passive joint follows from the zero
  passive momentum (dq₁ = −M₁ₐ/M₁₁ dqₐ), so the target is reached from the start at rest;
* **collision-free at the start** – every end-effector starts at least ``start_clearance`` outside
  every obstacle, and no obstacle covers a formation vertex or a base;
* **regular at the start** – J̄ has full rank (Assumption 1), with σ_min(J̄) ≥ ``min_sigma``.

Arms start at rest (Lemma 1 needs it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cascade import reduced_jacobian
from .dynamics import ArmParams, end_effector, mass_matrix
from .formation import Formation, shape_positions
from .safety import Obstacles, clearance
from .scenario import Scenario
from .validation import positive_int, real, whole_ratio

__all__ = ["RandomScenarioOptions", "random_scenario"]


@dataclass(frozen=True)
class RandomScenarioOptions:
    """What :func:`random_scenario` draws.

    The team's structure (links and passive joints per arm) is fixed by the options, so the
    environments' spaces do not change between episodes; everything else is drawn.

    Attributes:
        n_arms: number of arms (≥ 2).
        links: links per arm: one integer for every arm, or one per arm (e.g. ``(2, 3, 4, 3)``).
        passive_fraction: fraction of arms whose first joint is passive: arms
            ``0 … round(passive_fraction · n_arms) − 1`` are PA arms, the rest fully actuated.
        n_obstacles: number of disk obstacles.
        shape: ``"polygon"`` (regular N-gon with fan diagonals) or ``"square"`` (N = 4).
        size: range of the formation's side length, metres.
        obstacle_radius: range of obstacle radii, metres.
        start_clearance: smallest clearance of a starting end-effector, metres.
        min_sigma: smallest singular value of J̄ at the start.
        kp: gain K_P of the nominal formation law of the drawn scenario.
        ke: gain K_e of the backstepping tracker of the drawn scenario.
        kappa: RCBF parameter κ of the drawn scenario.
        epsilon: RCBF parameter ε of the drawn scenario.
        physics_dt: physics (RK4) step of the drawn scenario, seconds.
        control_dt: control step of the drawn scenario, seconds.
        horizon: horizon of the drawn scenario, seconds.
    """

    n_arms: int = 4
    links: int | tuple[int, ...] = 3
    passive_fraction: float = 0.5
    n_obstacles: int = 3
    shape: str = "polygon"
    size: tuple[float, float] = (0.5, 0.9)
    obstacle_radius: tuple[float, float] = (0.05, 0.12)
    start_clearance: float = 0.05
    min_sigma: float = 0.05
    kp: float = 2.0
    ke: float = 100.0
    kappa: float = 0.5
    epsilon: float = 5.0
    physics_dt: float = 0.001
    control_dt: float = 0.001
    horizon: float = 100.0

    def __post_init__(self) -> None:
        n_arms = positive_int("RandomScenarioOptions.n_arms", self.n_arms, minimum=2)
        object.__setattr__(self, "n_arms", n_arms)
        links = self.links
        if isinstance(links, (int, np.integer)) and not isinstance(links, bool):
            links = (links,) * n_arms
        if not isinstance(links, (tuple, list)) or len(links) != n_arms:
            raise ValueError(f"RandomScenarioOptions.links must be an integer ≥ 2 or {n_arms} of them, "
                             f"got {self.links!r}")
        object.__setattr__(self, "links", tuple(positive_int("RandomScenarioOptions.links", n, minimum=2)
                                                for n in links))
        fraction = real("RandomScenarioOptions.passive_fraction", self.passive_fraction, non_negative=True)
        if fraction > 1:
            raise ValueError(f"RandomScenarioOptions.passive_fraction must lie in [0, 1], got {fraction!r}")
        object.__setattr__(self, "passive_fraction", fraction)
        object.__setattr__(self, "n_obstacles",
                           positive_int("RandomScenarioOptions.n_obstacles", self.n_obstacles, minimum=0))
        if self.shape not in ("polygon", "square"):
            raise ValueError(f"RandomScenarioOptions.shape must be 'polygon' or 'square', got {self.shape!r}")
        if self.shape == "square" and n_arms != 4:
            raise ValueError("RandomScenarioOptions.shape 'square' needs n_arms = 4")
        for name in ("size", "obstacle_radius"):
            value = getattr(self, name)
            if not isinstance(value, (tuple, list)) or len(value) != 2:
                raise ValueError(f"RandomScenarioOptions.{name} must be a range (low, high), got {value!r}")
            lo = real(f"RandomScenarioOptions.{name}[0]", value[0], positive=True)
            hi = real(f"RandomScenarioOptions.{name}[1]", value[1], positive=True)
            if lo > hi:
                raise ValueError(f"RandomScenarioOptions.{name} must have low ≤ high, got {value!r}")
            object.__setattr__(self, name, (lo, hi))
        for name in ("start_clearance", "min_sigma", "kp", "ke", "kappa", "epsilon", "physics_dt",
                     "control_dt", "horizon"):
            object.__setattr__(self, name, real(f"RandomScenarioOptions.{name}", getattr(self, name), positive=True))
        whole_ratio("RandomScenarioOptions.control_dt", self.control_dt, "physics_dt", self.physics_dt)

    @property
    def passive(self) -> tuple[bool, ...]:
        """Which arms have a passive first joint."""
        n_pa = int(round(self.passive_fraction * self.n_arms))
        return tuple(i < n_pa for i in range(self.n_arms))


def _passive_path(arm: ArmParams, q_target: np.ndarray, qa_start: np.ndarray, steps: int = 200) -> np.ndarray:
    """Start configuration joined to ``q_target`` by a straight path in the actuated joints."""
    if not arm.passive_first_joint:
        return qa_start.copy()
    s = np.linspace(0.0, 1.0, steps + 1)
    qa = q_target[1:] + s[:, None] * (qa_start - q_target[1:])
    q = np.concatenate([np.zeros((len(s), 1)), qa], axis=1)
    M = mass_matrix(arm, q)
    slope = -(M[:, 0, 1:] @ (qa_start - q_target[1:])) / M[:, 0, 0]  # dq1/ds
    q1 = q_target[0] + np.sum(0.5 * (slope[1:] + slope[:-1]) * np.diff(s))
    return np.concatenate([[q1], qa_start])


def _draw_arm(rng: np.random.Generator, n: int, passive: bool) -> ArmParams:
    lengths = rng.uniform(0.25, 0.5, n)
    masses = rng.uniform(0.2, 0.5, n)
    com = lengths * rng.uniform(0.35, 0.65, n)
    inertias = masses * lengths**2 / 12.0 * rng.uniform(0.8, 1.2, n)
    return ArmParams(masses, lengths, com, inertias, passive_first_joint=passive)


def random_scenario(rng: np.random.Generator, options: RandomScenarioOptions | None = None,
                    max_tries: int = 200) -> Scenario:
    """Draw a reachable, collision-free, regular scenario from ``rng`` (see the module docstring).

    Raises:
        RuntimeError: no valid draw within ``max_tries`` attempts (options too tight).
    """
    opt = options or RandomScenarioOptions()
    N = opt.n_arms
    for _ in range(max_tries):
        size = rng.uniform(*opt.size)
        pos, edges = shape_positions(opt.shape, size, N)
        rot = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
        targets = (pos - pos.mean(0)) @ R.T
        arms, q0 = [], []
        centroid = targets.mean(0)
        for i in range(N):
            n, passive = opt.links[i], opt.passive[i]
            proto = _draw_arm(rng, n, passive)
            # target configuration: a bent arm; the base goes where its end-effector meets vertex i
            q_t = rng.uniform(-np.pi, np.pi, n)
            q_t[1:] = rng.uniform(0.3, 1.2, n - 1) * rng.choice([-1.0, 1.0], n - 1)
            reach_vec = end_effector(proto, q_t) - proto.base
            outward = targets[i] - centroid
            outward /= np.linalg.norm(outward) + 1e-12
            # rotate the whole arm (through q_t[0]) so its base lies outside the formation
            ang_now = np.arctan2(reach_vec[0], reach_vec[1])
            ang_want = np.arctan2(-outward[0], -outward[1]) + rng.uniform(-0.6, 0.6)
            q_t[0] += ang_want - ang_now
            reach_vec = end_effector(proto, q_t) - proto.base
            base = targets[i] - reach_vec
            arm = ArmParams(proto.masses, proto.lengths, proto.com, proto.inertias, base=base,
                            passive_first_joint=passive)
            qa_start = q_t[1:] + rng.uniform(-1.0, 1.0, n - 1) if passive else \
                q_t + rng.uniform(-1.0, 1.0, n)
            arms.append(arm)
            q0.append(_passive_path(arm, q_t, qa_start))
        starts = np.array([end_effector(a, q) for a, q in zip(arms, q0, strict=True)])
        sig = [np.linalg.svd(reduced_jacobian(a, q), compute_uv=False).min()
               for a, q in zip(arms, q0, strict=True)]
        if min(sig) < opt.min_sigma:
            continue
        bases = np.array([a.base for a in arms])
        lo = np.minimum(starts.min(0), targets.min(0)) - 0.2
        hi = np.maximum(starts.max(0), targets.max(0)) + 0.2
        centers, radii = [], []
        for _ in range(50 * max(opt.n_obstacles, 1)):
            if len(radii) == opt.n_obstacles:
                break
            c = rng.uniform(lo, hi)
            r = rng.uniform(*opt.obstacle_radius)
            if (clearance(starts, c[None], np.array([r])).min() < opt.start_clearance
                    or np.linalg.norm(targets - c, axis=-1).min() < r + 0.05
                    or np.linalg.norm(bases - c, axis=-1).min() < r + 0.05
                    or any(np.linalg.norm(c - c2) < r + r2 for c2, r2 in zip(centers, radii, strict=True))):
                continue
            centers.append(c)
            radii.append(r)
        if len(radii) < opt.n_obstacles:
            continue
        formation = Formation.from_shape(opt.shape, size, N)
        for q in q0:
            q.setflags(write=False)
        return Scenario(
            name="random", description="drawn by pan1_env.random_scenario.random_scenario",
            arms=tuple(arms), q0=tuple(q0), formation=formation,
            obstacles=Obstacles(np.array(centers).reshape(-1, 2), np.array(radii)),
            kp=opt.kp, ke=opt.ke, kappa=opt.kappa, epsilon=opt.epsilon, physics_dt=opt.physics_dt,
            control_dt=opt.control_dt, horizon=opt.horizon, source="<random>",
        )
    raise RuntimeError(f"no valid random scenario in {max_tries} draws; loosen the options {opt}")
