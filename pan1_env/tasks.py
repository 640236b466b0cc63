"""Tasks: what a step of the engine means, written once and batched over B copies.

A task turns the engine's state and :class:`~pan1_env.engine.StepRecord` into observations,
rewards (with their terms), cost, success and termination, as arrays over copies (and arms). The
parallel env, the Gymnasium view and the vector env share :class:`FormationTask`; the reach env
uses :class:`ReachTask`. Nothing here steps the physics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .compiled import kernels
from .config import FormationConfig, ReachConfig
from .control import nominal_velocity, within_speed
from .dynamics import end_effector
from .engine import Engine
from .formation import SparseIncidence, edge_errors, edge_length_errors
from .motion import MotionTable
from .observation import OBS_BOUND, OBSTACLE_FEATURES, ObservationLayout
from .random_scenario import zero_momentum_start
from .safety import clearance
from .scenario import Scenario
from .step_record import StepRecord
from .team_draw import TeamDraws

__all__ = ["FormationTask", "ReachTask", "Outcome", "law_velocity"]

GOAL_DRAWS = 1000  # attempts at a reach goal clear of the obstacles before giving up


def law_velocity(engine: Engine, e_hat: np.ndarray, kp: np.ndarray, feed_forward: np.ndarray | None = None,
                 gain: np.ndarray | None = None, max_speed: float | None = None,
                 circulation: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """The paper's distributed law (Eq. 39, :func:`~pan1_env.control.nominal_velocity`) for every arm of every copy of
    ``engine``, ``(B, N, k_max)`` rad/s (padding zero), from each arm's formation gradient ``e_hat (B, N, 2)`` and each
    copy's gain ``kp (B,)``: a PAn−1 arm's drift and a moving formation's ``feed_forward (B, N, 2)`` compensated,
    ``gain (B, N, k_max)`` multiplying each joint's term, and each arm's vector scaled down as a whole to
    ``max_speed`` (None: unbounded). With ``circulation = (strength (B, N), activation)`` each arm's scaled vector
    then gets ``strength`` times its circulation term round the obstacles within ``activation`` m
    (:meth:`Engine.circulation`; > 0 anticlockwise) and is scaled down again. The one assembly of the law: the envs'
    and :class:`~pan1_env.simulation.Simulation`'s."""
    out = np.zeros((engine.copies, engine.n_arms, engine.k_max))
    for kind in engine.kinds:
        terms = engine.kind_terms(kind)
        e = e_hat[:, kind.ids].reshape(-1, 2)
        ff = None if feed_forward is None else feed_forward[:, kind.ids].reshape(-1, 2)
        v0 = nominal_velocity(terms.Jbar, e, np.repeat(kp, kind.A)[:, None], terms.drift, ff)
        if gain is not None:
            v0 *= kind.from_team(gain, kind.k)
        if max_speed is not None:
            within_speed(v0, max_speed)
        if circulation is not None:
            strength, activation = circulation
            v0 += kind.from_team(strength)[:, None] * engine.circulation(kind, v0, activation)
            if max_speed is not None:
                within_speed(v0, max_speed)
        kind.to_team(out, v0)
    return out


@dataclass
class Outcome:
    """A step's meaning per copy: ``reward (B, N)`` per agent and its ``terms`` (each broadcastable to
    ``(B, N)``; the reward is their sum),
    ``cost (B, N)`` (1.0 where an arm entered an obstacle), ``success (B,)``, ``terminated (B,)``, and
    task measures in ``measures`` (each ``(B,)``)."""

    reward: np.ndarray
    terms: dict[str, np.ndarray]
    cost: np.ndarray
    success: np.ndarray
    terminated: np.ndarray
    measures: dict[str, np.ndarray]


