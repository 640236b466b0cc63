"""The sub-step kernel's scratch space (:func:`pan1_env.kernels.substep._advance_arms`): the named groups its steps
(:mod:`.steps`) take, and their allocation.

Each ``_*_scratch`` function is inlined into the kernel by numba (``inline="always"``), so the arrays it makes with
:func:`._numba_ext._local` are stack arrays of the kernel's own frame (shapes from the size tuples ``links``,
``actuated``, ``lanes``, so fixed at compile time, the lanes last): call them only from a function they are inlined
into, never from Python or a function compiled on its own, where those arrays would not outlive the call. The arrays
whose size is not fixed at compile time (by the number of obstacles, capsules, filter rows or links) are on the
heap. The kernel passes the groups holding heap arrays to its steps unreferenced
(:func:`._numba_ext._borrowed`) and keeps the originals alive to its end."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ._numba_ext import _JIT, _local
from .capsules import NEAR_COLUMNS, most_rows, speed_box_rows

f8, b1, i8 = np.float64, np.bool_, np.int64  # the scratch arrays' dtypes


class Dynamics(NamedTuple):
    """The terms at a state, per lane (:func:`pan1_env.kernels.physics._mass_lanes`)."""
    M: np.ndarray
    R: np.ndarray
    Sn: np.ndarray
    Mc: np.ndarray
    Hc: np.ndarray
    qd: np.ndarray
    thd: np.ndarray
    H: np.ndarray


class PassiveJoint(NamedTuple):
    """Per lane: a PAn−1 arm's passive momentum p₁ (state) and the first joint's damping b (docs/MODEL.md §7)."""
    p1: np.ndarray
    damping: np.ndarray


class AccelerationSolve(NamedTuple):
    """The solve for the accelerations (:func:`pan1_env.kernels.physics._acceleration_lanes`)."""
    rhs: np.ndarray
    Lc: np.ndarray
    yc: np.ndarray
    ok: np.ndarray


class Rk4Stages(NamedTuple):
    """RK4's trial state, stage derivative and weighted sums (:func:`.steps._rk4`)."""
    qt: np.ndarray
    vt: np.ndarray
    dv: np.ndarray
    sq: np.ndarray
    sv: np.ndarray
    pt: np.ndarray
    sp: np.ndarray


class Tracker(NamedTuple):
    """The tracker's terms the filters look ahead with: torque mode, K_e, dt, the lanes' actuated velocities v,
    their last v* and whether it is set."""
    torque_mode: bool
    ke: float
    dt: float
    v: np.ndarray
    v_prev: np.ndarray
    has_prev: np.ndarray


class QpSearch(NamedTuple):
    """One lane's full QP search (:func:`pan1_env.kernels.qp._project_one`): its rows, the target and answer."""
    Arows: np.ndarray
    brows: np.ndarray
    active: np.ndarray
    qrows: np.ndarray
    qviol: np.ndarray
    qnorm: np.ndarray
    qidx: np.ndarray
    qv0: np.ndarray
    qvs: np.ndarray
    qG: np.ndarray
    qL: np.ndarray
    qr: np.ndarray
    qlam: np.ndarray
    qcand: np.ndarray
    qy: np.ndarray
    qtarget: np.ndarray


class EndEffectorScratch(NamedTuple):
    """The end-effector filter's Jacobians, rows and lane-batched first candidate
    (:func:`.steps._filter_end_effector`)."""
    J: np.ndarray
    Jbar: np.ndarray
    drift: np.ndarray
    filtered: np.ndarray
    row_A: np.ndarray
    row_b: np.ndarray
    row_h: np.ndarray
    row_norm: np.ndarray
    row_act: np.ndarray
    obst_rows: np.ndarray
    needs_qp: np.ndarray
    q_best: np.ndarray
    q_best_viol: np.ndarray
    q_Ab: np.ndarray
    q_bb: np.ndarray
    q_cand: np.ndarray
    q_found: np.ndarray


class WholeArmScratch(NamedTuple):
    """One lane's whole-arm rows (bodies × capsules, speed bounds), its joints, and the lanes' joints and nearest
    obstacle (:func:`.steps._filter_whole_arm`)."""
    wA: np.ndarray
    wb: np.ndarray
    wact: np.ndarray
    wP: np.ndarray
    wnear: np.ndarray
    wrows: np.ndarray
    wviol: np.ndarray
    wnorm: np.ndarray
    wb0: np.ndarray
    wn0: np.ndarray
    joints_x: np.ndarray
    joints_y: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    orad: np.ndarray


