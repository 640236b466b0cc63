"""Which serial kernel an arm kind steps with (pan1_env.kernels.specialise): its own once it is compiled
or in the disk cache, else the generic kernel (same results bit for bit) while a background process
compiles its own; and that background process itself."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from pan1_env import kernels
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise

TEAM = {"n_arms": 2, "links": (3, 2)}  # a PA2 arm and a fully actuated 2-link arm


def _args(n: int, passive: bool, A: int = 2) -> tuple:
    """group_advance's arguments for A resting arms of one kind (no obstacles)."""
    k = n - 1 if passive else n
    z = lambda *shape: np.zeros(shape)  # noqa: E731
    lam = np.broadcast_to(np.eye(n), (A, n, n)).copy()
    return (*kernels.kernel_sizes(n, k), lam, np.full((A, n), 0.3), z(A, 2), z(A), passive, z(A, n), z(A, k), z(A, k),
            np.zeros(A, bool), z(A, k), False, True, z(A, 0, 2), z(A, 0), np.zeros((A, 0), bool), 1.0, 1.0, 0.0, 100.0,
            0.01, 1, np.inf, z(A, k), z(A, k), z(A, n), z(A, 2), np.full(A, np.inf), np.full(A, np.inf),
            np.zeros((A, 3), np.int64), z(A), np.ones(A, bool), None)


def test_policy_reads_the_environment(monkeypatch) -> None:
    monkeypatch.delenv("PAN1_ENV_KERNELS", raising=False)
    assert specialise.policy() == "auto"
    monkeypatch.setenv("PAN1_ENV_KERNELS", "Generic")
    assert specialise.policy() == "generic"
    monkeypatch.setenv("PAN1_ENV_KERNELS", "fast")
    with pytest.raises(ValueError, match="PAN1_ENV_KERNELS"):
        specialise.policy()


def test_the_switch_rule(monkeypatch) -> None:
    """Own kernel when compiled here or in the disk cache (or asked for, or beyond the generic kernel's
    sizes); else the generic kernel, and one background compilation is asked for."""
    started = []
    monkeypatch.setattr(specialise, "_start_next", lambda: started.append(list(specialise._pending)))
    asked = lambda: specialise._pending  # noqa: E731
    monkeypatch.setattr(specialise, "_requested", set())
    monkeypatch.setattr(specialise, "_pending", [])
    monkeypatch.delenv("PAN1_ENV_KERNELS", raising=False)
    compiled = _args(2, True)
    kernels.group_advance(*compiled)  # compiled in this process (or loaded from the cache)
    assert specialise.specialised_ready(compiled)
    sig = specialise._signature(compiled)
    assert specialise._in_disk_cache(kernels.group_advance, sig), "cache=True: numba saved it"
    assert specialise.specialised_ready(_args(9, False)), "beyond GENERIC_MAX_LINKS: always the kind's own"
    # a kind neither compiled nor cached (as numba's cache index would say)
    monkeypatch.setattr(specialise, "_in_disk_cache", lambda dispatcher, sig: False)
    fresh = _args(7, True)
    assert sig not in [specialise._signature(fresh)]
    assert not specialise.specialised_ready(fresh)
    assert not specialise.specialised_ready(fresh)
    assert asked() == [specialise._signature(fresh)] and not started, "asked for once, started by the engine"
    specialise.start_background()
    assert started == [[specialise._signature(fresh)]]
    monkeypatch.setenv("PAN1_ENV_KERNELS", "specialised")
    assert specialise.specialised_ready(fresh)
    monkeypatch.setenv("PAN1_ENV_KERNELS", "generic")
    assert not specialise.specialised_ready(compiled)


def _rollout(steps: int = 40) -> tuple[list[np.ndarray], list[bool | None]]:
    env = parallel_env("random", random_options=TEAM, safety_filter=True)
    env.reset(seed=2)
    rng = np.random.default_rng(2)
    out = []
    for _ in range(steps):
        obs, *_ = env.step({a: rng.uniform(-1, 1, env.action_space(a).shape) for a in env.agents})
        q, qd = env.unwrapped.joint_state()
        out += [q.copy(), qd.copy(), *(obs[a] for a in sorted(obs))]
    return out, [kind.specialised for kind in env.unwrapped.engine.kinds]


def test_the_engine_steps_the_same_with_either_kernel(monkeypatch) -> None:
    monkeypatch.setenv("PAN1_ENV_KERNELS", "generic")
    generic, used = _rollout()
    assert used == [False, False]
    monkeypatch.setenv("PAN1_ENV_KERNELS", "specialised")
    own, used = _rollout()
    assert used == [True, True]
    for a, b in zip(generic, own, strict=True):
        np.testing.assert_array_equal(a, b)


_SWITCH = r"""
import os, time
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise
env = parallel_env("random", random_options={"n_arms": 2, "links": (3, 2)}, safety_filter=True)
env.reset(seed=0)
kinds = env.unwrapped.engine.kinds
steps, start = 0, time.perf_counter()
while not all(kind.specialised for kind in kinds) and time.perf_counter() - start < 600:
    env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    if steps == 0:
        print("first", [kind.specialised for kind in kinds], getattr(specialise._child, "pid", None), flush=True)
    steps += 1
    if not env.agents:
        env.reset(seed=steps)
    time.sleep(0.01)
print("switched", [kind.specialised for kind in kinds])
print("child", specialise._child)
"""

_EARLY = r"""
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise
env = parallel_env("random", random_options={"n_arms": 2, "links": (3, 2)})
env.reset(seed=0)
for _ in range(2):  # the background compilation starts at the second step
    env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
print(specialise._child.pid)
"""


def _gone(pid: int, wait: float = 10.0) -> bool:
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        if not os.path.exists(f"/proc/{pid}"):
            return True
        time.sleep(0.1)
    return False


@pytest.mark.slow
def test_a_new_kind_steps_at_once_and_switches_when_its_kernel_is_compiled(tmp_path) -> None:
    """In an empty cache: the first step uses the generic kernel, and from the second a background
    compilation runs per kind; the engine switches to each kind's own kernel once it is in the cache;
    the next process loads them and starts no child."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("PAN1_ENV_KERNELS", None)
    first = subprocess.run([sys.executable, "-c", _SWITCH], env=env, capture_output=True, text=True, timeout=900)
    assert first.returncode == 0, first.stderr[-2000:]
    lines = first.stdout.split("\n")
    assert lines[0].startswith("first [False, False] ") and lines[1] == "switched [True, True]", first.stdout
    assert "compiling the generic sub-step kernel" in first.stderr
    assert "while their own kernel compiles in a background process" in first.stderr
    again = subprocess.run([sys.executable, "-c", _SWITCH], env=env, capture_output=True, text=True, timeout=900)
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout.split("\n")[:3] == ["first [True, True] None", "switched [True, True]", "child None"]
    assert "compil" not in again.stderr, again.stderr[-2000:]


@pytest.mark.slow
def test_the_background_compilation_ends_with_its_process(tmp_path) -> None:
    """A process that ends while its background compilation runs ends that too (no orphan, no zombie)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("PAN1_ENV_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", _EARLY], env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    assert _gone(int(run.stdout.split()[-1]))
    # killed outright (no atexit): the child gets SIGTERM from the kernel (PR_SET_PDEATHSIG)
    script = _EARLY.replace("print(specialise._child.pid)", "print(specialise._child.pid, flush=True)\n"
                            "import os, signal; os.kill(os.getpid(), signal.SIGKILL)")
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == -9, run.stderr[-2000:]
    if sys.platform.startswith("linux"):
        assert _gone(int(run.stdout.split()[-1]))
