"""pan1-env: multi-arm PAn−1 formation control with robust-CBF safety.

Importing the package registers its Gymnasium ids (:data:`ENV_IDS`, listed in :mod:`pan1_env.env_ids`) and the
one-arm ``pan1_env/PAReach-v0`` (:mod:`pan1_env.registration`). The PettingZoo constructors
:func:`parallel_env`, :func:`env` and :data:`raw_env` are imported on first use, so
``import pan1_env`` stays fast.
"""

from __future__ import annotations

import importlib
from typing import Any

from .registration import ENV_IDS, register_envs

__version__ = "0.1.0"
__all__ = ["parallel_env", "env", "raw_env", "Pan1ParallelEnv", "ENV_IDS", "__version__"]

register_envs()


def __getattr__(name: str) -> Any:
    if name in ("parallel_env", "env", "raw_env", "Pan1ParallelEnv"):
        return getattr(importlib.import_module("pan1_env.environment"), name)
    raise AttributeError(f"module 'pan1_env' has no attribute {name!r}")