@njit(**_JIT, inline="always")
def _lane_arms_scratch(links, actuated, lanes):
    """The lanes' arms, parameters and state, in this order: the arm's index, whether the lane is real (not
    padding), its λ (n × n), link lengths, q, v, last v*, base x, y and angle φ, and its passive joint."""
    lw, nw, kw = (lanes,), (links, lanes), (actuated, lanes)
    return (_local(lw, i8), _local(lw, b1), _local((links, links, lanes), f8), _local(nw, f8), _local(nw, f8),
            _local(kw, f8), _local(kw, f8), _local(lw, f8), _local(lw, f8), _local(lw, f8),
            PassiveJoint(_local(lw, f8), _local(lw, f8)))


@njit(**_JIT, inline="always")
def _dynamics_scratch(links, actuated, lanes):
    """The terms at a state and the solve for the accelerations, per lane."""
    nw, kw, nnw, kkw = (links, lanes), (actuated, lanes), (links, links, lanes), (actuated, actuated, lanes)
    dyn = Dynamics(_local(nnw, f8), _local(nnw, f8), _local(nnw, f8), _local(kkw, f8), _local(kw, f8), _local(nw, f8),
                   _local(nw, f8), _local(nw, f8))
    return dyn, AccelerationSolve(_local(kw, f8), _local(kkw, f8), _local(kw, f8), _local((lanes,), b1))


@njit(**_JIT, inline="always")
def _rk4_scratch(links, actuated, lanes):
    """RK4's trial state, stage derivative and weighted sums, per lane."""
    lw, nw, kw = (lanes,), (links, lanes), (actuated, lanes)
    return Rk4Stages(_local(nw, f8), _local(kw, f8), _local(kw, f8), _local(nw, f8), _local(kw, f8), _local(lw, f8),
                     _local(lw, f8))


@njit(**_JIT, inline="always")
def _end_effector_scratch(links, actuated, lanes, obstacles, k):
    """The end-effector filter's Jacobians, rows (one obstacle's row per lane at a time; every obstacle's on the
    heap) and lane-batched first candidate."""
    lw, kw = (lanes,), (actuated, lanes)
    return EndEffectorScratch(_local(((0, 0), links, lanes), f8), _local(((0, 0), actuated, lanes), f8),
                              _local(((0, 0), lanes), f8), _local(lw, b1), _local(kw, f8), _local(lw, f8),
                              _local(lw, f8), _local(lw, f8), _local(lw, b1), np.empty((obstacles, k + 2, len(lanes))),
                              _local(lw, b1), _local(lw, i8), _local(lw, f8), _local(kw, f8), _local(lw, f8),
                              _local(kw, f8), _local(lw, b1))


@njit(**_JIT, inline="always")
def _qp_search_scratch(actuated, obstacles, k, v_max):
    """One lane's full QP search (on the heap): rows for the ``obstacles``, then 2k speed bounds and 2k for torque
    mode's input bound, of max(k, 1) columns. With a finite ``v_max`` the speed bounds ±v_t ≤ v_max are set here
    once: the same in every lane."""
    kx, kkx = (actuated,), (actuated, actuated)
    rows = obstacles + 4 * k
    search = QpSearch(np.zeros((rows, max(k, 1))), np.zeros(rows), np.zeros(rows, dtype=b1), np.empty(rows, dtype=i8),
                      np.empty(rows), np.empty(rows), _local(kx, i8), _local(kx, f8), _local(kx, f8), _local(kkx, f8),
                      _local(kkx, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8), _local(kx, f8))
    if v_max < np.inf:
        speed_box_rows(obstacles, k, v_max, search.Arows, search.brows, search.active)
    return search


@njit(**_JIT, inline="always")
def _whole_arm_scratch(whole, links, lanes, n, k):
    """One lane's whole-arm rows (bodies × capsules, speed bounds; on the heap), and the lanes' joints (n + 1 per
    lane) and nearest obstacle."""
    lw, jw = (lanes,), (links + (0,), lanes)
    rows = most_rows(n if whole.link_bodies else 1, whole.caps.shape[1], whole.n_world, k)
    return WholeArmScratch(np.zeros((rows, max(k, 1))), np.zeros(rows), np.zeros(rows, dtype=b1), np.empty((n + 1, 2)),
                           np.empty((whole.caps.shape[1], NEAR_COLUMNS)), np.empty(rows, dtype=i8), np.empty(rows),
                           np.empty(rows), np.empty(rows), np.empty(rows), _local(jw, f8), _local(jw, f8),
                           _local(lw, f8), _local(lw, f8), _local(lw, f8))
