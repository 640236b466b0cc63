"""The tasks' per-step numbers, compiled: the formation's and the reach task's outcome (rewards, costs, success,
termination) and the safety filter's report of a step. tests/test_tasks.py checks each against its numpy twin."""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_ext import _EXACT, _JIT


@njit(**_JIT)
def formation_outcome(err, min_clear, formation_weight, tolerance, formation, formation_error, success, cost):
    """The formation task's per-step numbers of B teams, in one pass (the formulas of
    :meth:`pan1_env.tasks.FormationTask.evaluate`): from the edge errors ``err (B, E)`` and the arms'
    smallest clearances ``min_clear (B, N)``, ``formation[b] = −w·mean_e |err|``,
    ``formation_error[b] = max_e |err|``, ``success[b] = formation_error < tolerance`` and
    ``cost[b, i] = 1.0`` where arm i's clearance is negative."""
    B, E = err.shape
    for b in range(B):
        total = 0.0
        worst = 0.0
        for e in range(E):
            x = abs(err[b, e])
            total += x
            worst = max(worst, x)
        formation[b] = -formation_weight * (total / E)
        formation_error[b] = worst
        success[b] = worst < tolerance
        for i in range(min_clear.shape[1]):
            cost[b, i] = 1.0 if min_clear[b, i] < 0.0 else 0.0


@njit(**_JIT)
def reach_outcome(goal, p, min_clear, effort, weights, tolerance, on_success, on_collision, distance, terms, reward,
                  cost, success, terminated):
    """The reach task's per-step numbers of A arms, in one pass (the formulas of
    :meth:`pan1_env.tasks.ReachTask.evaluate`'s numpy twin): ``distance = ‖goal − p‖``, ``cost = 1.0`` where the
    clearance ``min_clear (A,)`` is negative, the reward's terms ``terms (A, 3)`` (distance ``−distance``, effort
    ``−weights[0]·effort``, collision ``−weights[1]·cost``; a term of weight 0 is 0 and not added), ``reward`` their
    sum in that order, ``success = distance < tolerance`` and ``terminated`` (success with ``on_success``, a
    collision with ``on_collision``)."""
    for i in range(goal.shape[0]):
        dx = goal[i, 0] - p[i, 0]
        dy = goal[i, 1] - p[i, 1]
        d = np.sqrt(dx * dx + dy * dy)
        c = 1.0 if min_clear[i] < 0.0 else 0.0
        distance[i] = d
        cost[i] = c
        terms[i, 0] = -d
        terms[i, 1] = -weights[0] * effort[i] if weights[0] != 0.0 else 0.0
        terms[i, 2] = -weights[1] * c if weights[1] != 0.0 else 0.0
        r = -d
        if weights[0] != 0.0:
            r += terms[i, 1]
        if weights[1] != 0.0:
            r += terms[i, 2]
        reward[i] = r
        success[i] = d < tolerance
        terminated[i] = (on_success and d < tolerance) or (on_collision and c > 0.0)


@njit(**_JIT)
def shield_report(counts, source, columns, padding, faulted, inv_unit, intervened, fallback, status, applied):
    """The filter's report of B teams' step (:meth:`pan1_env.core.FormationCore` infos): from the sub-steps per QP
    status ``counts (B, N, 3)``, ``intervened`` (solved or fallback in some sub-step), ``fallback`` and ``status``
    (2 fallback, 1 solved, 0 nominal) ``(B, N)``; ``applied (B, N, k_max)`` float32, the last sub-step's command
    ``source[b, i, columns[i, j]]`` (v* or τ) times ``inv_unit`` in float32 (as numpy's float32 multiply), 0 in the
    ``padding (N, k_max)`` and in the first slot of a ``faulted (B, N)`` arm."""
    B, N, K = applied.shape
    for b in range(B):
        for i in range(N):
            solved = counts[b, i, 1] > 0
            lost = counts[b, i, 2] > 0
            intervened[b, i] = solved or lost
            fallback[b, i] = lost
            status[b, i] = 2 if lost else (1 if solved else 0)
            for j in range(K):
                if padding[i, j] or (j == 0 and faulted[b, i]):
                    applied[b, i, j] = 0.0
                else:
                    applied[b, i, j] = np.float32(source[b, i, columns[i, j]]) * np.float32(inv_unit)


# The team views' aggregates of per-arm infos (pan1_env.core.FormationCore.team_infos): each copy's row of a (B, N)
# array reduced over its N arms, numpy's reductions over axis 1 bit for bit below 8 arms (a sum adds one value after
# another from 0, as numpy's does there; from 8 arms numpy sums pairwise, and the core calls numpy). Compiled without
# fast-math flags (_EXACT).


@njit(**_EXACT, inline="always")
def _row_sum(values, b):
    """``values[b]``'s sum, one value after another from 0 (an integer for bools, 0.0 for floats: numba unifies)."""
    total = 0
    for i in range(values.shape[1]):
        total += values[b, i]
    return total


@njit(**_EXACT)
def arms_sum(values, out):
    """``out[b] = Σ_i values[b, i]`` (bools count as 1)."""
    for b in range(values.shape[0]):
        out[b] = _row_sum(values, b)


@njit(**_EXACT)
def arms_sum_columns(values, out):
    """``out[b, j] = Σ_i values[b, i, j]`` for integer counts (the QP statuses): exact in any order."""
    for b in range(values.shape[0]):
        for j in range(values.shape[2]):
            total = 0
            for i in range(values.shape[1]):
                total += values[b, i, j]
            out[b, j] = total


@njit(**_EXACT)
def arms_min(values, out):
    """``out[b]`` = the smallest of ``values[b]`` by numpy's rule for numbers (of equal values, such as 0 and −0, the
    later); returns False, leaving ``out`` to the caller, if some value is NaN: which NaN numpy's minimum returns
    depends on its vector code."""
    for b in range(values.shape[0]):
        least = values[b, 0]
        if least != least:
            return False
        for i in range(1, values.shape[1]):
            x = values[b, i]
            if x != x:
                return False
            if not least < x:
                least = x
        out[b] = least
    return True


@njit(**_EXACT)
def arms_mean(values, out):
    """``out[b]`` = the mean of ``values[b]``: their sum (:func:`arms_sum`) over N."""
    for b in range(values.shape[0]):
        out[b] = _row_sum(values, b) / values.shape[1]


@njit(**_EXACT)
def arms_max(values, out):
    """``out[b]`` = the largest of ``values[b]`` (integers: the filter's status)."""
    for b in range(values.shape[0]):
        most = values[b, 0]
        for i in range(1, values.shape[1]):
            most = max(most, values[b, i])
        out[b] = most


@njit(**_EXACT)
def arms_any(values, out):
    """``out[b]`` = whether any of ``values[b]`` is true."""
    for b in range(values.shape[0]):
        hit = False
        for i in range(values.shape[1]):
            hit = hit or values[b, i]
        out[b] = hit
