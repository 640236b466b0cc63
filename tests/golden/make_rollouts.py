"""Record the golden rollouts that tests/test_golden.py replays.

Both paper scenarios under fixed, deterministic actions, in three set-ups: velocity mode shielded,
velocity mode unshielded and torque mode shielded. For each the file keeps, every ``EVERY`` steps,
the float64 joint angles and velocities of every arm and each step's reward and per-arm
smallest clearance. A change of the engine that keeps these within 1e-6 keeps the physics, the
filter and the reward as they were.

Regenerate (only when a behaviour change is intended, and say so in the commit):

    python tests/golden/make_rollouts.py
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

STEPS = 240
EVERY = 40
SCENARIOS = ("paper_pa3_square", "paper_pa_mixed_square")
SETUPS = {"velocity_shielded": ("velocity", True), "velocity_unshielded": ("velocity", False),
          "torque_shielded": ("torque", True)}
PATH = Path(__file__).with_name("rollouts.npz")


def actions(step: int, agent_index: int, k: int) -> np.ndarray:
    """A fixed action: slow sinusoids, different per agent and joint, reaching ±0.9."""
    j = np.arange(k)
    return 0.9 * np.sin(0.07 * step * (1 + 0.3 * j) + 1.3 * agent_index + 0.5 * j)


def make_env(scenario: str, mode: str, shielded: bool):
    from pan1_env import parallel_env
    from pan1_env.wrappers import SafetyShield

    env = parallel_env(scenario, action_mode=mode, max_steps=STEPS + 1)
    return SafetyShield(env) if shielded else env


def rollout(env, joint_state) -> dict[str, np.ndarray]:
    """Run the fixed actions; ``joint_state(env)`` gives padded float64 ``(q, q̇)`` arrays."""
    env.reset(seed=0)
    agents = list(env.possible_agents)
    qs, qds, rewards, clear = [], [], [], []
    for t in range(STEPS):
        act = {a: actions(t, i, env.action_space(a).shape[0]).astype(np.float32) for i, a in enumerate(agents)}
        _, rew, _, _, infos = env.step(act)
        rewards.append(rew[agents[0]])
        clear.append([infos[a]["min_clearance"] for a in agents])
        if (t + 1) % EVERY == 0:
            q, qd = joint_state(env)
            qs.append(q)
            qds.append(qd)
    return {"q": np.array(qs), "qd": np.array(qds), "reward": np.array(rewards), "min_clearance": np.array(clear)}


def main() -> None:
    def joint_state(env):
        return env.unwrapped.joint_state()

    out = {}
    for scenario in SCENARIOS:
        for name, (mode, shielded) in SETUPS.items():
            for key, value in rollout(make_env(scenario, mode, shielded), joint_state).items():
                out[f"{scenario}/{name}/{key}"] = value
    np.savez_compressed(PATH, **out)
    print(f"wrote {PATH} ({len(out)} arrays)")


if __name__ == "__main__":
    main()
