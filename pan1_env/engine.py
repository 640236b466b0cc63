"""The engine: B copies of a team, stepped by one call of the compiled sub-step kernel per arm kind.

:class:`Engine` is the one owner of stepping. It holds the state of every arm of B copies of a
team in arrays batched over ``B × (arms of one kind)`` (an arm kind is a number of links and an
actuation; copies are stacked copy-major) and the safety filter's parameters; its step runs them
through the sub-step kernel (:func:`pan1_env.kernels.group_advance`, or its multi-threaded twin for
large batches), whose calls :mod:`pan1_env.kernel_step` makes. A step holds one command per arm for
a number of physics sub-steps; at every sub-step the kernel filters the command through the RCBF-QP
(when the filter is on), tracks it with the backstepping law in velocity mode, and takes one RK4 step
(docs/MODEL.md). It returns a :class:`StepRecord`. What a step *means* (observations, rewards, cost,
success) is a task's (:mod:`pan1_env.tasks`); the environments are adapters over an engine and a
task, and B = 1 is a batch of one.

The filter's QP runs in the kernel (``qp_solver="active_set"``, exact:
:class:`~pan1_env.kernel_step.KernelQP`, whose calls of the kernel live in :mod:`pan1_env.kernel_step`); with
``"piqp"`` the engine is given a :class:`~pan1_env.piqp_filter.PiqpFilter`, which solves the same rows
(the paper's end-effector rows, or the whole-arm rows) with qpsolvers + PIQP instead, one sub-step at
a time (velocity mode, one copy; slow, for cross-checks). A step goes through the one it was given.
"""

from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, replace

import numpy as np

from .bodies import arm_pair_floors, capsule_clearance, obstacle_floors, obstacle_velocities
from .compiled import kernels
from .kernel_groups import EndEffectorObstacles, WholeArm, plain
from .kernel_step import KernelQP
from .kinds import Kind
from .piqp_filter import PiqpFilter
from .safety import QP_SOLVERS, FilterParams, check_choices, clearance, filter_parameters
from .scenario import Scenario
from .step_record import StepRecord
from .team_draw import TeamDraws, Teams
from .validation import real

__all__ = ["Engine", "Physics", "FilterParams", "KindTerms", "StepRecord", "filter_parameters", "PARALLEL_THRESHOLD",
           "SENSING_RADIUS", "BRAKING_SENSING_RADIUS", "SKIN"]

PARALLEL_THRESHOLD = 256  # arms of one kind from which the kernel runs on numba's thread pool
FLOOR_SLACK = 1e-9  #: m taken off the capsules' floors (Engine._load_capsules)
#: m: with whole-arm safety, a body's filter takes a row for a capsule only when their clearance is at
#: most this plus what the gap can close in a sub-step (:func:`pan1_env.kernels.capsules.whole_arm_rows`)
SENSING_RADIUS = 0.1
#: m: the range instead with torque mode's bound, from where an arm at full speed can still brake within it
#: (docs/MODEL.md §5d: at 0.1 m, bang-bang torques drove links 130 mm into obstacles)
BRAKING_SENSING_RADIUS = 1.0
#: m: with whole-arm safety the filter keeps every capsule this much (plus an obstacle's travel in one
#: sub-step) farther out than its radius, against what a sub-step's discretisation lets through
SKIN = 0.002


#: :meth:`Engine.kind_terms`: a kind's end-effectors, reduced Jacobians, passive momenta and end-effector drifts
KindTerms = namedtuple("KindTerms", "p Jbar momentum drift")


@dataclass(frozen=True)
class Physics:
    """How an engine steps its arms, beside the team: an env config's ``physics_dt``, ``max_joint_speed``, the
    bound on the filter's own torques and ``qp_solver`` (:attr:`pan1_env.config.FormationConfig.physics` is this
    part of a config).

    Attributes:
        physics_dt: the RK4 sub-step, seconds (None: the scenario's).
        max_joint_speed: with the filter on, its QP also bounds every filtered speed by this (rad/s).
        max_torque: with the filter on in torque mode, its QP also bounds by this (N·m) every actuated joint's torque
            where it changes the command (docs/MODEL.md §5d); a command's own torque is the caller's to bound (the
            envs' actions are at most ±``max_torque``). inf: no bound.
        qp_solver: ``"active_set"`` (exact, in the kernel: :class:`~pan1_env.kernel_step.KernelQP`) or ``"piqp"``
            (the same rows, whole-arm ones included, solved by qpsolvers + PIQP:
            :class:`~pan1_env.piqp_filter.PiqpFilter`; one copy, velocity mode only).
    """

    physics_dt: float | None = None
    max_joint_speed: float = np.inf
    max_torque: float = np.inf
    qp_solver: str = "active_set"

    def __post_init__(self) -> None:
        if self.physics_dt is not None:
            object.__setattr__(self, "physics_dt", real("physics_dt", self.physics_dt, positive=True))
        for name in ("max_joint_speed", "max_torque"):
            object.__setattr__(self, name, real(name, getattr(self, name), positive=True, allow_inf=True))
        if self.qp_solver not in QP_SOLVERS:
            raise ValueError(f"unknown qp_solver {self.qp_solver!r}; choose one of {QP_SOLVERS}")


