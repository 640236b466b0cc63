"""Random scenarios: teams of arms, formations and obstacles drawn from a seeded generator.

:func:`random_scenario` draws a :class:`~pan1_env.scenario.Scenario` from ``numpy`` randomness only,
so the same generator state gives the same scenario. Every draw is checked to be

* **reachable** – the formation is placed in the plane first and every arm is built around a
  *target configuration* whose end-effector sits on its vertex; the start is joined to the target
  by a straight path in the actuated joints, along which the passive joint follows from the zero
  passive momentum (dq₁ = −M₁ₐ/M₁₁ dqₐ), so the target is reached from the start at rest (with the
  frictionless passive joint; ``passive_damping`` > 0 lets the momentum leave zero on the way);
* **collision-free at the start** – every end-effector starts at least ``start_clearance`` outside
  every obstacle, and no obstacle covers a formation vertex or a base (it stays ``BASE_MARGIN`` clear);
  with ``bodies="links"`` every link capsule (radius ``link_radius``) starts ``start_clearance`` clear of
  every obstacle, and with ``inter_arm`` of every other arm's capsules;
* **moving obstacles clear of the bases** – with ``obstacle_speed`` above 0 each obstacle draws a speed
  and a path (direction uniform, length in ``obstacle_path_length``) whose every point keeps the
  obstacle ``BASE_MARGIN + link_radius`` clear of every base, so no base is ever hit, and, for a PA
  arm, clear of the disk its first link sweeps (radius L₀ more): that link moves only as the passive
  joint reacts, so an obstacle running into it could find the arm unable to get out of the way; with
  ``clear_paths`` the whole path (the capsule the disk sweeps) passes the checks a still obstacle passes
  at the start, so that every arm held still where it starts is never touched;
* **regular at the start** – J̄ has full rank (Assumption 1), with σ_min(J̄) ≥ ``min_sigma``.

Arms start at rest (Lemma 1 needs it). With the default options (end-effectors only, still
obstacles) no random number is drawn for the whole-arm options, so a seed's end-effector team does not
depend on them (the shipped models' held-out seeds stay the same teams).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .bodies import (
    closest_point_on_segment,
    inter_arm_clearance,
    link_clearance,
    link_segments,
    segment_distance,
)
from .cascade import reduced_jacobian
from .dynamics import ArmParams, end_effector, mass_matrix
from .formation import SHAPES, Formation, shape_positions
from .motion import FormationMotion, check_motion, check_times
from .safety import BARRIERS, FALLBACKS, FilterParams, Obstacles, clearance
from .scenario import BODIES, Scenario
from .validation import positive_int, real, whole_ratio

__all__ = ["RandomScenarioOptions", "random_scenario", "drawn_scenario", "draw_motion", "zero_momentum_start",
           "obstacles_at_size", "BASE_MARGIN", "DrawError"]

BASE_MARGIN = 0.05  # m: how far every obstacle (and, moving, its whole path) stays outside each base, plus ρ


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
        shape: ``"polygon"`` (regular N-gon with the fan of diagonals from arm 0, whose degree is N − 1),
            ``"ring"`` (the same N-gon with the chords that skip one arm: at most 4 neighbours per arm whatever
            N; :func:`pan1_env.formation.shape_positions`) or ``"square"`` (N = 4).
        arm_redraws: 0 (the default): an arm that fails its checks (σ_min(J̄), clearance to the other arms)
            fails the team's attempt, and the whole team is drawn again. k > 0: an arm failing its checks (against
            the arms drawn before it) is drawn again, up to k more times, keeping the arms that passed, so that a
            team of 32 arms is found at a cost that grows with N rather than exponentially. It changes the draws.
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
        bodies: what the drawn scenario protects, ``"end_effector"`` or ``"links"``.
        link_radius: capsule radius ρ of every link, metres (> 0 only with ``bodies="links"``).
        inter_arm: keep the arms' capsules apart (only with ``bodies="links"``).
        obstacle_speed: range of obstacle speeds, m/s; ``(0, 0)`` keeps the obstacles still.
        obstacle_path_length: range of the length of a moving obstacle's path, metres.
        clear_paths: every moving obstacle's whole path, the capsule its disk sweeps, keeps the start clearance
            from every starting end-effector (and, with links, every link) and 5 cm from every formation vertex:
            the team held still where it starts is never touched, and no target lies on a path. False (the
            default) checks the obstacle where it starts only; it draws no random number, so it changes the
            draws of moving obstacles only.
        barrier: the filter's barrier in the drawn scenario, ``"squared"`` (the paper's) or ``"distance"``.
        decay: λ ≥ 0 of the filter's tunable ε(h̃) = ε e^{λ h̃} in the drawn scenario (0: the paper's).
        gate: width (m) of the filter's smooth activation past its sensing range in the drawn scenario
            (0: a hard range; :class:`pan1_env.safety.FilterParams`).
        fallback: the whole-arm filter's last resort in the drawn scenario (:class:`pan1_env.safety.FilterParams`).
        lookahead: how far ahead (s) the whole-arm filter keeps moving obstacles' paths out in the drawn scenario
            (0: where they are; inf: their whole paths).
        fault_margin: whether the drawn scenario's filter keeps a lost actuator's drift stoppable short of the
            obstacles (:class:`pan1_env.safety.FilterParams`). None of these six changes what is drawn.
        passive_damping: viscous damping b ≥ 0 (N·m·s/rad) of every arm's first joint while it is passive
            (:class:`pan1_env.dynamics.ArmParams`; 0: the paper's frictionless joint). It changes no draw: the
            start is the frictionless arm's, from which the target is reached with p₁ = 0 (with damping p₁
            leaves 0 as the arm moves, docs/MODEL.md §7).
        fault_probability: the chance that a fully actuated arm loses its first joint's actuator during the
            episode (0: never, and the team is drawn as without the option; docs/MODEL.md §7).
        fault_time: the range (low, high) in seconds the fault's time is drawn from, within the horizon.
            The two fault options are drawn after everything else: a team with faults is the same seed's
            team without them, plus its fault times.
        formation_scale: the range (low, high) of the moving formation's scale s (docs/MODEL.md §8); the
            default (1, 1) keeps the shape still and draws nothing.
        scale_period: seconds between the scale's keyframes: s = 1 at 0 s, then at every multiple of the
            period within the horizon a scale drawn from ``formation_scale``, linear in between. Drawn after
            the faults, and redrawn (up to 20 times, then a new team) until every arm reaches its vertex of
            the drawn placement, scaled, at every scale between the lowest and highest keyframe (1 cm inside
            its reach annulus) and the scaled vertices stay 5 cm clear of the obstacles (where they start).
        formation_turn: the range (low, high) in rad of the placed shape's turn from the drawn placement at
            each keyframe after 0 s (the default (0, 0) places nothing). A turn or a travel places the shape
            (``FormationMotion.centre``): every arm is then asked to be at its own point, which is checked (1 cm
            inside its reach annulus, 5 cm clear of the obstacles) at the keyframes and between them.
        formation_travel: the range (low, high) in m of the placed centroid's distance from where it starts,
            at each keyframe after 0 s, in a direction drawn uniformly.
    """

    n_arms: int = 4
    links: int | tuple[int, ...] = 3
    passive_fraction: float = 0.5
    n_obstacles: int = 3
    shape: str = "polygon"
    arm_redraws: int = 0
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
    bodies: str = "end_effector"
    link_radius: float = 0.0
    inter_arm: bool = False
    obstacle_speed: tuple[float, float] = (0.0, 0.0)
    obstacle_path_length: tuple[float, float] = (0.2, 0.6)
    clear_paths: bool = False
    barrier: str = "squared"
    decay: float = 0.0
    gate: float = 0.0
    fallback: str = "command"
    lookahead: float = 0.0
    fault_margin: bool = False
    passive_damping: float = 0.0
    fault_probability: float = 0.0
    fault_time: tuple[float, float] = (1.0, 10.0)
    formation_scale: tuple[float, float] = (1.0, 1.0)
    scale_period: float = 15.0
    formation_turn: tuple[float, float] = (0.0, 0.0)
    formation_travel: tuple[float, float] = (0.0, 0.0)

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
        for name in ("n_obstacles", "arm_redraws"):
            object.__setattr__(self, name, positive_int(f"RandomScenarioOptions.{name}", getattr(self, name),
                                                        minimum=0))
        if self.shape not in SHAPES:
            raise ValueError(f"RandomScenarioOptions.shape must be one of {SHAPES}, got {self.shape!r}")
        if self.shape == "square" and n_arms != 4:
            raise ValueError("RandomScenarioOptions.shape 'square' needs n_arms = 4")
        for name in ("size", "obstacle_radius"):
            self._range(name, positive=True)
        for name in ("start_clearance", "min_sigma", "kp", "ke", "kappa", "epsilon", "physics_dt",
                     "control_dt", "horizon"):
            object.__setattr__(self, name, real(f"RandomScenarioOptions.{name}", getattr(self, name), positive=True))
        whole_ratio("RandomScenarioOptions.control_dt", self.control_dt, "physics_dt", self.physics_dt)
        self._check_bodies()

    def _check_bodies(self) -> None:
        if not isinstance(self.bodies, str) or self.bodies not in BODIES:
            raise ValueError(f"RandomScenarioOptions.bodies must be one of {BODIES}, got {self.bodies!r}")
        rho = real("RandomScenarioOptions.link_radius", self.link_radius, non_negative=True)
        object.__setattr__(self, "link_radius", rho)
        if not isinstance(self.inter_arm, (bool, np.bool_)):
            raise ValueError(f"RandomScenarioOptions.inter_arm must be True or False, got {self.inter_arm!r}")
        object.__setattr__(self, "inter_arm", bool(self.inter_arm))
        if self.bodies != "links" and (rho > 0 or self.inter_arm):
            raise ValueError("RandomScenarioOptions.link_radius > 0 and inter_arm=True need bodies='links', "
                             f"got bodies={self.bodies!r}, link_radius={rho}, inter_arm={self.inter_arm}")
        for name, positive in (("obstacle_speed", False), ("obstacle_path_length", True)):
            self._range(name, positive=positive, non_negative=True)
        if not isinstance(self.clear_paths, (bool, np.bool_)):
            raise ValueError(f"RandomScenarioOptions.clear_paths must be True or False, got {self.clear_paths!r}")
        object.__setattr__(self, "clear_paths", bool(self.clear_paths))
        if not isinstance(self.barrier, str) or self.barrier not in BARRIERS:
            raise ValueError(f"RandomScenarioOptions.barrier must be one of {BARRIERS}, got {self.barrier!r}")
        object.__setattr__(self, "decay", real("RandomScenarioOptions.decay", self.decay, non_negative=True))
        object.__setattr__(self, "gate", real("RandomScenarioOptions.gate", self.gate, non_negative=True))
        if not isinstance(self.fallback, str) or self.fallback not in FALLBACKS:
            raise ValueError(f"RandomScenarioOptions.fallback must be one of {FALLBACKS}, got {self.fallback!r}")
        object.__setattr__(self, "lookahead", real("RandomScenarioOptions.lookahead", self.lookahead,
                                                   non_negative=True, allow_inf=True))
        if not isinstance(self.fault_margin, (bool, np.bool_)):
            raise ValueError(f"RandomScenarioOptions.fault_margin must be True or False, got {self.fault_margin!r}")
        object.__setattr__(self, "fault_margin", bool(self.fault_margin))
        object.__setattr__(self, "passive_damping",
                           real("RandomScenarioOptions.passive_damping", self.passive_damping, non_negative=True))
        self._check_faults()

    def _check_faults(self) -> None:
        chance = real("RandomScenarioOptions.fault_probability", self.fault_probability, non_negative=True)
        if chance > 1:
            raise ValueError(f"RandomScenarioOptions.fault_probability must lie in [0, 1], got {chance!r}")
        object.__setattr__(self, "fault_probability", chance)
        # within the episode, where faults are drawn (the default range need not fit a short horizon without them)
        self._range("fault_time", " in seconds", horizon=self.horizon if chance > 0 else None, non_negative=True)
        self._range("formation_scale", positive=True)
        self._range("formation_turn")
        if max(np.abs(self.formation_turn)) > np.pi:
            raise ValueError(f"RandomScenarioOptions.formation_turn must lie within ±π (a turn from the drawn "
                             f"placement, rad), got {self.formation_turn!r}")
        self._range("formation_travel", " in m", non_negative=True)
        object.__setattr__(self, "scale_period", real("RandomScenarioOptions.scale_period", self.scale_period,
                                                      positive=True))

    def _range(self, name: str, unit: str = "", horizon: float | None = None, **bounds: bool) -> None:
        """Option ``name`` checked to be a range (low, high) of real numbers with ``bounds`` (:func:`real`'s),
        low ≤ high (≤ ``horizon`` if given), and stored as a tuple of floats."""
        value = getattr(self, name)
        if not isinstance(value, (tuple, list)) or len(value) != 2:
            raise ValueError(f"RandomScenarioOptions.{name} must be a range (low, high){unit}, got {value!r}")
        lo = real(f"RandomScenarioOptions.{name}[0]", value[0], **bounds)
        hi = real(f"RandomScenarioOptions.{name}[1]", value[1], **bounds)
        if horizon is not None and (lo > hi or hi > horizon):
            raise ValueError(f"RandomScenarioOptions.{name} must have low ≤ high ≤ horizon ({horizon:g} s), "
                             f"got {value!r}")
        if lo > hi:
            raise ValueError(f"RandomScenarioOptions.{name} must have low ≤ high, got {value!r}")
        object.__setattr__(self, name, (lo, hi))

    @property
    def moving(self) -> bool:
        """Whether the drawn obstacles move (``obstacle_speed`` above 0)."""
        return self.obstacle_speed[1] > 0

    @property
    def moving_formation(self) -> bool:
        """Whether the drawn formation moves (``formation_scale`` other than (1, 1), or :attr:`placed_formation`)."""
        return self.formation_scale != (1.0, 1.0) or self.placed_formation

    @property
    def placed_formation(self) -> bool:
        """Whether the drawn shape is placed (``formation_turn`` or ``formation_travel`` other than (0, 0))."""
        return self.formation_turn != (0.0, 0.0) or self.formation_travel != (0.0, 0.0)

    @property
    def passive(self) -> tuple[bool, ...]:
        """Which arms have a passive first joint."""
        n_pa = int(round(self.passive_fraction * self.n_arms))
        return tuple(i < n_pa for i in range(self.n_arms))


