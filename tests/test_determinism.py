"""Bit-for-bit reproducibility across processes: a freshly compiled engine and the same engine loaded
from numba's disk cache give identical trajectories.

The first process compiles every kernel into an empty cache directory; the second loads them from it;
a third steps the serial cases with the generic kernel instead (``PAN1_ENV_KERNELS=generic``).
Each runs a seeded shielded episode of the parallel env and of the vector env (its serial and
multi-threaded kernels) and prints a digest of the states and observations. (With fused
multiply-adds left to LLVM, the two differed at rounding level: see ``_JIT`` in
``pan1_env/kernels/_numba_ext.py``.) The first process must also announce each arm kind it compiles
(:mod:`pan1_env.compile_notice`), and the second must say nothing of compiling.
"""

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.slow

_RUN = r"""
import hashlib
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.vector import Pan1VectorEnv
from pan1_env.wrappers import SafetyShield

digest = hashlib.sha256()
rng = np.random.default_rng(3)
# the paper's mixed team, then a 5-link PA arm (PA4) with a 2-link fully actuated one: longer chains of
# divisions, where a value-changing fast-math flag (arcp) once made the cached kernel differ from the fresh one
for seed, (scenario, options) in enumerate([("paper_pa_mixed_square", None),
                                            ("random", {"n_arms": 2, "links": (5, 2)})], start=3):
    env = SafetyShield(parallel_env(scenario, random_options=options, max_steps=60))
    obs, _ = env.reset(seed=seed)
    while env.agents:
        obs, *_ = env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})
        for a in sorted(obs):
            digest.update(obs[a].tobytes())
    q, v = env.unwrapped.joint_state()
    digest.update(q.tobytes() + v.tobytes())
for threads in (False, True):
    venv = Pan1VectorEnv("paper_pa3_square", 8, threads=threads, max_steps=40)
    obs, _ = venv.reset(seed=5)
    venv.action_space.seed(5)
    for _ in range(50):
        obs, reward, *_ = venv.step(venv.action_space.sample())
        kind = venv.engine.kinds[0]
        digest.update(obs.tobytes() + reward.tobytes() + kind.q.tobytes() + kind.v.tobytes())
print(digest.hexdigest())
# where each kernel came from: compiled here (misses) or loaded from the disk cache (hits)
from pan1_env import kernels
for f in (kernels.group_advance, kernels.group_advance_parallel, kernels.formation_observations,
          kernels.group_observations_parallel, kernels.scale_command):
    print(sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values()))
"""


def test_fresh_compile_and_cache_load_agree_bit_for_bit(tmp_path) -> None:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"), PAN1_ENV_KERNELS="specialised")
    runs = [subprocess.run([sys.executable, "-c", _RUN], env=env, capture_output=True, text=True, timeout=900)
            for _ in range(2)]
    # the generic kernel (which the engine uses while a kind's own kernel is not compiled) agrees too; it
    # compiles into the suite's own cache, where the other tests' generic runs find it
    runs.append(subprocess.run([sys.executable, "-c", _RUN], env=dict(os.environ, PAN1_ENV_KERNELS="generic"),
                               capture_output=True, text=True, timeout=900))
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    (fresh, *compiled), (cached, *loaded), (generic, *_) = (r.stdout.strip().split("\n") for r in runs)
    assert generic == fresh
    # every kernel was compiled in the first process and loaded from the cache in the second
    assert all(line.split()[0] == "0" and line.split()[1] != "0" for line in compiled), compiled
    assert all(line.split()[0] != "0" and line.split()[1] == "0" for line in loaded), loaded
    assert len(fresh) == 64 and fresh == cached
    # the first use of each arm kind is announced, with the cache's place; a cache load is silent
    cache = str(tmp_path / "numba-cache")
    for kind in ("2 links, fully actuated", "2 links, passive first joint (PA1)", "4 links, passive first joint (PA3)",
                 "4 links, passive first joint (PA3) (multi-threaded)", "5 links, passive first joint (PA4)"):
        notice = f"pan1_env: compiling the sub-step kernel for arms of {kind}: once per arm kind"
        assert notice in runs[0].stderr and cache in runs[0].stderr, runs[0].stderr[-2000:]
        assert f"pan1_env: compiled the sub-step kernel for arms of {kind} in " in runs[0].stderr
    assert "compil" not in runs[1].stderr, runs[1].stderr[-2000:]
