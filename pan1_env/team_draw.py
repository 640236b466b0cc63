"""Random teams for many copies at once: the envs' draw at every reset of a random scenario.

:func:`draw_teams` gives the teams of the copies being reset as arrays (:class:`TeamDraws`), one team per copy from
that copy's own generator, so a copy's team depends on its generator only (not on which other copies reset with
it). The attempts run compiled (:mod:`pan1_env.draw_kernel`), the same attempts, in the same order, with the same
random numbers as :func:`pan1_env.random_scenario.random_scenario`, the reference: a team equals the reference's
from the same generator state up to floating-point rounding, and keeps every guarantee of that module's docstring.
The engine and the task load the arrays for all the copies at once (:meth:`pan1_env.engine.Engine.load_teams`);
:meth:`TeamDraws.scenario` builds a copy's :class:`~pan1_env.scenario.Scenario` only when something asks for it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .bodies import reachable_obstacles
from .dynamics import ArmParams
from .formation import Formation, shape_positions
from .random_scenario import BASE_MARGIN, DrawError, RandomScenarioOptions, draw_motion, drawn_scenario
from .scenario import Scenario

__all__ = ["TeamDraws", "Teams", "draw_teams", "check_numpy_streams"]


@dataclass
class TeamDraws:
    """The teams drawn for ``C`` copies (every array's first axis), from ``options``. Per arm ``(C, N, n_max)``
    (unused links 0): ``lengths``, ``masses``, ``com``, ``inertias``, ``q0``; ``lam (C, N, n_max, n_max)`` (λ);
    ``bases`` and ``targets`` (the placed vertices) ``(C, N, 2)``; ``joints (C, N, n_max + 1, 2)`` at the start;
    ``centers`` and ``path_ends`` ``(C, O, 2)``, ``radii`` and ``speeds`` ``(C, O)`` (a still obstacle's path
    end is its centre, its speed 0); ``size_rot (C, 2)``: the formation's side and the placement's turn;
    ``fault_times (C, N)`` (inf: none); ``motions``: each copy's formation motion (None: still)."""

    options: RandomScenarioOptions
    lengths: np.ndarray
    masses: np.ndarray
    com: np.ndarray
    inertias: np.ndarray
    lam: np.ndarray
    bases: np.ndarray
    q0: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    path_ends: np.ndarray
    speeds: np.ndarray
    size_rot: np.ndarray
    targets: np.ndarray
    joints: np.ndarray
    fault_times: np.ndarray
    motions: list

    @property
    def reach(self) -> np.ndarray:
        """Σ L_α of every arm, ``(C, N)``."""
        return self.lengths.sum(axis=-1)

    def obstacle_mask(self) -> np.ndarray:
        """:meth:`Scenario.obstacle_mask <pan1_env.scenario.Scenario.obstacle_mask>` of every copy, ``(C, N, O)``
        (drawn scenarios ignore unreachable obstacles)."""
        return reachable_obstacles(self.bases, self.reach, self.centers, self.path_ends, self.radii,
                                   self.options.link_radius)

    def distances(self, edges: np.ndarray) -> np.ndarray:
        """The formation's desired lengths on ``edges (E, 2)`` for every copy, ``(C, E)``, as
        :meth:`~pan1_env.formation.Formation.from_shape` computes them."""
        opt = self.options
        unit, divisor = _shape_unit(opt)
        pos = (self.size_rot[:, 0] / divisor)[:, None, None] * unit
        return np.linalg.norm(pos[:, edges[:, 0]] - pos[:, edges[:, 1]], axis=-1)

    def realisation(self, c: int) -> np.ndarray:
        """Copy ``c``'s formation realisation ``(N, 2)``: its Formation's ``target``."""
        unit, divisor = _shape_unit(self.options)
        return (self.size_rot[c, 0] / divisor) * unit

    def scenario(self, c: int) -> Scenario:
        """Copy ``c``'s team as a validated :class:`~pan1_env.scenario.Scenario` (what the reference returns)."""
        opt = self.options
        arms, q0 = [], []
        for i, (n, passive) in enumerate(zip(opt.links, opt.passive, strict=True)):
            arms.append(ArmParams(self.masses[c, i, :n], self.lengths[c, i, :n], self.com[c, i, :n],
                                  self.inertias[c, i, :n], base=self.bases[c, i], passive_first_joint=passive,
                                  passive_damping=opt.passive_damping))
            q = self.q0[c, i, :n].copy()
            q.setflags(write=False)
            q0.append(q)
        formation = Formation.from_shape(opt.shape, self.size_rot[c, 0], opt.n_arms)
        faults = self.fault_times[c].copy() if opt.fault_probability > 0 else None
        paths, speeds = (self.path_ends[c], self.speeds[c]) if opt.moving else (None, None)
        return drawn_scenario(opt, arms, q0, formation, self.centers[c], self.radii[c], paths, speeds, faults,
                              self.motions[c])


class Teams(list):
    """An engine's teams, one :class:`~pan1_env.scenario.Scenario` per copy: a drawn team (:meth:`put`) is built
    into its Scenario when first read, so that a reset pays for no Scenario nobody reads."""

    def put(self, b: int, draws: TeamDraws, c: int) -> None:
        """Copy ``b``'s team is team ``c`` of ``draws``."""
        super().__setitem__(b, (draws, c))

    def __getitem__(self, index):  # type: ignore[override]
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        item = super().__getitem__(index)
        if isinstance(item, tuple):
            item = item[0].scenario(item[1])
            super().__setitem__(index, item)
        return item

    def __iter__(self):
        return (self[i] for i in range(len(self)))

    def __reduce__(self):  # a copy or pickle keeps the teams not yet built as they are
        return Teams, (list(super().__iter__()),)


def _shape_unit(opt: RandomScenarioOptions) -> tuple[np.ndarray, float]:
    """The shape's vertices for side ``divisor`` (polygon: the unit circle's, divisor 2 sin(π/N); else side 1)."""
    N = opt.n_arms
    if opt.shape in ("polygon", "ring") and N > 2:
        ang = 2.0 * np.pi * np.arange(N) / N
        return np.stack([np.cos(ang), np.sin(ang)], axis=-1), 2.0 * np.sin(np.pi / N)
    return shape_positions(opt.shape, 1.0, N)[0], 1.0


@cache
def check_numpy_streams(k: int = 8) -> None:
    """Raise ``RuntimeError`` unless the kernel draws what this numpy's ``Generator.uniform``, ``choice([−1, 1])``
    and ``random`` draw, leaving the generator in the same state (checked once per process). numpy may change a
    distribution between releases; the envs' teams would then part from the reference's without a word."""
    from .draw_kernel import stream_sample

    kernel, numpy = np.random.default_rng(20261127), np.random.default_rng(20261127)
    drawn = np.empty(k), np.empty(k), np.empty(k)
    stream_sample(_addresses([kernel])[0], *drawn)
    expected = numpy.uniform(0.3, 1.2, k), numpy.choice([-1.0, 1.0], k), numpy.random(k)
    same = all(np.array_equal(a, b) for a, b in zip(drawn, expected, strict=True))
    if not same or kernel.bit_generator.state != numpy.bit_generator.state:
        raise RuntimeError(f"numpy {np.__version__} draws uniform, choice or random differently from what "
                           "pan1_env's team-draw kernel reproduces: random teams cannot be drawn; please report it")


def _addresses(rngs: list[np.random.Generator]) -> np.ndarray:
    """The address of each generator's ``bitgen_t`` (numpy's C API: its state and functions), ``(C,)`` int64."""
    return np.array([rng.bit_generator.ctypes.bit_generator.value for rng in rngs], dtype=np.int64)


def _kernel_options(opt: RandomScenarioOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's real and integer options, the arms' links and passive flags, and the shape's unit vertices."""
    from .draw_kernel import FLAG_OPTIONS, REAL_OPTIONS

    unit, divisor = _shape_unit(opt)
    values = {"size_lo": opt.size[0], "size_hi": opt.size[1], "radius_lo": opt.obstacle_radius[0],
              "radius_hi": opt.obstacle_radius[1], "start_clearance": opt.start_clearance, "min_sigma": opt.min_sigma,
              "link_radius": opt.link_radius, "speed_lo": opt.obstacle_speed[0], "speed_hi": opt.obstacle_speed[1],
              "path_lo": opt.obstacle_path_length[0], "path_hi": opt.obstacle_path_length[1],
              "fault_probability": opt.fault_probability, "fault_lo": opt.fault_time[0], "fault_hi": opt.fault_time[1],
              "shape_divisor": divisor, "base_margin": BASE_MARGIN}  # an argument: a cached kernel keeps no constant
    flags = {"n_obstacles": opt.n_obstacles, "links_bodies": opt.bodies == "links", "inter_arm": opt.inter_arm,
             "moving": opt.moving, "arm_redraws": opt.arm_redraws, "clear_paths": opt.moving and opt.clear_paths}
    return (np.array([values[n] for n in REAL_OPTIONS], dtype=float),
            np.array([flags[n] for n in FLAG_OPTIONS], dtype=np.int64),
            np.array(opt.links, dtype=np.int64), np.array(opt.passive, dtype=np.bool_), np.ascontiguousarray(unit))


def _empty(C: int, opt: RandomScenarioOptions) -> dict[str, np.ndarray]:
    """The kernel's output arrays for ``C`` copies (zeros; no fault: ``inf``)."""
    N, O, n = opt.n_arms, opt.n_obstacles, max(opt.links)
    arrays = {name: np.zeros((C, N, n)) for name in ("lengths", "masses", "com", "inertias", "q0")}
    arrays |= {"lam": np.zeros((C, N, n, n)), "bases": np.zeros((C, N, 2)), "targets": np.zeros((C, N, 2)),
               "joints": np.zeros((C, N, n + 1, 2)), "centers": np.zeros((C, O, 2)), "radii": np.zeros((C, O)),
               "path_ends": np.zeros((C, O, 2)), "speeds": np.zeros((C, O)), "size_rot": np.zeros((C, 2)),
               "fault_times": np.full((C, N), np.inf)}
    return arrays


def _run(rngs: list[np.random.Generator], tries: np.ndarray, arrays: dict[str, np.ndarray],
         opt: RandomScenarioOptions) -> np.ndarray:
    """Run the compiled draw for every generator into ``arrays``; returns each copy's attempts (−1: none valid)."""
    from .compile_notice import install
    from .draw_kernel import draw_teams as kernel

    install()  # the first use compiles the kernel: say so
    check_numpy_streams()

    real, flags, links, passive, unit = _kernel_options(opt)
    a = arrays
    return kernel(_addresses(rngs), tries, real, flags, links, passive, unit, a["lengths"], a["masses"], a["com"],
                  a["inertias"], a["lam"], a["bases"], a["q0"], a["centers"], a["radii"], a["path_ends"],
                  a["speeds"], a["size_rot"], a["targets"], a["joints"], a["fault_times"])


def draw_teams(rngs: list[np.random.Generator], options: RandomScenarioOptions | None = None,
               max_tries: int = 200) -> TeamDraws:
    """One team per generator (``C = len(rngs)``), each as :func:`~pan1_env.random_scenario.random_scenario`
    draws it from that generator (up to rounding), every generator left where the reference leaves it.

    Raises:
        DrawError: a copy found no valid team within ``max_tries`` attempts (options too tight).
    """
    opt = options or RandomScenarioOptions()
    C = len(rngs)
    arrays = _empty(C, opt)
    used = _run(rngs, np.full(C, max_tries, dtype=np.int64), arrays, opt)
    motions: list = [None] * C
    if opt.moving_formation:
        edges = Formation.from_shape(opt.shape, 1.0, opt.n_arms).edges
        for c in range(C):
            motions[c], used[c] = _motion(rngs[c], c, used[c], max_tries, arrays, opt, edges)
    if np.any(used > max_tries):
        raise DrawError(f"no valid random scenario in {max_tries} draws; loosen the options {opt}")
    return TeamDraws(opt, motions=motions, **arrays)


def _motion(rng: np.random.Generator, c: int, used: int, max_tries: int, arrays: dict[str, np.ndarray],
            opt: RandomScenarioOptions, edges: np.ndarray) -> tuple[object, int]:
    """Copy c's formation motion, drawn after its team as the reference draws it; a new team (the kernel's next
    attempts) while none is found. Returns the motion and the attempts used."""
    one = {name: value[c: c + 1] for name, value in arrays.items()}
    while used <= max_tries:
        lengths = one["lengths"][0]
        outer = lengths.sum(axis=-1)
        inner = np.maximum(0.0, 2.0 * lengths.max(axis=-1) - outer)  # ArmParams.inner_reach (unused links are 0)
        motion = draw_motion(rng, opt, one["targets"][0], one["bases"][0], inner, outer, one["centers"][0],
                             list(one["radii"][0]), one["size_rot"][0, 1], edges)
        if motion is not None:
            return motion, used
        if used == max_tries:
            break
        used += int(_run([rng], np.array([max_tries - used]), one, opt)[0])
    return None, max_tries + 1
