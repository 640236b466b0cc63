"""Random-team resets against steps (``python benchmarks/bench.py --only reset``).

A reset of all B copies of a random-team env draws B teams; under autoreset every episode's end draws one. The rows
give the reset of all B = 1024 copies (from the copies' own generators, no reseeding: what autoreset does) in steps
of the same batch, both timed in alternation in one process, for RandomFormation-v1 and WholeArmStaticFormation-v1,
and the per-copy reference path it replaced (``random_scenario``, then ``load_team`` into the engine and the task),
timed on 64 copies and scaled to B.
"""

from __future__ import annotations

import statistics
import sys
import time

RESET_IDS = ("pan1_env/RandomFormation-v1", "pan1_env/WholeArmStaticFormation-v1")


def _reference_reset(venv, copies: int) -> float:
    """Seconds per copy of the per-copy path: random_scenario from the copy's generator, then load_team."""
    from pan1_env.random_scenario import random_scenario

    core = venv.core
    start = time.perf_counter()
    for b in range(copies):
        team = random_scenario(core.rngs[b], core.config.random_options)
        core.engine.load_team(b, team)
        core.task.load_team(b, team)
    return (time.perf_counter() - start) / copies


def bench_reset(repeats: int, B: int = 1024, reference_copies: int = 64) -> list[tuple[str, float, str]]:
    """Per env id: the median reset of all B copies, the median step, their ratio (target ≤ 10 steps) and the
    reference path's cost in steps."""
    from pan1_env.vector import Pan1VectorEnv

    rows = []
    for env_id in RESET_IDS:
        print(f"bench: resets at B = {B}, {env_id} ...", file=sys.stderr, flush=True)
        venv = Pan1VectorEnv(env_id, B)
        venv.reset(seed=0)
        venv.action_space.seed(0)
        actions = venv.action_space.sample()
        venv.step(actions)
        resets, steps = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            venv.reset()
            resets.append(time.perf_counter() - start)
            start = time.perf_counter()
            for _ in range(5):
                venv.step(actions)
            steps.append((time.perf_counter() - start) / 5)
        reset, step = statistics.median(resets), statistics.median(steps)
        reference = _reference_reset(venv, reference_copies) * B
        name = env_id.removeprefix("pan1_env/")
        rows += [(f"{name}: reset of all B = {B} copies (new random teams)", reset, ""),
                 (f"  {name}: one step of the B = {B} copies", step, ""),
                 (f"  ratio: reset / step at B = {B} (target ≤ 10)", reset / step, "ratio"),
                 (f"  the per-copy reference draw and load, in steps ({reference_copies} copies timed, × {B})",
                  reference / step, "ratio")]
    return rows
