"""Registers the package's ids (:data:`pan1_env.env_ids.ENV_IDS`, listed and explained there) with Gymnasium, as
:class:`~pan1_env.centralized.CentralizedEnv` (one agent controlling every arm), and the one-arm task
``pan1_env/PAReach-v0`` (:class:`~pan1_env.reach.PAReachEnv`). The envs truncate their episodes themselves, after
``max_steps`` steps (an argument: the default is the scenario's horizon / ``control_dt``), so no ``TimeLimit`` is
added; ``gymnasium.make(id, max_episode_steps=…)`` still adds one.

The table and :func:`~pan1_env.env_ids.env_arguments` are importable from here too.
"""

from __future__ import annotations

import gymnasium

from .env_ids import DEFAULT_REACH_STEPS, ENV_IDS, REACH_ENV_ID, env_arguments

__all__ = ["register_envs", "env_arguments", "ENV_IDS", "REACH_ENV_ID", "DEFAULT_REACH_STEPS", "RENDER_MODES",
           "RENDER_FPS"]

RENDER_MODES = ["human", "rgb_array"]
RENDER_FPS = 20


def register_envs() -> None:
    """Register the package's Gymnasium ids (idempotent)."""
    for env_id in ENV_IDS:
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point="pan1_env.centralized:CentralizedEnv",
            # the id itself: the env's config resolves it, merging random_options given to make() key by key
            kwargs={"scenario": env_id},
        )
    if REACH_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=REACH_ENV_ID, entry_point="pan1_env.reach:PAReachEnv")
