"""The calls of the compiled sub-step kernel: how an engine's step runs every arm kind through it.

:class:`KernelQP` is the engine's solver object for the filter's QP solved inside the kernel (exact active set, any
number of copies, both modes); :mod:`pan1_env.piqp_filter`'s ``PiqpFilter`` is the other one. A step of either goes
through :func:`advance_compiled` (or, one kind at a time, :func:`advance_kind`), which builds each kind's kernel groups
(:mod:`pan1_env.kernel_groups`) from the engine's state and the step's record, calls the kernel (the kind's own, the
generic one while its own compiles, or the multi-threaded twin for large batches) and scatters what it produced into
the record. The engine (:class:`~pan1_env.engine.Engine`) owns the state these functions step; nothing else calls
the kernel.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .compiled import kernel_filter, kernels
from .kernel_groups import FILTER_OFF, Command, StepOutputs, Stepping, WholeArm, plain
from .kinds import Kind
from .safety import FilterParams
from .step_record import StepRecord

if TYPE_CHECKING:
    from .engine import Engine

__all__ = ["KernelQP", "advance_compiled", "advance_kind"]

#: the record's field each of the kernel's outputs that the record holds goes to (the kind's own ``qd`` and ``p``
#: complete :class:`~pan1_env.kernel_groups.StepOutputs`)
_RECORD_FIELDS = {"v_star": "v_star", "tau": "tau", "min_clear": "min_clearance", "min_h": "min_barrier",
                  "qp_counts": "qp_counts", "max_track": "max_tracking_error", "finite": "finite"}


class KernelQP:
    """The filter's QP solved in the sub-step kernel (exact active set, any number of copies, both
    modes): a step is :func:`advance_compiled`."""

    name = "active_set"

    @staticmethod
    def check(copies: int, torque: bool = False, faults: bool = False) -> None:
        """Everything is allowed."""

    @staticmethod
    def advance(engine: Engine, command: np.ndarray, substeps: int, torque: bool, rec: StepRecord) -> None:
        advance_compiled(engine, command, substeps, torque, rec)


def advance_compiled(engine: Engine, command: np.ndarray, substeps: int, torque: bool, rec: StepRecord) -> None:
    """Every arm of every copy ``substeps`` sub-steps through the sub-step kernel, its QP included,
    into ``rec``: one kernel call per kind, or with ``inter_arm`` one per kind and sub-step. An arm that
    loses its actuator within the step (:meth:`Engine.fault_substeps`) is held by its full kind's call from the
    start of the sub-step that contains its fault time and goes on from there in its faulted twin's (the
    kernel's ``window``); with ``inter_arm`` the calls split there instead. An arm whose fault falls
    within the next step's first sub-step loses it before the step returns (its observation shows it)."""
    if engine.inter_arm:
        done = 0
        while done < substeps:
            at = engine.fault_substeps() if engine.faults else np.full(1, np.inf)
            engine.lose_actuators(at == 0, rec)
            todo = int(min(substeps - done, at[at > 0].min(initial=np.inf)))
            _advance_inter_arm(engine, command, todo, torque, rec)
            done += todo
    elif not engine.faults:  # every kind steps the whole step in one call
        if engine.whole_arm:
            engine.refresh_capsules()
        for kind in engine.kinds:
            if len(kind.stepped):
                _advance_whole_step(engine, kind, command, substeps, torque, rec)
        engine.tick(substeps)
        return
    else:
        at = engine.fault_substeps()
        within = (at > 0) & (at < substeps)
        engine.lose_actuators(at == 0, rec)
        if engine.whole_arm:
            engine.refresh_capsules()
        split = within.any()
        for twins in (False, True):  # a full kind's call hands its arms that fault within the step over
            if twins and split:
                engine.lose_actuators(within, rec)
                if engine.whole_arm:
                    engine.refresh_capsules()  # the twins' new rows' clock
            for kind in engine.kinds:
                if kind.faulted == twins and len(kind.stepped):
                    _advance(engine, kind, command, substeps, torque, engine.filter, rec,
                             (at, within) if split else None)
        engine.tick(substeps)
    if engine.faults:
        engine.lose_actuators(engine.fault_substeps() == 0, None)


