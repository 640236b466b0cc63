"""The agents' local observations, built for a whole team (or a batch of teams) in a few array ops.

:class:`ObservationLayout` fixes, from a scenario's structure, what each agent sees and where
(the table in its docstring):
``[cos q, sin q, q̇ / v_max, p − p0, D neighbour slots (present, dx, dy, err), K obstacle slots
(present, dx, dy, r, h)]``, with moving obstacles the K slots' velocities (vx, vy), with a moving formation the
velocity its motion asks of the end-effector, and on a team whose arms may lose an actuator a last flag: this arm
has lost its first joint's actuator.
:meth:`ObservationLayout.build` computes every agent's observation
from batched state arrays with a leading batch axis B (the parallel env passes B = 1, the vector
env B copies), one compiled call (:func:`pan1_env.kernels.group_observations`) per group of
equal-sized agents, with no per-agent Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .compiled import kernels
from .formation import ring_neighbours
from .scenario import Scenario

__all__ = ["ObservationLayout", "NEIGHBOUR_FEATURES", "OBSTACLE_FEATURES", "OBS_BOUND"]

NEIGHBOUR_FEATURES = 4  # present, dx, dy, edge error
OBSTACLE_FEATURES = 5  # present, dx, dy, radius, barrier h
OBS_BOUND = 1e6  # observation entries other than cos/sin and flags are clipped to ±OBS_BOUND


def _check_chunks(n_chunks: int) -> None:
    if isinstance(n_chunks, bool) or not isinstance(n_chunks, (int, np.integer)) or n_chunks < 0:
        raise ValueError(f"n_chunks must be 0 (one thread) or a positive int, got {n_chunks!r}")


@dataclass(frozen=True)
class ObservationLayout:
    """Where each agent's observation entries come from (fixed by the team's structure).

    ``Box(-inf, inf, (3n + 2 + 4D + 5K,), float32)`` per agent (``+ 2K`` with moving obstacles), *local* to
    the agent:

    | slice | content |
    |---|---|
    | ``[0, n)`` | cos q (own joint angles) |
    | ``[n, 2n)`` | sin q |
    | ``[2n, 3n)`` | q̇ / ``max_joint_speed`` |
    | ``[3n, 3n+2)`` | own end-effector relative to own base, p − p0 (m) |
    | next ``4D`` | D neighbour slots ``[present, dx, dy, err]`` |
    | next ``5K`` | K obstacle slots ``[present, dx, dy, r, h]`` |
    | next ``2K`` | only with moving obstacles: the same slots' obstacle velocities ``[vx, vy]`` (m/s) |
    | next 2 | only with a moving formation (``Scenario.motion``): the feed-forward ṗ_ff,i (m/s; :mod:`~.motion`) |
    | last 1 | only where arms may fault (``Scenario.fault_times``): 1.0 once the arm's first joint lost its drive |

    D is the most neighbours the team's graph can give an arm (random polygon teams: N − 1; a ring: 4 whatever N,
    so the size does not depend on the team's; a scenario file's graph: its largest degree); for neighbour j,
    (dx, dy) = p_j − p_i and err = ‖p_j − p_i‖ − d_ij (m). The K obstacles are the nearest by
    clearance; for obstacle o, (dx, dy) = o − p_i, r its radius and h = ‖p_i − o‖² − r² the barrier
    value. Absent slots are zeros. Entries other than cos, sin and flags are clipped to ±1e6.


    Attributes:
        n: links per arm, ``(N,)``.
        slots: D, neighbour slots per agent.
        n_obstacle_obs: K, obstacle slots per agent.
        neighbour: ``(N, D)`` neighbour index per slot (own index in absent slots).
        neighbour_edge: ``(N, D)`` edge index per slot (0 in absent slots).
        neighbour_present: ``(N, D)`` 1.0 where the slot is used.
        groups: ``(n, arm indices)`` for each distinct n, in increasing n.
        obstacle_velocity: the scenario has moving obstacles: the observation ends with the K obstacle
            slots' velocities ``[vx, vy]`` (m/s).
        faults: the team's arms may lose an actuator: the observation ends with the arm's fault flag.
        motion: the formation moves: the observation has the velocity its motion asks of the end-effector.
    """

    n: np.ndarray
    slots: int
    n_obstacle_obs: int
    neighbour: np.ndarray
    neighbour_edge: np.ndarray
    neighbour_present: np.ndarray
    groups: tuple[tuple[int, np.ndarray], ...]
    obstacle_velocity: bool = False
    faults: bool = False
    motion: bool = False

    @classmethod
    def from_scenario(cls, scenario: Scenario, slots: int, n_obstacle_obs: int, ring: bool = False
                      ) -> ObservationLayout:
        """The layout of ``scenario``'s team with D = ``slots`` and K = ``n_obstacle_obs``. An arm's neighbours
        fill its slots in edge order, or with ``ring`` (a ring formation) in the order every arm shares: one
        back, one forward, two back, two forward (:func:`~pan1_env.formation.ring_neighbours`)."""
        N = scenario.n_arms
        f = scenario.formation
        edge_of = {}
        for k, (a, b) in enumerate(f.edges):
            edge_of[(int(a), int(b))] = edge_of[(int(b), int(a))] = k
        neighbour = np.tile(np.arange(N)[:, None], (1, slots))
        edge = np.zeros((N, slots), dtype=np.int64)
        present = np.zeros((N, slots))
        for i in range(N):
            nbrs = f.neighbours(i)
            if ring:
                if sorted(ring_neighbours(i, N)) != sorted(nbrs):
                    raise ValueError(f"arm {i}'s neighbours {nbrs} are not a ring's")
                nbrs = ring_neighbours(i, N)
            if len(nbrs) > slots:
                raise ValueError(f"arm {i} has {len(nbrs)} neighbours, more than the {slots} slots")
            for s, j in enumerate(nbrs):
                neighbour[i, s], edge[i, s], present[i, s] = j, edge_of[(i, j)], 1.0
        n = np.array([a.n_links for a in scenario.arms])
        groups = tuple((int(m), np.flatnonzero(n == m)) for m in np.unique(n))
        return cls(n=n, slots=int(slots), n_obstacle_obs=int(n_obstacle_obs), neighbour=neighbour,
                   neighbour_edge=edge, neighbour_present=present, groups=groups,
                   obstacle_velocity=scenario.obstacle_paths is not None, faults=scenario.fault_times is not None,
                   motion=scenario.motion is not None)

    @cached_property
    def _neighbour_mask(self) -> np.ndarray:
        return self.neighbour_present > 0

    @cached_property
    def _group_sizes(self) -> tuple[tuple[np.ndarray, int], ...]:
        """Each group's arms and the size the compiled builders write (the feed-forward and the fault flag come
        after)."""
        return tuple((ids, self.size(n) - self.faults - 2 * self.motion) for n, ids in self.groups)

    def size(self, n: int) -> int:
        """Observation length of an agent with n links."""
        velocities = 2 * self.n_obstacle_obs if self.obstacle_velocity else 0
        return (3 * n + 2 + NEIGHBOUR_FEATURES * self.slots + OBSTACLE_FEATURES * self.n_obstacle_obs + velocities
                + 2 * self.motion + self.faults)

    def segments(self, n: int) -> dict[str, slice]:
        """Where each part of an n-link agent's observation lies, as slices of its vector.

        ``cos_q``, ``sin_q``, ``qd_scaled`` (q̇ / max_joint_speed), ``ee_rel_base`` (p − p0),
        ``neighbours`` (:attr:`slots` × :data:`NEIGHBOUR_FEATURES` entries ``[present, dx, dy, err]``)
        and ``obstacles`` (:attr:`n_obstacle_obs` × :data:`OBSTACLE_FEATURES` entries
        ``[present, dx, dy, r, h]``), in this order, then with :attr:`obstacle_velocity`
        ``obstacle_velocities`` (the same slots' ``[vx, vy]``), then with :attr:`motion` ``formation_velocity``
        (ṗ_ff, two entries), then with :attr:`faults` ``actuator_lost`` (one entry), covering :meth:`size` entries.
        """
        nb = 3 * n + 2
        ob = nb + NEIGHBOUR_FEATURES * self.slots
        end = ob + OBSTACLE_FEATURES * self.n_obstacle_obs
        parts = {"cos_q": slice(0, n), "sin_q": slice(n, 2 * n), "qd_scaled": slice(2 * n, 3 * n),
                 "ee_rel_base": slice(3 * n, nb), "neighbours": slice(nb, ob), "obstacles": slice(ob, end)}
        if self.obstacle_velocity:
            end += 2 * self.n_obstacle_obs
            parts["obstacle_velocities"] = slice(end - 2 * self.n_obstacle_obs, end)
        if self.motion:
            parts["formation_velocity"] = slice(end, end + 2)
            end += 2
        if self.faults:
            parts["actuator_lost"] = slice(end, end + 1)
        return parts

    def n_links(self, size: int) -> int:
        """The number of links of an agent whose observation has ``size`` entries (inverse of :meth:`size`)."""
        n, rest = divmod(int(size) - self.size(0), 3)
        if n < 1 or rest:
            raise ValueError(f"an observation of {size} entries does not fit this layout "
                             f"(3n + {self.size(0)} entries for an n-link arm)")
        return n

    def bounds(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """cos/sin in [−1, 1], presence flags in [0, 1], everything else in ±OBS_BOUND."""
        size = self.size(n)
        seg = self.segments(n)
        low = np.full(size, -OBS_BOUND, dtype=np.float32)
        high = np.full(size, OBS_BOUND, dtype=np.float32)
        low[: 2 * n], high[: 2 * n] = -1.0, 1.0
        nb, ob = seg["neighbours"], seg["obstacles"]
        flags = [*range(nb.start, nb.stop, NEIGHBOUR_FEATURES), *range(ob.start, ob.stop, OBSTACLE_FEATURES),
                 *range(size - self.faults, size)]
        low[flags], high[flags] = 0.0, 1.0
        return low, high

    def build_with_errors(self, q: np.ndarray, qd: np.ndarray, P: np.ndarray, base: np.ndarray, edges: np.ndarray,
                          distances: np.ndarray, centers: np.ndarray, radii: np.ndarray,
                          max_joint_speed: float, n_chunks: int = 0, *, velocities: np.ndarray | None = None,
                          faulted: np.ndarray | None = None, formation_velocity: np.ndarray | None = None
                          ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The edges' length errors ‖z_k‖ − d_k ``(B, E)`` and :meth:`build`'s observations, computed
        together (``edges (E, 2)`` int64, ``distances (B, E)``; other arguments as :meth:`build`)."""
        _check_chunks(n_chunks)
        kern = kernels()
        err = np.empty(distances.shape)
        velocities = self._velocities(velocities, radii)
        if n_chunks:
            kern.edge_length_errors(P, edges, distances, err)
            return err, self.build(q, qd, P, base, err, centers, radii, max_joint_speed, n_chunks,
                                   velocities=velocities, faulted=faulted, formation_velocity=formation_velocity)
        out = []
        for r, (ids, size) in enumerate(self._group_sizes):
            obs = np.empty((P.shape[0], len(ids), size), dtype=np.float32)
            if r == 0:
                kern.formation_observations(P, edges, distances, err, q, qd, base, centers, radii, velocities, ids,
                                            self.neighbour, self.neighbour_edge, self._neighbour_mask,
                                            self.n_obstacle_obs, 1.0 / max_joint_speed, OBS_BOUND, obs)
            else:
                kern.group_observations(q, qd, P, base, err, centers, radii, velocities, ids, self.neighbour,
                                        self.neighbour_edge, self._neighbour_mask, self.n_obstacle_obs,
                                        1.0 / max_joint_speed, OBS_BOUND, obs)
            out.append(obs)
        return err, self._appended(out, faulted, formation_velocity)

    def _velocities(self, velocities: np.ndarray | None, radii: np.ndarray) -> np.ndarray:
        """The kernels' velocity argument: ``(B, O, 2)`` with :attr:`obstacle_velocity`, else ``(B, 0, 2)``."""
        if not self.obstacle_velocity:
            return np.empty((radii.shape[0], 0, 2))
        if velocities is None or np.shape(velocities) != (*radii.shape, 2):
            raise ValueError(f"this layout observes obstacle velocities: pass velocities of shape {(*radii.shape, 2)}")
        return np.ascontiguousarray(velocities, dtype=float)

    def build(self, q: np.ndarray, qd: np.ndarray, P: np.ndarray, base: np.ndarray, edge_errors: np.ndarray,
              centers: np.ndarray, radii: np.ndarray, max_joint_speed: float, n_chunks: int = 0, *,
              velocities: np.ndarray | None = None, faulted: np.ndarray | None = None,
              formation_velocity: np.ndarray | None = None) -> list[np.ndarray]:
        """Every agent's observation, one float32 array ``(B, A, size(n))`` per group of :attr:`groups`.

        Args:
            q, qd: ``(B, N, n_max)`` joint angles and velocities (padding ignored).
            P: ``(B, N, 2)`` end-effectors; base: ``(B, N, 2)`` arm bases.
            edge_errors: ``(B, E)`` ‖z_k‖ − d_k.
            centers: ``(B, O, 2)``, radii: ``(B, O)``: each team's obstacles.
            max_joint_speed: scale of q̇.
            velocities: ``(B, O, 2)`` the obstacles' velocities, for a layout with
                :attr:`obstacle_velocity` (required there, ignored otherwise).
            faulted: ``(B, N)`` booleans, the arms that have lost their first joint's actuator, for a layout
                with :attr:`faults` (required there, ignored otherwise).
            formation_velocity: ``(B, N, 2)`` the feed-forward ṗ_ff (m/s), for a layout with :attr:`motion`
                (required there, ignored otherwise).
            n_chunks: 0 for the single-threaded kernel; otherwise the teams are split into this
                many chunks on numba's thread pool (for large B).
        """
        _check_chunks(n_chunks)
        kern = kernels()
        velocities = self._velocities(velocities, radii)
        out = []
        for ids, size in self._group_sizes:
            obs = np.empty((P.shape[0], len(ids), size), dtype=np.float32)
            args = (q, qd, P, base, edge_errors, centers, radii, velocities, ids, self.neighbour, self.neighbour_edge,
                    self._neighbour_mask, self.n_obstacle_obs, 1.0 / max_joint_speed, OBS_BOUND, obs)
            if n_chunks:
                kern.group_observations_parallel(*args, n_chunks)
            else:
                kern.group_observations(*args)
            out.append(obs)
        return self._appended(out, faulted, formation_velocity)

    def _appended(self, out: list[np.ndarray], faulted: np.ndarray | None,
                  formation_velocity: np.ndarray | None) -> list[np.ndarray]:
        """Each group's observations with, after what the compiled builders wrote, the feed-forward
        (with :attr:`motion`) and the fault flag (with :attr:`faults`)."""
        B, N = out[0].shape[0], len(self.n)
        extra = []
        if self.motion:
            if formation_velocity is None or np.shape(formation_velocity) != (B, N, 2):
                raise ValueError(f"this layout observes a moving formation: pass formation_velocity of shape "
                                 f"{(B, N, 2)}")
            extra.append(np.clip(formation_velocity, -OBS_BOUND, OBS_BOUND).astype(np.float32))
        if self.faults:
            if faulted is None or np.shape(faulted) != (B, N):
                raise ValueError(f"this layout observes faults: pass faulted of shape {(B, N)}")
            extra.append(np.asarray(faulted, dtype=np.float32)[..., None])
        if not extra:
            return out
        columns = np.concatenate(extra, axis=-1)
        return [np.concatenate([obs, columns[:, ids]], axis=-1) for (ids, _), obs in
                zip(self._group_sizes, out, strict=True)]
