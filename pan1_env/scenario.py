"""Scenario files: a team of arms, its formation, obstacles, gains and time steps, in TOML.

``load(name_or_path)`` reads a built-in scenario by name (see :func:`builtin_names`) or a TOML file
by path, validates every key, and returns a frozen :class:`Scenario`. Any problem raises
:class:`ScenarioError` naming the file, the key and what is wrong. The schema is documented in
the README ("Scenario files"); in short::

    name = "my_scenario"                  # optional; defaults to the file's stem
    description = "..."                   # optional
    [simulation]  physics_dt, control_dt, horizon          (seconds)
    [controller]  kp, ke                                   (K_P, K_e)
    [safety]      kappa, epsilon, margin = 0, ignore_unreachable_obstacles = true,
                  bodies = "end_effector" | "links", link_radius = 0, inter_arm = false,
                  barrier = "squared" | "distance", decay = 0, gate = 0 (m; a smooth activation past the sensing range),
                  fallback = "command" | "barrier_rate", lookahead = 0 (s; inf keeps moving obstacles' whole paths out),
                  fault_margin = false (keep a lost actuator's drift stoppable short of the obstacles)
    [arm_defaults] masses, lengths, com, inertias, passive_first_joint, phi,
                  passive_damping = 0 (N·m·s/rad at a passive first joint)   (optional)
    [[arms]]      base, q0, and any arm_defaults key to override it
    [formation]   shape = "square" | "polygon" | "ring" with size,  or  edges + distances (0-based arms)
    [formation.motion]  scale = [[t, s], ...], switch_distances, switch_time, switch_duration = 0, and to place
                  the shape centre = [x, y], turn = [[t, θ], ...] (rad), path = [[t, dx, dy], ...] (m)  (optional)
    [[obstacles]] center, radius, and for a moving obstacle path_end = [x, y] and speed (m/s)

Angles (``q0``, ``phi``, a turn's angles) are numbers in radians or strings such as ``"-3*pi/4"``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .bodies import (
    closest_point_on_segment,
    inter_arm_clearance,
    link_clearance,
    obstacle_centers,
    obstacle_velocities,
    reachable_obstacles,
)
from .dynamics import ArmParams
from .formation import Formation, FormationError
from .motion import FormationMotion, check_motion, switch_shape
from .safety import FilterParams, Obstacles, clearance
from .toml_values import FILTER_KEYS, ScenarioError, as_angle, filter_settings, known_keys, number, table, vector

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Scenario", "ScenarioError", "load", "from_dict", "builtin_names", "BODIES"]

#: What the ``[safety]`` table's ``bodies`` key may protect: the end-effectors (the paper) or every link.
BODIES = ("end_effector", "links")


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Arms are numbered from 0 (the paper numbers from 1).

    Whole-arm fields (the engine's filter protects what they say, docs/SCENARIOS.md): ``bodies`` ("end_effector"
    or "links"), ``link_radius`` ρ (m, the capsule radius of every link), ``inter_arm`` (keep the
    arms' capsules apart), and ``obstacle_paths (O, 2)`` / ``obstacle_speeds (O,)``: each obstacle
    goes back and forth between its centre and its path end at its speed (0: still; None: all still).
    """

    name: str
    description: str
    arms: tuple[ArmParams, ...]
    q0: tuple[np.ndarray, ...]
    formation: Formation
    obstacles: Obstacles
    kp: float
    ke: float
    #: the safety filter's settings (the ``[safety]`` table's κ, ε, margin and filter choices)
    filter: FilterParams
    physics_dt: float
    control_dt: float
    horizon: float
    ignore_unreachable_obstacles: bool = True
    source: str = field(default="<dict>", compare=False)
    bodies: str = "end_effector"
    link_radius: float = 0.0
    inter_arm: bool = False
    obstacle_paths: np.ndarray | None = None
    obstacle_speeds: np.ndarray | None = None
    #: ``(N,)`` s: when each arm's first joint loses its actuator (inf: never; docs/MODEL.md §7); None: no arm
    #: of this team or of the teams an engine loads after it can fault
    fault_times: np.ndarray | None = None
    #: how the desired shape moves (:class:`pan1_env.motion.FormationMotion`, docs/MODEL.md §8); None: it stands
    motion: FormationMotion | None = None

    def __post_init__(self) -> None:
        if self.bodies not in BODIES:
            raise ValueError(f"Scenario.bodies must be one of {BODIES}, got {self.bodies!r}")
        if not (math.isfinite(self.link_radius) and self.link_radius >= 0):
            raise ValueError(f"Scenario.link_radius must be finite and non-negative, got {self.link_radius!r}")
        if self.inter_arm and self.bodies != "links":
            raise ValueError('Scenario.inter_arm keeps link capsules apart: it needs bodies="links"')
        if not isinstance(self.filter, FilterParams):  # it validated its own fields when it was made
            raise ValueError("Scenario.filter must be a pan1_env.safety.FilterParams, got "
                             f"{type(self.filter).__name__}")
        n_obs = len(self.obstacles)
        if (self.obstacle_paths is None) != (self.obstacle_speeds is None):
            raise ValueError("Scenario.obstacle_paths and obstacle_speeds go together: give both or neither")
        if self.obstacle_paths is not None:
            paths = np.array(self.obstacle_paths, dtype=float).reshape(-1, 2)
            speeds = np.array(self.obstacle_speeds, dtype=float).reshape(-1)
            if len(paths) != n_obs or len(speeds) != n_obs or np.any(speeds < 0):
                raise ValueError(f"Scenario: obstacle_paths (O, 2) and obstacle_speeds (O,) ≥ 0 for the {n_obs} "
                                 f"obstacles, got shapes {paths.shape} and {speeds.shape}")
            paths.setflags(write=False)
            speeds.setflags(write=False)
            object.__setattr__(self, "obstacle_paths", paths)
            object.__setattr__(self, "obstacle_speeds", speeds)
        if self.fault_times is not None:
            object.__setattr__(self, "fault_times", self._checked_fault_times())
        if self.motion is not None:
            if not isinstance(self.motion, FormationMotion):
                raise ValueError(f"Scenario.motion must be a FormationMotion or None, got {type(self.motion).__name__}")
            try:
                check_motion(self.motion, self.formation.target, self.formation.edges,
                             np.array([a.base for a in self.arms]), np.array([a.reach for a in self.arms]),
                             self.horizon, inner=np.array([a.inner_reach for a in self.arms]))
            except ValueError as err:
                raise ValueError(f"Scenario.motion: {err}") from None

    def _checked_fault_times(self) -> np.ndarray:
        times = np.array(self.fault_times, dtype=float).reshape(-1)
        if len(times) != len(self.arms):
            raise ValueError(f"Scenario.fault_times needs one time per arm ({len(self.arms)}), got {len(times)}")
        for i, (t, arm) in enumerate(zip(times, self.arms, strict=True)):
            if np.isinf(t) and t > 0:
                continue
            if arm.passive_first_joint:
                raise ValueError(f"Scenario.fault_times[{i}]: arm {i}'s first joint is passive already; only a fully "
                                 f"actuated arm can lose its first joint's actuator")
            if not 0.0 <= t <= self.horizon:
                raise ValueError(f"Scenario.fault_times[{i}] must lie within the episode, [0, {self.horizon:g}] s "
                                 f"(inf: never), got {t!r}")
        times.setflags(write=False)
        return times

    @property
    def moving_obstacles(self) -> np.ndarray:
        """``(O,)`` booleans: which obstacles move."""
        if self.obstacle_speeds is None:
            return np.zeros(len(self.obstacles), dtype=bool)
        return self.obstacle_speeds > 0

    def obstacle_motion(self) -> tuple[np.ndarray, np.ndarray]:
        """Every obstacle's path end ``(O, 2)`` and speed ``(O,)``: its centre and 0 for a still one."""
        if self.obstacle_paths is None:
            return self.obstacles.centers, np.zeros(len(self.obstacles))
        return self.obstacle_paths, self.obstacle_speeds

    def obstacle_centers(self, t: float | np.ndarray) -> np.ndarray:
        """Obstacle centres at time ``t`` (s): ``(..., O, 2)`` (:func:`pan1_env.bodies.obstacle_centers`)."""
        return obstacle_centers(self.obstacles.centers, *self.obstacle_motion(), t)

    def obstacle_velocities(self, t: float | np.ndarray) -> np.ndarray:
        """Obstacle velocities at time ``t`` (s): ``(..., O, 2)`` (:func:`pan1_env.bodies.obstacle_velocities`)."""
        return obstacle_velocities(self.obstacles.centers, *self.obstacle_motion(), t)

    @property
    def n_arms(self) -> int:
        return len(self.arms)

    @property
    def substeps(self) -> int:
        """Physics sub-steps per control step."""
        return int(round(self.control_dt / self.physics_dt))

    def obstacle_mask(self) -> np.ndarray:
        """``(N, O)`` booleans: which obstacles each arm's safety filter considers.

        With ``ignore_unreachable_obstacles`` an obstacle that never comes within an arm's reach plus
        its radius (plus ``link_radius``) of the arm's base, anywhere on its path, is dropped for that
        arm: it can never be hit, and its RCBF row would only slow the arm down far from it
        (docs/PAPER_REPRODUCTION.md, Section 5.2).
        """
        if not self.ignore_unreachable_obstacles:
            return np.ones((self.n_arms, len(self.obstacles)), dtype=bool)
        bases, reach = np.array([arm.base for arm in self.arms]), np.array([arm.reach for arm in self.arms])
        return reachable_obstacles(bases, reach, self.obstacles.centers, self.obstacle_motion()[0],
                                   self.obstacles.radii, self.link_radius)