def zero_momentum_start(arm: ArmParams, q_target: np.ndarray, qa_start: np.ndarray, steps: int = 200) -> np.ndarray:
    """The configuration with actuated angles ``qa_start`` that the arm reaches from ``q_target`` when its
    actuated joints move along the straight line between them and its passive first joint follows with
    zero passive momentum (M_11 q̇_1 + M_1a q̇_a = 0, integrated by the trapezoid rule over ``steps``).
    For a fully actuated arm: ``qa_start`` itself."""
    if not arm.passive_first_joint:
        return qa_start.copy()
    s = np.linspace(0.0, 1.0, steps + 1)
    qa = q_target[1:] + s[:, None] * (qa_start - q_target[1:])
    q = np.concatenate([np.zeros((len(s), 1)), qa], axis=1)
    M = mass_matrix(arm, q)
    slope = -(M[:, 0, 1:] @ (qa_start - q_target[1:])) / M[:, 0, 0]  # dq1/ds
    q1 = q_target[0] + np.sum(0.5 * (slope[1:] + slope[:-1]) * np.diff(s))
    return np.concatenate([[q1], qa_start])


class DrawError(RuntimeError, ValueError):
    """No team satisfies the options: a ``RuntimeError`` (the draw ran out of tries) and a ``ValueError`` (the
    options are the input at fault), so that the CLI reports it in one line."""


