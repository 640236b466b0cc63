"""What compiling costs a user, each measured in fresh interpreters with an empty numba cache (part of
``benchmarks/bench.py``: ``--only cold_start,warmup``).

* the cold start: the first step of a team of new arm kinds (the generic sub-step kernel and the
  observation kernels compiled) and that process's peak memory;
* ``pan1-env warmup`` of the built-in scenarios' kinds, serial and multi-threaded kernels (what it does
  with no option), and the same command again once they are cached.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time

_COLD_START = r"""
import resource, sys, time
t = time.perf_counter()
import pan1_env
team = TEAM
env = pan1_env.parallel_env("random", random_options=team)
env.reset(seed=0)
env.step({a: env.action_space(a).sample() for a in env.agents})
print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
pan1_env.kernels.specialise.stop_background()  # no compilation left to run on under the next rows
"""


def _cold_team(kinds: tuple[str, ...]) -> dict:
    """``random_options`` of a team with one arm of each kind (two of a single kind), PA arms first."""
    kinds = tuple(sorted(kinds, key=lambda kind: kind[-1] != "p")) * (2 if len(kinds) == 1 else 1)
    passive = sum(kind[-1] == "p" for kind in kinds)
    return {"n_arms": len(kinds), "links": tuple(int(kind[:-1]) for kind in kinds),
            "passive_fraction": passive / len(kinds)}


def bench_cold_start(kinds: tuple[str, ...] = ("2f", "4p", "5p"),
                     teams: tuple[tuple[str, ...], ...] = (("5p", "2f"),)) -> list[tuple[str, float, str]]:
    """The first step of a two-arm team of one arm kind (and of each team of ``teams``) in a fresh
    interpreter with an empty numba cache: everything compiled (the generic sub-step kernel, which
    stands in for the kinds' own while a background process compiles them, and the observation
    kernels), and the process's peak memory (targets: ≤ 10 s and ≤ 400 MB). The process then
    forgets its background compilation (it has started none yet: that starts at the next step or at
    the exit), so none runs on under the next rows."""

    rows = []
    for team in [(kind,) for kind in kinds] + [tuple(t) for t in teams]:
        code = _COLD_START.replace("TEAM", repr(_cold_team(team)))
        env = {key: value for key, value in os.environ.items() if key != "PAN1_ENV_KERNELS"}  # the default
        with tempfile.TemporaryDirectory() as cache:
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                 env=dict(env, NUMBA_CACHE_DIR=cache)).stdout.split()
        what = f"arm kind {team[0]}" if len(team) == 1 else "team " + " + ".join(team)
        rows.append((f"cold start, {what}: first step with an empty numba cache", float(out[0]), ""))
        rows.append(("  peak memory of that process [MB] (target ≤ 400)", float(out[1]), "count"))
    return rows


def _children_cpu() -> float:
    """Core seconds (user + system) of this process's ended children so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def bench_warmup() -> list[tuple[str, float, str]]:
    """``pan1-env warmup`` (the built-in scenarios' kinds, serial and multi-threaded) in a fresh interpreter
    with an empty numba cache, wall time and core time (user + system: less sensitive to other jobs on the
    machine than the wall time); then the same command again, which loads everything from the cache. The
    default kernel policy, as a user runs it."""
    env = {key: value for key, value in os.environ.items() if key != "PAN1_ENV_KERNELS"}
    command = [sys.executable, "-m", "pan1_env", "warmup"]
    took = []
    with tempfile.TemporaryDirectory() as cache:
        for _ in range(2):
            start, cpu = time.perf_counter(), _children_cpu()
            subprocess.run(command, capture_output=True, text=True, check=True, env=dict(env, NUMBA_CACHE_DIR=cache))
            took.append((time.perf_counter() - start, _children_cpu() - cpu))
    return [("pan1-env warmup, built-in kinds (serial + multi-threaded), empty numba cache", took[0][0], ""),
            ("  its core time (user + system)", took[0][1], ""),
            ("  the same again, everything cached", took[1][0], ""),
            ("  its core time", took[1][1], "")]
