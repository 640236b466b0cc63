"""Compiled random teams: :func:`pan1_env.random_scenario.random_scenario`'s attempts, for many copies in one call.

:func:`draw_teams` runs, for each copy, the reference's loop of attempts (arms around their target configuration,
their zero-momentum start, the σ_min(J̄) and inter-arm checks, the obstacles' rejection loop, the faults) in
compiled code. Each copy draws from its own ``numpy.random.Generator``: the kernel calls that generator's own bit
generator functions (``next_double``, ``next_uint32``, through the ``bitgen_t`` struct numpy's C API publishes
in ``BitGenerator.capsule``) in the reference's order, with the reference's distributions (uniform: low + (high − low)
· u; ``choice([−1, 1])``: the top bit of a 32-bit draw, numpy's Lemire bound for two values). So a copy's team,
and the generator state it leaves, depend on its generator only, and equal the reference's up to floating-point
rounding in the geometry (the formulas are the same; sums and products run in another order, so the last bits
can differ: tests/test_team_draw.py compares the two on hundreds of seeds). The formation's motion, when the
options move it, stays with the reference (:func:`pan1_env.random_scenario.draw_motion`): the caller draws it
after the kernel, and asks the kernel for a new team if it fails.

Importing this module imports numba; :mod:`pan1_env` imports it only when an env draws teams. It lives outside
:mod:`pan1_env.kernels`, whose cache stamp covers that whole package, so that it compiles (about ten seconds) on its
own.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["draw_teams", "stream_sample", "REAL_OPTIONS", "FLAG_OPTIONS"]

#: the kernel's real options, in order (``pan1_env.team_draw._kernel_options`` packs them)
REAL_OPTIONS = ("size_lo", "size_hi", "radius_lo", "radius_hi", "start_clearance", "min_sigma", "link_radius",
                "speed_lo", "speed_hi", "path_lo", "path_hi", "fault_probability", "fault_lo", "fault_hi",
                "shape_divisor", "base_margin")
#: the kernel's integer options, in order
FLAG_OPTIONS = ("n_obstacles", "links_bodies", "inter_arm", "moving", "arm_redraws", "clear_paths")
_R = {name: i for i, name in enumerate(REAL_OPTIONS)}
_F = {name: i for i, name in enumerate(FLAG_OPTIONS)}
SIZE_LO, SIZE_HI, RAD_LO, RAD_HI, CLEAR, SIGMA, RHO = (_R[n] for n in REAL_OPTIONS[:7])
SPEED_LO, SPEED_HI, PATH_LO, PATH_HI, FAULT_P, FAULT_LO, FAULT_HI, DIVISOR, MARGIN = (_R[n] for n in REAL_OPTIONS[7:])
N_OBST, LINKS, INTER_ARM, MOVING, REDRAWS, CLEAR_PATHS = (_F[n] for n in FLAG_OPTIONS)
_STEPS = 200  # zero_momentum_start's trapezoid steps
_JIT = {"cache": True, "error_model": "numpy"}  # no fast-math: the reference's rounding as far as possible


def _bitgen_call(builder, bitgen, field, result):
    """Call field ``field`` of numpy's ``bitgen_t {state, next_uint64, next_uint32, next_double, next_raw}`` at the
    address ``bitgen`` on its state."""
    pointers = builder.inttoptr(bitgen, ir.ArrayType(cgutils.voidptr_t, 5).as_pointer())
    state = builder.load(builder.gep(pointers, [ir.Constant(ir.IntType(32), 0), ir.Constant(ir.IntType(32), 0)]))
    address = builder.load(builder.gep(pointers, [ir.Constant(ir.IntType(32), 0), ir.Constant(ir.IntType(32), field)]))
    fn = builder.bitcast(address, ir.FunctionType(result, [cgutils.voidptr_t]).as_pointer())
    return builder.call(fn, [state])


@intrinsic
def _next_double(typingctx, bitgen):
    """The bit generator's ``next_double`` (a uniform double in [0, 1)); ``bitgen``: its ``bitgen_t`` address."""
    sig = types.float64(types.int64)

    def codegen(context, builder, signature, args):
        return _bitgen_call(builder, args[0], 3, ir.DoubleType())

    return sig, codegen


@intrinsic
def _next_uint32(typingctx, bitgen):
    """The bit generator's ``next_uint32``; ``bitgen``: its ``bitgen_t`` address."""
    sig = types.uint32(types.int64)

    def codegen(context, builder, signature, args):
        return _bitgen_call(builder, args[0], 2, ir.IntType(32))

    return sig, codegen


