"""Scenario files: a team of arms, its formation, obstacles, gains and time steps, in TOML.

``load(name_or_path)`` reads a built-in scenario by name (see :func:`builtin_names`) or a TOML file
by path, validates every key, and returns a frozen :class:`Scenario`. Any problem raises
:class:`ScenarioError` naming the file, the key and what is wrong. The schema is documented in
the README ("Scenario files"); in short::

    name = "my_scenario"                  # optional; defaults to the file's stem
    description = "..."                   # optional
    [simulation]  physics_dt, control_dt, horizon          (seconds)
    [controller]  kp, ke                                   (K_P, K_e)
    [safety]      kappa, epsilon, margin = 0, ignore_unreachable_obstacles = true
    [arm_defaults] masses, lengths, com, inertias, passive_first_joint, phi   (optional)
    [[arms]]      base, q0, and any arm_defaults key to override it
    [formation]   shape = "square" | "polygon" with size,  or  edges + distances (0-based arms)
    [[obstacles]] center, radius

Angles (``q0``, ``phi``) are numbers in radians or strings such as ``"-3*pi/4"``.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .dynamics import ArmParams
from .formation import Formation, FormationError
from .safety import Obstacles, clearance

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["Scenario", "ScenarioError", "load", "from_dict", "builtin_names"]


class ScenarioError(ValueError):
    """An invalid scenario: the message names the source, the key and the problem."""

    def __init__(self, source: str, key: str, problem: str) -> None:
        self.source, self.key, self.problem = source, key, problem
        super().__init__(f"{source}: {key}: {problem}")


@dataclass(frozen=True)
class Scenario:
    """A validated scenario. Arms are numbered from 0 (the paper numbers from 1)."""

    name: str
    description: str
    arms: tuple[ArmParams, ...]
    q0: tuple[np.ndarray, ...]
    formation: Formation
    obstacles: Obstacles
    kp: float
    ke: float
    kappa: float
    epsilon: float
    physics_dt: float
    control_dt: float
    horizon: float
    safety_margin: float = 0.0
    ignore_unreachable_obstacles: bool = True
    source: str = field(default="<dict>", compare=False)

    @property
    def n_arms(self) -> int:
        return len(self.arms)

    @property
    def substeps(self) -> int:
        """Physics sub-steps per control step."""
        return int(round(self.control_dt / self.physics_dt))

    def obstacle_mask(self) -> np.ndarray:
        """``(N, O)`` booleans: which obstacles each arm's safety filter considers.

        With ``ignore_unreachable_obstacles`` an obstacle farther from an arm's base than its reach
        plus the radius is dropped for that arm: it can never be hit, and its RCBF row would only
        slow the arm down far from it (docs/PAPER_REPRODUCTION.md, Section 5.2).
        """
        mask = np.ones((self.n_arms, len(self.obstacles)), dtype=bool)
        if self.ignore_unreachable_obstacles:
            for i, arm in enumerate(self.arms):
                dist = np.linalg.norm(self.obstacles.centers - arm.base, axis=-1)
                mask[i] = dist <= arm.reach + self.obstacles.radii
        return mask


_TOP_KEYS = {"name", "description", "simulation", "controller", "safety", "arm_defaults", "arms",
             "formation", "obstacles"}
_ARM_PARAM_KEYS = {"masses", "lengths", "com", "inertias", "passive_first_joint", "phi"}
_ARM_KEYS = _ARM_PARAM_KEYS | {"base", "q0"}

_ANGLE = re.compile(
    r"^\s*(?P<sign>[+-])?\s*(?P<num>\d+(?:\.\d*)?|\.\d+)?\s*\*?\s*(?P<pi>pi|π)?"
    r"\s*(?:/\s*(?P<den>\d+(?:\.\d*)?))?\s*$"
)


MAX_SUBSTEPS = 1_000_000  # physics sub-steps per control step
MAX_MAGNITUDE = 1e9  # every number in a scenario file must satisfy |x| ≤ MAX_MAGNITUDE


def _float(value: int | float, src: str, key: str) -> float:
    """A TOML number as a float within ±MAX_MAGNITUDE (TOML integers can be arbitrarily large)."""
    if isinstance(value, int) and abs(value) > MAX_MAGNITUDE:
        raise ScenarioError(src, key, f"an integer of {len(str(abs(value)))} digits is out of range: numbers "
                            f"must lie within ±{MAX_MAGNITUDE:g}")
    out = float(value)
    if math.isfinite(out) and abs(out) > MAX_MAGNITUDE:
        raise ScenarioError(src, key, f"{out:g} is out of range: numbers must lie within ±{MAX_MAGNITUDE:g}")
    return out


def _angle(value: Any, src: str, key: str) -> float:
    if isinstance(value, bool):
        raise ScenarioError(src, key, f"expected an angle, got {value!r}")
    if isinstance(value, (int, float)):
        out = _float(value, src, key)
    elif isinstance(value, str):
        m = _ANGLE.match(value)
        if not m or not (m.group("num") or m.group("pi")):
            raise ScenarioError(src, key, f"cannot read angle {value!r}; write e.g. 0.5 or '-3*pi/4'")
        out = _float(float(m.group("num") or 1.0), src, key) * (math.pi if m.group("pi") else 1.0)
        if m.group("den"):
            den = _float(float(m.group("den")), src, key)
            if den == 0:
                raise ScenarioError(src, key, f"division by zero in angle {value!r}")
            out /= den
        if m.group("sign") == "-":
            out = -out
    else:
        raise ScenarioError(src, key, f"expected an angle (number or string like 'pi/3'), got {value!r}")
    if not math.isfinite(out):
        raise ScenarioError(src, key, f"angle must be finite, got {value!r}")
    return out


def _number(table: Mapping[str, Any], key: str, src: str, prefix: str, *, positive: bool = True,
            default: float | None = None) -> float:
    full = f"{prefix}.{key}"
    if key not in table:
        if default is None:
            raise ScenarioError(src, full, "missing")
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(src, full, f"expected a number, got {value!r}")
    value = _float(value, src, full)
    if not math.isfinite(value):
        raise ScenarioError(src, full, f"must be finite, got {value!r}")
    if positive and value <= 0:
        raise ScenarioError(src, full, f"must be positive, got {value!r}")
    if not positive and value < 0:
        raise ScenarioError(src, full, f"must be non-negative, got {value!r}")
    return value


def _vector(value: Any, src: str, key: str, size: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ScenarioError(src, key, f"expected a non-empty list of numbers, got {value!r}")
    if any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in value):
        raise ScenarioError(src, key, f"expected a list of numbers, got {value!r}")
    arr = np.array([_float(x, src, key) for x in value], dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(src, key, f"values must be finite, got {value!r}")
    if size is not None and arr.size != size:
        raise ScenarioError(src, key, f"expected {size} numbers, got {arr.size}")
    return arr


def _table(data: Mapping[str, Any], key: str, src: str, allowed: set[str],
           required: bool = True) -> dict[str, Any]:
    if key not in data:
        if required:
            raise ScenarioError(src, key, "missing table")
        return {}
    return _known_keys(data[key], key, src, allowed)


def _known_keys(table: Any, key: str, src: str, allowed: set[str]) -> dict[str, Any]:
    """``table`` checked to be a TOML table whose keys are all in ``allowed``."""
    if not isinstance(table, dict):
        raise ScenarioError(src, key, f"expected a table, got {type(table).__name__}")
    unknown = set(table) - allowed
    if unknown:
        raise ScenarioError(src, f"{key}.{sorted(unknown)[0]}", f"unknown key; allowed keys are {sorted(allowed)}")
    return table


def _arm(entry: Any, defaults: Mapping[str, Any], src: str, index: int) -> tuple[ArmParams, np.ndarray]:
    prefix = f"arms[{index}]"
    _known_keys(entry, prefix, src, _ARM_KEYS)
    merged = {**defaults, **entry}
    vectors = {}
    for key in ("masses", "lengths", "com", "inertias"):
        if key not in merged:
            raise ScenarioError(src, f"{prefix}.{key}", "missing (give it here or in [arm_defaults])")
        vectors[key] = _vector(merged[key], src, f"{prefix}.{key}")
    n = vectors["masses"].size
    for key, arr in vectors.items():
        if arr.size != n:
            raise ScenarioError(src, f"{prefix}.{key}",
                                f"has {arr.size} entries but masses has {n}: one per link")
    if n < 2:
        raise ScenarioError(src, f"{prefix}.masses", "an arm needs at least 2 links")
    for key, arr in vectors.items():
        if np.any(arr <= 0):
            raise ScenarioError(src, f"{prefix}.{key}", f"must be positive, got {arr.tolist()}")
    if np.any(vectors["com"] > vectors["lengths"]):
        raise ScenarioError(src, f"{prefix}.com", "each centre of mass must lie on its link "
                            f"(0 < com ≤ length), got com={vectors['com'].tolist()} "
                            f"lengths={vectors['lengths'].tolist()}")
    if "base" not in merged:
        raise ScenarioError(src, f"{prefix}.base", "missing")
    base = _vector(merged["base"], src, f"{prefix}.base", size=2)
    phi = _angle(merged.get("phi", 0.0), src, f"{prefix}.phi")
    passive = merged.get("passive_first_joint", True)
    if not isinstance(passive, bool):
        raise ScenarioError(src, f"{prefix}.passive_first_joint", f"expected true or false, got {passive!r}")
    if "q0" not in merged:
        raise ScenarioError(src, f"{prefix}.q0", "missing")
    q0_raw = merged["q0"]
    if not isinstance(q0_raw, list) or len(q0_raw) != n:
        raise ScenarioError(src, f"{prefix}.q0", f"expected a list of {n} angles, got {q0_raw!r}")
    q0 = np.array([_angle(x, src, f"{prefix}.q0[{k}]") for k, x in enumerate(q0_raw)])
    arm = ArmParams(base=base, phi=phi, passive_first_joint=passive, **vectors)
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

    sim = _table(data, "simulation", src, {"physics_dt", "control_dt", "horizon"})
    physics_dt = _number(sim, "physics_dt", src, "simulation")
    control_dt = _number(sim, "control_dt", src, "simulation", default=physics_dt)
    horizon = _number(sim, "horizon", src, "simulation")
    ratio = control_dt / physics_dt
    if not ratio <= MAX_SUBSTEPS:
        raise ScenarioError(src, "simulation.control_dt", f"control_dt / physics_dt = {ratio:.3g} sub-steps per "
                            f"control step is more than {MAX_SUBSTEPS}")
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
        raise ScenarioError(src, "simulation.control_dt",
                            f"must be a whole multiple of physics_dt={physics_dt}, got {control_dt}")

    ctrl = _table(data, "controller", src, {"kp", "ke"})
    kp = _number(ctrl, "kp", src, "controller")
    ke = _number(ctrl, "ke", src, "controller")
    saf = _table(data, "safety", src, {"kappa", "epsilon", "margin", "ignore_unreachable_obstacles"})
    kappa = _number(saf, "kappa", src, "safety")
    epsilon = _number(saf, "epsilon", src, "safety")
    margin = _number(saf, "margin", src, "safety", positive=False, default=0.0)
    ignore = saf.get("ignore_unreachable_obstacles", True)
    if not isinstance(ignore, bool):
        raise ScenarioError(src, "safety.ignore_unreachable_obstacles", f"expected true or false, got {ignore!r}")

    defaults = _table(data, "arm_defaults", src, _ARM_PARAM_KEYS, required=False)
    arms_raw = data.get("arms")
    if not isinstance(arms_raw, list) or not arms_raw:
        raise ScenarioError(src, "arms", "missing: give at least one [[arms]] entry")
    built = [_arm(entry, defaults, src, i) for i, entry in enumerate(arms_raw)]
    arms = tuple(a for a, _ in built)
    q0 = tuple(q for _, q in built)

    form = _table(data, "formation", src, {"shape", "size", "edges", "distances"})
    try:
        if "shape" in form:
            if "edges" in form or "distances" in form:
                raise ScenarioError(src, "formation", "give either shape + size or edges + distances, not both")
            if not isinstance(form["shape"], str):
                raise ScenarioError(src, "formation.shape", f"expected a string, got {form['shape']!r}")
            size = _number(form, "size", src, "formation")
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
            distances = _vector(form["distances"], src, "formation.distances")
            formation = Formation.from_edges(edges, distances, len(arms))
    except FormationError as err:
        raise ScenarioError(src, "formation", str(err)) from None

    obs_raw = data.get("obstacles", [])
    if not isinstance(obs_raw, list):
        raise ScenarioError(src, "obstacles", "expected an array of tables [[obstacles]]")
    centers, radii = [], []
    for j, entry in enumerate(obs_raw):
        key = f"obstacles[{j}]"
        _known_keys(entry, key, src, {"center", "radius"})
        if "center" not in entry:
            raise ScenarioError(src, f"{key}.center", "missing")
        centers.append(_vector(entry["center"], src, f"{key}.center", size=2))
        radii.append(_number(entry, "radius", src, key))
    obstacles = Obstacles(np.array(centers).reshape(-1, 2), np.array(radii))

    from .dynamics import end_effector

    for i, (arm, q) in enumerate(zip(arms, q0, strict=True)):
        if len(obstacles):
            c = clearance(end_effector(arm, q), obstacles.centers, obstacles.radii)
            j = int(np.argmin(c))
            if c[j] <= 0:
                raise ScenarioError(src, f"arms[{i}].q0", f"the end-effector starts inside or on obstacle {j} "
                                    f"(clearance {c[j]:.4f} m); move the arm or the obstacle")

    return Scenario(
        name=name, description=description, arms=arms, q0=q0, formation=formation,
        obstacles=obstacles, kp=kp, ke=ke, kappa=kappa, epsilon=epsilon, physics_dt=physics_dt,
        control_dt=control_dt, horizon=horizon, safety_margin=margin,
        ignore_unreachable_obstacles=ignore, source=source,
    )


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
