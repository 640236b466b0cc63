"""An engine's arm kinds: the arms of one number of links and one actuation, in every copy, as the rows
of the arrays the sub-step kernel advances (:mod:`pan1_env.engine`).

Row ``b·A + r`` of a kind holds arm ``ids[r]`` of copy b. An engine whose arms may lose an actuator
gives each fully actuated kind a *faulted twin*: a PAn−1 kind of the same arms and rows, whose row takes
over an arm of one copy from the moment its first joint loses its actuator (docs/MODEL.md §7) until
that copy's next reset. Each row is stepped in exactly one of the two; the kernel advances a kind's
``stepped`` rows and leaves the others as they are, and a kind writes into the team's arrays only
from the rows it steps. A twin's actuated joints are the arm's joints 2 … n, so its commands and
filtered velocities sit one column further in the team's ``(B, N, k_max)`` arrays (``shift``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from .cascade import passive_momentum
from .compiled import kernel_sizes, kernels
from .dynamics import ArmBatch
from .kernel_groups import ArmModel, ArmState, EndEffectorObstacles, Stepped, plain
from .scenario import Scenario

if TYPE_CHECKING:
    from .team_draw import TeamDraws


def kind_rows(team: np.ndarray) -> np.ndarray:
    """A kind's columns of a team array ``(B, A, …)`` as its rows ``b·A + r``, C-contiguous (the kernel's
    layout): a copy, or with one copy a view."""
    return np.ascontiguousarray(team).reshape(-1, *team.shape[2:])


class Kind:
    """The arms of one kind in every copy: rows ``b·A + r`` hold arm ``ids[r]`` of copy b.

    With ``faulted`` the arms are fully actuated arms whose first joint has lost its actuator: a PAn−1
    kind (k = n − 1) whose rows start unstepped (:meth:`take_over`)."""

    def __init__(self, ids: list[int], scenario: Scenario, copies: int, *, faulted: bool = False) -> None:
        batch = ArmBatch.stack([scenario.arms[i] for i in ids])
        self.ids = np.asarray(ids, dtype=np.int64)
        self.copies = copies
        # its columns of the team arrays (B, N, …): a slice when its arms are consecutive (basic indexing,
        # several times faster than an index array on the per-step gathers and scatters)
        consecutive = np.array_equal(self.ids, np.arange(self.ids[0], self.ids[0] + len(ids)))
        self.cols = slice(int(self.ids[0]), int(self.ids[0]) + len(ids)) if consecutive else self.ids
        self.A, self.n = len(ids), batch.n_links
        self.faulted = faulted
        if faulted and batch.passive_first_joint:
            raise ValueError("a faulted twin is made of fully actuated arms")
        self.passive = batch.passive_first_joint or faulted
        self.k = self.n - 1 if self.passive else self.n
        self.shift = 1 if faulted else 0  # the team column of its first actuated joint
        self.sizes = kernel_sizes(self.n, self.k)
        rows, O = copies * self.A, len(scenario.obstacles)
        self.lam, self.lengths = np.empty((rows, self.n, self.n)), np.empty((rows, self.n))
        self.base, self.phi, self.damping = np.empty((rows, 2)), np.empty(rows), np.empty(rows)
        self.centers, self.radii = np.empty((rows, O, 2)), np.empty((rows, O))
        self.mask, self.q0 = np.empty((rows, O), dtype=bool), np.empty((rows, self.n))
        #: the kernel's end-effector obstacles (none with whole-arm safety: Engine._whole_arm_setup)
        self.world = plain(EndEffectorObstacles(centers=self.centers, radii=self.radii, mask=self.mask))
        # the state, updated in place (views of it stay valid for the engine's life)
        self.q, self.v, self.qd, self.p = (np.zeros((rows, self.n)), np.zeros((rows, self.k)),
                                           np.zeros((rows, self.n)), np.zeros((rows, 2)))
        self.momentum = np.zeros(rows)  # a PAn−1 arm's passive momentum p₁ (docs/MODEL.md §7)
        self.v_prev, self.has_prev = np.zeros((rows, self.k)), np.zeros(rows, dtype=bool)
        self.active = np.full(rows, not faulted)
        #: the sub-steps [start, stop) of a call in which each row is stepped (the sub-step kernel's ``window``):
        #: all, but in a step where the row's arm loses its actuator (kernel_step._advance)
        self.window_default = np.array([0, np.iinfo(np.int64).max], dtype=np.int64)
        self.window = np.tile(self.window_default, (rows, 1))
        self.twin: Kind | None = None  # a fully actuated kind's faulted twin (Engine: arms that may fault)
        self.set_stepped()
        # the serial kernel: None until the first step decides (kernel_step._specialised), False while the
        # generic kernel stands in for the kind's own, True from then on
        self.specialised: bool | None = None
        self.generation = -1
        self.whole = None  # the kernel's whole-arm argument (Engine._whole_arm_setup)
        #: the command the kernel holds, the kind's rows of the step's command (kernel_step), and the kernel's
        #: groups built from it and the kind's state (kernel_step._groups; each step reuses them while they hold)
        self.held = np.zeros((rows, self.k))
        self.held_team = self.held.reshape(copies, self.A, self.k)  # (the team's command when the kind is the team)
        self.plan: tuple | None = None
        self.ready: tuple | None = None

    def set_stepped(self) -> None:
        """After ``active`` changed: the rows the kernel steps, and the kind's kernel groups (arrays updated in
        place, never replaced): its arms' constants, their state, and which of them a call steps."""
        self.stepped = np.flatnonzero(self.active).astype(np.int64)
        self.complete = len(self.stepped) == len(self.active)
        self.model = plain(ArmModel(lam=self.lam, lengths=self.lengths, base=self.base, phi=self.phi,
                                    damping=self.damping, passive=self.passive))
        self.state = plain(ArmState(q=self.q, v=self.v, momentum=self.momentum, v_prev=self.v_prev,
                                    has_prev=self.has_prev))
        self.selection = plain(Stepped(rows=self.stepped, window=self.window))

    def __getstate__(self) -> dict:
        # another process decides for itself; the plan's views of the engine's working record do not survive a copy
        state = {**self.__dict__, "specialised": None, "plan": None, "ready": None}
        del state["held_team"]  # a view of held, made again on loading
        if "block" in state:  # views of the engine's team arrays, which Engine.__setstate__ takes again
            for name in ("caps", "start_time", "joints", "whole"):
                del state[name]
        return state

    def __setstate__(self, state: dict) -> None:
        state.setdefault("held", np.zeros_like(state["v"]))  # pickled before the held command was the kind's
        state.setdefault("plan", None)
        state.setdefault("ready", None)
        self.__dict__.update(state)
        self.held_team = self.held.reshape(self.copies, self.A, self.k)  # a view again (a pickle copies it)

    def rows(self, copies: np.ndarray) -> np.ndarray:
        return (np.asarray(copies)[:, None] * self.A + np.arange(self.A)[None]).ravel()

    def load(self, b: int, scenario: Scenario, mask: np.ndarray) -> None:
        sl = slice(b * self.A, (b + 1) * self.A)
        batch = ArmBatch.stack([scenario.arms[i] for i in self.ids])
        self.lam[sl], self.lengths[sl], self.base[sl], self.phi[sl] = batch.lam, batch.lengths, batch.base, batch.phi
        self.damping[sl] = batch.passive_damping
        self.centers[sl] = scenario.obstacles.centers[None]
        self.radii[sl] = scenario.obstacles.radii[None]
        self.mask[sl] = mask[self.ids]
        self.q0[sl] = np.array([scenario.q0[i] for i in self.ids])

    def load_drawn(self, copies: np.ndarray, draws: TeamDraws, mask: np.ndarray) -> None:
        """:meth:`load` for the drawn teams of ``copies`` at once (``mask (C, N, O)``: each copy's obstacle mask)."""
        rows, ids, n = self.rows(copies), self.ids, self.n
        self.lam[rows] = draws.lam[:, ids, :n, :n].reshape(-1, n, n)
        self.lengths[rows] = draws.lengths[:, ids, :n].reshape(-1, n)
        self.base[rows] = draws.bases[:, ids].reshape(-1, 2)
        self.phi[rows] = 0.0
        self.damping[rows] = draws.options.passive_damping
        self.centers[rows] = np.repeat(draws.centers, self.A, axis=0)
        self.radii[rows] = np.repeat(draws.radii, self.A, axis=0)
        self.mask[rows] = mask[:, ids].reshape(len(rows), -1)
        self.q0[rows] = draws.q0[:, ids, :n].reshape(-1, n)

    def load_capsules(self, copies: np.ndarray, obstacles: np.ndarray, mask: np.ndarray, world_floor: np.ndarray,
                      arm_floor: np.ndarray | None, n_links: list[int], link_radius: float) -> None:
        """Its capsules in ``copies``: the obstacles' columns ``obstacles (C, O, ·)``, active for its arms where
        ``mask (C, N, O)`` is, with their floors ``world_floor (C, N, O)``; with ``arm_floor (C, N, N)`` (inter-arm)
        a slot for each link of every other arm (radius ρ, share ½; the segments are set every sub-step), in
        order of the floor, active where the two arms' reaches can meet (floor ≤ 0), then unused slots."""
        K = kernels().capsules
        O = obstacles.shape[1]
        block = np.zeros((len(copies), self.A, *self.caps.shape[1:]))
        block[:, :, :O] = obstacles[:, None]
        block[:, :, :O, K.CAP_ACTIVE] = mask[:, self.ids]
        block[:, :, :O, K.CAP_FLOOR] = world_floor[:, self.ids]
        block[:, :, O:, K.CAP_ARM], block[:, :, O:, K.CAP_FLOOR] = -1.0, np.inf
        if arm_floor is not None:
            for r, i in enumerate(self.ids):
                arm, link = _other_links(tuple(n_links), int(i))
                floor = arm_floor[:, i, arm]  # (C, S): stable, so an arm's links stay together and in order
                order = np.argsort(floor, axis=1, kind="stable")
                slots = block[:, r, O:O + len(arm)]
                slots[..., K.CAP_ARM], slots[..., K.CAP_LINK] = arm[order], link[order]
                slots[..., K.CAP_FLOOR] = np.take_along_axis(floor, order, axis=1)
                slots[..., K.CAP_ACTIVE] = slots[..., K.CAP_FLOOR] <= 0.0
                slots[..., K.CAP_RADIUS], slots[..., K.CAP_SHARE] = link_radius, 0.5
        self.caps.reshape(self.copies, self.A, *self.caps.shape[1:])[copies] = block

    def from_team(self, team: np.ndarray, width: int | None = None, *, first: int | None = None) -> np.ndarray:
        """Its rows of a team array ``(B, N)`` or ``(B, N, ·)`` (``width`` columns from ``first``, default
        ``shift``)."""
        if width is None:
            return kind_rows(team[:, self.cols])
        start = self.shift if first is None else first
        return kind_rows(team[:, self.cols, start: start + width])

    def to_team(self, team: np.ndarray, values: np.ndarray, *, first: int | None = None, add: bool = False,
                both: bool = False) -> None:
        """Write its rows ``values (B·A, …)`` into a team array ``(B, N, …)`` (columns from ``first``, default
        ``shift``, when ``values`` has a second axis), or add them (``add``), or with ``both`` keep the
        logical and of the two: only from the rows it steps."""
        B = self.copies
        values = values.reshape(B, self.A, *values.shape[1:])
        if values.ndim == 2:
            index = (slice(None), self.cols)
        else:
            start = self.shift if first is None else first
            index = (slice(None), self.cols, slice(start, start + values.shape[2]))
        if isinstance(self.cols, slice):  # a view: written in place, only where stepped
            where = True if self.complete else self.active.reshape(B, self.A, *(1,) * (values.ndim - 2))
            target = team[index]
            if add:
                np.add(target, values, out=target, where=where)
            elif both:
                np.logical_and(target, values, out=target, where=where)
            else:
                np.copyto(target, values, where=where)
            return
        if self.complete and not (add or both):
            team[index] = values
            return
        current = team[index]
        new = current + values if add else (current & values if both else values)
        if not self.complete:
            where = self.active.reshape(B, self.A)
            new = np.where(where.reshape(where.shape + (1,) * (values.ndim - 2)), new, current)
        team[index] = new

    def put_state(self, rows: np.ndarray, q: np.ndarray, qd: np.ndarray) -> None:
        """Rows ``rows`` at joint angles ``q`` moving at ``qd`` (n columns each): v = the actuated joints' speeds
        and, for a PAn−1 kind, p₁ = Σ_α M_1α q̇_α, from which its passive speed follows (docs/MODEL.md §7); the
        tracker starts afresh. The end-effectors ``p`` are the caller's to set."""
        self.q[rows], self.qd[rows], self.v[rows] = q, qd, qd[:, self.n - self.k:]
        self.momentum[rows] = 0.0
        if self.passive:
            arms = ArmBatch(lam=self.lam[rows], lengths=self.lengths[rows], base=self.base[rows], phi=self.phi[rows],
                            passive_first_joint=False)
            self.momentum[rows] = passive_momentum(arms, q, qd)
        self.v_prev[rows], self.has_prev[rows] = 0.0, False

    def take_over(self, full: Kind, rows: np.ndarray) -> None:
        """Rows ``rows`` of the full kind ``full`` lose their first joint's actuator: this twin steps them from
        now on, from the same angles, joint speeds and end-effectors (:meth:`put_state`)."""
        self.put_state(rows, full.q[rows], full.v[rows])
        self.p[rows] = full.p[rows]
        full.active[rows], self.active[rows] = False, True
        full.set_stepped()
        self.set_stepped()


@lru_cache(maxsize=256)
def _other_links(n_links: tuple[int, ...], i: int) -> tuple[np.ndarray, np.ndarray]:
    """Every link of the arms other than i, as (its arm, its index): one slot each, an arm's links together."""
    arm = np.array([j for j in range(len(n_links)) if j != i for _ in range(n_links[j])], dtype=np.int64)
    link = np.array([a for j in range(len(n_links)) if j != i for a in range(n_links[j])], dtype=float)
    arm.setflags(write=False)  # shared by every call through the cache
    link.setflags(write=False)
    return arm, link