class FormationTask:
    """Bring the end-effectors into the scenario's rigid formation without touching an obstacle.

    Reward of agent i: ``−formation_weight · mean_k |‖z_k‖ − d_k| − effort_weight · ‖a_i‖²/k_i
    − collision_penalty · cost_i + success_bonus · success − intervention_penalty · ‖(v_i − v*_i)/v_max‖²/k_i``
    (v_i the commanded, v*_i the filtered velocity of the step's last sub-step); success: every edge
    within ``success_tolerance`` of its length (for ``success_hold`` seconds without a break, if set). With a moving
    formation (``Scenario.motion``) the lengths are the moving shape's at the copy's clock, and the law gets
    the motion's feed-forward (:mod:`pan1_env.motion`). A placed shape (a motion with a ``centre``) also asks
    every end-effector to be at its point p*_i: the formation term adds ``− formation_weight · mean_i ‖p_i − p*_i‖``,
    ``formation_error`` is the larger of the worst edge's and the worst arm's distance, and success needs both
    within the tolerance.
    The observation layout (:class:`~pan1_env.observation.ObservationLayout`) is the one public
    description of what each agent sees.

    What an action ``a`` in [−1, 1] (clipped) means, by ``action_mode``:

    * ``action_mode="velocity"`` (default): the desired active-joint velocity
      v = a · ``max_joint_speed`` (rad/s), held for the control step and tracked inside the env by
      the paper's backstepping law (Eq. 64) at every physics sub-step.
    * ``action_mode="torque"``: the active-joint torque τ_a = a · ``max_torque`` (N·m), held.
    * ``action_mode="residual"``: a correction to the paper's distributed law (Eq. 39),
      v = clip(v_0 + a · ``max_joint_speed``, ±``max_joint_speed``), tracked as in velocity mode;
      v_0 = −K_P J̄ᵀ ê computed from the true state at the step's start and scaled down as a whole
      to ``max_joint_speed`` (as :class:`pan1_env.baselines.ReferencePolicy` does). The zero action
      is the reference controller (behind the safety filter, the paper's safe controller); the
      effort term penalises the correction only. With ``residual_gate=g`` (m, > 0) arm i's
      correction is scaled by min(1, (e_i/g)²), e_i the largest length error of its edges, so it
      vanishes at the formation and the formed shape stays an equilibrium. With ``blocked_gate=c``
      (> 0) it is also scaled by min(1, b_i/c), b_i how much the safety filter changed the arm's
      previous command (the intervention term's measure, 0 at a reset): the correction acts only
      where the filter holds the paper's law back.
    * ``action_mode="gain"``: a re-weighting of the paper's law: joint j's term of v_0 is multiplied
      by ``gain_range`` ** a_j (default 4, so gains from 1/4 to 4) before the vector is scaled down
      as a whole to ``max_joint_speed``. The zero action is the reference controller; any action
      keeps the command from ever ascending V (a positive diagonal re-weighting of −K_P J̄ᵀ ê, before
      the filter and with the velocity tracked exactly) and the formed shape an equilibrium: unlike a
      residual, a gain cannot point against the law. The effort term penalises the log-gains a. That holds
      for a still formation and an arm without drift: the gains multiply the whole command, so they also
      re-weight a drift's cancellation (§7) and a moving formation's feed-forward (§8).
    * ``action_mode="circulation"``: gain actions with one entry more, first, a signed turn round the obstacles
      an arm is driven into (:meth:`circulate`); the zero action is the reference controller.
    """

    _tracked: tuple | None = None  # the inputs track() last computed the targets from (None: none yet)

    def __init__(self, config: FormationConfig, copies: int) -> None:
        self.config = config  # the task's settings, read from it where they are used (weights, gates, tolerances)
        scenario = config.team
        self.layout = layout = ObservationLayout.from_scenario(scenario, config.neighbour_slots, config.n_obstacle_obs,
                                                               ring=config.ring)
        self.blocked = np.zeros((copies, layout.n.size))  # the filter's change of each arm's last command
        self.edges = np.ascontiguousarray(scenario.formation.edges, dtype=np.int64)
        self.incidence = SparseIncidence.of(self.edges, scenario.n_arms)  # for the law and the residual gate
        self.distances = np.tile(np.asarray(scenario.formation.distances, dtype=float)[None], (copies, 1))
        self.kp = np.full(copies, float(scenario.kp))
        self.below_since = np.zeros(copies)  # the clock when the error last was at or above the tolerance
        self.motion = None
        if layout.motion:
            self.motion = MotionTable(copies, scenario.n_arms, scenario.motion.keyframes)
            for b in range(copies):
                self.motion.load(b, scenario.formation.target, scenario.motion)
        self.feed_forward = np.zeros((copies, scenario.n_arms, 2))  # ṗ_ff (m/s): zero for a still formation
        self.misplacement = np.zeros((copies, scenario.n_arms))  # m: each arm's distance from a placed shape's point
        self.sizes = [layout.size(n) for n in layout.n]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        # every arm in one layout group, in agent order: the flat observation is a reshape
        in_order = layout.groups[0][1].tolist() == list(range(len(self.sizes)))
        self._one_group_in_order = len(layout.groups) == 1 and in_order

    @staticmethod
    def reset_options(options: dict | None) -> dict:
        """The reset options: the formation task has none and ignores what it is given (PettingZoo's API test
        passes options of its own)."""
        return {}

    def reset(self, copies: np.ndarray, rngs: list[np.random.Generator], engine: Engine, options: dict) -> None:
        """A new episode in ``copies`` (their arms at their start): no filter change of a previous command yet,
        and no time below the tolerance."""
        self.blocked[copies] = 0.0
        self.below_since[copies] = 0.0

    def bounds(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Agent i's observation bounds."""
        return self.layout.bounds(int(self.layout.n[i]))

    def load_team(self, b: int, scenario: Scenario) -> None:
        """Copy ``b`` now has ``scenario``'s formation (and its motion, where the env's formations move)."""
        self.distances[b] = scenario.formation.distances
        self.kp[b] = scenario.kp
        if self.motion is not None:
            self.motion.load(b, scenario.formation.target, scenario.motion)
            self._tracked = None

    def load_teams(self, copies: np.ndarray, draws: TeamDraws) -> None:
        """:meth:`load_team` for the drawn teams of ``copies`` at once."""
        self.distances[copies] = draws.distances(self.edges)
        self.kp[copies] = draws.options.kp
        if self.motion is not None:
            for c, b in enumerate(np.asarray(copies).tolist()):
                self.motion.load(b, draws.realisation(c), draws.motions[c])
            self._tracked = None

    def track(self, engine: Engine) -> None:
        """With a moving formation, the desired lengths and the feed-forward at every copy's clock and state,
        computed once for a clock and end-effectors (a step's observation, the next step's law and a critic's state
        all ask at the same ones; the motions loaded since count too)."""
        if self.motion is None:
            return
        P = engine.positions()
        inputs = (engine.elapsed.tobytes(), P.tobytes())
        if inputs == self._tracked:
            return
        self.distances[:], self.feed_forward, self.misplacement = self.motion.targets(engine.elapsed, self.edges, P)
        self._tracked = inputs

    @property
    def target_size(self) -> int:
        """Columns of :meth:`target_state`: ``E + 2N`` for a moving formation, else 0."""
        return 0 if self.motion is None else len(self.edges) + 2 * self.feed_forward.shape[1]

    def target_state(self, engine: Engine) -> np.ndarray:
        """What of the target a centralised state needs, ``(B, target_size)``: for a moving formation the desired
        lengths now and every arm's feed-forward, else nothing."""
        if self.motion is None:
            return np.empty((engine.copies, 0))
        self.track(engine)
        return np.concatenate([self.distances, self.feed_forward.reshape(engine.copies, -1)], axis=1)

    def nominal_velocity(self, engine: Engine, gain: np.ndarray | None = None,
                         circulation: np.ndarray | None = None) -> np.ndarray:
        """The paper's distributed law for every arm, ``(B, N, k_max)`` rad/s (padding zero):
        ``v_i0 = −K_P J̄_iᵀ ê_i``, ``ê_i = Σ_j 2 (p_i − p_j)(‖p_i − p_j‖² − d_ij²)`` (Eq. 39; for a PAn−1 arm
        whose passive joint turns, minus J̄⁺ of its end-effector's drift, docs/MODEL.md §7), each arm's
        vector scaled down as a whole to ``max_joint_speed`` when an entry exceeds it (so it stays a
        descent direction of V), as :class:`~pan1_env.baselines.ReferencePolicy` does from observations.
        ``gain (B, N, k_max)``, if given, multiplies each joint's term before that scaling. A moving formation
        adds J̄⁺ ṗ_ff (its feed-forward) before that scaling. ``circulation (B, N)``, if given, adds that multiple
        of each arm's circulation term (``circulation_activation``) after it, and scales down again."""
        self.track(engine)
        z = self.incidence.edge_vectors(engine.positions())  # (B, E, 2)
        e_hat = self.incidence.gradient(z, edge_errors(z, self.distances))  # (B, N, 2)
        c = self.config
        return law_velocity(engine, e_hat, self.kp, self.feed_forward if self.motion is not None else None, gain,
                            c.max_joint_speed, None if circulation is None else (circulation,
                                                                                   c.circulation_activation))

    def compose(self, action_mode: str, command: np.ndarray, engine: Engine) -> np.ndarray:
        """The engine's command ``(B, N, k_max)`` from the scaled actions ``command`` (``(B, N, action_width)``):
        :meth:`add_nominal` for ``"residual"`` and :meth:`scale_nominal` for ``"gain"``, in place;
        :meth:`circulate` for ``"circulation"``, a new array; the other modes' actions are their commands
        already."""
        if action_mode == "residual":
            self.add_nominal(command, engine)
        elif action_mode == "gain":
            self.scale_nominal(command, engine)
        elif action_mode == "circulation":
            return self.circulate(command, engine)
        return command

    def circulate(self, actions: np.ndarray, engine: Engine) -> np.ndarray:
        """Circulation actions ``(B, N, 1 + k_max)``: arm i's entry 0 adds that multiple of ``circulation_gain`` times
        its circulation term, where the law drives a body point within ``circulation_activation`` m of an obstacle
        as fast a turn round it (> 0 anticlockwise, < 0 clockwise; :mod:`pan1_env.kernels.circulation`); its next
        k_i entries re-weight the paper's law as gain actions do. Entry 0 means the same for every arm kind, so one
        network shared by the arms reads it alike. The zero action is the law. The term adds, for each body point
        and obstacle in range, a turn round the obstacle as fast (in joint space) as the command's push into it;
        the push itself stays, for the filter, if it is on, to hold back; the sum is scaled down to the speed
        bound."""
        return self.nominal_velocity(engine, self.config.gain_range ** actions[..., 1:],
                                     actions[..., 0] * self.config.circulation_gain)

    def scale_nominal(self, command: np.ndarray, engine: Engine) -> None:
        """Gain actions: joint j of arm i gets the paper's law with its term multiplied by
        ``gain_range ** a_ij``, in place of the actions ``command`` (a in [−1, 1], unscaled: the zero
        action is the law itself). With a positive diagonal gain D, ê·J̄ (−D J̄ᵀ ê) ≤ 0: the command
        never ascends V (before the filter, velocity tracked exactly), and the formed shape (ê = 0)
        stays an equilibrium whatever the policy outputs; it re-weights the law, it cannot point
        against it."""
        command[:] = self.nominal_velocity(engine, self.config.gain_range ** command)

    def add_nominal(self, command: np.ndarray, engine: Engine) -> None:
        """Residual actions: add :meth:`nominal_velocity` to the scaled corrections ``command
        (B, N, k_max)`` (rad/s) in place and clip to ``±max_joint_speed``. With a ``residual_gate`` g > 0
        each arm's correction is first scaled by ``min(1, (e_i / g)²)``, e_i the largest length error of
        the arm's edges: it vanishes at the formation faster than the law's pull grows, so the formed
        shape stays an equilibrium whatever the policy outputs. With a ``blocked_gate`` c > 0 it is also
        scaled by ``min(1, blocked_i / c)``, ``blocked_i`` the filter's change of the arm's previous
        command (the intervention term's measure): the correction acts only where the filter holds the
        paper's law back."""
        c = self.config
        if c.blocked_gate > 0:
            command *= np.minimum(1.0, self.blocked / c.blocked_gate)[..., None]
        if c.residual_gate > 0:
            err = np.abs(edge_length_errors(self.incidence.edge_vectors(engine.positions()), self.distances))
            arm_err = self.incidence.largest_at_vertex(err)  # (B, N)
            command *= np.minimum(1.0, (arm_err / c.residual_gate) ** 2)[..., None]
        command += self.nominal_velocity(engine)
        np.clip(command, -c.max_joint_speed, c.max_joint_speed, out=command)

    def observe(self, engine: Engine, copies: np.ndarray | None = None) -> tuple[np.ndarray, list[np.ndarray]]:
        """The edges' length errors ``(B, E)`` and every agent's observation, one float32 array
        ``(B, A, size)`` per group of :attr:`ObservationLayout.groups`; with ``copies`` (indices) those copies'
        only, in their order (each copy's observation depends on its own state alone)."""
        self.track(engine)
        q, qd = engine.joint_state()
        velocities = engine.obstacle_velocities() if self.layout.obstacle_velocity else None
        parts = (q, qd, engine.positions(), engine.bases, self.distances, engine.centers, engine.radii, velocities,
                 engine.faulted, self.feed_forward)
        if copies is not None:
            parts = tuple(None if part is None else part[copies] for part in parts)
        q, qd, P, bases, distances, centers, radii, velocities, faulted, feed_forward = parts
        return self.layout.build_with_errors(q, qd, P, bases, self.edges, distances, centers, radii,
                                             self.config.max_joint_speed, engine.chunks(len(q) * engine.n_arms),
                                             velocities=velocities, faulted=faulted, formation_velocity=feed_forward)

    def flat(self, mats: list[np.ndarray]) -> np.ndarray:
        """The agents' observations concatenated in agent order, ``(B, Σ size)``."""
        if self._one_group_in_order:
            return mats[0].reshape(len(mats[0]), -1)
        out = np.empty((len(mats[0]), self.offsets[-1]), dtype=np.float32)
        for (_, ids), mat in zip(self.layout.groups, mats, strict=True):
            for r, i in enumerate(ids):
                out[:, self.offsets[i] : self.offsets[i + 1]] = mat[:, r]
        return out

    def evaluate(self, record: StepRecord | None, engine: Engine | None, err: np.ndarray, effort: np.ndarray,
                 command: np.ndarray | None = None, copies: np.ndarray | None = None) -> Outcome:
        """The step's outcome from its record, the edge errors after it (:meth:`observe`'s) and each agent's
        effort ``‖a_i‖²/k_i (B, N)``; at a reset (``record`` None) of the state in ``engine``, with ``copies``
        (indices) for those copies only (``err`` and ``effort`` their rows). The intervention term needs the
        commanded velocities ``command (B, N, k_max)`` (rad/s; None in torque mode, where the term is left
        out)."""
        c = self.config
        if record is not None and copies is not None:
            raise ValueError("a step's outcome covers every copy; copies is for a reset's")
        rows = slice(None) if copies is None else copies
        min_clear = record.min_clearance if record is not None else engine.clearance(copies)
        B = len(err)
        formation, formation_error, success = np.empty(B), np.empty(B), np.empty(B, dtype=bool)
        cost = np.empty(min_clear.shape)
        kernels().formation_outcome(err, min_clear, c.formation_weight, c.success_tolerance, formation, formation_error,
                                    success, cost)
        if self.motion is not None and self.motion.placed.any():  # a placed shape: each arm also at its point
            misplacement = self.misplacement[rows]
            formation -= c.formation_weight * misplacement.mean(axis=1)
            formation_error = np.maximum(formation_error, misplacement.max(axis=1))
            success &= formation_error < c.success_tolerance
        if c.success_hold > 0:
            clock = engine.elapsed[rows]
            self.below_since[rows] = below_since = np.where(success, self.below_since[rows], clock)
            success &= clock - below_since >= c.success_hold - 1e-9
        reward = np.empty_like(cost)
        reward[:] = formation[:, None]
        intervention = 0.0
        if record is not None and command is not None and (c.intervention_penalty or c.blocked_gate):
            change = ((command - record.v_star) / c.max_joint_speed) ** 2  # NaN in the padding
            intervention = np.nansum(change, axis=-1) / np.isfinite(change).sum(axis=-1)
            self.blocked[:] = intervention
        terms = _terms(reward, {"formation": formation[:, None]}, effort=(c.effort_weight, effort),
                       collision=(c.collision_penalty, cost),
                       success=(-c.success_bonus, success[:, None].astype(float)),
                       intervention=(c.intervention_penalty, intervention))
        terminated = _terminated(success, cost, c)
        return Outcome(reward, terms, cost, success, terminated,
                       {"formation_error": formation_error, "min_clearance": min_clear})


def _terms(reward: np.ndarray, terms: dict[str, np.ndarray], **weighted: tuple[float, np.ndarray]) -> dict:
    """Add each ``−weight · value`` term with a non-zero weight to ``reward`` (in place) and ``terms``."""
    for name, (weight, value) in weighted.items():
        if weight:
            terms[name] = -weight * value
            reward += terms[name]
    return terms


def _terminated(success: np.ndarray, cost: np.ndarray, config: FormationConfig | ReachConfig) -> np.ndarray:
    """Per copy: success ends the episode with the config's ``terminate_on_success``, any arm's collision with its
    ``terminate_on_collision``."""
    terminated = success & config.terminate_on_success
    if config.terminate_on_collision:
        terminated |= cost.any(axis=1) > 0
    return terminated


class ReachTask:
    """One arm brings its end-effector within ``goal_tolerance`` of a goal point.

    Reward: ``−‖goal − p‖ − effort_weight · ‖a‖²/k − collision_penalty · cost``.
    Observation: ``[cos q, sin q, q̇ / v_max, p − base, goal − p, K obstacle slots]``. The goal is drawn at
    every reset (:meth:`reset`).
    """

    def __init__(self, config: ReachConfig, copies: int) -> None:
        self.config = c = config
        self.arm, self.q0 = c.team.arms[0], np.asarray(c.team.q0[0], dtype=float)
        self.goal = np.zeros((copies, 2))
        self.size = 3 * self.arm.n_links + 4 + OBSTACLE_FEATURES * c.n_obstacle_obs
        self._reward_parts()

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._reward_parts()  # (a task pickled by an earlier build has none)

    def _reward_parts(self) -> None:
        """The weights :func:`~pan1_env.kernels.reach_outcome` takes, and the reward's terms as (name, column of its
        ``terms``): the distance always, the others where their weight is not zero."""
        c = self.config
        self._weights = np.array([c.effort_weight, c.collision_penalty])
        self._terms = [(name, t) for t, (name, weight) in enumerate(
            [("distance", 1.0), ("effort", c.effort_weight), ("collision", c.collision_penalty)]) if weight]

    @staticmethod
    def reset_options(options: dict | None) -> dict:
        """The reset options, checked before anything changes: ``goal``, two finite numbers (x, y)."""
        options = dict(options or {})
        goal = options.pop("goal", None)
        if options:
            raise ValueError(f"unknown reset option {sorted(options)[0]!r}; the only option is 'goal'")
        if goal is None:
            return {}
        try:
            point = np.asarray(goal, dtype=float)
        except (TypeError, ValueError):
            point = None
        if point is None or point.shape != (2,) or not np.isfinite(point).all():
            raise ValueError(f"options['goal'] must be 2 finite numbers (x, y), got {goal!r}")
        return {"goal": point}

    def reset(self, copies: np.ndarray, rngs: list[np.random.Generator], engine: Engine, options: dict) -> None:
        """A goal for each copy in ``copies``: ``options["goal"]`` (x, y), or one drawn from the copy's generator:
        the end-effector of a configuration reached from the start at rest (the actuated joints moved in a
        straight line by up to ±``goal_spread`` rad each, the passive joint by zero momentum), redrawn until it
        is ``goal_clearance`` clear of every obstacle."""
        goal = options.get("goal")
        for b in np.asarray(copies).tolist():
            self.goal[b] = self._draw_goal(rngs[b], engine, b) if goal is None else goal

    def _draw_goal(self, rng: np.random.Generator, engine: Engine, b: int) -> np.ndarray:
        arm, k, spread = self.arm, self.arm.n_actuated, self.config.goal_spread
        for _ in range(GOAL_DRAWS):
            q = zero_momentum_start(arm, self.q0, self.q0[-k:] + rng.uniform(-spread, spread, k))
            goal = end_effector(arm, q)
            if clearance(goal, engine.centers[b], engine.radii[b]).min(initial=np.inf) >= self.config.goal_clearance:
                return goal
        raise RuntimeError(f"no goal {self.config.goal_clearance} m clear of the obstacles in {GOAL_DRAWS} draws; "
                           "lower goal_clearance")

    def load_team(self, b: int, scenario: Scenario) -> None:
        raise ValueError("the reach task keeps its arm")

    def load_teams(self, copies: np.ndarray, draws: TeamDraws) -> None:
        raise ValueError("the reach task keeps its arm")

    target_size = 0  # the goal is not part of the state

    @staticmethod
    def target_state(engine: Engine) -> np.ndarray:
        """Nothing: the goal is not part of the state (``(B, 0)``)."""
        return np.empty((engine.copies, 0))

    def compose(self, action_mode: str, command: np.ndarray, engine: Engine) -> np.ndarray:
        """Velocity actions only: the command is the action."""
        return command

    def bounds(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """cos/sin in [−1, 1], presence flags in [0, 1], everything else in ±OBS_BOUND."""
        n = self.arm.n_links
        low, high = np.full(self.size, -OBS_BOUND, dtype=np.float32), np.full(self.size, OBS_BOUND, dtype=np.float32)
        low[: 2 * n], high[: 2 * n] = -1.0, 1.0
        flags = [3 * n + 4 + OBSTACLE_FEATURES * s for s in range(self.config.n_obstacle_obs)]
        low[flags], high[flags] = 0.0, 1.0
        return low, high

    def observe(self, engine: Engine, copies: np.ndarray | None = None) -> tuple[None, list[np.ndarray]]:
        """Every copy's observation, ``[(B, 1, size)]`` (the engine's team is the one arm); with ``copies`` (indices)
        those copies' only, in their order."""
        kind = engine.kinds[0]
        parts = (kind.q, kind.qd, kind.p, kind.base, self.goal, engine.centers, engine.radii)
        if copies is not None:
            parts = tuple(part[copies] for part in parts)
        out = np.empty((len(parts[0]), self.size), dtype=np.float32)
        kernels().reach_observations(*parts, self.config.n_obstacle_obs, 1.0 / self.config.max_joint_speed,
                                     OBS_BOUND, out)
        return None, [out[:, None]]

    def flat(self, mats: list[np.ndarray]) -> np.ndarray:
        return mats[0].reshape(len(mats[0]), -1)

    def evaluate(self, record: StepRecord | None, engine: Engine, state: None, effort: np.ndarray,
                 command: np.ndarray | None = None, copies: np.ndarray | None = None) -> Outcome:
        """The step's outcome (``record`` None at a reset, with ``copies`` (indices) for those copies only) for effort
        ``‖a‖²/k (B, 1)``, computed in one compiled pass (:func:`pan1_env.kernels.reach_outcome`; tests/test_tasks.py
        holds its numpy twin)."""
        if record is not None and copies is not None:
            raise ValueError("a step's outcome covers every copy; copies is for a reset's")
        goal, p = (self.goal, engine.kinds[0].p) if copies is None else (self.goal[copies], engine.kinds[0].p[copies])
        B = len(goal)
        min_clear = engine.clearance(copies) if record is None else record.min_clearance
        distance, terms, reward = np.empty(B), np.empty((B, 3)), np.empty((B, 1))
        cost, success, terminated = np.empty((B, 1)), np.empty(B, dtype=bool), np.empty(B, dtype=bool)
        kernels().reach_outcome(goal, p, min_clear[:, 0], effort[:, 0], self._weights,
                                self.config.goal_tolerance, self.config.terminate_on_success,
                                self.config.terminate_on_collision, distance, terms, reward[:, 0], cost[:, 0], success,
                                terminated)
        named = {name: terms[:, t: t + 1] for name, t in self._terms}
        return Outcome(reward, named, cost, success, terminated, {"distance": distance, "min_clearance": min_clear})
