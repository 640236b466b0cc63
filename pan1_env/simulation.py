"""The paper's closed loop for one team: :class:`Simulation`, an engine of one copy and its clock.

``pan1-env reproduce`` (:mod:`pan1_env.experiment`) drives it with the paper's controller: the
distributed formation law :meth:`Simulation.nominal_velocity` (Eq. 39) as the command, recomputed
every control step, filtered by the RCBF-QP (Eq. 61) at every physics sub-step for the "safe"
controller, tracked by the backstepping torque (Eq. 64) and integrated by RK4. The stepping itself
is its :class:`~pan1_env.engine.Engine`'s (``self.engine``, B = 1); this class adds the clock, the
running smallest clearance and the reference-layer quantities of one team (docs/MODEL.md), with
arrays over the team's arms (padded team arrays use NaN beyond an arm's size), where the engine's
have a leading copy axis.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .control import MAX_JOINT_SPEED
from .engine import Engine, Physics
from .formation import edge_errors, edge_vectors, formation_gradient
from .motion import MotionTable
from .scenario import Scenario
from .step_record import StepRecord
from .tasks import law_velocity

__all__ = ["Simulation", "StepRecord"]


class Simulation:
    """One copy of a scenario's team under the paper's controller.

    Args:
        scenario: a validated :class:`~pan1_env.scenario.Scenario`.
        safety_filter: ``True`` filters every command through the RCBF-QP ("safe" controller);
            ``False`` tracks it directly ("nominal" controller); or a
            :class:`~pan1_env.engine.FilterParams`.
        qp_solver: ``"active_set"`` (exact, compiled) or ``"piqp"`` (qpsolvers + PIQP).
        physics_dt: overrides the scenario's physics step (seconds).
    """

    def __init__(self, scenario: Scenario, *, safety_filter=True, qp_solver: str = "active_set",
                 physics_dt: float | None = None) -> None:
        self.scenario = scenario
        self.engine = Engine(scenario, 1, Physics(physics_dt, qp_solver=qp_solver), safety_filter=safety_filter)
        self.motion = None
        if scenario.motion is not None:
            self.motion = MotionTable(1, scenario.n_arms, scenario.motion.keyframes)
            self.motion.load(0, scenario.formation.target, scenario.motion)
        self.reset()

    @property
    def n_arms(self) -> int:
        return self.engine.n_arms

    @property
    def n_max(self) -> int:
        """The most links of any arm (the width of padded joint arrays)."""
        return self.engine.n_max

    @property
    def k_max(self) -> int:
        """The most actuated joints of any arm (the width of a command)."""
        return self.engine.k_max

    @property
    def physics_dt(self) -> float:
        return self.engine.physics_dt

    @property
    def time(self) -> float:
        """Seconds since the last reset: the engine's clock."""
        return float(self.engine.elapsed[0])

    def reset(self, q0: list[np.ndarray] | None = None) -> None:
        """Put every arm at rest at ``q0`` (default: the scenario's), time 0."""
        if q0 is not None and len(q0) != self.n_arms:
            raise ValueError(f"q0 needs one configuration per arm ({self.n_arms}), got {len(q0)}")
        self.engine.reset(None if q0 is None else [0], q0)
        self.min_clearance = self.clearance()  # (N,) running minimum since reset

    def positions(self) -> np.ndarray:
        """End-effectors ``(N, 2)``."""
        return self.engine.positions()[0]

    def joint_state(self, pad: float = np.nan) -> tuple[np.ndarray, np.ndarray]:
        """Padded ``q (N, n_max)`` and ``q̇ (N, n_max)`` (copies)."""
        q, qd = self.engine.joint_state(pad)
        return q[0].copy(), qd[0].copy()

    def clearance(self) -> np.ndarray:
        """Smallest clearance of each arm's protected bodies, ``(N,)`` (inf with nothing to hit)."""
        return self.engine.clearance()[0]

    def passive_momentum(self) -> np.ndarray:
        """Σ_α M_1α q̇_α for every arm, ``(N,)`` (NaN for fully actuated arms)."""
        out = np.full((1, self.n_arms), np.nan)
        for kind in self.engine.kinds:
            kind.to_team(out, self.engine.kind_terms(kind).momentum)
        return out[0]

    def targets(self) -> tuple[np.ndarray, np.ndarray]:
        """The desired edge lengths ``(E,)`` now and the feed-forward ṗ_ff ``(N, 2)`` (zero for a still formation;
        a moving one's at the clock, :mod:`pan1_env.motion`)."""
        formation = self.scenario.formation
        if self.motion is None:
            return formation.distances, np.zeros((self.n_arms, 2))
        d, ff, _ = self.motion.targets(np.array([self.time]), formation.edges, self.engine.positions())
        return d[0], ff[0]

    def nominal_velocity(self) -> np.ndarray:
        """The distributed formation law v_i0 = −K_P J̄_iᵀ ê_i (Eq. 39) of every arm, ``(N, k_max)`` (a moving
        formation's lengths now and J̄⁺ of its feed-forward added, docs/MODEL.md §8). The paper's law has no speed
        bound; with a moving formation each arm's command is scaled down as the envs' is, to at most
        ``MAX_JOINT_SPEED`` per joint, since J̄⁺ of a moving target grows without bound where J̄ loses rank."""
        formation = self.scenario.formation
        distances, ff = self.targets()
        z = edge_vectors(formation.incidence, self.positions())
        e_hat = formation_gradient(formation.incidence, z, edge_errors(z, distances))
        moving = self.motion is not None
        return law_velocity(self.engine, e_hat[None], np.array([self.scenario.kp]), ff[None] if moving else None,
                            max_speed=MAX_JOINT_SPEED if moving else None)[0]

    def step(self, command: np.ndarray, substeps: int, *, torque: bool = False,
             max_speed: float | None = None) -> StepRecord:
        """Hold ``command (N, k_max)`` for ``substeps`` physics steps; the record's arrays are the
        team's ``(N, …)`` (``finite`` per arm). ``max_speed`` bounds the filtered speeds (rad/s)."""
        command = np.asarray(command, dtype=float)
        if command.shape != (self.n_arms, self.k_max):
            raise ValueError(f"command must have shape {(self.n_arms, self.k_max)}, got {command.shape}")
        if max_speed is not None:
            self.engine.physics = replace(self.engine.physics, max_joint_speed=max_speed)
        rec = self.engine.step(command[None], substeps, torque=torque)
        out = StepRecord(rec.v_star[0], rec.tau[0], rec.min_clearance[0], rec.min_barrier[0], rec.qp_counts[0],
                         rec.max_tracking_error[0], rec.finite[0], rec.all_finite)
        np.minimum(self.min_clearance, out.min_clearance, out=self.min_clearance)
        return out
