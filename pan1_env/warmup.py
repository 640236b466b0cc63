"""Compile the sub-step kernels ahead of time (``pan1-env warmup``), for CI, cluster images and notebooks.

The kernel is compiled once per arm kind (number of links; passive first joint or fully actuated) and
cached on disk by numba: :func:`warm_up` pays that cost up front by stepping the envs once on teams of
the kinds asked for, so that every later process starts in seconds. A kind is written ``LINKS`` followed
by ``p`` (passive first joint, a PAn−1 arm) or ``f`` (fully actuated): ``"4p"`` is the paper's PA3 arm.
"""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_SCENARIOS", "parse_kind", "warm_up"]

# the built-in scenarios and the random task's default team (3-link arms, half of them passive)
DEFAULT_SCENARIOS = ("paper_pa3_square", "paper_pa_mixed_square", "random")

_KIND = re.compile(r"(\d+)([pf])")


def parse_kind(text: str) -> tuple[int, bool]:
    """``"4p"`` → ``(4, True)`` (4 links, passive first joint); ``"2f"`` → ``(2, False)``."""
    match = _KIND.fullmatch(str(text).strip().lower())
    if match is None or int(match.group(1)) < 2:
        raise ValueError(f"arm kind {text!r}: expected LINKS (≥ 2) followed by 'p' (passive first joint) or "
                         f"'f' (fully actuated), e.g. '4p' or '2f'")
    return int(match.group(1)), match.group(2) == "p"


def _kinds_team(kinds: Sequence[tuple[int, bool]]) -> dict[str, Any]:
    """``random_options`` of one random team holding every kind (passive arms first, as the generator
    numbers them; a single kind gets two arms, the smallest team)."""
    unique = sorted(set(kinds), key=lambda kind: (not kind[1], kind[0]))
    if len(unique) == 1:
        unique = unique * 2
    passive = sum(p for _, p in unique)
    return {"n_arms": len(unique), "links": tuple(n for n, _ in unique), "passive_fraction": passive / len(unique)}


def warm_up(kinds: Iterable[str] | None = None, scenarios: Iterable[str | Path] | None = None, *,
            threaded: bool = True, say: Callable[[str], None] = print) -> float:
    """Compile (or load from numba's cache) every kernel the envs use for the given arm kinds and
    scenarios; with neither, for :data:`DEFAULT_SCENARIOS`: each kind's own serial kernel and, unless
    ``threaded=False``, the multi-threaded kernels a vector or TorchRL env runs from
    :data:`~pan1_env.engine.PARALLEL_THRESHOLD` arms of a kind (the sub-step, geometry and observation
    kernels' ``_parallel`` twins). Returns the seconds it took."""
    kinds = [parse_kind(k) for k in (kinds or ())]
    teams: list[tuple[str, str, dict[str, Any]]] = [(str(s), str(s), {}) for s in (scenarios or ())]
    if kinds:
        names = " ".join(f"{n}{'p' if passive else 'f'}" for n, passive in sorted(set(kinds)))
        teams.insert(0, (f"the arm kinds {names}", "random", {"random_options": _kinds_team(kinds)}))
    if not teams:
        teams = [(s, s, {}) for s in DEFAULT_SCENARIOS]
    start = time.perf_counter()
    saved = os.environ.get("PAN1_ENV_KERNELS")
    os.environ["PAN1_ENV_KERNELS"] = "specialised"  # each kind's own kernel, not the generic stand-in
    try:
        _step_teams(teams, threaded, say)
    finally:
        if saved is None:
            del os.environ["PAN1_ENV_KERNELS"]
        else:
            os.environ["PAN1_ENV_KERNELS"] = saved
    took = time.perf_counter() - start
    say(f"kernels ready in {took:.0f} s (cached on disk: later processes load them in about a second)")
    return took


def _step_teams(teams: list[tuple[str, str, dict[str, Any]]], threaded: bool, say: Callable[[str], None]) -> None:
    import numpy as np

    from .environment import parallel_env
    from .vector import Pan1VectorEnv

    for label, scenario, kwargs in teams:
        say(f"warming up {label} ...")
        env = parallel_env(scenario, **kwargs)
        env.reset(seed=0)
        env.step({agent: np.zeros(env.action_space(agent).shape, np.float32) for agent in env.agents})
        env.state()  # the centralised critics' state (TorchRL, MAPPO): its own two small kernels
        env.close()
        for threads in (False, True) if threaded else (False,):
            venv = Pan1VectorEnv(scenario, num_envs=1, threads=threads, **kwargs)
            venv.reset(seed=0)
            venv.step(np.zeros(venv.action_space.shape, np.float32))
            venv.close()