@njit(**_JIT)
def _uniform(gen, lo, hi):
    """``Generator.uniform(lo, hi)``: lo + (hi − lo) · u. ``gen``: the address of the generator's ``bitgen_t``."""
    return lo + (hi - lo) * _next_double(gen)


@njit(**_JIT)
def _sign(gen):
    """``Generator.choice([−1.0, 1.0])``: index (u32 · 2) >> 32, numpy's Lemire bound for two values."""
    return 1.0 if (np.uint64(_next_uint32(gen)) * np.uint64(2)) >> np.uint64(32) else -1.0


@njit(**_JIT)
def stream_sample(gen, uniforms, signs, doubles):
    """Fill the arrays with ``_uniform(gen, 0.3, 1.2)``, ``_sign(gen)`` and ``_next_double(gen)`` in turn (k of each,
    in this order), as the reference draws them with ``uniform``, ``choice([−1, 1])`` and ``random``: the check that
    this numpy's distributions are still the ones the kernel reproduces (``pan1_env.team_draw``)."""
    k = len(uniforms)
    for i in range(k):
        uniforms[i] = _uniform(gen, 0.3, 1.2)
    for i in range(k):
        signs[i] = _sign(gen)
    for i in range(k):
        doubles[i] = _next_double(gen)


@njit(**_JIT)
def _tip(lengths, q, n, base):
    """End-effector p0 + Σ L_α [sin θ_α, cos θ_α], θ = cumsum(q) (φ = 0), as (x, y)."""
    theta, x, y = 0.0, 0.0, 0.0
    for a in range(n):
        theta += q[a]
        x += lengths[a] * math.sin(theta)
        y += lengths[a] * math.cos(theta)
    return base[0] + x, base[1] + y


@njit(**_JIT)
def _lam(m, L, com, inertia, n, lam):
    """λ (docs/MODEL.md §1) into ``lam[:n, :n]``, as :func:`pan1_env.dynamics._lambda`."""
    for a in range(n):
        tail = 0.0
        for g in range(n - 1, a, -1):
            tail += m[g]
        lam[a, a] = inertia[a] + m[a] * com[a] ** 2 + L[a] ** 2 * tail
    for b in range(n):
        tail = 0.0
        for g in range(n - 1, b, -1):
            tail += m[g]
        for a in range(b):
            lam[a, b] = lam[b, a] = m[b] * L[a] * com[b] + L[a] * L[b] * tail


@njit(**_JIT)
def _first_row(lam, q, n, cos, row):
    """Row 1 of M(q) into ``row[:n]``: M_1j = Σ_α Σ_{β≥j} λ_αβ cos(θ_β − θ_α), summed in
    :func:`pan1_env.dynamics.in_joint_coordinates`' order (β, then α, from the last); ``cos (n, n)`` scratch."""
    for a in range(n):
        cos[a, a] = 1.0
        t = 0.0
        for b in range(a + 1, n):
            t += q[b]  # θ_β − θ_α
            cos[a, b] = cos[b, a] = math.cos(t)
    _row_from_cos(lam, n, cos, row)


@njit(**_JIT)
def _row_from_cos(lam, n, cos, row):
    """``row[j] = Σ_a Σ_{b ≥ j} λ_ab cos_ab`` for the ``n`` joints: the mass matrix's first row M₁ⱼ at the
    cosines ``cos`` of the angle differences, whose ratio −M₁ₐ/M₁₁ is the passive joint's slope along the path."""
    for j in range(n):
        total = 0.0
        for a in range(n - 1, -1, -1):
            y = 0.0
            for b in range(n - 1, j - 1, -1):
                y += lam[a, b] * cos[a, b]
            total += y
        row[j] = total


