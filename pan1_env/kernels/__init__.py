"""Compiled (numba) kernels of the physics sub-step: the engine's single implementation.

The formulas are those of :mod:`pan1_env.dynamics`, :mod:`pan1_env.cascade`,
:mod:`pan1_env.safety` and :mod:`pan1_env.control` (the documented, vectorised numpy reference);
the tests check the physics, filter and observation kernels against them (the small helpers
:func:`scale_command`, :func:`edge_length_errors`, :func:`formation_observations` and
:func:`reach_observations` through the environments' tests). The kernels loop over the arms of one
group (arms with the same number of links n and actuation, k actuated joints) so that a sub-step
costs a handful of calls whatever the team size.

The package is split by job: :mod:`.physics` (the building blocks of dynamics and kinematics),
:mod:`.qp` (the filter's QP) and :mod:`.last_resort` (its answer when the QP has none), :mod:`.capsules`
(whole-arm geometry and rows) and :mod:`.team_geometry` (its passes over a team between kernel calls),
:mod:`.circulation` (the circulation term round obstacles of ``action_mode="circulation"``),
:mod:`.substep` (the sub-step kernel), :mod:`.steps` and :mod:`.scratch` (its steps and scratch space, inlined
into it), :mod:`.specialise` (which kernel an arm kind steps with), :mod:`.observe` (observations and small
helpers), :mod:`.outcome` (the tasks' per-step numbers) and :mod:`._numba_ext` (numba plumbing).

The sub-step kernel advances the arms W at a time, one arm per lane of arrays whose last axis is
the lanes, so that LLVM's SLP vectoriser (switched on for these kernels only:
:func:`_slp_vectorised`) packs four arms into each AVX register; it keeps this scratch space in
its own stack frame (:func:`_local`, fixed shapes from the :func:`pan1_env.compiled.kernel_sizes`
tuples), where LLVM can keep it in registers. A lane's results do not depend on the lane count or on the arms that
share its group, bit for bit (tests/test_kernels.py).

Importing this module imports numba (about half a second); :mod:`pan1_env` itself does not, so
``import pan1_env`` stays fast. Compiled code is cached on disk (``cache=True``).
"""

from __future__ import annotations

from .. import compile_notice
from . import capsules, last_resort, specialise, team_geometry
from .circulation import group_circulation
from .observe import (
    edge_length_errors,
    formation_observations,
    group_observations,
    group_observations_parallel,
    kind_state,
    obstacle_state,
    reach_observations,
    scale_command,
)
from .outcome import (
    arms_any,
    arms_max,
    arms_mean,
    arms_min,
    arms_sum,
    arms_sum_columns,
    formation_outcome,
    reach_outcome,
    shield_report,
)
from .physics import group_end_effectors, group_terms
from .qp import STATUS_FALLBACK, STATUS_NOMINAL, STATUS_SOLVED, compiled_projection, qp_project
from .substep import GENERIC_MAX_LINKS, group_advance, group_advance_generic, group_advance_parallel

__all__ = [
    "group_terms",
    "group_advance",
    "group_advance_parallel",
    "group_advance_generic",
    "GENERIC_MAX_LINKS",
    "specialise",
    "capsules",
    "last_resort",
    "team_geometry",
    "group_end_effectors",
    "group_circulation",
    "group_observations",
    "group_observations_parallel",
    "kind_state",
    "obstacle_state",
    "qp_project",
    "compiled_projection",
    "scale_command",
    "edge_length_errors",
    "formation_observations",
    "formation_outcome",
    "reach_observations",
    "reach_outcome",
    "shield_report",
    "arms_sum",
    "arms_mean",
    "arms_max",
    "arms_any",
    "arms_min",
    "arms_sum_columns",
]

compile_notice.install()  # a first use of an arm kind compiles for tens of seconds: say so

__all__ += ["STATUS_NOMINAL", "STATUS_SOLVED", "STATUS_FALLBACK"]