_TOP_KEYS = {"name", "description", "simulation", "controller", "safety", "arm_defaults", "arms",
             "formation", "obstacles", "faults"}
_ARM_PARAM_KEYS = {"masses", "lengths", "com", "inertias", "passive_first_joint", "phi", "passive_damping"}
_ARM_KEYS = _ARM_PARAM_KEYS | {"base", "q0"}

MAX_SUBSTEPS = 1_000_000  # physics sub-steps per control step


def _arm(entry: Any, defaults: Mapping[str, Any], src: str, index: int) -> tuple[ArmParams, np.ndarray]:
    prefix = f"arms[{index}]"
    known_keys(entry, prefix, src, _ARM_KEYS)
    merged = {**defaults, **entry}

    def where(key: str) -> str:
        """The key as the file spells it: a value inherited from [arm_defaults] is reported there."""
        return f"arm_defaults.{key}" if key not in entry and key in defaults else f"{prefix}.{key}"

    vectors = {}
    for key in ("masses", "lengths", "com", "inertias"):
        if key not in merged:
            raise ScenarioError(src, f"{prefix}.{key}", "missing (give it here or in [arm_defaults])")
        vectors[key] = vector(merged[key], src, where(key))
    # the odd one out is the list whose size most of the others disagree with (masses on a tie)
    sizes = [arr.size for arr in vectors.values()]
    n = max(sizes, key=lambda s: (sizes.count(s), s == vectors["masses"].size))
    for key, arr in vectors.items():
        if arr.size != n:
            others = [k for k, a in vectors.items() if a.size == n]
            raise ScenarioError(src, where(key), f"has {arr.size} entries but {', '.join(others)} "
                                f"{'has' if len(others) == 1 else 'have'} {n}: one per link")
    if n < 2:
        raise ScenarioError(src, where("masses"), "an arm needs at least 2 links")
    for key, arr in vectors.items():
        if np.any(arr <= 0):
            raise ScenarioError(src, where(key), f"must be positive, got {arr.tolist()}")
    if np.any(vectors["com"] > vectors["lengths"]):
        raise ScenarioError(src, where("com"), "each centre of mass must lie on its link "
                            f"(0 < com ≤ length), got com={vectors['com'].tolist()} "
                            f"lengths={vectors['lengths'].tolist()}")
    if "base" not in merged:
        raise ScenarioError(src, f"{prefix}.base", "missing")
    base = vector(merged["base"], src, f"{prefix}.base", size=2)
    phi = as_angle(merged.get("phi", 0.0), src, f"{prefix}.phi")
    passive = merged.get("passive_first_joint", True)
    if not isinstance(passive, bool):
        raise ScenarioError(src, f"{prefix}.passive_first_joint", f"expected true or false, got {passive!r}")
    if "q0" not in merged:
        raise ScenarioError(src, f"{prefix}.q0", "missing")
    q0_raw = merged["q0"]
    if not isinstance(q0_raw, list) or len(q0_raw) != n:
        raise ScenarioError(src, f"{prefix}.q0", f"expected a list of {n} angles, got {q0_raw!r}")
    q0 = np.array([as_angle(x, src, f"{prefix}.q0[{k}]") for k, x in enumerate(q0_raw)])
    table = entry if "passive_damping" in entry else defaults  # where the key is, for the error
    damping = number(table, "passive_damping", src, where("passive_damping").rpartition(".")[0], positive=False,
                      default=0.0)
    arm = ArmParams(base=base, phi=phi, passive_first_joint=passive, passive_damping=damping, **vectors)
    q0.setflags(write=False)
    return arm, q0