@njit(**_JIT)
def _zero_momentum_q1(lam, q_target, qa_start, n, cos, sin, step_cos, step_sin, row):
    """:func:`pan1_env.random_scenario.zero_momentum_start`'s passive angle: q₁ after the straight actuated path
    s ∈ [0, 1] (the trapezoid rule on the same 200 steps). θ_β − θ_α is linear in s, so its cosine goes from step
    to step by one rotation (no trigonometric call per step; it drifts from the reference by ~1e-14 rad)."""
    h = 1.0 / _STEPS
    for a in range(n):
        t0, dt = 0.0, 0.0
        for b in range(a + 1, n):
            t0 += q_target[b]
            dt += qa_start[b - 1] - q_target[b]
            cos[a, b], sin[a, b] = math.cos(t0), math.sin(t0)
            cos[b, a] = cos[a, b]
            step_cos[a, b], step_sin[a, b] = math.cos(h * dt), math.sin(h * dt)
        cos[a, a] = 1.0
    total, previous = 0.0, 0.0
    for k in range(_STEPS + 1):
        if k > 0:
            for a in range(n):
                for b in range(a + 1, n):
                    c, s = cos[a, b], sin[a, b]
                    cos[a, b] = c * step_cos[a, b] - s * step_sin[a, b]
                    sin[a, b] = s * step_cos[a, b] + c * step_sin[a, b]
                    cos[b, a] = cos[a, b]
        _row_from_cos(lam, n, cos, row)
        dot = 0.0
        for j in range(1, n):
            dot += row[j] * (qa_start[j - 1] - q_target[j])
        slope = -dot / row[0]
        if k > 0:
            total += 0.5 * (slope + previous) * h
        previous = slope
    return q_target[0] + total


@njit(**_JIT)
def _sigma_min(lam, L, q, n, passive, scratch, cos):
    """σ_min(J̄) at ``q``: J̄ = J g0 (2 × k), from the 2 × 2 Gram matrix J̄ J̄ᵀ. It does not depend on q₁ (turning
    the whole arm turns J̄), which may be a stand-in."""
    theta, row, jx, jy = scratch[1], scratch[2], scratch[3], scratch[4]
    t = 0.0
    for a in range(n):
        t += q[a]
        theta[a] = t
    sx, sy = 0.0, 0.0
    for a in range(n - 1, -1, -1):  # J's columns: reverse sums of L [cos θ, −sin θ]
        sx += L[a] * math.cos(theta[a])
        sy += -L[a] * math.sin(theta[a])
        jx[a], jy[a] = sx, sy
    first = 0
    if passive:
        _first_row(lam, q, n, cos, row)
        first = 1
    gxx, gyy, gxy = 0.0, 0.0, 0.0
    for c in range(first, n):
        cx, cy = jx[c], jy[c]
        if passive:
            g = -row[c] / row[0]
            cx, cy = jx[0] * g + cx, jy[0] * g + cy
        gxx += cx * cx
        gyy += cy * cy
        gxy += cx * cy
    if n - first == 1:
        return math.sqrt(gxx + gyy)
    half = 0.5 * (gxx - gyy)
    low = 0.5 * (gxx + gyy) - math.sqrt(half * half + gxy * gxy)
    return math.sqrt(max(low, 0.0))


@njit(**_JIT)
def _segment_distance(a1x, a1y, b1x, b1y, a2x, a2y, b2x, b2y):
    """:func:`pan1_env.bodies.segment_distance`'s d (Ericson §5.1.9)."""
    d1x, d1y, d2x, d2y, rx, ry = b1x - a1x, b1y - a1y, b2x - a2x, b2y - a2y, a1x - a2x, a1y - a2y
    A, E, B = d1x * d1x + d1y * d1y, d2x * d2x + d2y * d2y, d1x * d2x + d1y * d2y
    C, F = d1x * rx + d1y * ry, d2x * rx + d2y * ry
    A_safe, E_safe = A if A > 0 else 1.0, E if E > 0 else 1.0
    denom = A * E - B * B
    s = min(max((B * F - C * E) / denom, 0.0), 1.0) if denom > 1e-12 * A * E else 0.0
    t = (B * s + F) / E_safe
    if t < 0:
        s = min(max(-C / A_safe, 0.0), 1.0)
    elif t > 1:
        s = min(max((B - C) / A_safe, 0.0), 1.0)
    t = min(max(t, 0.0), 1.0)
    dx = (a1x + s * d1x) - (a2x + t * d2x)
    dy = (a1y + s * d1y) - (a2y + t * d2y)
    return math.sqrt(dx * dx + dy * dy)


@njit(**_JIT)
def _point_segment_distance(ax, ay, bx, by, px, py):
    """‖x − p‖ for x the closest point of segment [a, b] to p (:func:`pan1_env.bodies.closest_point_on_segment`)."""
    abx, aby = bx - ax, by - ay
    length2 = abx * abx + aby * aby
    t = min(max(((px - ax) * abx + (py - ay) * aby) / (length2 if length2 > 0 else 1.0), 0.0), 1.0)
    dx, dy = ax + t * abx - px, ay + t * aby - py
    return math.sqrt(dx * dx + dy * dy)