def _advance_inter_arm(engine: Engine, command: np.ndarray, substeps: int, torque: bool, rec: StepRecord) -> None:
    """:func:`advance_compiled` with other arms in each arm's filter, which sees their capsules as they
    are at each sub-step: one kernel call per sub-step (each kind's outputs gathered once: the kernel
    accumulates minima, maxima and counts over calls), then one compiled pass (after_substep) that
    refreshes the capsules from the joints the kernel left and measures the clearance between arms,
    seeded with the obstacle clearance so far (pairs that cannot lower it are skipped). The kinds'
    running clearances and finite flags live in team-level arrays (views of the record with one kind
    in team order)."""
    B, N = engine.copies, engine.n_arms
    R = len(engine.team_start_time)
    clear, finite = (None, None) if engine.team_order else (np.empty(R), np.empty(R, dtype=bool))
    kinds = [kind for kind in engine.kinds if len(kind.stepped)]
    calls = [_kernel_args(engine, kind, command, 1, torque, engine.filter, rec,
                          None if clear is None else clear[kind.block],
                          None if finite is None else finite[kind.block]) for kind in kinds]
    if clear is None:
        _, first = calls[0]
        clear, finite = first.min_clear, first.finite
    ok = finite.copy()  # the kernel marks an arm finite afresh each call
    P = engine.joint_positions()
    between = np.full((B, N), np.inf)
    engine.refresh_capsules(P)
    sensing = engine.filter_range(torque)
    for sub in range(substeps):
        for kind, (args, _) in zip(kinds, calls, strict=True):
            # a call after the step's first starts from the link angles' sines and cosines the
            # previous one ended with (`carried`, as one call's sub-steps do); only the last
            # computes the joint velocities and end-effectors (`finish`)
            _call(engine, kind, args, kind.whole._replace(carried=sub > 0, finish=sub == substeps - 1,
                                                          sensing=sensing))
        # the kernel placed the obstacles from the clock itself; the clock moves on here
        engine.geometry("after_substep", B * N, engine.copy_rows, engine.team_joints, clear, finite,
                        ok, engine.team_start_time, engine.team_caps, engine.radii.shape[1], engine.link_radius,
                        engine.physics_dt, sub < substeps - 1, engine.elapsed, P, between)
    finite[:] = ok
    for kind, (_, out) in zip(kinds, calls, strict=True):
        _finish(engine, kind, out, torque, rec)
    np.minimum(rec.min_clearance, between, out=rec.min_clearance)
    engine.place_obstacles()


def advance_kind(engine: Engine, kind: Kind, command: np.ndarray, substeps: int, rec: StepRecord, *,
                 filtered: bool) -> None:
    """One kernel call in velocity mode: every arm of ``kind`` ``substeps`` sub-steps at ``command``,
    through the filter or not (for a solver that filters by itself: :mod:`pan1_env.piqp_filter`)."""
    _advance(engine, kind, command, substeps, False, engine.filter if filtered else None, rec)