def from_dict(data: Mapping[str, Any], source: str = "<dict>", default_name: str = "scenario") -> Scenario:
    """Validate a parsed TOML document and build a :class:`Scenario`."""
    src = source
    if not isinstance(data, Mapping):
        raise ScenarioError(src, "<root>", "expected a table")
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise ScenarioError(src, sorted(unknown)[0], f"unknown key; allowed keys are {sorted(_TOP_KEYS)}")
    name = data.get("name", default_name)
    description = data.get("description", "")
    if not isinstance(name, str) or not name:
        raise ScenarioError(src, "name", f"expected a non-empty string, got {name!r}")
    if not isinstance(description, str):
        raise ScenarioError(src, "description", f"expected a string, got {description!r}")

    sim = table(data, "simulation", src, {"physics_dt", "control_dt", "horizon"})
    physics_dt = number(sim, "physics_dt", src, "simulation")
    control_dt = number(sim, "control_dt", src, "simulation", default=physics_dt)
    horizon = number(sim, "horizon", src, "simulation")
    ratio = control_dt / physics_dt
    if not ratio <= MAX_SUBSTEPS:
        raise ScenarioError(src, "simulation.control_dt", f"control_dt / physics_dt = {ratio:.3g} sub-steps per "
                            f"control step is more than {MAX_SUBSTEPS}")
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
        raise ScenarioError(src, "simulation.control_dt",
                            f"must be a whole multiple of physics_dt={physics_dt}, got {control_dt}")

    ctrl = table(data, "controller", src, {"kp", "ke"})
    kp = number(ctrl, "kp", src, "controller")
    ke = number(ctrl, "ke", src, "controller")
    saf = table(data, "safety", src, {"kappa", "epsilon", "margin", "ignore_unreachable_obstacles", "bodies",
                                       "link_radius", "inter_arm", *FILTER_KEYS})
    filter_params = FilterParams(number(saf, "kappa", src, "safety"), number(saf, "epsilon", src, "safety"),
                                 number(saf, "margin", src, "safety", positive=False, default=0.0),
                                 **filter_settings(saf, src))
    ignore = saf.get("ignore_unreachable_obstacles", True)
    if not isinstance(ignore, bool):
        raise ScenarioError(src, "safety.ignore_unreachable_obstacles", f"expected true or false, got {ignore!r}")
    bodies, link_radius, inter_arm = _bodies(saf, src)

    defaults = table(data, "arm_defaults", src, _ARM_PARAM_KEYS, required=False)
    arms_raw = data.get("arms")
    if not isinstance(arms_raw, list) or not arms_raw:
        raise ScenarioError(src, "arms", "missing: give at least one [[arms]] entry")
    built = [_arm(entry, defaults, src, i) for i, entry in enumerate(arms_raw)]
    arms = tuple(a for a, _ in built)
    q0 = tuple(q for _, q in built)

    form = table(data, "formation", src, {"shape", "size", "edges", "distances", "motion"})
    try:
        if "shape" in form:
            if "edges" in form or "distances" in form:
                raise ScenarioError(src, "formation", "give either shape + size or edges + distances, not both")
            if not isinstance(form["shape"], str):
                raise ScenarioError(src, "formation.shape", f"expected a string, got {form['shape']!r}")
            size = number(form, "size", src, "formation")
            formation = Formation.from_shape(form["shape"], size, len(arms))
        else:
            for key in ("edges", "distances"):
                if key not in form:
                    raise ScenarioError(src, f"formation.{key}", "missing (or give shape + size)")
            edges = form["edges"]
            if not isinstance(edges, list) or not all(
                isinstance(e, list) and len(e) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in e)
                for e in edges
            ):
                raise ScenarioError(src, "formation.edges", f"expected a list of [i, j] integer pairs, got {edges!r}")
            distances = vector(form["distances"], src, "formation.distances")
            formation = Formation.from_edges(edges, distances, len(arms))
    except FormationError as err:
        raise ScenarioError(src, "formation", str(err)) from None

    obs_raw = data.get("obstacles", [])
    if not isinstance(obs_raw, list):
        raise ScenarioError(src, "obstacles", "expected an array of tables [[obstacles]]")
    centers, radii, paths, speeds = [], [], [], []
    for j, entry in enumerate(obs_raw):
        key = f"obstacles[{j}]"
        known_keys(entry, key, src, {"center", "radius", "path_end", "speed"})
        if "center" not in entry:
            raise ScenarioError(src, f"{key}.center", "missing")
        centers.append(vector(entry["center"], src, f"{key}.center", size=2))
        radii.append(number(entry, "radius", src, key))
        paths.append(centers[-1])
        speeds.append(0.0)
        if "speed" in entry and "path_end" not in entry:
            raise ScenarioError(src, f"{key}.speed", "a speed without a path: give path_end = [x, y] too (the "
                                "obstacle goes back and forth between center and path_end)")
        if "path_end" in entry:
            if "speed" not in entry:
                raise ScenarioError(src, f"{key}.path_end", "a path without a speed: give speed (m/s, > 0) too")
            paths[-1] = vector(entry["path_end"], src, f"{key}.path_end", size=2)
            speeds[-1] = number(entry, "speed", src, key)
            if np.array_equal(paths[-1], centers[-1]):
                raise ScenarioError(src, f"{key}.path_end", f"equals center {centers[-1].tolist()}: a moving "
                                    "obstacle needs a path of positive length")
    obstacles = Obstacles(np.array(centers).reshape(-1, 2), np.array(radii))
    moving = any(s > 0 for s in speeds)
    obstacle_paths = np.array(paths).reshape(-1, 2) if moving else None
    obstacle_speeds = np.array(speeds) if moving else None

    from .dynamics import end_effector

    for i, (arm, q) in enumerate(zip(arms, q0, strict=True)):
        if len(obstacles):
            c = clearance(end_effector(arm, q), obstacles.centers, obstacles.radii)
            j = int(np.argmin(c))
            if c[j] <= 0:
                raise ScenarioError(src, f"arms[{i}].q0", f"the end-effector starts inside or on obstacle {j} "
                                    f"(clearance {c[j]:.4f} m); move the arm or the obstacle")
    rho = link_radius if bodies == "links" else 0.0
    _check_paths(obstacles, obstacle_paths, arms, rho, src)
    if bodies == "links":
        _check_link_starts(arms, q0, obstacles, rho, inter_arm, src)

    return Scenario(
        name=name, description=description, arms=arms, q0=q0, formation=formation,
        obstacles=obstacles, kp=kp, ke=ke, filter=filter_params, physics_dt=physics_dt,
        control_dt=control_dt, horizon=horizon,
        ignore_unreachable_obstacles=ignore, source=source, bodies=bodies, link_radius=link_radius,
        inter_arm=inter_arm, obstacle_paths=obstacle_paths, obstacle_speeds=obstacle_speeds,
        fault_times=_fault_times(data, arms, horizon, src),
        motion=_motion(form, formation, arms, horizon, src),
    )