@njit(**_JIT)
def _joints(L, q, n, base, out):
    """Base and joint positions ``out[:n + 1]`` of an arm (φ = 0)."""
    theta, x, y = 0.0, 0.0, 0.0
    out[0, 0], out[0, 1] = base[0], base[1]
    for a in range(n):
        theta += q[a]
        x += L[a] * math.sin(theta)
        y += L[a] * math.cos(theta)
        out[a + 1, 0], out[a + 1, 1] = base[0] + x, base[1] + y


@njit(**_JIT)
def _draw_arm(gen, i, n, passive, target, outward, out, q_t):
    """Arm i's parameters, base, target configuration ``q_t`` and start (``out``: lengths, masses, com, inertias,
    lam, base, q0, … of this copy), its end-effector at ``target`` in ``q_t`` (random_scenario's per-arm draws).
    A PA arm's q₁ at the start is left at its target's (:func:`_zero_momentum_q1` gives it)."""
    L, m, com, inertia, lam, base, q0 = out[0][i], out[1][i], out[2][i], out[3][i], out[4][i], out[5][i], out[6][i]
    for a in range(n):
        L[a] = _uniform(gen, 0.25, 0.5)
    for a in range(n):
        m[a] = _uniform(gen, 0.2, 0.5)
    for a in range(n):
        com[a] = L[a] * _uniform(gen, 0.35, 0.65)
    for a in range(n):
        inertia[a] = m[a] * (L[a] * L[a]) / 12.0 * _uniform(gen, 0.8, 1.2)
    for a in range(n):
        q_t[a] = _uniform(gen, -np.pi, np.pi)
    for a in range(1, n):
        q_t[a] = _uniform(gen, 0.3, 1.2)
    for a in range(1, n):
        q_t[a] = q_t[a] * _sign(gen)
    zero = np.zeros(2)
    rx, ry = _tip(L, q_t, n, zero)
    ang_now = math.atan2(rx, ry)
    ang_want = math.atan2(-outward[0], -outward[1]) + _uniform(gen, -0.6, 0.6)
    q_t[0] += ang_want - ang_now
    rx, ry = _tip(L, q_t, n, zero)
    base[0], base[1] = target[0] - rx, target[1] - ry
    _lam(m, L, com, inertia, n, lam)
    if passive:
        q0[0] = q_t[0]
        for a in range(1, n):
            q0[a] = q_t[a] + _uniform(gen, -1.0, 1.0)
    else:
        for a in range(n):
            q0[a] = q_t[a] + _uniform(gen, -1.0, 1.0)


@njit(**_JIT)
def _arms_apart(links, joints, N, rho, clear):
    """Every pair of arms' link capsules at least ``clear`` apart (segment distance − 2ρ)."""
    for i in range(N):
        if not _apart_from_earlier(i, links, joints, rho, clear):
            return False
    return True


@njit(**_JIT)
def _place_obstacles(gen, real, flags, links, passive, starts, targets, joints, out):
    """The reference's obstacle rejection loop; False if it ran out of candidates."""
    N, O = len(links), flags[N_OBST]
    lengths, base, centers, radii, ends, speeds = out[0], out[5], out[7], out[8], out[9], out[10]
    rho, clear, margin = real[RHO], real[CLEAR], real[MARGIN]
    lo_x = min(starts[:, 0].min(), targets[:, 0].min()) - 0.2
    lo_y = min(starts[:, 1].min(), targets[:, 1].min()) - 0.2
    hi_x = max(starts[:, 0].max(), targets[:, 0].max()) + 0.2
    hi_y = max(starts[:, 1].max(), targets[:, 1].max()) + 0.2
    placed = 0
    for _ in range(50 * max(O, 1)):
        if placed == O:
            break
        cx, cy = _uniform(gen, lo_x, hi_x), _uniform(gen, lo_y, hi_y)
        r = _uniform(gen, real[RAD_LO], real[RAD_HI])
        ok = True
        for i in range(N):
            if (math.sqrt((starts[i, 0] - cx) ** 2 + (starts[i, 1] - cy) ** 2) - r < clear
                    or math.sqrt((targets[i, 0] - cx) ** 2 + (targets[i, 1] - cy) ** 2) < r + 0.05
                    or math.sqrt((base[i, 0] - cx) ** 2 + (base[i, 1] - cy) ** 2) < r + margin + rho):
                ok = False
        for o in range(placed):
            if math.sqrt((cx - centers[o, 0]) ** 2 + (cy - centers[o, 1]) ** 2) < r + radii[o]:
                ok = False
        if not ok:
            continue
        if flags[LINKS]:
            for i in range(N):
                for a in range(links[i]):
                    d = _point_segment_distance(joints[i, a, 0], joints[i, a, 1], joints[i, a + 1, 0],
                                                joints[i, a + 1, 1], cx, cy)
                    if d - r - rho < clear:
                        ok = False
            if not ok:
                continue
        if flags[MOVING]:
            lo, hi = real[SPEED_LO], real[SPEED_HI]
            speed = hi - _uniform(gen, 0.0, hi - lo)
            angle = _uniform(gen, -np.pi, np.pi)
            length = _uniform(gen, real[PATH_LO], real[PATH_HI])
            ex, ey = cx + length * math.cos(angle), cy + length * math.sin(angle)
            for i in range(N):
                sweep = lengths[i, 0] if passive[i] else 0.0
                if _point_segment_distance(cx, cy, ex, ey, base[i, 0], base[i, 1]) < r + margin + rho + sweep:
                    ok = False
            if not ok or (flags[CLEAR_PATHS] and not _path_clear(flags[LINKS], links, starts, targets, joints, cx, cy,
                                                                 ex, ey, r, rho, clear)):
                continue
            ends[placed, 0], ends[placed, 1], speeds[placed] = ex, ey, speed
        else:
            ends[placed, 0], ends[placed, 1], speeds[placed] = cx, cy, 0.0
        centers[placed, 0], centers[placed, 1], radii[placed] = cx, cy, r
        placed += 1
    return placed == O


