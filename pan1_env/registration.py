"""Gymnasium ids and the centralised single-agent view used by ``gymnasium.make``.

:class:`CentralizedEnv` wraps :class:`~pan1_env.environment.Pan1ParallelEnv`: its observation is the
concatenation of every agent's observation (agent order ``arm_0``, ``arm_1``, …), its action the
concatenation of every agent's action, its reward the mean of the agents' rewards, and
``info["cost"]`` the number of arms that entered an obstacle in the step (0.0 when none did);
``info["agents"]`` keeps the per-agent infos. :func:`register_envs` registers

* ``pan1_env/PaperPA3Square-v0`` (Section 5.1),
* ``pan1_env/PaperMixedPA-v0`` (Section 5.2),
* ``pan1_env/RandomFormation-v0`` (a new random team every reset),
* ``pan1_env/WholeArmStaticFormation-v0`` (the same task with whole-arm safety: every link a capsule
  of radius 0.03 m kept out of the obstacles and the other arms),
* ``pan1_env/WholeArmFormation-v0`` (the same with obstacles moving at 0.05–0.2 m/s),

each with ``max_episode_steps`` equal to the env's ``max_steps`` at default arguments, and the
one-arm task ``pan1_env/PAReach-v0`` (:class:`~pan1_env.reach.PAReachEnv`, 200 steps).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from .validation import float_array, forwards_keywords

__all__ = ["CentralizedEnv", "register_envs", "env_arguments", "ENV_IDS", "REACH_ENV_ID", "DEFAULT_REACH_STEPS"]

_WHOLE_ARM = {"bodies": "links", "link_radius": 0.03, "inter_arm": True}
ENV_IDS = {
    "pan1_env/PaperPA3Square-v0": {"scenario": "paper_pa3_square"},
    "pan1_env/PaperMixedPA-v0": {"scenario": "paper_pa_mixed_square"},
    "pan1_env/RandomFormation-v0": {"scenario": "random"},
    "pan1_env/WholeArmStaticFormation-v0": {"scenario": "random", "random_options": _WHOLE_ARM},
    "pan1_env/WholeArmFormation-v0": {"scenario": "random",
                                      "random_options": _WHOLE_ARM | {"obstacle_speed": (0.05, 0.2)}},
}
REACH_ENV_ID = "pan1_env/PAReach-v0"
DEFAULT_MAX_EPISODE_STEPS = 2000  # 100 s at the default control_dt of 0.05 s
DEFAULT_REACH_STEPS = 200  # PAReach-v0: 10 s at the default control_dt of 0.05 s
RENDER_MODES = ["human", "rgb_array"]
RENDER_FPS = 20


class CentralizedEnv(gymnasium.Env):
    """One agent controlling every arm of a :class:`~pan1_env.environment.Pan1ParallelEnv`.

    Takes the same arguments as the parallel env (its docstring's "Arguments" documents them, and
    ``inspect.signature``/``help()`` list them here). See the module docstring for the spaces, reward
    and cost; the parallel env's docstring documents everything else.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": RENDER_FPS}

    @forwards_keywords("pan1_env.environment:Pan1ParallelEnv")
    def __init__(self, scenario: Any = "paper_pa3_square", **kwargs: Any) -> None:
        from .environment import Pan1ParallelEnv

        self.parallel = Pan1ParallelEnv(scenario, **kwargs)
        self.render_mode = self.parallel.render_mode
        agents = self.parallel.possible_agents
        obs = [self.parallel.observation_space(a) for a in agents]
        act = [self.parallel.action_space(a) for a in agents]
        self.observation_space = gymnasium.spaces.Box(
            np.concatenate([s.low for s in obs]), np.concatenate([s.high for s in obs]), dtype=np.float32)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (sum(s.shape[0] for s in act),), np.float32)
        self._splits = np.cumsum([s.shape[0] for s in act])[:-1]

    def agent_actions(self, action: np.ndarray) -> dict[str, np.ndarray]:
        """The flat action split into the agents' actions (agent order)."""
        parts = np.split(np.asarray(action, dtype=float), self._splits)
        return dict(zip(self.parallel.possible_agents, parts, strict=True))

    def _flat_obs(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([obs[a] for a in self.parallel.possible_agents]).astype(np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        obs, infos = self.parallel.reset(seed=seed, options=options)
        return self._flat_obs(obs), {"cost": 0.0, "agents": infos}

    def step(self, action: np.ndarray):
        action = float_array("action", action, self.action_space.shape)
        agents = list(self.parallel.possible_agents)
        obs, rewards, terms, truncs, infos = self.parallel.step(self.agent_actions(action))
        reward = float(np.mean([rewards[a] for a in agents]))
        info = {
            "cost": float(sum(infos[a]["cost"] for a in agents)),
            "formation_error": infos[agents[0]]["formation_error"],
            "is_success": infos[agents[0]]["is_success"],
            "min_clearance": float(min(infos[a]["min_clearance"] for a in agents)),
            "agents": infos,
        }
        faults = [infos[a]["fault"] for a in agents if "fault" in infos[a]]
        if faults:
            info["fault"] = faults[0]
        return self._flat_obs(obs), reward, bool(terms[agents[0]]), bool(truncs[agents[0]]), info

    def render(self):
        return self.parallel.render()

    def close(self) -> None:
        self.parallel.close()


def env_arguments(name: str, overrides: dict[str, Any] | None = None) -> tuple[str, dict[str, Any]]:
    """A scenario (built-in name, ``.toml`` path or ``"random"``) or one of the team ids of
    :data:`ENV_IDS` (with or without the ``pan1_env:`` prefix), as the parallel env's ``scenario`` and
    its further arguments, ``overrides`` on top (``random_options`` merged key by key, so that one
    option changed keeps the id's others): ``"pan1_env/WholeArmFormation-v0"`` →
    ``("random", {"random_options": {"bodies": "links", …}})``, ``"random"`` → ``("random", {})``."""
    env_id = name.removeprefix("pan1_env:") if isinstance(name, str) else name
    kwargs: dict[str, Any] = {}
    if env_id in ENV_IDS:
        kwargs = {key: dict(value) if isinstance(value, dict) else value for key, value in ENV_IDS[env_id].items()}
        name = kwargs.pop("scenario")
    for key, value in (overrides or {}).items():
        if key == "random_options" and isinstance(value, dict) and isinstance(kwargs.get(key), dict):
            kwargs[key] = kwargs[key] | value
        else:
            kwargs[key] = value
    return name, kwargs


def register_envs() -> None:
    """Register the package's Gymnasium ids (idempotent)."""
    for env_id, kwargs in ENV_IDS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="pan1_env.registration:CentralizedEnv",
            kwargs=kwargs,
            max_episode_steps=DEFAULT_MAX_EPISODE_STEPS,
        )
    if REACH_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=REACH_ENV_ID, entry_point="pan1_env.reach:PAReachEnv",
                           max_episode_steps=DEFAULT_REACH_STEPS)