def _keyframe_list(table: Mapping[str, Any], key: str, src: str, what: str, default: list,
                   angle: bool = False) -> np.ndarray:
    """``formation.motion.<key>``, a list of keyframes of ``len(default[0])`` numbers each, as ``(K, width)``
    (with ``angle``, ``[time, angle]`` pairs whose angle may be written as ``q0``'s are, e.g. ``"pi/4"``)."""
    keyframes = table.get(key, default)
    if not isinstance(keyframes, list) or not keyframes or not all(isinstance(k, list) for k in keyframes):
        raise ScenarioError(src, f"formation.motion.{key}", f"expected a list of {what}, got {keyframes!r}")
    width, out = len(default[0]), []
    for m, k in enumerate(keyframes):
        name = f"formation.motion.{key}[{m}]"
        if angle and len(k) == 2:
            out.append([*vector(k[:1], src, name), as_angle(k[1], src, name)])
        else:
            out.append(vector(k, src, name, size=width))
    return np.array(out, dtype=float)


def _motion(form: Mapping[str, Any], formation: Formation, arms: tuple[ArmParams, ...], horizon: float,
            src: str) -> FormationMotion | None:
    """``[formation.motion]`` as :attr:`Scenario.motion` (None without the table): ``scale``, a list of
    ``[time, scale]`` keyframes (default ``[[0, 1]]``), for a switch ``switch_distances`` (the edges' new
    lengths), ``switch_time`` and ``switch_duration``, and to place the shape ``centre`` with ``turn``
    (``[time, angle]``) and ``path`` (``[time, dx, dy]``) keyframes, checked against the team
    (:func:`pan1_env.motion.check_motion`)."""
    if "motion" not in form:
        return None
    table = known_keys(form["motion"], "formation.motion", src,
                        {"scale", "switch_distances", "switch_time", "switch_duration", "centre", "turn", "path"})
    keyframes = _keyframe_list(table, "scale", src, "[time, scale] pairs", [[0.0, 1.0]])
    placed = {}
    if "centre" in table:
        turn = _keyframe_list(table, "turn", src, "[time, angle] pairs", [[0.0, 0.0]], angle=True)
        path = _keyframe_list(table, "path", src, "[time, dx, dy] triples", [[0.0, 0.0, 0.0]])
        placed = {"centre": vector(table["centre"], src, "formation.motion.centre", size=2),
                  "turn_times": turn[:, 0], "turns": turn[:, 1], "path_times": path[:, 0], "path": path[:, 1:]}
    elif "turn" in table or "path" in table:
        raise ScenarioError(src, "formation.motion.centre", "a turn or a path places the shape: it needs centre = "
                            "[x, y], the point (m) where the shape's centroid starts")
    switch = {}
    if "switch_distances" in table:
        distances = vector(table["switch_distances"], src, "formation.motion.switch_distances")
        try:
            Formation.from_edges(formation.edges.tolist(), distances, formation.n_agents)
        except FormationError as err:
            raise ScenarioError(src, "formation.motion.switch_distances", str(err)) from None
        shape = switch_shape(formation.edges, distances, formation.target)
        if shape is None:
            raise ScenarioError(src, "formation.motion.switch_distances", "every realisation of these lengths found "
                                "next to the formation turns a triangle over on the way (the blend degenerates): "
                                "choose lengths closer to the formation's")
        switch = {"switch_shape": shape,
                  "switch_time": number(table, "switch_time", src, "formation.motion", positive=False),
                  "switch_duration": number(table, "switch_duration", src, "formation.motion", positive=False,
                                             default=0.0)}
    elif "switch_time" in table or "switch_duration" in table:
        raise ScenarioError(src, "formation.motion.switch_time", "a switch needs switch_distances (the edges' "
                            "lengths after it)")
    try:
        motion = FormationMotion(keyframes[:, 0], keyframes[:, 1], **switch, **placed)
        check_motion(motion, formation.target, formation.edges, np.array([a.base for a in arms]),
                     np.array([a.reach for a in arms]), horizon, inner=np.array([a.inner_reach for a in arms]))
    except ValueError as err:
        raise ScenarioError(src, "formation.motion", str(err)) from None
    return motion