@njit(**_JIT)
def _path_clear(link_bodies, links, starts, targets, joints, cx, cy, ex, ey, r, rho, clear):
    """The reference's ``clear_paths`` check: the swept capsule from (cx, cy) to (ex, ey) of radius r keeps
    ``clear`` from every starting end-effector (and link) and 5 cm from every target."""
    for i in range(len(links)):
        if (_point_segment_distance(cx, cy, ex, ey, starts[i, 0], starts[i, 1]) - r < clear
                or _point_segment_distance(cx, cy, ex, ey, targets[i, 0], targets[i, 1]) < r + 0.05):
            return False
        if link_bodies:
            for a in range(links[i]):
                d = _segment_distance(joints[i, a, 0], joints[i, a, 1], joints[i, a + 1, 0], joints[i, a + 1, 1],
                                      cx, cy, ex, ey)
                if d - r - rho < clear:
                    return False
    return True


@njit(**_JIT)
def _start(i, n, passive, out, q_target, mats, scratch, starts, joints):
    """Arm i's start: a PA arm's q₁ from its zero-momentum path, then its end-effector and joint positions."""
    q0 = out[6][i]
    if passive:
        q0[0] = _zero_momentum_q1(out[4][i], q_target, q0[1:], n, mats[0], mats[1], mats[2], mats[3], scratch[2])
    starts[i, 0], starts[i, 1] = _tip(out[0][i], q0, n, out[5][i])
    _joints(out[0][i], q0, n, out[5][i], joints[i])


@njit(**_JIT)
def _apart_from_earlier(i, links, joints, rho, clear):
    """Arm i's link capsules at least ``clear`` from those of arms 0 … i − 1 (segment distance − 2ρ)."""
    for j in range(i):
        for a in range(links[i]):
            for b in range(links[j]):
                d = _segment_distance(joints[i, a, 0], joints[i, a, 1], joints[i, a + 1, 0], joints[i, a + 1, 1],
                                      joints[j, b, 0], joints[j, b, 1], joints[j, b + 1, 0], joints[j, b + 1, 1])
                if d - 2.0 * rho < clear:
                    return False
    return True


