"""Teams of many arms: what a whole-arm step costs per arm as the team grows, what drawing a team costs, and
what the env holds in memory (``python benchmarks/bench.py --only sizes``).

Ring teams of `WholeArmStaticFormation-v1` (every link a capsule kept off the obstacles and the other arms, three
obstacles per four arms, arms redrawn alone) at 4, 16, 64 and 256 arms, on the serial kernels, each timed over
the same number of arm-steps (B = 8 copies, 2 at 256 arms). Each arm's filter and clearance visit the capsules
of the nearby arms first and stop where nothing farther can matter, so the work per arm should follow the
nearby arms, not N: the ratios to 4 arms say how far that holds. Beside them, the time to draw one team with
arms redrawn alone (``arm_redraws=20``, v2's options and the whole-arm ones) and the peak memory of building
and resetting the env, per arm and copy.
"""

from __future__ import annotations

import statistics
import time
import tracemalloc

SIZES = (4, 16, 64, 256)


def _options(n_arms: int) -> dict:
    return {"n_arms": n_arms, "n_obstacles": max(3, 3 * n_arms // 4), "shape": "ring", "arm_redraws": 20}


def _arm_step(n_arms: int, copies: int, repeats: int, arm_steps: int) -> tuple[float, float]:
    """(median seconds per arm-step, peak bytes per arm and copy of building and resetting the env) of a
    whole-arm ring team of ``n_arms`` arms, ``copies`` copies, gain mode."""
    import numpy as np

    from pan1_env.vector import Pan1VectorEnv

    tracemalloc.start()
    venv = Pan1VectorEnv("pan1_env/WholeArmStaticFormation-v1", copies, random_options=_options(n_arms),
                         safety_filter=True, action_mode="gain", threads=False)
    venv.reset(seed=0)
    memory = tracemalloc.get_traced_memory()[1] / (n_arms * copies)
    tracemalloc.stop()
    action = np.zeros(venv.action_space.shape, np.float32)
    for _ in range(3):  # the first steps compile what this size needs
        venv.step(action)
    steps = max(2, arm_steps // (copies * n_arms))
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(steps):
            venv.step(action)
        samples.append((time.perf_counter() - start) / (steps * copies * n_arms))
    venv.close()
    return statistics.median(samples), memory


def _draw_time(n_arms: int, whole_arm: bool, repeats: int) -> float:
    """Median seconds per team of the batched draw of ring teams of ``n_arms`` arms, arms redrawn alone (v2's
    options; with ``whole_arm`` WholeArmStaticFormation-v1's), after a first call that compiles."""
    import numpy as np

    from pan1_env.random_scenario import RandomScenarioOptions
    from pan1_env.registration import ENV_IDS
    from pan1_env.team_draw import draw_teams

    env_id = "pan1_env/WholeArmStaticFormation-v1" if whole_arm else "pan1_env/RandomFormation-v2"
    options = RandomScenarioOptions(**(ENV_IDS[env_id]["random_options"] | _options(n_arms)))
    teams = max(4, 256 // n_arms)
    draw_teams([np.random.default_rng(0)], options)
    samples = []
    for r in range(repeats):
        rngs = [np.random.default_rng([r, c]) for c in range(teams)]
        start = time.perf_counter()
        draw_teams(rngs, options)
        samples.append((time.perf_counter() - start) / teams)
    return statistics.median(samples)


def bench_sizes(repeats: int, arm_steps: int = 4096) -> list[tuple[str, float, str]]:
    """The rows: at each size the draw of one team (end-effector and whole-arm options), a whole-arm step per
    arm and its ratio to 4 arms, and the memory per arm and copy."""
    rows = [(f"draw of a {n}-arm ring team{' (whole-arm)' if whole else ''}", _draw_time(n, whole, repeats), "")
            for n in SIZES for whole in (False, True)]
    measured = {n: _arm_step(n, 2 if n > 64 else 8, repeats, arm_steps) for n in SIZES}
    rows += [(f"whole-arm ring team of {n} arms, per arm-step (B = {2 if n > 64 else 8})", t, "")
             for n, (t, _) in measured.items()]
    rows += [(f"ratio: per arm-step at {n} arms / at 4 arms (≈ 1 or less: work follows the nearby arms)",
              measured[n][0] / measured[4][0], "ratio") for n in SIZES[1:]]
    rows += [(f"memory of building and resetting a {n}-arm team, per arm and copy (MB)", m / 1e6, "mean")
             for n, (_, m) in measured.items()]
    return rows