def _fault_times(data: Mapping[str, Any], arms: tuple[ArmParams, ...], horizon: float, src: str) -> np.ndarray | None:
    """``[[faults]]`` entries ``{arm, time}`` as :attr:`Scenario.fault_times` (None without the key)."""
    if "faults" not in data:
        return None
    entries = data["faults"]
    if not isinstance(entries, list):
        raise ScenarioError(src, "faults", "expected an array of tables [[faults]]")
    times = np.full(len(arms), np.inf)
    for f, entry in enumerate(entries):
        key = f"faults[{f}]"
        known_keys(entry, key, src, {"arm", "time"})
        i = entry.get("arm")
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(arms):
            raise ScenarioError(src, f"{key}.arm", f"expected an arm index from 0 to {len(arms) - 1}, got {i!r}")
        if arms[i].passive_first_joint:
            raise ScenarioError(src, f"{key}.arm", f"arm {i}'s first joint is passive already: only a fully "
                                "actuated arm (passive_first_joint = false) can lose its first joint's actuator")
        if np.isfinite(times[i]):
            raise ScenarioError(src, f"{key}.arm", f"arm {i} has a fault already: one [[faults]] entry per arm")
        times[i] = number(entry, "time", src, key, positive=False)
        if times[i] > horizon:
            raise ScenarioError(src, f"{key}.time", f"{times[i]:g} s is after the episode's end "
                                f"(simulation.horizon = {horizon:g} s)")
    return times