#: the keywords an engine took one by one before they were one Physics, and their names there (_refuse_loose)
_LOOSE = {"physics_dt": "physics_dt", "max_speed": "max_joint_speed", "max_torque": "max_torque",
          "qp_solver": "qp_solver"}


def _refuse_loose(loose: dict) -> None:
    """TypeError for keywords an engine does not take: its old loose settings with the Physics call instead."""
    unknown = sorted(set(loose) - set(_LOOSE))
    if unknown:
        raise TypeError(f"Engine() got an unexpected keyword argument {unknown[0]!r}")
    given = ", ".join(f"{_LOOSE[key]}={value!r}" for key, value in loose.items())
    raise TypeError(f"Engine takes how it steps as one Physics: Engine(scenario, copies, physics=Physics({given})), "
                    "not one by one")


def _physics(physics: Physics) -> Physics:
    if not isinstance(physics, Physics):
        raise TypeError(f"Engine: physics must be a pan1_env.engine.Physics, got {type(physics).__name__}")
    return physics


class Engine:
    """B copies of a team's arms and the safety filter, stepped through the sub-step kernel (by
    :mod:`pan1_env.kernel_step`).

    Args:
        scenario: the team (every copy starts as this one; :meth:`load_team` puts another team of the
            same structure into a copy, e.g. a new random team at a reset).
        copies: B.
        physics: the sub-step, the filter's speed and torque bounds and its QP solver (:class:`Physics`; default:
            the scenario's sub-step, no bounds, the kernel's active set). ``engine.physics`` may be replaced between
            steps (a new bound, say); the filter's choices are checked against it when the filter is set.
        safety_filter: ``False``, ``True`` (the scenario's κ, ε, margin) or a :class:`FilterParams`.
        threads: ``"auto"`` (numba's thread pool from :data:`PARALLEL_THRESHOLD` arms of a kind),
            ``True`` or ``False``; the two kernels give the same results bit for bit.
    """

    def __init__(self, scenario: Scenario, copies: int = 1, physics: Physics | None = None, *,
                 safety_filter: bool | FilterParams = False, threads: bool | str = "auto", **loose) -> None:
        if loose:
            _refuse_loose(loose)
        physics = _physics(Physics() if physics is None else physics)
        if threads not in ("auto", True, False):
            raise ValueError(f"threads must be 'auto', True or False, got {threads!r}")
        self._physics = physics if physics.physics_dt is not None else replace(physics,
                                                                                physics_dt=scenario.physics_dt)
        #: the solver of the filter's QPs, which a step goes through
        self.qp: KernelQP | PiqpFilter = PiqpFilter() if physics.qp_solver == "piqp" else KernelQP()
        self.qp.check(int(copies), faults=scenario.fault_times is not None)
        self.copies, self.threads = int(copies), threads
        self.ke = scenario.ke
        self.n_arms = scenario.n_arms
        self.n_links = [a.n_links for a in scenario.arms]
        self.n_actuated = [a.n_actuated for a in scenario.arms]
        self.n_max, self.k_max = max(self.n_links), max(self.n_actuated)
        kinds: dict[tuple[int, bool], list[int]] = {}
        for i, arm in enumerate(scenario.arms):
            kinds.setdefault((arm.n_links, arm.passive_first_joint), []).append(i)
        self.kinds = [Kind(ids, scenario, self.copies) for _, ids in sorted(kinds.items())]
        # arms that may lose their first joint's actuator: each fully actuated kind gets a faulted twin
        self.faults = scenario.fault_times is not None
        for kind in self.kinds:
            if self.faults and not kind.passive:
                kind.twin = Kind(kind.ids.tolist(), scenario, self.copies, faulted=True)
        self.kinds += [kind.twin for kind in self.kinds if kind.twin is not None]
        self.fault_times = np.full((self.copies, self.n_arms), np.inf)  # s since a copy's reset
        self.faulted = np.zeros((self.copies, self.n_arms), dtype=bool)
        # one kind in team order: its (B·N, ·) state arrays reshaped are the team arrays
        self.team_order = len(self.kinds) == 1 and self.kinds[0].ids.tolist() == list(range(self.n_arms))
        B, O = self.copies, len(scenario.obstacles)
        self.teams = Teams([scenario] * B)  # each copy's Scenario (a drawn team's built when read)
        self.bases, self.centers, self.radii = np.empty((B, self.n_arms, 2)), np.empty((B, O, 2)), np.empty((B, O))
        # whole-arm safety (links, other arms, moving obstacles): the kernel's capsule path; the
        # obstacles' motion per copy, and each copy's time since its reset
        self.link_bodies, self.inter_arm = scenario.bodies == "links", scenario.inter_arm
        self.link_radius = scenario.link_radius
        self.whole_arm = self.link_bodies or self.inter_arm or scenario.obstacle_paths is not None
        self.start_centers, self.path_ends, self.speeds = np.empty((B, O, 2)), np.empty((B, O, 2)), np.zeros((B, O))
        self.velocities = np.zeros((B, O, 2))
        self.moving = False  # whether some copy's obstacles may move (set as teams load)
        self.elapsed = np.zeros(B)  # s since each copy's reset: where moving obstacles are
        self.filter: FilterParams | None = None  # set_safety_filter's, below
        if self.whole_arm:
            self._whole_arm_setup()
        for b in range(B):
            self.load_team(b, scenario)
        self.set_safety_filter(safety_filter)
        N = self.n_arms
        self._blank = StepRecord.initial(B, N, self.k_max, self.n_max)  # a record's initial values
        self._blank.tau[:, [i for i, a in enumerate(scenario.arms) if a.passive_first_joint], 0] = 0.0  # passive: 0
        self._work = StepRecord.initial(B, N, self.k_max, self.n_max)  # what a step writes into (step)
        self.reset()

    @property
    def physics(self) -> Physics:
        """How the arms are stepped (:class:`Physics`, its sub-step resolved: the scenario's if it names none). It may
        be replaced between steps, by bounds or a sub-step the filter's choices allow (checked as the filter is when
        it is set); the QP solver stays the one the engine was built with."""
        return self._physics

    @physics.setter
    def physics(self, physics: Physics) -> None:
        physics = _physics(physics)
        if physics.physics_dt is None:
            physics = replace(physics, physics_dt=self._physics.physics_dt)
        if physics.qp_solver != self._physics.qp_solver:
            raise ValueError(f"an engine keeps the QP solver it was built with ({self._physics.qp_solver!r}); "
                             f"build another engine for qp_solver={physics.qp_solver!r}")
        if self.filter is not None:
            self._check_filter(self.filter, physics)
        self._physics = physics

    def _check_filter(self, params: FilterParams, physics: Physics) -> None:
        """The filter's choices against these arms and how they are stepped (:func:`~pan1_env.safety.check_choices`)."""
        reach = max(float(kind.lengths.sum(axis=-1).max()) for kind in self.kinds)
        check_choices(params, self.whole_arm, physics.max_joint_speed, reach, physics.physics_dt)

    @property
    def physics_dt(self) -> float:
        """The RK4 sub-step, seconds (``physics.physics_dt``)."""
        return self._physics.physics_dt

    @property
    def max_joint_speed(self) -> float:
        """The filter's bound on every filtered speed, rad/s (``physics.max_joint_speed``)."""
        return self._physics.max_joint_speed

    @property
    def max_torque(self) -> float:
        """The filter's bound on its own torques in torque mode, N·m (``physics.max_torque``)."""
        return self._physics.max_torque

    def __setstate__(self, state: dict) -> None:
        if "_physics" not in state:  # its arrays' names differ: linked wrongly, it would step silently wrong
            raise ValueError("this engine was pickled by an older pan1-env (a checkpoint's env, say): resume it with "
                             "the release that wrote it")
        self.__dict__.update(state)
        if "moving" not in state:  # pickled before the engine kept whether some copy's obstacles move
            self.moving = bool(self.speeds.any())
        # a pickle keeps the records' values but not their layout in blocks (StepRecord.restart copies blocks)
        self._blank = self._blank.laid_out()
        self._work = self._blank.laid_out() if "_work" not in state else self._work.laid_out()
        if getattr(self, "team_caps", None) is not None:  # a copy: the kinds' views of the team arrays again
            for kind in self.kinds:
                kind.caps, kind.start_time = self.team_caps[kind.block], self.team_start_time[kind.block]
                kind.joints = self.team_joints[kind.block]
                kind.whole = self.whole_arm_args(kind)

    # ------------------------------------------------------------------ set-up
    def set_safety_filter(self, safety_filter: bool | FilterParams) -> None:
        """Switch the filter off (``False``) or on (``True``: the scenario's parameters, or a
        :class:`FilterParams`); it acts from the next sub-step."""
        params = filter_parameters(safety_filter, self.teams[0])
        if params is not None:
            self._check_filter(params, self._physics)
        self.filter = params
        # a sensing range and the fault margin live in the whole-arm rows: the end-effector as their body
        rows = self.filter is not None and (self.filter.sensing_radius is not None or self.filter.fault_margin)
        if rows and not self.whole_arm:
            self.whole_arm = True
            self._whole_arm_setup()
            for b, team in enumerate(self.teams):
                self._load_team_capsules(b, team, team.obstacle_mask())
        for kind in self.kinds:
            if kind.whole is not None:
                kind.whole = self.whole_arm_args(kind)

    def load_team(self, b: int, scenario: Scenario) -> None:
        """Put ``scenario``'s team (same arm kinds in the same order) into copy ``b``; it starts there
        at the next :meth:`reset` of that copy."""
        if [a.n_links for a in scenario.arms] != self.n_links or [a.n_actuated for a in scenario.arms] != \
                self.n_actuated:
            raise ValueError("the scenario's team structure does not match the engine's")
        if scenario.ke != self.ke or len(scenario.obstacles) != self.radii.shape[1]:
            raise ValueError("a loaded team must keep the tracker gain K_e and the number of obstacles")
        if (scenario.bodies == "links", scenario.inter_arm, scenario.link_radius) != \
                (self.link_bodies, self.inter_arm, self.link_radius) or \
                (scenario.obstacle_paths is not None and not self.whole_arm):
            raise ValueError("a loaded team must keep the protected bodies, link_radius and inter_arm, and may have "
                             "moving obstacles only if the engine's first team had them")
        if scenario.fault_times is not None and not self.faults:
            raise ValueError("a loaded team may have fault_times only if the engine's first team had them")
        mask = scenario.obstacle_mask()
        for kind in self.kinds:
            kind.load(b, scenario, mask)
        self.teams[b] = scenario
        self.fault_times[b] = np.inf if scenario.fault_times is None else scenario.fault_times
        self.bases[b] = [a.base for a in scenario.arms]
        self.centers[b], self.radii[b] = scenario.obstacles.centers, scenario.obstacles.radii
        self.start_centers[b] = scenario.obstacles.centers
        self.path_ends[b], self.speeds[b] = scenario.obstacle_motion()
        self._note_motion(self.speeds[b])
        self.velocities[b] = scenario.obstacle_velocities(0.0)
        if self.whole_arm:
            self._load_team_capsules(b, scenario, mask)

    def load_teams(self, copies: np.ndarray, draws: TeamDraws) -> None:
        """:meth:`load_team` for the drawn teams of ``copies`` at once (``draws``: one team per copy, drawn from the
        options of the engine's first team, so their structure matches it); each copy's :class:`Scenario` is built
        only when read from :attr:`teams`."""
        copies = np.asarray(copies, dtype=np.int64)
        mask = draws.obstacle_mask()
        for kind in self.kinds:
            kind.load_drawn(copies, draws, mask)
        for c, b in enumerate(copies.tolist()):
            self.teams.put(b, draws, c)
        self.fault_times[copies] = draws.fault_times
        self.bases[copies] = draws.bases
        self.centers[copies], self.radii[copies] = draws.centers, draws.radii
        self.start_centers[copies] = draws.centers
        self.path_ends[copies], self.speeds[copies] = draws.path_ends, draws.speeds
        self._note_motion(draws.speeds)
        self.velocities[copies] = obstacle_velocities(draws.centers, draws.path_ends, draws.speeds, 0.0)
        if self.whole_arm:
            self._load_capsules(copies, mask, draws.bases, draws.reach)

    def _note_motion(self, speeds: np.ndarray) -> None:
        """``moving`` is set once a loaded team's obstacles move, and stays set (placing still obstacles by their
        motion leaves them where they are): the loads need not look at every copy."""
        self.moving = self.moving or bool(speeds.any())

    def _whole_arm_setup(self) -> None:
        """Capsule arrays per kind (:mod:`pan1_env.kernels.capsules`): the world obstacles, then, with
        ``inter_arm``, ``n_max`` slots for the links of every other arm; and the end-effector obstacles'
        stand-ins the kernel gets instead (none)."""
        B, N, O, L = self.copies, self.n_arms, self.radii.shape[1], self.n_max
        C = O + ((N - 1) * L if self.inter_arm else 0)
        # team-level arrays, each kind's rows a contiguous block of them (the kind's arrays are views), so
        # that one compiled pass reaches every arm of a copy between sub-steps: row copy_rows[b, i] is arm
        # i of copy b
        R = sum(len(kind.q) for kind in self.kinds)  # B·N, and B·A more for each faulted twin
        caps, start_time = np.zeros((R, C, kernels().capsules.CAPSULE_COLUMNS)), np.zeros(R)
        joints = np.zeros((R, L + 1, 2))
        self.copy_rows = np.empty((B, N), dtype=np.int64)
        first = 0
        for kind in self.kinds:
            rows = len(kind.q)
            block = slice(first, first + rows)
            kind.caps, kind.start_time, kind.joints = caps[block], start_time[block], joints[block]
            kind.block = block
            if not kind.faulted:  # a twin's rows take over copy_rows' entries at a fault (_lose_actuator)
                self.copy_rows[:, kind.ids] = first + np.arange(rows).reshape(B, kind.A)
            kind.angles = np.zeros((rows, 2, kind.n))
            kind.whole = self.whole_arm_args(kind)
            kind.world = plain(EndEffectorObstacles(np.empty((rows, 0, 2)), np.empty((rows, 0)),
                                                    np.empty((rows, 0), dtype=bool)))
            first += rows
        self.team_joints, self.team_caps, self.team_start_time = joints, caps, start_time

    def whole_arm_args(self, kind: Kind) -> WholeArm:
        """The kernel's ``whole`` argument for a kind (:func:`pan1_env.kernels.substep.group_advance`)."""
        return WholeArm(caps=kind.caps, start_time=kind.start_time, link_radius=self.link_radius,
                        link_bodies=self.link_bodies, sensing=self.filter_range(False),
                        gate=0.0 if self.filter is None else self.filter.gate, skin=SKIN, joints=kind.joints,
                        n_world=self.radii.shape[1], angles=kind.angles, carried=False, finish=True)

    def filter_range(self, torque: bool) -> float:
        """The whole-arm filter's range for a step (m): the filter's ``sensing_radius``, else :data:`SENSING_RADIUS`,
        or in torque mode behind the torque bound :data:`BRAKING_SENSING_RADIUS` (docs/MODEL.md §5d)."""
        sensing = None if self.filter is None else self.filter.sensing_radius
        if sensing is None:
            return BRAKING_SENSING_RADIUS if torque and self.max_torque < np.inf else SENSING_RADIUS
        return sensing

    def _load_team_capsules(self, b: int, scenario: Scenario, mask: np.ndarray) -> None:
        """Copy b's capsules (:meth:`_load_capsules`) from its ``scenario`` and obstacle ``mask (N, O)``."""
        self._load_capsules(np.array([b]), mask[None], np.array([a.base for a in scenario.arms])[None],
                            np.array([a.reach for a in scenario.arms])[None])

    def _load_capsules(self, copies: np.ndarray, mask: np.ndarray, bases: np.ndarray, reach: np.ndarray) -> None:
        """The capsules of ``copies`` (``mask (C, N, O)``, their arms' ``bases (C, N, 2)`` and ``reach (C, N)``): their
        obstacles (start, path, radius, share 1) and, with ``inter_arm``, the other arms' link slots (each kind's
        :meth:`~pan1_env.kinds.Kind.load_capsules`), with the floors of their clearances to each arm."""
        K = kernels().capsules
        starts = self.start_centers[copies]
        step = self.path_ends[copies] - starts
        length = np.linalg.norm(step, axis=-1)
        obstacles = np.zeros((*starts.shape[:2], K.CAPSULE_COLUMNS))
        obstacles[..., [K.CAP_AX, K.CAP_AY]] = obstacles[..., [K.CAP_BX, K.CAP_BY]] = starts
        obstacles[..., [K.CAP_UX, K.CAP_UY]] = step / np.where(length > 0, length, 1.0)[..., None]
        obstacles[..., K.CAP_RADIUS], obstacles[..., K.CAP_SHARE] = self.radii[copies], 1.0
        obstacles[..., K.CAP_PATH], obstacles[..., K.CAP_SPEED] = length, self.speeds[copies]
        obstacles[..., K.CAP_ARM] = -1.0
        # the floors less a nanometre: the kernels' distances round otherwise, and a skip must never be a near thing
        world_floor = obstacle_floors(bases, reach, starts, self.path_ends[copies], self.radii[copies],
                                      self.link_radius if self.link_bodies else 0.0) - FLOOR_SLACK
        arm_floor = arm_pair_floors(bases, reach, self.link_radius) - FLOOR_SLACK if self.inter_arm else None
        for kind in self.kinds:
            kind.load_capsules(copies, obstacles, mask, world_floor, arm_floor, self.n_links, self.link_radius)

    def reset(self, copies: np.ndarray | None = None, q0: list[np.ndarray] | None = None) -> None:
        """Put the ``copies`` (default: all) at rest at their team's start (or, for one copy, at ``q0``)."""
        copies = np.arange(self.copies) if copies is None else np.asarray(copies, dtype=np.int64)
        if q0 is not None:
            if len(copies) != 1 or len(q0) != self.n_arms:
                raise ValueError(f"q0 needs one configuration per arm ({self.n_arms}) and resets one copy")
            self._check_per_arm("q0", q0, "joint angles")
        self._restore_actuators(copies)
        self.elapsed[copies] = 0.0
        self.centers[copies] = self.start_centers[copies]
        self.velocities[copies] = obstacle_velocities(self.start_centers[copies], self.path_ends[copies],
                                                      self.speeds[copies], 0.0)
        for kind in self.kinds:
            rows = kind.rows(copies)
            kind.q[rows] = kind.q0[rows] if q0 is None else [q0[i] for i in kind.ids]
            kind.v[rows] = kind.v_prev[rows] = kind.qd[rows] = 0.0
            kind.momentum[rows] = 0.0
            kind.has_prev[rows] = False
            _end_effectors(kind, rows)
        if self.faults:  # a fault within the first sub-step: lost from the start (the first observation shows it)
            self.lose_actuators(np.isin(np.arange(self.copies), copies)[:, None] & (self.fault_substeps() == 0), None)

    def fault_substeps(self) -> np.ndarray:
        """``(B, N)``: in how many sub-steps from now each arm's coming fault begins (0: the sub-step that starts
        now contains its time, docs/MODEL.md §7; inf: none). 1e-6 sub-steps absorb the clock's rounding."""
        wait = np.where(self.faulted, np.inf, (self.fault_times - self.elapsed[:, None]) / self.physics_dt)
        return np.where(wait < 1.0 - 1e-6, 0.0, np.floor(wait + 1e-6))

    def lose_actuators(self, due: np.ndarray, rec: StepRecord | None) -> None:
        """The arms ``due (B, N)`` go over to their kind's faulted twin (:meth:`pan1_env.kinds.Kind.take_over`):
        their first joint's torque is 0 from now on and their action there is ignored (v* NaN); ``rec``: the
        step's record, where the faults come within the step."""
        if not due.any():
            return
        for full in self.kinds:
            if full.twin is None or not due[:, full.ids].any():
                continue
            rows = np.flatnonzero(due[:, full.ids])  # b·A + r, as the kind's rows
            full.twin.take_over(full, rows)
            if self.whole_arm:  # the next call refreshes the rows' capsules and clock, and starts from their q
                self.copy_rows[rows // full.A, full.ids[rows % full.A]] = full.twin.block.start + rows
        self.faulted |= due
        self._blank.tau[due, 0] = 0.0  # (the full kind's kernel writes it again after a reset)
        if rec is not None:
            rec.tau[due, 0], rec.v_star[due, 0] = 0.0, np.nan

    def _restore_actuators(self, copies: np.ndarray) -> None:
        """At a reset: the faulted arms of ``copies`` step in their full kind again."""
        if not self.faulted[copies].any():
            return
        for full in self.kinds:
            twin = full.twin
            if twin is None:
                continue
            rows = full.rows(copies)
            full.active[rows], twin.active[rows] = True, False
            full.set_stepped()
            twin.set_stepped()
            if self.whole_arm:
                self.copy_rows[np.ix_(copies, full.ids)] = full.block.start + rows.reshape(len(copies), full.A)
        self.faulted[copies] = False

    # ------------------------------------------------------------------ state
    def positions(self) -> np.ndarray:
        """End-effectors ``(B, N, 2)`` (a view of the state when one kind is the team in order)."""
        if self.team_order:
            return self.kinds[0].p.reshape(self.copies, self.n_arms, 2)
        P = np.empty((self.copies, self.n_arms, 2))
        for kind in self.kinds:
            kind.to_team(P, kind.p, first=0)
        return P

    def joint_state(self, pad: float = np.nan) -> tuple[np.ndarray, np.ndarray]:
        """Team arrays ``q, q̇ (B, N, n_max)``, ``pad`` beyond an arm's links (views when one kind is
        the team in order: do not write to them)."""
        B, N = self.copies, self.n_arms
        if self.team_order:
            return self.kinds[0].q.reshape(B, N, -1), self.kinds[0].qd.reshape(B, N, -1)
        q, qd = np.full((B, N, self.n_max), pad), np.full((B, N, self.n_max), pad)
        for kind in self.kinds:
            kind.to_team(q, kind.q, first=0)
            kind.to_team(qd, kind.qd, first=0)
        return q, qd

    def _check_per_arm(self, name: str, rows: list[np.ndarray], what: str) -> None:
        """``rows[i]``: one finite value per link of arm i, else a ValueError naming ``name[i]``."""
        for i, row in enumerate(rows):
            row = np.asarray(row, dtype=float)
            if row.shape != (self.n_links[i],) or not np.all(np.isfinite(row)):
                raise ValueError(f"{name}[{i}] must be {self.n_links[i]} finite {what}, got {row.tolist()}")

    def passive_momentum(self) -> np.ndarray:
        """p₁ = Σ_α M_1α q̇_α of every PAn−1 arm ``(B, N)``: the state its passive speed follows from, in float64
        (constant without damping, docs/MODEL.md §7); NaN for a fully actuated arm."""
        out = np.full((self.copies, self.n_arms), np.nan)
        for kind in self.kinds:
            if kind.passive:
                kind.to_team(out, kind.momentum)
        return out

    def set_state(self, copy: int, q: list[np.ndarray], qd: list[np.ndarray]) -> None:
        """Put copy ``copy``'s arms at joint angles ``q[i]`` moving at ``qd[i]`` (n_i values each), for example
        where an arm was when its actuator failed. A PAn−1 arm keeps v = q̇_a and its passive momentum
        p₁ = Σ_α M_1α q̇_α, from which its passive speed follows (docs/MODEL.md §7). The tracker starts afresh,
        as after a reset; the copy's clock and obstacles stay where they are."""
        if isinstance(copy, bool) or not isinstance(copy, (int, np.integer)) or not 0 <= copy < self.copies:
            raise ValueError(f"copy must be an integer in [0, {self.copies}), got {copy!r}")
        if len(q) != self.n_arms or len(qd) != self.n_arms:
            raise ValueError(f"set_state needs q and qd for every arm ({self.n_arms})")
        self._check_per_arm("q", q, "joint angles")
        self._check_per_arm("qd", qd, "joint speeds")
        for kind in self.kinds:
            rows = kind.rows(np.array([copy]))
            kind.put_state(rows, np.array([q[i] for i in kind.ids], dtype=float),
                           np.array([qd[i] for i in kind.ids], dtype=float))
            _end_effectors(kind, rows)

    def obstacle_velocities(self) -> np.ndarray:
        """Every copy's obstacle velocities now, ``(B, O, 2)`` (zeros for still obstacles)."""
        return self.velocities.copy()

    def joint_positions(self, copies: np.ndarray | None = None) -> np.ndarray:
        """Base, joints and end-effector of every arm, ``(B, N, n_max + 1, 2)``; an arm of fewer links
        repeats its end-effector (its padding links have length 0). With ``copies`` (indices) those copies'
        only, in their order, computed for them alone."""
        P = np.empty((self.copies, self.n_arms, self.n_max + 1, 2))
        for kind in self.kinds:
            rows = kind.stepped
            if copies is not None:
                rows = kind.rows(copies)
                rows = rows[kind.active[rows]]
            self.geometry("kind_joints", len(rows), kind.q, kind.lengths, kind.base, kind.phi, kind.ids, rows, P)
        return P if copies is None else P[copies]

    def clearance(self, copies: np.ndarray | None = None) -> np.ndarray:
        """Smallest clearance of every arm's protected bodies, ``(B, N)`` (inf with nothing to hit): the
        end-effector's ‖p_i − o_j‖ − r_j, or with whole-arm safety every body's to the obstacles where
        they are now and, with ``inter_arm``, to the other arms' capsules (:mod:`pan1_env.bodies`). With
        ``copies`` (indices) those copies' rows only, in their order."""
        rows = slice(None) if copies is None else copies
        centers, radii = self.centers[rows], self.radii[rows]
        B, N, O = len(centers), self.n_arms, radii.shape[1]
        if not self.whole_arm:
            if O == 0:
                return np.full((B, N), np.inf)
            return clearance(self.positions()[rows], centers[:, None], radii[:, None]).min(axis=-1)
        P = self.joint_positions(copies)
        a, b = (P[:, :, :-1], P[:, :, 1:]) if self.link_bodies else (P[:, :, -1:], P[:, :, -1:])
        clear = np.full((B, N), np.inf)
        if O:
            clear = capsule_clearance(a, b, centers[:, None], radii[:, None],
                                      self.link_radius if self.link_bodies else 0.0).min(axis=(2, 3))
        return np.minimum(clear, self.inter_arm_clearance(P))

    def inter_arm_clearance(self, P: np.ndarray | None = None) -> np.ndarray:
        """Smallest d − 2ρ between each arm's link capsules and any other arm's, ``(B, N)`` (inf without
        ``inter_arm``); ``P`` from :meth:`joint_positions`."""
        clear = np.full((self.copies if P is None else len(P), self.n_arms), np.inf)
        if self.inter_arm and self.n_arms > 1:
            kernels().team_geometry.inter_arm_clearance(self.joint_positions() if P is None else P, self.link_radius,
                                                        clear)
        return clear

    def kind_terms(self, kind: Kind) -> KindTerms:
        """A kind's end-effectors ``(B·A, 2)``, reduced Jacobians J̄ ``(B·A, 2, k)``, passive momenta (from q̇)
        and end-effector drifts ``(B·A, 2)``."""
        rows = len(kind.q)
        p, Jbar, Mc = np.empty((rows, 2)), np.empty((rows, 2, kind.k)), np.empty((rows, kind.k, kind.k))
        Hc, momentum, drift = np.empty((rows, kind.k)), np.empty(rows), np.empty((rows, 2))
        kernels().group_terms(kind.lam, kind.lengths, kind.base, kind.phi, kind.damping, kind.passive, kind.q, kind.v,
                              kind.momentum, p, Jbar, Mc, Hc, momentum, drift)
        return KindTerms(p, Jbar, momentum, drift)

    def circulation(self, kind: Kind, v0: np.ndarray, activation: float) -> np.ndarray:
        """The anticlockwise circulation term of every arm of ``kind`` for its command ``v0 (B·A, k)`` (rad/s),
        ``(B·A, k)``: round the obstacles where they are now, from each link's closest point with whole-arm bodies,
        else from the end-effector, for body points within ``activation`` m (:mod:`pan1_env.kernels.circulation`;
        the rule's :func:`~pan1_env.baselines.circulation.circulation_term` is its numpy twin)."""
        out = np.empty_like(v0)
        kernels().group_circulation(kind.lam, kind.lengths, kind.base, kind.phi, kind.passive, kind.q,
                                    np.arange(len(kind.q)) // kind.A, self.centers, self.radii, self.link_radius,
                                    self.link_bodies, float(activation), np.ascontiguousarray(v0, dtype=float), out)
        return out

    # --------------------------------------------------------------- stepping
    def step(self, command: np.ndarray, substeps: int, *, torque: bool = False) -> StepRecord:
        """Hold ``command (B, N, k_max)`` (desired actuated velocities in rad/s, or with ``torque``
        actuated torques in N·m; padding ignored) for ``substeps`` physics steps."""
        B, N = self.copies, self.n_arms
        command = np.asarray(command, dtype=float)
        if command.shape != (B, N, self.k_max):
            raise ValueError(f"command must have shape {(B, N, self.k_max)}, got {command.shape}")
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        for kind in self.kinds:
            if kind.specialised is False:
                kernels().specialise.start_background()  # from the second step on: see kernel_step._specialised
                break
        # the kernel writes into one working record (its calls' outputs are views of it, built once: kernel_step);
        # the step hands out a copy, so that records handed out are never overwritten
        work = self._work
        work.restart(self._blank)
        self.qp.advance(self, command, int(substeps), torque, work)
        finite = work.finite
        # (a small team's flags read faster as a list than through numpy's reduction)
        work.all_finite = all(finite.ravel().tolist()) if finite.size <= 64 else bool(finite.all())
        if not work.all_finite:  # a faulty arm stopped early: include the (finite) state it was left in
            np.minimum(work.min_clearance, self.clearance(), out=work.min_clearance)
        return work.copy()

    def tick(self, substeps: int) -> None:
        """Advance every copy's clock by ``substeps`` sub-steps, and the obstacles with it."""
        self.elapsed += substeps * self._physics.physics_dt
        self.place_obstacles()

    def place_obstacles(self) -> None:
        """``centers`` and ``velocities`` (which observations and :meth:`clearance` read) where every copy's
        clock puts the obstacles, as the filter places them (whole-arm safety: from the capsules)."""
        if self.moving:
            kernels().team_geometry.obstacles_now(self.copy_rows, self.team_caps, self.elapsed, self.centers,
                                             self.velocities)

    def refresh_capsules(self, P: np.ndarray | None = None) -> None:
        """Before a kernel call: every copy's time, and (``inter_arm``) the other arms' link segments
        from their joints ``P`` (:meth:`joint_positions`, as they are now), which each arm's filter holds
        for the call (one sub-step)."""
        if self.inter_arm:
            self.geometry("refresh_capsules", self.copies * self.n_arms, self.copy_rows, self.team_start_time,
                          self.team_caps, self.radii.shape[1], self.elapsed, P)
            return
        self.team_start_time[self.copy_rows] = self.elapsed[:, None]

    def geometry(self, name: str, rows: int, *args) -> None:
        """The whole-arm geometry pass ``name`` of :mod:`pan1_env.kernels.team_geometry` over ``rows`` arms, or its
        ``_parallel`` twin on numba's threads when :meth:`chunks` says so."""
        chunks = self.chunks(rows)
        if chunks:
            getattr(kernels().team_geometry, name + "_parallel")(*args, chunks)
        else:
            getattr(kernels().team_geometry, name)(*args)

    def chunks(self, rows: int) -> int:
        """0 to run a kernel call on one thread, else its number of chunks on numba's thread pool."""
        if not (self.threads is True or (self.threads == "auto" and rows >= PARALLEL_THRESHOLD)):
            return 0
        from numba import get_num_threads

        return 4 * get_num_threads()


def _end_effectors(kind: Kind, rows: np.ndarray) -> None:
    """The end-effectors ``kind.p`` of the kind's rows ``rows`` from their joint angles (the others are left as they
    are: a reset of some copies costs what it resets)."""
    p = np.empty((len(rows), 2))
    kernels().group_end_effectors(kind.lengths[rows], kind.base[rows], kind.phi[rows], kind.q[rows], p)
    kind.p[rows] = p