def _draw_arm(rng: np.random.Generator, n: int, passive: bool) -> ArmParams:
    lengths = rng.uniform(0.25, 0.5, n)
    masses = rng.uniform(0.2, 0.5, n)
    com = lengths * rng.uniform(0.35, 0.65, n)
    inertias = masses * lengths**2 / 12.0 * rng.uniform(0.8, 1.2, n)
    return ArmParams(masses, lengths, com, inertias, passive_first_joint=passive)


def obstacles_at_size(n_obstacles: int, n_arms: int, size: int) -> int:
    """The obstacles of a team of ``size`` arms at the density of ``n_obstacles`` per ``n_arms``, rounded half up (a
    task's teams of another size keep its density)."""
    return (2 * n_obstacles * size + n_arms) // (2 * n_arms)


def random_scenario(rng: np.random.Generator, options: RandomScenarioOptions | None = None,
                    max_tries: int = 200) -> Scenario:
    """Draw a reachable, collision-free, regular scenario from ``rng`` (see the module docstring).

    Raises:
        DrawError: (a ``RuntimeError``) no valid draw within ``max_tries`` attempts (options too tight).
    """
    opt = options or RandomScenarioOptions()
    N = opt.n_arms
    for _ in range(max_tries):
        size = rng.uniform(*opt.size)
        pos, edges = shape_positions(opt.shape, size, N)
        rot = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
        targets = (pos - pos.mean(0)) @ R.T
        drawn = _draw_arms(rng, opt, targets)
        if drawn is None:
            continue
        arms, q0 = drawn
        starts = np.array([end_effector(a, q) for a, q in zip(arms, q0, strict=True)])
        if not opt.arm_redraws and not all(_arm_passes(i, arms, q0, opt) for i in range(N)):
            continue  # drawn whole, checked whole (with arm_redraws each arm passed as it was drawn)
        bases = np.array([a.base for a in arms])
        lo = np.minimum(starts.min(0), targets.min(0)) - 0.2
        hi = np.maximum(starts.max(0), targets.max(0)) + 0.2
        centers, radii, paths, speeds = [], [], [], []
        rho = opt.link_radius
        # a PA arm's first link moves only as the passive joint reacts to the others: a moving obstacle
        # that sweeps into it can find the arm unable to get out of the way (an infeasible filter)
        passive_sweep = np.array([a.lengths[0] if a.passive_first_joint else 0.0 for a in arms])
        for _ in range(50 * max(opt.n_obstacles, 1)):
            if len(radii) == opt.n_obstacles:
                break
            c = rng.uniform(lo, hi)
            r = rng.uniform(*opt.obstacle_radius)
            if (clearance(starts, c[None], np.array([r])).min() < opt.start_clearance
                    or np.linalg.norm(targets - c, axis=-1).min() < r + 0.05
                    or np.linalg.norm(bases - c, axis=-1).min() < r + BASE_MARGIN + rho
                    or any(np.linalg.norm(c - c2) < r + r2 for c2, r2 in zip(centers, radii, strict=True))):
                continue
            if opt.bodies == "links" and not _links_clear(arms, q0, c, r, opt):
                continue
            if opt.moving:
                speed, end = _draw_path(rng, c, opt)
                x, _ = closest_point_on_segment(c, end, bases)
                if np.any(np.linalg.norm(bases - x, axis=-1) < r + BASE_MARGIN + rho + passive_sweep):
                    continue
                if opt.clear_paths and not _path_clear(arms, q0, starts, targets, c, end, r, opt):
                    continue
                paths.append(end)
                speeds.append(speed)
            centers.append(c)
            radii.append(r)
        if len(radii) < opt.n_obstacles:
            continue
        formation = Formation.from_shape(opt.shape, size, N)
        fault_times = None
        if opt.fault_probability > 0:  # drawn last: the team is the one drawn without faults
            faults = (rng.random(N) < opt.fault_probability) & ~np.array(opt.passive)
            fault_times = np.where(faults, rng.uniform(*opt.fault_time, N), np.inf)
        motion = None
        if opt.moving_formation:
            motion = draw_motion(rng, opt, targets, bases, np.array([a.inner_reach for a in arms]),
                                  np.array([a.reach for a in arms]), np.array(centers).reshape(-1, 2), radii, rot,
                                  formation.edges)
            if motion is None:
                continue
        for q in q0:
            q.setflags(write=False)
        paths_or_none = np.array(paths).reshape(-1, 2) if opt.moving else None
        return drawn_scenario(opt, arms, q0, formation, np.array(centers).reshape(-1, 2), np.array(radii),
                              paths_or_none, np.array(speeds) if opt.moving else None, fault_times, motion)
    raise DrawError(f"no valid random scenario in {max_tries} draws; loosen the options {opt}")


