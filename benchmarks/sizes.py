"""Teams of many arms: what a whole-arm step costs per arm as the team grows (``python benchmarks/bench.py
--only sizes``).

Ring teams of `WholeArmStaticFormation-v1` (every link a capsule kept off the obstacles and the other arms, three
obstacles per four arms, arms redrawn alone) at 4, 16, 32 and 64 arms, B = 8 copies on the serial kernels, each
timed over the same number of arm-steps. The filter's rows are for the capsules within sensing range, so its work
per arm should follow the nearby arms, not N: the ratios to 16 arms say how far that holds. Before them, the time
to draw one team of 32 and of 64 arms with arms redrawn alone (``arm_redraws=20``).
"""

from __future__ import annotations

import statistics
import time

SIZES = (4, 16, 32, 64)


def _arm_step_time(n_arms: int, copies: int, repeats: int, arm_steps: int) -> float:
    """Median seconds per arm-step of a whole-arm ring team of ``n_arms`` arms, ``copies`` copies, gain mode."""
    import numpy as np

    from pan1_env.vector import Pan1VectorEnv

    options = {"n_arms": n_arms, "n_obstacles": max(3, 3 * n_arms // 4), "shape": "ring", "arm_redraws": 20}
    venv = Pan1VectorEnv("pan1_env/WholeArmStaticFormation-v1", copies, random_options=options, safety_filter=True,
                         action_mode="gain", threads=False)
    venv.reset(seed=0)
    action = np.zeros(venv.action_space.shape, np.float32)
    for _ in range(3):  # the first steps compile what this size needs
        venv.step(action)
    steps = max(1, arm_steps // (copies * n_arms))
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            venv.step(action)
        samples.append((time.perf_counter() - start) / (steps * copies * n_arms))
    venv.close()
    return statistics.median(samples)


def _draw_time(n_arms: int, whole_arm: bool, repeats: int, teams: int = 64) -> float:
    """Median seconds per team of the batched draw of ``teams`` ring teams of ``n_arms`` arms, arms redrawn alone
    (v2's options; with ``whole_arm`` WholeArmStaticFormation-v1's), after a first call that compiles."""
    import numpy as np

    from pan1_env.random_scenario import RandomScenarioOptions
    from pan1_env.registration import ENV_IDS
    from pan1_env.team_draw import draw_teams

    env_id = "pan1_env/WholeArmStaticFormation-v1" if whole_arm else "pan1_env/RandomFormation-v2"
    options = RandomScenarioOptions(**(ENV_IDS[env_id]["random_options"] | {
        "n_arms": n_arms, "n_obstacles": max(3, 3 * n_arms // 4), "shape": "ring", "arm_redraws": 20}))
    draw_teams([np.random.default_rng(0)], options)
    samples = []
    for r in range(repeats):
        rngs = [np.random.default_rng([r, c]) for c in range(teams)]
        start = time.perf_counter()
        draw_teams(rngs, options)
        samples.append((time.perf_counter() - start) / teams)
    return statistics.median(samples)


def bench_sizes(repeats: int, copies: int = 8, arm_steps: int = 4096) -> list[tuple[str, float, str]]:
    """The rows: a whole-arm step per arm at each size and its ratio to 16 arms, and the draw of one team of 32
    and of 64 arms (end-effector and whole-arm options)."""
    rows = [(f"draw of a {n}-arm ring team{' (whole-arm)' if whole else ''}", _draw_time(n, whole, repeats), "")
            for n in (32, 64) for whole in (False, True)]
    times = {n: _arm_step_time(n, copies, repeats, arm_steps) for n in SIZES}
    rows += [(f"whole-arm ring team of {n} arms, per arm-step (B = {copies})", t, "") for n, t in times.items()]
    rows += [(f"ratio: per arm-step at {n} arms / at 16 arms (≈ 1: work follows the nearby arms)",
              times[n] / times[16], "ratio") for n in (32, 64)]
    return rows