def _bodies(saf: Mapping[str, Any], src: str) -> tuple[str, float, bool]:
    """``bodies``, ``link_radius`` and ``inter_arm`` of the ``[safety]`` table, checked together."""
    bodies = saf.get("bodies", "end_effector")
    if not isinstance(bodies, str) or bodies not in BODIES:
        raise ScenarioError(src, "safety.bodies", f"unknown protected bodies {bodies!r}; allowed values are "
                            + " or ".join(f'"{b}"' for b in BODIES))
    link_radius = number(saf, "link_radius", src, "safety", positive=False, default=0.0)
    inter_arm = saf.get("inter_arm", False)
    if not isinstance(inter_arm, bool):
        raise ScenarioError(src, "safety.inter_arm", f"expected true or false, got {inter_arm!r}")
    if bodies != "links" and link_radius > 0:
        raise ScenarioError(src, "safety.link_radius", f"{link_radius} has no effect with bodies = "
                            f'"{bodies}": set bodies = "links" or leave link_radius out')
    if bodies != "links" and inter_arm:
        raise ScenarioError(src, "safety.inter_arm", 'true needs bodies = "links": arms are kept apart link '
                            "by link")
    return bodies, link_radius, inter_arm


def _check_paths(obstacles: Obstacles, paths: np.ndarray | None, arms: tuple[ArmParams, ...], rho: float,
                 src: str) -> None:
    """No moving obstacle comes within a base's clearance anywhere on its path.

    A base's clearance, for obstacle j, is the disk of radius r_j + ρ about the base (ρ = link_radius
    with bodies = "links", else 0): the obstacle's disk must stay strictly outside it, as a start must
    be strictly clear (the end-effector check above), because a base cannot move out of the way.
    """
    if paths is None:
        return
    bases = np.array([arm.base for arm in arms])
    for j, (c, e, r) in enumerate(zip(obstacles.centers, paths, obstacles.radii, strict=True)):
        if np.array_equal(c, e):
            continue
        x, _ = closest_point_on_segment(c, e, bases)
        d = np.linalg.norm(bases - x, axis=-1)
        i = int(np.argmin(d))
        if d[i] <= r + rho:
            raise ScenarioError(src, f"obstacles[{j}].path_end", f"the path from center to path_end comes within "
                                f"{d[i]:.4f} m of arm {i}'s base, inside its clearance r + link_radius = "
                                f"{r + rho:.4f} m; a base cannot move out of the way")