def _draw_arms(rng: np.random.Generator, opt: RandomScenarioOptions, targets: np.ndarray
               ) -> tuple[list[ArmParams], list[np.ndarray]] | None:
    """Every arm built around its vertex of ``targets (N, 2)``, with its start; with ``arm_redraws`` each arm
    drawn again while it fails :func:`_arm_passes` against the arms before it (None: one never passed)."""
    arms: list[ArmParams] = []
    q0: list[np.ndarray] = []
    centroid = targets.mean(0)
    for i in range(opt.n_arms):
        for _ in range(opt.arm_redraws + 1):
            arm, q = _placed_arm(rng, opt, i, targets[i], centroid)
            if not opt.arm_redraws or _arm_passes(i, [*arms, arm], [*q0, q], opt):
                break
        else:
            return None
        arms.append(arm)
        q0.append(q)
    return arms, q0


def _placed_arm(rng: np.random.Generator, opt: RandomScenarioOptions, i: int, target: np.ndarray,
                centroid: np.ndarray) -> tuple[ArmParams, np.ndarray]:
    """Arm i drawn, its base placed so that its end-effector meets ``target`` in a drawn bent configuration
    turned away from the formation's ``centroid``, and its start near that configuration."""
    n, passive = opt.links[i], opt.passive[i]
    proto = _draw_arm(rng, n, passive)
    q_t = rng.uniform(-np.pi, np.pi, n)
    q_t[1:] = rng.uniform(0.3, 1.2, n - 1) * rng.choice([-1.0, 1.0], n - 1)
    reach_vec = end_effector(proto, q_t) - proto.base
    outward = target - centroid
    outward /= np.linalg.norm(outward) + 1e-12
    # rotate the whole arm (through q_t[0]) so its base lies outside the formation
    ang_now = np.arctan2(reach_vec[0], reach_vec[1])
    ang_want = np.arctan2(-outward[0], -outward[1]) + rng.uniform(-0.6, 0.6)
    q_t[0] += ang_want - ang_now
    reach_vec = end_effector(proto, q_t) - proto.base
    arm = ArmParams(proto.masses, proto.lengths, proto.com, proto.inertias, base=target - reach_vec,
                    passive_first_joint=passive, passive_damping=opt.passive_damping)
    qa_start = q_t[1:] + rng.uniform(-1.0, 1.0, n - 1) if passive else q_t + rng.uniform(-1.0, 1.0, n)
    return arm, zero_momentum_start(arm, q_t, qa_start)


