"""The paper's law with a circulation term: a non-learning baseline for the deadlocks at an obstacle.

Behind the whole-arm filter most of the law's failed teams are deadlocks: the law drives a link straight into an
obstacle and the filter's QP cancels the motion. The circulation term turns that push into a turn round the
obstacle, in the policy (the filter and its safety argument are untouched: whatever the policy asks, the QP keeps
the same rows). For every body point x of an arm within ``activation`` m of obstacle o (the end-effector on an
end-effector task, each link's closest point on a whole-arm task), with J_x the point's Jacobian through g0
(actuated velocities to ẋ):

    a = (x − o)ᵀ J_x                       the direction that moves x away from o (the barrier's row),
    t = (R (x − o))ᵀ J_x, less its part along a    the direction that moves x round o, R the quarter turn
                                                   anticlockwise (``ccw``) or clockwise (``cw``),
    v = v0 + γ max(0, −a·v0)/‖a‖ · t/‖t‖   summed over the pairs,

so the law's speed into an obstacle (what the QP cancels) becomes as fast a turn round it. The term reads the
team's true state and every obstacle, not an agent's local observation, and acts on obstacles only, not on the
other arms. :class:`CirculatingPolicy` adds a memory per arm, which the filter, a function of one instant, has
not: the term waits until an arm has been blocked ``delay`` s, and turns its sense round once it has pushed round
an obstacle ``flip_after`` s. Its defaults are the best rule of ``benchmarks/circulation.py`` (docs/ENVIRONMENTS.md,
*Deadlocks at an obstacle*); ``pan1-env benchmark --policies circulation`` runs it.
"""

from __future__ import annotations

import numpy as np

from pan1_env.bodies import closest_point_on_segment, link_point_jacobian, link_segments
from pan1_env.cascade import passive_velocity_map
from pan1_env.dynamics import end_effector
from pan1_env.safety import clearance

from .reference import ReferencePolicy

__all__ = ["circulation_term", "CirculatingPolicy", "SENSES", "PAUSE_S"]

SENSES = {"ccw": 1.0, "cw": -1.0}
PAUSE_S = 2.0  #: a pause in an arm's term this long ends its spell of contact


def circulation_term(arm, q, v0, centers, radii, link_radius, links, gain, sense, activation) -> np.ndarray:
    """The term added to one arm's velocity command ``v0 (k,)`` (rad/s) at joint angles ``q``: ``sense`` +1
    turns round the obstacles anticlockwise, −1 clockwise; ``links`` whether the bodies are the links (else the
    end-effector)."""
    term = np.zeros_like(v0)
    if links:  # the closest point of each link to each obstacle; Jacobians only for the pairs in range
        a, b = link_segments(arm, q)
        point, t_on = closest_point_on_segment(a[:, None], b[:, None], centers)
        gap = np.linalg.norm(point - centers, axis=-1) - radii - link_radius
        pairs = [(link, o, point[link, o], t_on[link, o]) for link, o in
                 zip(*np.nonzero(gap < activation), strict=True)]
    else:
        p = end_effector(arm, q)
        pairs = [(arm.n_links - 1, o, p, 1.0) for o in np.flatnonzero(clearance(p, centers, radii) < activation)]
    if not pairs:
        return term
    g0 = passive_velocity_map(arm, q)
    for link, o, x, t in pairs:
        Jx = link_point_jacobian(arm, q, link, t) @ g0
        rel = x - centers[o]
        a = rel @ Jx
        norm_a = np.linalg.norm(a)
        into = -(a @ v0)
        if norm_a < 1e-12 or into <= 0.0:
            continue
        tangent = sense * np.array([-rel[1], rel[0]]) @ Jx
        tangent -= (tangent @ a) / norm_a**2 * a
        norm_t = np.linalg.norm(tangent)
        if norm_t > 1e-12:
            term += gain * into / norm_a * tangent / norm_t
    return term


class CirculatingPolicy:
    """The paper's law (:class:`~pan1_env.baselines.ReferencePolicy`, velocity mode) plus
    :func:`circulation_term` for every arm, on a parallel env (wrapped or not) whose team it reads at every call.

    A spell of contact is the time an arm's term is non-zero without a pause of :data:`PAUSE_S`. ``delay`` (s)
    holds the term back for the spell's first seconds, so that it acts only on an arm that stays blocked.
    ``flip_after`` > 0 (s) turns the arm's sense round once the term has acted that long, once per spell; 0
    keeps the sense. The command is scaled down as the law's is if an entry passes the speed bound.

    Raises:
        ValueError: an env whose actions are not velocities, an unknown ``sense``, or a negative time.
    """

    def __init__(self, env, gain: float = 1.0, sense: str = "ccw", activation: float = 0.1, flip_after: float = 15.0,
                 delay: float = 5.0) -> None:
        if env.config.action_mode != "velocity":
            raise ValueError("the circulating law outputs velocities: use action_mode='velocity'")
        if sense not in SENSES:
            raise ValueError(f"sense must be one of {sorted(SENSES)}, got {sense!r}")
        if not all(np.isfinite(x) and x >= 0 for x in (gain, activation, flip_after, delay)):
            raise ValueError(f"gain, activation, flip_after and delay must be finite and ≥ 0, got {gain}, "
                             f"{activation}, {flip_after}, {delay}")
        self.env, self.law = env, ReferencePolicy(env)
        self.gain, self.sense, self.activation, self.flip_after = gain, SENSES[sense], activation, flip_after
        self.delay = delay
        self.arms: list[dict] = []

    def __call__(self, observations: dict) -> dict:
        actions = self.law(observations)
        team = self.env.unwrapped
        dt, scenario, speed = team.dt, team.scenario, team.config.max_joint_speed
        if team.num_steps == 0 or not self.arms:  # a new episode
            self.arms = [{"sense": self.sense, "acting": 0.0, "pause": 0.0, "flipped": False}
                         for _ in team.possible_agents]
        q = team.joint_state()[0]
        centers, radii = team.obstacle_centers_now[0], scenario.obstacles.radii  # where they are now, if they move
        for i, agent in enumerate(team.possible_agents):
            arm = self.arms[i]
            v0 = np.asarray(actions[agent], float) * speed
            term = circulation_term(scenario.arms[i], q[i, :scenario.arms[i].n_links], v0, centers, radii,
                                    scenario.link_radius, scenario.bodies == "links", self.gain,
                                    arm["sense"], self.activation)
            if np.any(term):
                arm["acting"] += dt
                arm["pause"] = 0.0
                if self.flip_after > 0 and arm["acting"] > self.delay + self.flip_after and not arm["flipped"]:
                    arm["sense"], arm["flipped"] = -arm["sense"], True
            else:
                arm["pause"] += dt
                if arm["pause"] > PAUSE_S:
                    arm["acting"], arm["flipped"] = 0.0, False
            v = v0 + term if arm["acting"] > self.delay else v0
            v /= speed * max(1.0, float(np.max(np.abs(v))) / speed)
            actions[agent] = v.astype(np.float32)
        return actions