def _check_link_starts(arms: tuple[ArmParams, ...], q0: tuple[np.ndarray, ...], obstacles: Obstacles,
                       rho: float, inter_arm: bool, src: str) -> None:
    """Every link capsule (radius ρ) clear of every obstacle at q0 and, with inter_arm, of other arms' capsules."""
    for i, (arm, q) in enumerate(zip(arms, q0, strict=True)):
        if len(obstacles):
            c = link_clearance(arm, q, obstacles.centers, obstacles.radii, rho)
            link, j = np.unravel_index(int(np.argmin(c)), c.shape)
            if c[link, j] <= 0:
                raise ScenarioError(src, f"arms[{i}].q0", f"link {link} starts inside or on obstacle {j} "
                                    f"(clearance {c[link, j]:.4f} m with link_radius {rho}); move the arm or "
                                    "the obstacle")
        if not inter_arm:
            continue
        for i2 in range(i):
            c = inter_arm_clearance(arms[i2], q0[i2], arm, q, rho)
            l2, link = np.unravel_index(int(np.argmin(c)), c.shape)
            if c[l2, link] <= 0:
                raise ScenarioError(src, f"arms[{i}].q0", f"link {link} starts touching link {l2} of arm {i2} "
                                    f"(clearance {c[l2, link]:.4f} m with link_radius {rho} on both); move one "
                                    "of the arms")