def _arm_passes(i: int, arms: list[ArmParams], q0: list[np.ndarray], opt: RandomScenarioOptions) -> bool:
    """Arm i regular at its start (σ_min(J̄) ≥ ``min_sigma``) and, with ``inter_arm``, its capsules
    ``start_clearance`` clear of arms 0 … i − 1's (so that all arms passing is every pair apart)."""
    if np.linalg.svd(reduced_jacobian(arms[i], q0[i]), compute_uv=False).min() < opt.min_sigma:
        return False
    return not opt.inter_arm or all(
        inter_arm_clearance(arms[i], q0[i], arms[j], q0[j], opt.link_radius).min() >= opt.start_clearance
        for j in range(i))


def drawn_scenario(opt: RandomScenarioOptions, arms: list[ArmParams], q0: list[np.ndarray], formation: Formation,
                   centers: np.ndarray, radii: np.ndarray, paths: np.ndarray | None, speeds: np.ndarray | None,
                   fault_times: np.ndarray | None, motion: FormationMotion | None) -> Scenario:
    """The :class:`~pan1_env.scenario.Scenario` of a drawn team (the reference's and the envs' batched draw's)."""
    return Scenario(
        name="random", description="drawn by pan1_env.random_scenario.random_scenario",
        arms=tuple(arms), q0=tuple(q0), formation=formation, obstacles=Obstacles(centers, radii),
        kp=opt.kp, ke=opt.ke, filter=FilterParams(opt.kappa, opt.epsilon, barrier=opt.barrier, decay=opt.decay,
                                                  gate=opt.gate, fallback=opt.fallback, lookahead=opt.lookahead,
                                                  fault_margin=opt.fault_margin),
        physics_dt=opt.physics_dt,
        control_dt=opt.control_dt, horizon=opt.horizon, source="<random>", bodies=opt.bodies,
        link_radius=opt.link_radius, inter_arm=opt.inter_arm, obstacle_paths=paths, obstacle_speeds=speeds,
        fault_times=fault_times,
        motion=motion,
    )


