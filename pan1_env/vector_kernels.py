"""Compiled per-copy bookkeeping of the vector env's step (:class:`pan1_env.vector.Pan1VectorEnv`).

Around the physics kernel (:func:`pan1_env.kernels.group_advance`), a step of B copies turns the
batched actions into each arm kind's commands, gathers the arms' clearances, QP statuses and
finiteness flags into per-copy arrays, and reduces them with the edge-length errors into costs and
rewards. In numpy this was some thirty calls over B-sized arrays; here it is one loop per kind and
one per step. The formulas are the parallel env's
(:mod:`pan1_env.environment`); the vector env's tests compare the two.

These are the vector env's internals: they trust the shapes and dtypes it builds (compiled code has
no bounds checks), so validate at the env's boundary, as :meth:`Pan1VectorEnv.step` does for actions.

Importing this module imports numba; :mod:`pan1_env.vector` imports it on its first step.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernels import _JIT

__all__ = ["gather_commands", "gather_arm_results", "team_rewards"]


@njit(**_JIT)
def gather_commands(actions, cols, scale, command):
    """``command[b·A + r, t] = clip(actions[b, cols[r, t]], −1, 1) · scale``: the commands ``(B·A, k)``
    of one arm kind (its A arms per copy, action columns ``cols (A, k)``) from the actions ``(B, S)``."""
    A, k = cols.shape
    for b in range(actions.shape[0]):
        for r in range(A):
            for t in range(k):
                command[b * A + r, t] = min(max(actions[b, cols[r, t]], -1.0), 1.0) * scale


@njit(**_JIT)
def gather_arm_results(ids, clear, counts, finite, min_clear, intervened, fallback, team_finite):
    """Per copy b, from one arm kind's per-arm results (rows b·A + r, arm ``ids[r]`` of the team):
    ``min_clear[b, ids[r]]`` the arm's smallest clearance; ``intervened[b]`` set if a QP changed a
    command (status solved or fallback), ``fallback[b]`` if one took the fallback; ``team_finite[b]``
    cleared if an arm's state went non-finite. The flags are or-ed (and-ed) with what they hold,
    so the kinds of a mixed team accumulate."""
    A = ids.shape[0]
    for b in range(min_clear.shape[0]):
        for r in range(A):
            x = b * A + r
            min_clear[b, ids[r]] = clear[x]
            if counts[x, 1] > 0 or counts[x, 2] > 0:
                intervened[b] = True
            if counts[x, 2] > 0:
                fallback[b] = True
            if not finite[x]:
                team_finite[b] = False


@njit(**_JIT)
def team_rewards(min_clear, err, actions, effort_weights, formation_weight, effort_weight, collision_penalty,
                 success_tolerance, cost, clearance, formation_error, success, reward):
    """Per copy b: ``cost`` the number of arms with negative clearance, ``clearance`` the smallest,
    ``formation_error`` max_k |err[b, k]|, ``success`` formation_error < tolerance, and the reward
    −w_f·mean_k |err| − w_e·effort/N − penalty·cost/N with effort Σ_c w_c·clip(a_c)² (the parallel
    env's reward, averaged over its N agents)."""
    B, N = min_clear.shape
    E = err.shape[1]
    for b in range(B):
        hits = 0
        low = np.inf
        for i in range(N):
            if min_clear[b, i] < 0.0:
                hits += 1
            low = min(low, min_clear[b, i])
        worst = 0.0
        total = 0.0
        for e in range(E):
            x = abs(err[b, e])
            worst = max(worst, x)
            total += x
        effort = 0.0
        for c in range(actions.shape[1]):
            a = min(max(actions[b, c], -1.0), 1.0)
            effort += effort_weights[c] * a * a
        cost[b] = hits
        clearance[b] = low
        formation_error[b] = worst
        success[b] = worst < success_tolerance
        reward[b] = (-formation_weight * (total / E) - effort_weight * effort / N
                     - collision_penalty * hits / N)
