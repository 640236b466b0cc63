"""The paper's nominal distributed formation law (Eq. 39) as a policy on local observations.

For agent i it reads only its own observation (joint angles, and for each neighbour j the
displacement Δ = p_j − p_i and the edge error ‖Δ‖ − d_ij) plus its own arm's known parameters, and
returns

    v_i0 = −K_P J̄_i(q_i)ᵀ ê_i,    ê_i = Σ_j 2 (p_i − p_j)(‖p_i − p_j‖² − d_ij²),

as a normalised velocity action v_i0 / max_joint_speed. If the largest entry exceeds 1 the whole
vector is scaled down (not clipped entry by entry), so the action stays a descent direction of V.
An arm whose observation says it has lost its first joint's actuator takes the law of its PAn−1
model in its actuated joints' entries (the lost joint's entry is 0, ignored). Such an arm, and a PAn−1
arm with a damped passive joint, subtract J̄⁺ of the drift their passive momentum gives the
end-effector (p₁ from the observed joint speeds, docs/MODEL.md §7). With a moving formation the arm adds
J̄⁺ of the feed-forward its observation carries (``formation_velocity``, docs/MODEL.md §8).
Behind :class:`pan1_env.wrappers.SafetyShield` this is the paper's full safe controller.
"""

from __future__ import annotations

import numpy as np

from pan1_env.cascade import end_effector_drift, passive_momentum, reduced_jacobian
from pan1_env.control import nominal_velocity, within_speed
from pan1_env.dynamics import faulted
from pan1_env.formation import edge_errors, formation_gradient
from pan1_env.observation import NEIGHBOUR_FEATURES, OBSTACLE_FEATURES, ObservationLayout

__all__ = ["ReferencePolicy", "decode_observation"]


def decode_observation(obs: np.ndarray, layout: ObservationLayout, n_links: int | None = None) -> dict[str, np.ndarray]:
    """Split one agent's observation by the env's public ``observation_layout``.

    Args:
        obs: the agent's observation vector.
        layout: ``env.observation_layout`` (works through wrappers).
        n_links: the agent's number of links (default: inferred from the observation's length).

    Returns ``q``, ``qd_scaled``, ``ee_rel_base``, the present neighbours' ``neighbour_delta``
    (p_j − p_i, ``(m, 2)``) and ``neighbour_error`` (``(m,)``), and every obstacle slot
    ``obstacles`` ``(K, 5)`` (``[present, dx, dy, r, h]``, absent slots zero), and where the layout
    observes faults ``actuator_lost`` (a bool), and where it observes a moving formation
    ``formation_velocity`` (ṗ_ff, ``(2,)`` m/s).
    """
    if not isinstance(layout, ObservationLayout):
        raise TypeError(f"decode_observation(obs, layout): layout is the env's observation_layout, got {layout!r}")
    obs = np.asarray(obs, dtype=float)
    n = layout.n_links(obs.shape[-1]) if n_links is None else int(n_links)
    if obs.shape != (layout.size(n),):
        raise ValueError(f"observation of shape {obs.shape}; the layout gives ({layout.size(n)},) for {n} links")
    seg = layout.segments(n)
    nb = obs[seg["neighbours"]].reshape(layout.slots, NEIGHBOUR_FEATURES)
    present = nb[:, 0] > 0.5
    out = {} if "actuator_lost" not in seg else {"actuator_lost": bool(obs[seg["actuator_lost"]][0] > 0.5)}
    if "formation_velocity" in seg:
        out["formation_velocity"] = obs[seg["formation_velocity"]]
    return out | {
        "q": np.arctan2(obs[seg["sin_q"]], obs[seg["cos_q"]]),
        "qd_scaled": obs[seg["qd_scaled"]],
        "ee_rel_base": obs[seg["ee_rel_base"]],
        "neighbour_delta": nb[present, 1:3],
        "neighbour_error": nb[present, 3],
        "obstacles": obs[seg["obstacles"]].reshape(layout.n_obstacle_obs, OBSTACLE_FEATURES),
    }


class ReferencePolicy:
    """The nominal law of every agent of a :class:`~pan1_env.environment.Pan1ParallelEnv` (velocity mode).

    Args:
        env: the parallel env, wrapped (e.g. in :class:`~pan1_env.wrappers.SafetyShield`) or not; only
            its public attributes are read: ``possible_agents``, ``scenario`` (each arm's parameters
            and K_P, re-read at every call, so random scenarios work), ``observation_layout`` and ``config``
            (its ``max_joint_speed`` and ``action_mode``).
        kp: overrides the scenario's K_P.
    """

    def __init__(self, env, kp: float | None = None) -> None:
        if env.config.action_mode != "velocity":
            raise ValueError("ReferencePolicy outputs velocities: use action_mode='velocity'")
        self.env = env
        self.kp = kp

    def act(self, agent: str, obs: np.ndarray, gain: np.ndarray | None = None) -> np.ndarray:
        """Agent ``agent``'s normalised velocity action; ``gain`` (one positive entry per actuated
        joint), if given, multiplies each joint's term before the scaling (``action_mode="gain"``)."""
        env = self.env
        i = env.possible_agents.index(agent)
        arm = env.scenario.arms[i]
        kp = env.scenario.kp if self.kp is None else self.kp
        d = decode_observation(obs, env.observation_layout, arm.n_links)
        z = -d["neighbour_delta"]  # p_i − p_j: the agent's edges, oriented away from it
        desired = np.linalg.norm(z, axis=-1) - d["neighbour_error"]
        e_hat = formation_gradient(np.ones((1, len(z))), z, edge_errors(z, desired))[0]
        lost, drift = d.get("actuator_lost", False), None
        arm = faulted(arm) if lost else arm
        if lost or (arm.passive_first_joint and arm.passive_damping > 0):  # p₁ ≠ 0 possible (else exactly 0)
            p1 = passive_momentum(arm, d["q"], d["qd_scaled"] * env.config.max_joint_speed)
            drift = end_effector_drift(arm, d["q"], p1)
        v0 = nominal_velocity(reduced_jacobian(arm, d["q"]), e_hat, kp, drift, d.get("formation_velocity"))
        if gain is not None:
            gain = np.asarray(gain, dtype=float)
            gain = gain[1:] if lost and gain.shape == (arm.n_links,) else gain  # one per action entry: drop the lost
            if gain.shape != v0.shape or not np.all(gain > 0):
                raise ValueError(f"gain for {agent} must be {v0.shape[0]} positive numbers, got {gain.tolist()}")
            v0 = v0 * gain
        a = within_speed(v0, env.config.max_joint_speed) / env.config.max_joint_speed
        if lost:  # the action keeps the full arm's shape; the lost joint's entry is ignored
            a = np.concatenate([[0.0], a])
        return a.astype(np.float32)

    def __call__(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {agent: self.act(agent, obs) for agent, obs in observations.items()}