def draw_motion(rng: np.random.Generator, opt: RandomScenarioOptions, targets: np.ndarray, bases: np.ndarray,
                 inner: np.ndarray, outer: np.ndarray, centers: np.ndarray, radii: list[float], rot: float,
                 edges: np.ndarray) -> FormationMotion | None:
    """Keyframes every ``scale_period`` s (s = 1, no turn and no travel at 0 s) such that each arm reaches its
    vertex of the placement ``targets (N, 2)`` (centred on the origin, the formation's realisation turned by
    ``rot``), scaled, at every scale between the lowest and the highest, and those vertices stay 5 cm clear of
    the obstacles; for a placed shape, each arm's point at the keyframes and between them; and that the scenario's
    own check passes (:func:`~pan1_env.motion.check_motion`: the speeds among others). ``bases (N, 2)``, ``inner``
    and ``outer (N,)``: the arms' bases and reach annuli. None after 20 draws."""
    times = np.minimum(np.arange(0.0, opt.horizon + 1e-9, opt.scale_period), opt.horizon)  # arange may overshoot
    scale = np.linspace(0.0, 1.0, 21)
    K = len(times) - 1
    for _ in range(20):
        scales = np.concatenate([[1.0], rng.uniform(*opt.formation_scale, K)])
        if opt.placed_formation:
            turns = rot + np.concatenate([[0.0], rng.uniform(*opt.formation_turn, K)])
            heading = rng.uniform(-np.pi, np.pi, K)
            travel = rng.uniform(*opt.formation_travel, K)[:, None] * np.stack([np.cos(heading), np.sin(heading)], -1)
            motion = FormationMotion(times, scales, centre=np.zeros(2), turn_times=times, turns=turns,
                                     path_times=times, path=np.concatenate([np.zeros((1, 2)), travel]))
            try:
                vertices = motion.placement(_unturned(targets, rot), check_times(motion, opt.horizon))[0]  # (T, N, 2)
            except ValueError:  # too many samples to check: as any other motion the scenario would refuse
                continue
        else:
            motion = None  # built once the scales pass the checks below (a validated motion costs a millisecond)
            s = scales.min() + scale * (scales.max() - scales.min())
            vertices = s[:, None, None] * targets[None]  # (21, N, 2)
        dist = np.linalg.norm(vertices - bases, axis=-1)
        if np.any(dist > outer - 0.01) or np.any(dist < inner + 0.01):
            continue
        if len(radii) and clearance(vertices.reshape(-1, 2), centers, np.asarray(radii)).min() < 0.05:
            continue
        try:
            motion = FormationMotion(times, scales) if motion is None else motion
            check_motion(motion, _unturned(targets, rot), edges, bases, outer, opt.horizon, inner=inner)
        except ValueError:
            continue
        return motion
    return None


