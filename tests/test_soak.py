"""Soak test: 10⁶ shielded arm-steps of random and adversarial policies across random scenarios.

Zero cost, no non-finite value, bounded memory. Prints its figures (``-s`` shows them; CI logs them
through the ``-ra`` summary's captured output on failure, and the README quotes a run).
"""

import json
import resource

import numpy as np
import pytest

from pan1_env.baselines import AdversarialPolicy
from pan1_env.environment import parallel_env
from pan1_env.wrappers import SafetyShield

pytestmark = pytest.mark.slow

ARM_STEPS = 1_000_000
TEAM = {"n_arms": 4, "links": (2, 3, 4, 3), "passive_fraction": 0.5}


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def test_soak_one_million_shielded_arm_steps(capsys) -> None:
    envs = {mode: parallel_env("random", random_options=TEAM, action_mode=mode, control_dt=0.01, max_steps=200)
            for mode in ("velocity", "torque")}
    shielded = {mode: SafetyShield(env) for mode, env in envs.items()}
    adversaries = {mode: AdversarialPolicy(env) for mode, env in envs.items()}
    rng = np.random.default_rng(0)
    stats = {"arm_steps": 0, "episodes": 0, "cost": 0.0, "fallback_steps": 0, "interventions": 0,
             "min_clearance_m": np.inf}
    rss_after_warmup = None
    seed = 0
    while stats["arm_steps"] < ARM_STEPS:
        mode = ("velocity", "torque")[seed % 2]
        env = shielded[mode]
        adversarial = (seed // 2) % 2 == 1
        obs, _ = env.reset(seed=seed)
        while env.agents:
            if adversarial:
                actions = adversaries[mode](obs)
            else:
                actions = {a: rng.uniform(-1, 1, env.action_space(a).shape).astype(np.float32) for a in env.agents}
            obs, rewards, _, truncs, infos = env.step(actions)
            for agent, info in infos.items():
                assert np.all(np.isfinite(obs[agent])) and np.isfinite(rewards[agent])
                assert "fault" not in info, info["fault"]
                stats["cost"] += info["cost"]
                stats["min_clearance_m"] = min(stats["min_clearance_m"], info["min_clearance"])
                stats["fallback_steps"] += int(info["shield"]["fallback"])
                stats["interventions"] += int(info["shield"]["intervened"])
                stats["arm_steps"] += 1
        stats["episodes"] += 1
        seed += 1
        if rss_after_warmup is None and stats["arm_steps"] >= ARM_STEPS // 10:
            rss_after_warmup = _peak_rss_mb()
    stats["peak_rss_mb"] = _peak_rss_mb()
    stats["rss_growth_after_warmup_mb"] = stats["peak_rss_mb"] - rss_after_warmup
    with capsys.disabled():
        print("\nsoak:", json.dumps(stats))
    assert stats["cost"] == 0.0
    assert stats["min_clearance_m"] >= 0.0
    assert stats["rss_growth_after_warmup_mb"] < 100.0
