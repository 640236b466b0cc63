"""The vector env against its own kernel calls (``python benchmarks/bench.py --only bound``).

At B = 1024 a step of the shielded vector env should cost little more than the engine's step, which is the compiled
sub-step kernel's calls (one per arm kind) and a few array copies: everything else (the command's scaling, the
observation, the outcome, the infos, the autoreset) is the part the env adds. The rows give the engine's step alone
as a fraction of the env's step, both timed in alternation in one process on the same copies, for the paper's team
(one arm kind, in team order) and random teams (two kinds): the vector env's rate as a share of the kernel-bound
rate (target ≥ 80 %).
"""

from __future__ import annotations

import statistics
import time

BOUND_SCENARIOS = ("paper_pa3_square", "pan1_env/RandomFormation-v1")


def bench_kernel_bound(repeats: int, B: int = 1024) -> list[tuple[str, float, str]]:
    """Per scenario: the median engine step, the median env step (inner rounds of 4 steps each, alternating) and
    their ratio."""
    from pan1_env.vector import Pan1VectorEnv

    rows = []
    for scenario in BOUND_SCENARIOS:
        venv = Pan1VectorEnv(scenario, B)
        venv.reset(seed=0)
        venv.action_space.seed(0)
        actions = [venv.action_space.sample() for _ in range(4)]
        engine, core = venv.core.engine, venv.core
        commands = []  # the commands those actions give, padded as the engine takes them (the core's own scaling)
        for a in actions:
            commands.append(core.commands(core.padded_actions(a).copy())[0])
        substeps = core.config.substeps
        venv.step(actions[0])  # the first calls start numba's threads and load the kernels: not a step's cost
        engine.step(commands[0], substeps)
        env_times, engine_times = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            for a in actions:
                venv.step(a)
            env_times.append((time.perf_counter() - start) / 4)
            start = time.perf_counter()
            for c in commands:
                engine.step(c, substeps)
            engine_times.append((time.perf_counter() - start) / 4)
        t_env, t_engine = statistics.median(env_times), statistics.median(engine_times)
        name = scenario.removeprefix("pan1_env/")
        rows.append((f"{name}, B = {B}: engine step alone (its kernel calls)", t_engine, ""))
        rows.append((f"{name}, B = {B}: vector env step", t_env, ""))
        rows.append((f"ratio: {name}'s vector env rate / the kernel-bound rate (target ≥ 0.8)", t_engine / t_env,
                     "ratio"))
        venv.close()
    return rows


if __name__ == "__main__":  # a quick look: python benchmarks/kernel_bound.py
    for row in bench_kernel_bound(5):
        print(f"{row[0]}: {row[1]:.4g}")
