"""What one engine step produced, per copy and arm: :class:`StepRecord` (:meth:`pan1_env.engine.Engine.step`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["StepRecord"]


@dataclass
class StepRecord:
    """What one :meth:`Engine.step` produced, per copy and arm (arrays with leading axes ``(B, N)``)."""

    v_star: np.ndarray  # (B, N, k_max) v* of the last sub-step (NaN in unfiltered torque mode, and as padding)
    tau: np.ndarray  # (B, N, n_max) joint torques of the last sub-step (passive entry 0; NaN padding)
    min_clearance: np.ndarray  # (B, N) smallest clearance of the arm's protected bodies after any sub-step (inf: none)
    min_barrier: np.ndarray  # (B, N) smallest filtered barrier value h seen (inf: no row)
    qp_counts: np.ndarray  # (B, N, 3) sub-steps per QP status: nominal, solved, fallback
    max_tracking_error: np.ndarray  # (B, N) largest ‖v − v*‖ at the start of a sub-step
    finite: np.ndarray  # (B, N) False where the state went non-finite (left at its last finite state)
    all_finite: bool = True  # every arm of every copy stayed finite

    @property
    def intervened(self) -> np.ndarray:
        """``(B, N)``: the filter changed the command (or braked) in some sub-step."""
        return (self.qp_counts[..., 1] + self.qp_counts[..., 2]) > 0

    @property
    def fallback(self) -> np.ndarray:
        """``(B, N)``: the filter's QP was infeasible and its fallback ran in some sub-step (braking; with
        whole-arm safety the relaxed QPs of docs/SCENARIOS.md)."""
        return self.qp_counts[..., 2] > 0