@njit(**_JIT)
def _attempt(gen, real, flags, links, passive, unit, out, work):
    """One of random_scenario's attempts into ``out``; True if it passed every check. ``work``: scratch."""
    scratch, mats, q_targets = work
    N = len(links)
    size = _uniform(gen, real[SIZE_LO], real[SIZE_HI])
    rot = _uniform(gen, -np.pi, np.pi)
    out[11][0], out[11][1] = size, rot
    radius = size / real[DIVISOR]
    mx, my = 0.0, 0.0
    for i in range(N):
        mx += radius * unit[i, 0]
        my += radius * unit[i, 1]
    mx, my = mx / N, my / N
    c, s = math.cos(rot), math.sin(rot)
    targets = out[12]
    cx, cy = 0.0, 0.0
    for i in range(N):
        px, py = radius * unit[i, 0] - mx, radius * unit[i, 1] - my
        targets[i, 0], targets[i, 1] = px * c - py * s, px * s + py * c
        cx += targets[i, 0]
        cy += targets[i, 1]
    cx, cy = cx / N, cy / N
    outward = np.empty(2)
    starts, joints, redraws = np.empty((N, 2)), out[13], flags[REDRAWS]
    for i in range(N):
        ox, oy = targets[i, 0] - cx, targets[i, 1] - cy
        norm = math.sqrt(ox * ox + oy * oy) + 1e-12
        outward[0], outward[1] = ox / norm, oy / norm
        passed = False
        for _ in range(redraws + 1):
            _draw_arm(gen, i, links[i], passive[i], targets[i], outward, out, q_targets[i])
            if redraws == 0:
                passed = True
                break
            if _sigma_min(out[4][i], out[0][i], out[6][i], links[i], passive[i], scratch, mats[0]) >= real[SIGMA]:
                _start(i, links[i], passive[i], out, q_targets[i], mats, scratch, starts, joints)
                if not flags[INTER_ARM] or _apart_from_earlier(i, links, joints, real[RHO], real[CLEAR]):
                    passed = True
                    break
        if not passed:
            return False
    if redraws == 0:
        for i in range(N):  # σ_min first: it needs no q₁, the costliest part of the start
            if _sigma_min(out[4][i], out[0][i], out[6][i], links[i], passive[i], scratch, mats[0]) < real[SIGMA]:
                return False
        for i in range(N):
            _start(i, links[i], passive[i], out, q_targets[i], mats, scratch, starts, joints)
        if flags[INTER_ARM] and not _arms_apart(links, joints, N, real[RHO], real[CLEAR]):
            return False
    return _place_obstacles(gen, real, flags, links, passive, starts, targets, joints, out)


@njit(**_JIT)
def _faults(gen, real, passive, fault_times):
    """Each fully actuated arm's fault time (inf: none), drawn as the reference does after the team."""
    N = len(passive)
    if real[FAULT_P] <= 0:
        fault_times[:] = np.inf
        return
    hit = np.empty(N, dtype=np.bool_)
    for i in range(N):
        hit[i] = _next_double(gen) < real[FAULT_P] and not passive[i]
    for i in range(N):
        t = _uniform(gen, real[FAULT_LO], real[FAULT_HI])
        fault_times[i] = t if hit[i] else np.inf


@njit(**_JIT)
def draw_teams(gens, tries, real, flags, links, passive, unit, lengths, masses, com, inertias, lam, base, q0,
               centers, radii, ends, speeds, size_rot, targets, joints, fault_times):
    """For each copy c: up to ``tries[c]`` attempts from its generator ``gens[c]`` (the address of its bit
    generator's ``bitgen_t``, the struct of numpy's C API); its team into row c of the outputs. Returns the
    attempts each copy used (``tries[c] + 1`` if none passed: the options are too tight).

    ``real`` and ``flags``: the options, as :data:`REAL_OPTIONS` and :data:`FLAG_OPTIONS` order them; ``links``
    and ``passive`` ``(N,)``: each arm's links and whether its first joint is passive; ``unit (N, 2)``: the shape's
    vertices for a side of ``real[shape_divisor]``. Outputs ``(C, N, n_max)`` (lengths, masses, com, inertias, q0),
    ``(C, N, n_max, n_max)`` (λ), ``(C, N, 2)`` (base, targets: the placed vertices), ``(C, O, 2)`` (centres, path
    ends), ``(C, O)`` (radii, speeds), ``(C, 2)`` (the side and the placement's turn), ``(C, N, n_max + 1, 2)``
    (joint positions at the start) and ``(C, N)`` (fault times, inf: none)."""
    C, N = len(gens), len(links)
    used = np.zeros(C, dtype=np.int64)
    width = max(links.max() + 1, N)
    for k in range(C):
        gen = gens[k]
        work = (np.zeros((8, width)), np.zeros((4, width, width)), np.zeros((N, width)))
        out = (lengths[k], masses[k], com[k], inertias[k], lam[k], base[k], q0[k], centers[k], radii[k], ends[k],
               speeds[k], size_rot[k], targets[k], joints[k])
        used[k] = tries[k] + 1
        for attempt in range(tries[k]):
            if _attempt(gen, real, flags, links, passive, unit, out, work):
                _faults(gen, real, passive, fault_times[k])
                used[k] = attempt + 1
                break
    return used