def builtin_names() -> list[str]:
    """Names of the scenarios shipped with the package."""
    files = resources.files("pan1_env.scenarios").iterdir()
    return sorted(Path(f.name).stem for f in files if f.name.endswith(".toml"))


def load(name_or_path: str | Path | Scenario) -> Scenario:
    """Load a built-in scenario by name, or a TOML scenario file by path.

    Raises:
        ScenarioError: the file is missing, not valid TOML, or fails validation.
    """
    if isinstance(name_or_path, Scenario):
        return name_or_path
    if not isinstance(name_or_path, (str, Path)):
        raise TypeError(f"scenario must be a name, a path or a Scenario, got {type(name_or_path).__name__}")
    text_name = str(name_or_path)
    path = Path(name_or_path)
    if text_name in builtin_names():
        res = resources.files("pan1_env.scenarios").joinpath(f"{text_name}.toml")
        raw, source = res.read_bytes(), f"<builtin {text_name}>"
    elif path.suffix == ".toml" or path.exists():
        if not path.is_file():
            raise ScenarioError(str(path), "<file>", "no such file")
        raw, source = path.read_bytes(), str(path)
    else:
        raise ScenarioError(text_name, "<name>",
                            f"not a built-in scenario ({', '.join(builtin_names())}) nor a .toml file")
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise ScenarioError(source, "<toml>", f"not valid TOML: {err}") from None
    return from_dict(data, source=source, default_name=path.stem if path.suffix else text_name)
