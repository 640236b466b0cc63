"""The sub-step kernel: every arm of a group advanced through the physics sub-steps of a control step
(filter, backstepping tracker, RK4), W arms at once; serial and multi-threaded entry points.

:func:`_advance_arms` advances the arms ``lo … hi−1`` of :func:`group_advance`; the steps in
:mod:`.steps` do the work, each on all lanes.

With ``sizes`` None (the per-kind kernels), ``n``, ``k`` and the lane count W are compile-time
constants (the lengths of the tuples ``links``, ``actuated`` and ``lanes``): with the loops over
links, joints and lanes of known length, LLVM unrolls them and packs the lanes into vector
registers. With ``sizes = (n, k)`` and ``lane_qp`` None (the generic kernel) n and k are read at
run time and the tuples only size the scratch arrays, and the QP skips its lane-batched first
candidate (:func:`_filter_rows_lanes` instead of :func:`_first_projection_lanes`); the
operations on each value and their order are the same, so are the results, bit for bit (no
fast-math flag lets LLVM round differently: ``_JIT``).

The arms go W at a time (the last group padded with copies of the last arm, never written
back). Each group's parameters and state are copied into stack arrays (:func:`_local`, made by
:mod:`.scratch`'s inlined functions) with the lanes as their last axis, advanced through the
sub-steps there and written back: the hot loop makes no array view and, but for the obstacles and
the filter's rows, touches no heap scratch.
Dynamics, tracker, RK4 and the safety filter's rows run on all lanes at once, and so does the QP
as far as one active row settles it (:func:`_first_projection_lanes`, many filtered sub-steps);
the lanes it does not settle get the full active-set search one by one (:func:`_project_one`).

The link angles' sines and cosines are computed from q (``_lane_angles``) once per arm at the
start of a call (and again after a non-finite state), or with whole-arm ``carried`` read from
``angles``, where the previous call left them; RK4 stages and the state a sub-step reaches get
theirs by rotating those at the sub-step's start (``_rotate_lanes``, within an ulp). Those at the
state reached serve its clearance and the next sub-step's filter, tracker and first RK4 stage.

An arm whose state goes non-finite stops there (its lane is frozen at the last finite state and
its outputs are those of the failing sub-step), as its own loop would; the other lanes go on.

``whole`` None (numba prunes the branches that read it) keeps the end-effector filter; a tuple
switches to whole-arm safety (:func:`group_advance`). Its ``joints`` and ``angles`` receive every arm's
joints and link angles' cosines and sines at the final state: the engine refreshes the other arms'
capsules from the joints between its calls within a control step (one per sub-step with other arms),
and each call after the first starts from the angles the previous one reached (``carried``), as one
call's sub-steps do; each step's first call starts from q, so a step is a function of the state.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..kernel_groups import (
    ArmModel,
    ArmState,
    Command,
    EndEffectorObstacles,
    FilterSettings,
    StepOutputs,
    Stepped,
    Stepping,
    WholeArm,
    plain,
)
from ._numba_ext import _JIT, _LANES, _borrowed, _check_chunks, _keep_alive, _local, _quick_when, _slp_vectorised
from .scratch import (
    Tracker,
    _dynamics_scratch,
    _end_effector_scratch,
    _lane_arms_scratch,
    _qp_search_scratch,
    _rk4_scratch,
    _whole_arm_scratch,
    b1,
    f8,
)
from .steps import (
    _clearance_after,
    _desired_velocity,
    _filter_end_effector,
    _filter_whole_arm,
    _load_arms,
    _load_filter,
    _rk4,
    _store_outputs,
    _store_state,
    _track,
)


@njit(**_JIT)
def _advance_arms(links, actuated, lanes, sizes, lane_qp, lo, hi, model_, state_, stepped_, held_, world_, rcbf_,
                  stepping_, out_, whole):
    """Arms ``rows[lo … hi−1]`` of :func:`group_advance` (the loop body, with its own scratch space), its plain groups
    named here (:mod:`pan1_env.kernel_groups`) and ``whole`` named by the caller (a :class:`WholeArm` or None, on
    whose type numba prunes the inlined steps' whole-arm branches): see the module's docstring for the lanes, the
    per-kind and generic signatures and the whole-arm calls."""
    model, state, stepped, held = ArmModel(*model_), ArmState(*state_), Stepped(*stepped_), Command(*held_)
    world, rcbf, stepping = EndEffectorObstacles(*world_), FilterSettings(*rcbf_), Stepping(*stepping_)
    out = StepOutputs(*out_)
    lam, lengths, base, phi, damping = model.lam, model.lengths, model.base, model.phi, model.damping
    q, v, momentum, v_prev, has_prev = state.q, state.v, state.momentum, state.v_prev, state.has_prev
    rows, window = stepped.rows, stepped.window
    command, torque_mode, filter_on = held.command, held.torque_mode, held.filter_on
    centers, radii, mask = world.centers, world.radii, world.mask
    ke, dt, n_sub, v_max = stepping.ke, stepping.dt, stepping.n_sub, stepping.v_max
    v_star_out, tau_out, qd_out, p_out, min_clear = out.v_star, out.tau, out.qd, out.p, out.min_clear
    min_h, qp_counts, max_track, finite_out = out.min_h, out.qp_counts, out.max_track, out.finite
    if sizes is None:  # the per-kind kernel (numba prunes the other branch by the argument's type)
        n = len(links)
        k = len(actuated)
    else:  # the generic kernel: n and k at run time, at most the tuples' lengths (which size the scratch)
        n, k = sizes
    W = len(lanes)
    passive = k < n  # a compile-time constant in the per-kind kernel (the argument, checked by callers, agrees)
    O = radii.shape[1]
    inv_dt = 1.0 / dt  # divisions by dt as products (_JIT leaves arcp off, so LLVM keeps divisions)
    # Scratch space in this function's stack frame (.scratch), the lanes last: the lanes' arms, parameters, state
    arm, real, lm, ln, qi, vi, vp, bx, by, ph, pj = _lane_arms_scratch(links, actuated, lanes)
    lw, nw, kw = (lanes,), (links, lanes), (actuated, lanes)
    # kinematics at a state (the link angles' cosines and sines, at the sub-step's start too), and the dynamics
    c, s, c0, s0, px, py = _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(nw, f8), _local(lw, f8), \
        _local(lw, f8)
    dyn, chol = _dynamics_scratch(links, actuated, lanes)
    # command, filter and tracker, per lane; the outputs of each lane's last sub-step (kept when it stops)
    vdes, vs, tau, acc = _local(kw, f8), _local(kw, f8), _local(kw, f8), _local(kw, f8)
    use_filter, prev_ok, live, status = _local(lw, b1), _local(lw, b1), _local(lw, b1), _local(lw, np.int64)
    # each lane's sub-steps [w_lo, w_hi) (it is live within them while its state stays finite: alive)
    w_lo, w_hi, alive = _local(lw, np.int64), _local(lw, np.int64), _local(lw, b1)
    arm_clear, arm_h, arm_track = _local(lw, f8), _local(lw, f8), _local(lw, f8)
    vs_last, tau_last, counts = _local(kw, f8), _local(kw, f8), _local(((0, 0, 0), lanes), np.int64)
    # every lane's obstacles (centre x, y, radius) and active rows; the filters' scratch (the end effector's
    # Jacobians, its drift J₁ p₁ / M_11 and rows; the full search's rows: O obstacles, 2k speed bounds and 2k for
    # torque mode's input bound); the groups' heap arrays unreferenced (_borrowed), kept alive to the end
    # (_keep_alive below)
    obstacles, lane_active = np.empty((3, O, W)), np.empty((O, W), dtype=np.bool_)
    ee_owned = _end_effector_scratch(links, actuated, lanes, O, k)
    search_owned = _qp_search_scratch(actuated, O, k, v_max)
    ee, search = _borrowed(ee_owned), _borrowed(search_owned)
    stages = _rk4_scratch(links, actuated, lanes)
    tracker = Tracker(torque_mode, ke, dt, vi, vp, prev_ok)  # the tracker's terms the filters look ahead with
    if whole is not None:
        owned = _whole_arm_scratch(whole, links, lanes, n, k)
        scratch = _borrowed(owned)
    else:  # no whole-arm scratch: the steps read it only where the kernel's own `whole` is not None
        owned = None
        scratch = None
    for first in range(lo, hi, W):
        _load_arms(first, hi, rows, n, k, W, lam, lengths, base, phi, q, v, v_prev, whole, arm, real, counts, lm, ln,
                   qi, vi, vp, bx, by, ph, vs_last, tau_last, c, s)
        for w in range(W):  # damping also for a fully actuated arm: the fault margin's b once it is passive
            pj.damping[w] = damping[arm[w]]
            if passive:
                pj.p1[w] = momentum[arm[w]]
        any_filter = _load_filter(W, O, filter_on, torque_mode, v_max, centers, radii, mask, has_prev, min_clear, min_h,
                                  max_track, finite_out, whole, arm, real, obstacles, lane_active, use_filter, prev_ok,
                                  live, arm_clear, arm_h, arm_track)
        for w in range(W):
            w_lo[w], w_hi[w], alive[w] = window[arm[w], 0], window[arm[w], 1], True
        for sub in range(n_sub):
            for w in range(W):
                live[w] = alive[w] and w_lo[w] <= sub < w_hi[w]
            _desired_velocity(n, k, W, passive, any_filter, torque_mode, dt, command, arm, lm, vi, pj, c, s, dyn, chol,
                              tau, acc, vdes, vs, status)
            if any_filter and whole is not None:
                _filter_whole_arm(sub, n, k, W, passive, rcbf, v_max, dt, whole, scratch, arm, real, ln, bx, by, c, s,
                                  dyn, pj, tracker, use_filter, live, vdes, vs, status, arm_h, search)
            elif any_filter:
                _filter_end_effector(n, k, W, passive, sizes, lane_qp, rcbf, v_max, real, ln, bx, by, c, s, dyn, pj,
                                     px, py, obstacles, lane_active, use_filter, live, vdes, vs, status, arm_h, ee,
                                     search, tracker)
            _track(k, W, torque_mode, ke, inv_dt, vi, vp, dyn.Mc, dyn.Hc, use_filter, live, prev_ok, status, counts,
                   arm_track, vs, acc, tau, vs_last, tau_last)
            _rk4(n, k, W, passive, dt, finite_out, arm, real, live, lm, qi, vi, pj, tau, c, s, c0, s0, dyn, chol,
                 stages)
            later = False  # a lane still to step in a later sub-step
            for w in range(W):
                alive[w] = live[w] if w_lo[w] <= sub < w_hi[w] else alive[w]
                later = later or (alive[w] and sub + 1 < w_hi[w])
            _clearance_after((sub + 1) * dt, n, W, O, whole, scratch, arm, live, ln, bx, by, c, s, px, py, obstacles,
                             arm_clear)
            if not later:
                break
        _store_outputs(k, W, arm, real, has_prev, prev_ok, qp_counts, counts, min_clear, arm_clear, min_h, arm_h,
                       max_track, arm_track, v_star_out, vs_last, tau_out, tau_last, v, vi, v_prev, vp)
        _store_state(n, k, W, passive, whole, scratch, q, momentum, qd_out, p_out, arm, real, live, ph, lm, ln, bx, by,
                     qi, vi, pj, c, s, dyn, px, py)
    _keep_alive((obstacles, lane_active, ee_owned, search_owned, owned))


_ADVANCE_DOC = """Advance every arm of a group by ``n_sub`` physics steps with a held command (in place).

    ``group_advance(links, actuated, model, state, stepped, held, world, rcbf, stepping, out, whole)``: after the
    size tuples, one plain tuple per group of :mod:`pan1_env.kernel_groups` (:data:`~pan1_env.kernel_groups.
    KERNEL_GROUPS`, each built by name and passed through :func:`~pan1_env.kernel_groups.plain`), then ``whole``.

    ``links, actuated = kernel_sizes(n, k)`` are tuples of length n and k, the arms' numbers of
    links and actuated joints (``q.shape[1]`` and ``v.shape[1]``, else ValueError): numba types a
    tuple by its length, so n and k are compile-time constants and the kernel is compiled once per
    (n, k) pair, on its first use, and cached on disk. ``model.passive`` must agree with them (k = n − 1
    for a PAn−1 arm, k = n for a fully actuated one, else ValueError): the kernel takes it from k < n,
    a compile-time constant too.

    Arrays are per arm (leading axis A). ``model`` (:class:`~pan1_env.kernel_groups.ArmModel`) holds the
    parameters and ``damping (A,)`` (b of a passive first joint); ``state`` (:class:`~pan1_env.kernel_groups.
    ArmState`) ``q (A, n)``, ``v (A, k)`` and ``momentum (A,)`` (a PAn−1 arm's passive momentum p₁: q̇₁ =
    (p₁ − M_1a v) / M_11, ṗ₁ = −b q̇₁, docs/MODEL.md §7; a fully actuated arm ignores both). ``stepped.rows (R,)``
    (int64, distinct) are the arms advanced: the others, their outputs included, are left as they are
    (an engine's arm that has changed kind keeps a row here, unused, until its next reset). ``stepped.window (A, 2)``
    (int64): arm i is advanced in the call's sub-steps ``window[i, 0] ≤ s < window[i, 1]`` only and held
    where it is outside them (as a non-finite arm is), so that one call can stop an arm where it loses an
    actuator and the next start it there in another kind; ``(0, n_sub)`` or wider: every sub-step. ``world``
    (:class:`~pan1_env.kernel_groups.EndEffectorObstacles`) holds the obstacles each arm's filter sees (a team's
    obstacles are broadcast to every arm).

    ``rcbf`` (:class:`~pan1_env.kernel_groups.FilterSettings`, :func:`pan1_env.compiled.kernel_filter`) is the
    filter's settings: the end-effector filter's rows
    (:func:`pan1_env.kernels.qp._rcbf_row_lanes`) take κ, ε, the margin, the barrier (``distance`` True:
    h = ‖p − o‖ − r, else the paper's squared one) and λ ``decay`` of the tunable ε(h̃) = ε e^{λ h̃} (0: the
    paper's constant ε); ``min_h`` is then in that barrier's unit. The whole-arm rows (``whole``) take the same
    choices, ``by_rate`` picks their last-resort fallback's measure of violation
    (:func:`pan1_env.kernels.last_resort.least_violation`) and ``lookahead`` (s, 0: the obstacles where they are)
    the stretch of each moving obstacle's path that they keep out (:func:`pan1_env.kernels.capsules._capsule_ahead`);
    ``fault_margin`` keeps the fault margin with each arm's ``damping``
    (:func:`pan1_env.kernels.capsules.whole_arm_rows`), and ``tau_max`` (N·m, inf: none) is torque mode's input bound
    (:func:`pan1_env.kernels.qp._keep_torque`). ``stepping`` (:class:`~pan1_env.kernel_groups.Stepping`) holds the
    tracker's gain ``ke``, the sub-step ``dt``, ``n_sub`` and the speed bound ``v_max``; ``held``
    (:class:`~pan1_env.kernel_groups.Command`) the command, ``torque_mode`` and ``filter_on``.

    Velocity mode (``torque_mode`` False): ``command`` is the desired active velocity; each
    sub-step filters it through the RCBF-QP when ``filter_on`` (against the obstacles of ``mask``)
    and tracks v* with the backstepping torque, v̇* by backward difference (``v_prev``/``has_prev``
    hold the previous sub-step's v* per arm; on return they hold the last v*). Torque mode:
    ``command`` is τ_a. Without the filter it is applied as is; with it, the velocity the torque
    would produce after one sub-step, v + dt·M_comb⁻¹(τ_a − H_comb), is filtered, and if the QP
    changes it the arm is driven to the filtered velocity in one sub-step,
    τ_a = M_comb (v* − v)/dt + H_comb, instead. With a finite ``v_max`` the filter's QP also bounds
    every actuated speed, |v_t| ≤ ``v_max``, in both modes: the filtered velocity stays within the
    arm's speed limit (without it, steady torque builds speeds at which a sub-step jumps over the
    safe set's boundary, and a nearly degenerate RCBF row, tiny ‖L_g0 h‖ with b < 0, has a huge
    exact optimum). A problem the box makes infeasible takes the braking fallback.

    ``whole``: None for the end-effector filter above (the paper's); a plain
    :class:`~pan1_env.kernel_groups.WholeArm` for whole-arm safety
    (:mod:`pan1_env.kernels.capsules`): the obstacle arrays are then empty, each filtered arm's rows
    are its bodies against its capsules at the sub-step's time (``start_time`` + elapsed sub-steps),
    solved by the full search, with a fallback that drops the robust term, then takes the least
    violating velocity, ``min_clear`` is its bodies' clearance to the world obstacles, and ``joints``
    gets the arms' base, joints and end-effector at the final state and ``angles`` their link angles'
    cosines and sines, from which a call with ``carried`` starts (with ``finish`` False, ``out.qd`` and
    ``out.p`` are left as they were).

    Outputs (per arm, ``out``: :class:`~pan1_env.kernel_groups.StepOutputs`): ``v_star``/``tau`` of the last
    sub-step (``tau`` either ``(A, k)`` actuated torques or full ``(A, n)`` rows, whose passive entry is left as
    passed in), ``qd`` the joint velocities q̇ = g0 v and ``p`` the end-effector at the final state, ``min_clear`` the
    smallest clearance ‖p − o_j‖ − r_j to any obstacle after every sub-step (running minimum with
    the value passed in), ``min_h`` the smallest filtered barrier seen, ``qp_counts[i, s]`` the
    number of sub-steps with QP status s, ``max_track`` the largest tracking error ‖v − v*‖ at the
    start of a sub-step (velocity mode; running maximum with the value passed in), ``finite``
    False for an arm whose state went non-finite (left at its last finite value). The first stage
    of each RK4 step reuses the terms the filter and tracker computed at the same state.
    """


@njit(**_JIT)
def _check_sizes(links, actuated, model_, state_, stepped_):
    model, state, stepped = ArmModel(*model_), ArmState(*state_), Stepped(*stepped_)
    q, window = state.q, stepped.window
    if window.shape[0] != q.shape[0] or window.shape[1] != 2:
        raise ValueError("group_advance: window needs a (start, stop) pair of sub-steps per arm (q.shape[0], 2)")
    for r in stepped.rows:  # the lanes index the arrays by them unchecked
        if r < 0 or r >= q.shape[0]:
            raise ValueError("group_advance: rows must index the arms (0 <= row < q.shape[0])")
    if q.shape[1] != len(links) or state.v.shape[1] != len(actuated):
        raise ValueError("group_advance: links, actuated must be kernel_sizes(q.shape[1], v.shape[1])")
    if state.momentum.shape[0] != q.shape[0] or model.damping.shape[0] != q.shape[0]:
        raise ValueError("group_advance: momentum and damping need one value per arm (q.shape[0])")
    if len(actuated) != len(links) - (1 if model.passive else 0):
        raise ValueError("group_advance: a PAn-1 arm (passive) has k = n - 1 actuated joints, a full one k = n")


@njit(**_JIT)
def group_advance(links, actuated, model, state, stepped, held, world, rcbf, stepping, out, whole):
    _check_sizes(links, actuated, model, state, stepped)
    hi = len(Stepped(*stepped).rows)
    lo = hi * 0  # an int64, like the parallel kernel's chunk bounds
    groups = (model, state, stepped, held, world, rcbf, stepping, out)
    if whole is None:  # numba prunes the other branch by the argument's type
        _advance_arms(links, actuated, _LANES, None, True, lo, hi, *groups, None)
    else:
        _advance_arms(links, actuated, _LANES, None, True, lo, hi, *groups, WholeArm(*whole))


@njit(**_JIT, parallel=True)
def group_advance_parallel(links, actuated, model, state, stepped, held, world, rcbf, stepping, out, whole, n_chunks):
    _check_sizes(links, actuated, model, state, stepped)
    _check_chunks(n_chunks)
    R = len(Stepped(*stepped).rows)
    for c in prange(n_chunks):
        lo, hi = c * R // n_chunks, (c + 1) * R // n_chunks
        groups = (model, state, stepped, held, world, rcbf, stepping, out)
        if whole is None:
            _advance_arms(links, actuated, _LANES, None, True, lo, hi, *groups, None)
        else:  # named in the loop: numba's parallel loops take plain tuples in, not named ones
            _advance_arms(links, actuated, _LANES, None, True, lo, hi, *groups, WholeArm(*whole))


# The generic kernel: arms of any kind up to GENERIC_MAX_LINKS links, n and k read at run time, one
# lane; compiled once for all kinds (the per-kind kernel's helpers are compiled again for every kind,
# since n, k and W are constants in their types). Scratch arrays are sized for the largest kind.
GENERIC_MAX_LINKS = 8
_GENERIC_SIZES = (0,) * GENERIC_MAX_LINKS
_ONE_LANE = (0,)


def group_advance_generic(links, actuated, model, state, stepped, held, world, rcbf, stepping, out, whole):
    """:func:`group_advance` (same arguments, same results bit for bit) through one kernel compiled for
    every arm kind of at most ``GENERIC_MAX_LINKS`` links: a new kind costs no compilation, and the
    kernel steps 3–4× slower (one arm at a time, loops of run-time length). The engine uses it while a
    kind's own kernel is neither compiled nor in the disk cache (:mod:`pan1_env.kernels.specialise`).
    It calls :func:`_advance_arms` from Python (``whole`` named here): a compiled wrapper would compile its code a
    second time (numba links a callee into its caller's module), about 2 s more."""
    arms, now, which = ArmModel(*model), ArmState(*state), Stepped(*stepped)  # the checks read them by name
    n, k = len(links), len(actuated)
    if now.q.shape[1] != n or now.v.shape[1] != k or not 1 <= k <= n <= GENERIC_MAX_LINKS or \
            k != n - bool(arms.passive):
        raise ValueError(f"group_advance_generic: arms of n ≤ {GENERIC_MAX_LINKS} links (q.shape[1]) and k actuated "
                         "joints (v.shape[1]), links, actuated = kernel_sizes(n, k): k = n − 1 with a passive first "
                         "joint, else k = n")
    if len(now.momentum) != len(now.q) or len(arms.damping) != len(now.q):
        raise ValueError("group_advance_generic: momentum and damping need one value per arm (q.shape[0])")
    rows = np.asarray(which.rows)
    if rows.dtype != np.int64 or rows.ndim != 1 or (len(rows) and not 0 <= rows.min() <= rows.max() < len(now.q)):
        raise ValueError("group_advance_generic: rows must be int64 indices of the arms (0 <= row < q.shape[0])")
    window = np.asarray(which.window)
    if window.dtype != np.int64 or window.shape != (len(now.q), 2):
        raise ValueError("group_advance_generic: window needs an int64 (start, stop) pair of sub-steps per arm")
    model = plain(arms._replace(passive=bool(arms.passive)))  # one type for every caller's flag: one compilation
    _advance_arms(_GENERIC_SIZES, _GENERIC_SIZES, _ONE_LANE, (n, k), None, 0, len(rows), model, state,
                  plain(Stepped(rows, window)), held, world, rcbf, stepping, out,
                  None if whole is None else WholeArm(*whole))


group_advance.__doc__ = _ADVANCE_DOC
_quick_when(_slp_vectorised(_advance_arms), 3)  # the generic kernel's signature (sizes given) at LLVM -O1
_slp_vectorised(group_advance)
_slp_vectorised(group_advance_parallel)
group_advance_parallel.__doc__ = _ADVANCE_DOC + """
    The same, with the arms split into ``n_chunks`` chunks run on numba's thread pool (for large
    batches; a call costs a few microseconds more than :func:`group_advance`). Both run the same
    compiled :func:`_advance_arms`, chunk by chunk here: each lane computes its own arm with no
    reduction across lanes or arms, so the chunks' padded lane groups change nothing and the two give
    the same results bit for bit (``tests/test_kernels.py``, ``tests/test_vector.py``,
    ``tests/test_determinism.py``).
    """

