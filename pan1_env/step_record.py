"""What one engine step produced, per copy and arm: :class:`StepRecord` (:meth:`pan1_env.engine.Engine.step`)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

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
    #: the arrays' storage when they are views of one block per dtype (:meth:`initial`), else empty
    blocks: tuple = field(default=(), repr=False, compare=False)

    @classmethod
    def initial(cls, copies: int, arms: int, k_max: int, n_max: int) -> StepRecord:
        """A record's initial values, each array a view of one block per dtype (so :meth:`restart` is three copies):
        v* and τ NaN (the padding stays so), clearances and barriers inf, no QP counts, no tracking error, finite."""
        B, N = copies, arms
        floats = np.empty(B * N * (k_max + n_max + 3))
        counts, finite = np.zeros((B, N, 3), dtype=np.int64), np.ones((B, N), dtype=bool)
        cut = np.cumsum([B * N * k_max, B * N * n_max, B * N, B * N])
        v_star, tau, clear, barrier, track = np.split(floats, cut)
        v_star[:], tau[:], clear[:], barrier[:], track[:] = np.nan, np.nan, np.inf, np.inf, 0.0
        return cls(v_star.reshape(B, N, k_max), tau.reshape(B, N, n_max), clear.reshape(B, N), barrier.reshape(B, N),
                   counts, track.reshape(B, N), finite, blocks=(floats, counts, finite))

    def __getstate__(self) -> dict:
        # a pickle (or deepcopy) stores each view as an array of its own: the copy has no blocks (Engine re-lays it)
        return {key: value for key, value in self.__dict__.items() if key != "blocks"}

    def laid_out(self) -> StepRecord:
        """The same values in :meth:`initial`'s layout (one block per dtype)."""
        B, N, k_max = self.v_star.shape
        out = StepRecord.initial(B, N, k_max, self.tau.shape[2])
        out.restart(self)
        out.all_finite = self.all_finite
        return out

    def copy(self) -> StepRecord:
        """A record of its own arrays (the engine hands these out and writes the next step elsewhere)."""
        return StepRecord(self.v_star.copy(), self.tau.copy(), self.min_clearance.copy(), self.min_barrier.copy(),
                          self.qp_counts.copy(), self.max_tracking_error.copy(), self.finite.copy(), self.all_finite)

    def restart(self, initial: StepRecord) -> None:
        """Every array set in place to ``initial``'s values (a step starts from them): block by block when both are
        laid out alike (:meth:`initial`)."""
        if self.blocks and len(self.blocks) == len(initial.blocks):
            for mine, theirs in zip(self.blocks, initial.blocks, strict=True):
                np.copyto(mine, theirs)
        else:
            for name in _ARRAYS:
                np.copyto(getattr(self, name), getattr(initial, name))
        self.all_finite = True

    @property
    def intervened(self) -> np.ndarray:
        """``(B, N)``: the filter changed the command (or braked) in some sub-step."""
        return (self.qp_counts[..., 1] + self.qp_counts[..., 2]) > 0

    @property
    def fallback(self) -> np.ndarray:
        """``(B, N)``: the filter's QP was infeasible and its fallback ran in some sub-step (braking; with
        whole-arm safety the relaxed QPs of docs/SCENARIOS.md)."""
        return self.qp_counts[..., 2] > 0


_ARRAYS = [f.name for f in fields(StepRecord) if f.name not in ("all_finite", "blocks")]