def _advance(engine: Engine, kind: Kind, command: np.ndarray, substeps: int, torque: bool, params: FilterParams | None,
             rec: StepRecord, faults: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """The kernel call: every arm of a kind in every copy, ``substeps`` sub-steps; with ``faults`` (the step's
    :meth:`Engine.fault_substeps` and the arms that fault within it) a full kind's arms stop where their fault
    begins and its twin's start there (the kernel's ``window``)."""
    args, out = _kernel_args(engine, kind, command, substeps, torque, params, rec)
    whole = _whole(engine, kind, torque)
    if faults is None or (kind.twin is None and not kind.faulted):
        _call(engine, kind, args, whole)
    else:
        rows, end = np.flatnonzero(faults[1][:, kind.ids]), 0 if kind.faulted else 1  # a twin's start, a full's stop
        kind.window[rows, end] = faults[0][:, kind.ids].ravel()[rows]
        try:
            _call(engine, kind, args, whole)
        finally:
            kind.window[rows, end] = kind.window_default[end]
    _finish(engine, kind, out, torque, rec)


def _advance_whole_step(engine: Engine, kind: Kind, command: np.ndarray, substeps: int, torque: bool,
                        rec: StepRecord) -> None:
    """:func:`_advance` of a step no fault splits. Once the kind steps with its own serial kernel (velocity mode, one
    kind in team order), the kernel and its whole argument tuple are kept beside the plan (``kind.ready``) and called
    as they are while the plan's groups and the kind's ``whole`` stay the same objects."""
    args, out = _kernel_args(engine, kind, command, substeps, torque, engine.filter, rec)
    ready = kind.ready
    if ready is not None and ready[0] is args and ready[1] is kind.whole:  # (a new mode is a new plan: new args)
        ready[2](*ready[3])
    else:
        _call(engine, kind, args, _whole(engine, kind, torque))
        if kind.specialised and engine.team_order and not torque and not engine.chunks(len(kind.q)):
            kind.ready = (args, kind.whole, kernels().group_advance, (*kind.sizes, *args, plain(kind.whole)))
    _finish(engine, kind, out, torque, rec)


def _whole(engine: Engine, kind: Kind, torque: bool) -> WholeArm | None:
    """The kernel's ``whole`` argument: the kind's, which holds the velocity-mode range (whole_arm_args); torque
    mode's may differ."""
    whole = kind.whole
    if whole is not None and torque:
        whole = whole._replace(sensing=engine.filter_range(True))
    return whole


def _kernel_args(engine: Engine, kind: Kind, command: np.ndarray, substeps: int, torque: bool,
                 params: FilterParams | None, rec: StepRecord, clear: np.ndarray | None = None,
                 finite: np.ndarray | None = None) -> tuple[tuple, StepOutputs]:
    """The kernel's groups for a kind but ``whole`` (:func:`_call`), plain, and its outputs: views of the
    record when one kind is the team in order, else gathered copies of the record's rows (the kernel
    accumulates into them), or for the running clearance and finite flags the caller's ``clear`` and
    ``finite`` (filled with them). The kind's rows of ``command`` are copied into the array it holds."""
    _hold(engine, kind, command)
    if clear is None:
        return _groups(engine, kind, substeps, torque, params, rec)
    args, out = _build(engine, kind, substeps, torque, params, rec)
    clear[:], finite[:] = out.min_clear, out.finite
    out = out._replace(min_clear=clear, finite=finite)
    return (*args[:-1], plain(out)), out


def _hold(engine: Engine, kind: Kind, command: np.ndarray) -> None:
    """The kind's rows of the step's ``command (B, N, k_max)`` into ``kind.held``, the array its calls hold."""
    if engine.team_order:
        np.copyto(kind.held_team, command)
    else:
        kind.held.reshape(engine.copies, kind.A, kind.k)[:] = command[:, kind.cols, kind.shift: kind.shift + kind.k]


def _groups(engine: Engine, kind: Kind, substeps: int, torque: bool, params: FilterParams | None,
            rec: StepRecord) -> tuple[tuple, StepOutputs]:
    """:func:`_build`'s groups, built once and kept on the kind (``kind.plan``) while everything they are made of is
    the same object: the kind's own groups, the filter, the physics, the sub-steps, the mode and the record (its
    outputs are views of the engine's working record when one kind is the team in order; otherwise they are
    gathered afresh each step)."""
    key = (kind.model, kind.state, kind.selection, kind.world, params, engine.physics, substeps, torque, rec)
    identity = tuple(map(id, key))  # unique while the plan keeps the key's objects alive
    plan = kind.plan
    if plan is not None and plan[0] == identity:
        if engine.team_order:
            return plan[2], plan[3]
        out = _outputs(engine, kind, rec)
        return (*plan[2][:-1], plain(out)), out
    args, out = _build(engine, kind, substeps, torque, params, rec)
    kind.plan = (identity, key, args, out)
    return args, out


def _build(engine: Engine, kind: Kind, substeps: int, torque: bool, params: FilterParams | None,
           rec: StepRecord) -> tuple[tuple, StepOutputs]:
    out = _outputs(engine, kind, rec)
    rcbf = plain(FILTER_OFF if params is None else kernel_filter(params, engine.max_torque))
    held = plain(Command(command=kind.held, torque_mode=torque, filter_on=params is not None))
    stepping = plain(Stepping(ke=engine.ke, dt=engine.physics_dt, n_sub=substeps, v_max=engine.max_joint_speed))
    return (kind.model, kind.state, kind.selection, held, kind.world, rcbf, stepping, plain(out)), out


def _outputs(engine: Engine, kind: Kind, rec: StepRecord) -> StepOutputs:
    """A call's outputs: views of the record when one kind is the team in order, else gathered copies of the record's
    rows (the kernel accumulates into them; :func:`_finish` scatters them back)."""
    rows, n, k = engine.copies * kind.A, kind.n, kind.k
    if engine.team_order:
        return StepOutputs(v_star=rec.v_star.reshape(rows, k), tau=rec.tau.reshape(rows, n), qd=kind.qd, p=kind.p,
                           min_clear=rec.min_clearance.reshape(rows), min_h=rec.min_barrier.reshape(rows),
                           qp_counts=rec.qp_counts.reshape(rows, 3), max_track=rec.max_tracking_error.reshape(rows),
                           finite=rec.finite.reshape(rows))
    return StepOutputs(v_star=np.empty((rows, k)), tau=kind.from_team(rec.tau, n, first=0), qd=kind.qd, p=kind.p,
                       min_clear=kind.from_team(rec.min_clearance), min_h=kind.from_team(rec.min_barrier),
                       qp_counts=np.zeros((rows, 3), dtype=np.int64), max_track=kind.from_team(rec.max_tracking_error),
                       finite=np.ones(rows, dtype=bool))


def _call(engine: Engine, kind: Kind, groups: tuple, whole: WholeArm | None) -> None:
    """One call of the sub-step kernel on every arm of a kind: the multi-threaded one for large batches,
    else the kind's own or the generic one (:func:`_specialised`); ``whole`` goes as a plain tuple."""
    whole = plain(whole)
    chunks = engine.chunks(len(kind.q))
    if chunks:
        kernels().group_advance_parallel(*kind.sizes, *groups, whole, chunks)
    elif kind.specialised or _specialised(kind, (*kind.sizes, *groups, whole)):
        kernels().group_advance(*kind.sizes, *groups, whole)
    else:
        kernels().group_advance_generic(*kind.sizes, *groups, whole)


def _finish(engine: Engine, kind: Kind, out: StepOutputs, torque: bool, rec: StepRecord) -> None:
    """After a kind's kernel call(s): scatter gathered outputs back into the record (counts add up, and an
    arm is finite if it was in every call)."""
    if torque:
        kind.has_prev[:] = False
    if not engine.team_order:
        for name, field in _RECORD_FIELDS.items():
            kind.to_team(getattr(rec, field), getattr(out, name), add=name == "qp_counts", both=name == "finite",
                         first=0 if name in ("tau", "qp_counts") else None)


def _specialised(kind: Kind, args: tuple) -> bool:
    """Whether the kind steps with its own compiled kernel (``group_advance``) rather than the generic
    one, which gives the same results bit for bit: asked at its first serial step and again whenever
    a background compilation has ended (:mod:`pan1_env.kernels.specialise`), until the answer is yes.
    A kind that is not ready is queued for a background compilation, which the next :meth:`Engine.step`
    starts (so that the child's start does not compete with the step that compiles the generic
    kernel, nor with the first observations after it)."""
    if kind.specialised:
        return True
    generation = kernels().specialise.background_generation()
    if kind.specialised is None or generation != kind.generation:
        kind.generation = generation
        kind.specialised = kernels().specialise.specialised_ready(args)
    return kind.specialised