def _unturned(targets: np.ndarray, rot: float) -> np.ndarray:
    """The placement ``targets (N, 2)`` turned back by ``rot``: the formation's realisation, centred."""
    c, s = np.cos(rot), np.sin(rot)
    return targets @ np.array([[c, -s], [s, c]])


def _links_clear(arms: list[ArmParams], q0: list[np.ndarray], c: np.ndarray, r: float,
                 opt: RandomScenarioOptions) -> bool:
    """Every link capsule at least ``start_clearance`` outside the obstacle (c, r) at the start."""
    return all(link_clearance(arm, q, c[None], np.array([r]), opt.link_radius).min() >= opt.start_clearance
               for arm, q in zip(arms, q0, strict=True))


def _path_clear(arms: list[ArmParams], q0: list[np.ndarray], starts: np.ndarray, targets: np.ndarray,
                c: np.ndarray, end: np.ndarray, r: float, opt: RandomScenarioOptions) -> bool:
    """The capsule an obstacle (c, r) sweeps to ``end`` and back keeps the start clearance from every starting
    end-effector (and link, with ``bodies="links"``) and 5 cm from every formation vertex (``clear_paths``)."""
    x, _ = closest_point_on_segment(c, end, starts)
    if np.linalg.norm(starts - x, axis=-1).min() - r < opt.start_clearance:
        return False
    x, _ = closest_point_on_segment(c, end, targets)
    if np.linalg.norm(targets - x, axis=-1).min() < r + 0.05:
        return False
    if opt.bodies != "links":
        return True
    for arm, q in zip(arms, q0, strict=True):
        a, b = link_segments(arm, q)
        if segment_distance(a, b, c, end)[0].min() - r - opt.link_radius < opt.start_clearance:
            return False
    return True


def _draw_path(rng: np.random.Generator, c: np.ndarray, opt: RandomScenarioOptions) -> tuple[float, np.ndarray]:
    """A speed in (lo, hi] and a path end at a uniform direction and a length in ``obstacle_path_length``."""
    lo, hi = opt.obstacle_speed
    speed = hi - rng.uniform(0.0, hi - lo)
    angle = rng.uniform(-np.pi, np.pi)
    length = rng.uniform(*opt.obstacle_path_length)
    return float(speed), c + length * np.array([np.cos(angle), np.sin(angle)])
