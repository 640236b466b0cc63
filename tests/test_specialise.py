"""Which serial kernel an arm kind steps with (pan1_env.kernels.specialise): its own once it is compiled
or in the disk cache, else the generic kernel (same results bit for bit) while a background process
compiles its own; and that background process itself: detached (it outlives a short script), bounded,
reaped, one per kind across processes, and not losing another's cache entry."""

from __future__ import annotations

import errno
import os
import pickle
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from kernel_args import kernel_groups

from pan1_env import kernels
from pan1_env.compiled import kernel_filter, kernel_sizes
from pan1_env.dynamics import ArmBatch
from pan1_env.environment import parallel_env
from pan1_env.kernel_groups import plain
from pan1_env.kernels import specialise, substep
from pan1_env.safety import FilterParams

TEAM = {"n_arms": 2, "links": (3, 2)}  # a PA2 arm and a fully actuated 2-link arm


def _args(n: int, passive: bool, A: int = 2) -> tuple:
    """group_advance's arguments for A resting arms of one kind (no obstacles)."""
    k = n - 1 if passive else n
    z = lambda *shape: np.zeros(shape)  # noqa: E731
    arms = ArmBatch(lam=np.broadcast_to(np.eye(n), (A, n, n)).copy(), lengths=np.full((A, n), 0.3), base=z(A, 2),
                    phi=z(A), passive_first_joint=passive)
    outputs = (z(A, k), z(A, k), z(A, n), z(A, 2), np.full(A, np.inf), np.full(A, np.inf), np.zeros((A, 3), np.int64),
               z(A), np.ones(A, bool))
    groups = kernel_groups(arms, z(A), passive, z(A, n), z(A, k), z(A), z(A, k), np.zeros(A, bool), np.arange(A),
                           np.tile(np.array([0, 1]), (A, 1)), z(A, k), False, True, z(A, 0, 2), z(A, 0),
                           np.zeros((A, 0), bool), plain(kernel_filter(FilterParams(1.0, 1.0))), 100.0, 0.01, 1,
                           np.inf, outputs)
    return (*kernel_sizes(n, k), *groups, None)


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

_ONE_KIND = {"n_arms": 2, "links": 2, "passive_fraction": 0.0}  # two fully actuated 2-link arms: one kind

# steps a new kind once, as the quickstart does, and exits at once: its background compilation starts at
# the exit (a second step would have started it)
_EARLY = r"""
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise
env = parallel_env("random", random_options=KIND)
env.reset(seed=0)
env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
print([kind.specialised for kind in env.unwrapped.engine.kinds], specialise._child, flush=True)
""".replace("KIND", repr(_ONE_KIND))

# a next process: one step, then whether its kind steps with its own kernel and how many children it started
_NEXT = r"""
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise
env = parallel_env("random", random_options=KIND)
env.reset(seed=0)
env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
print([kind.specialised for kind in env.unwrapped.engine.kinds], specialise._started)
""".replace("KIND", repr(_ONE_KIND))

# steps a new kind until it switches to its own kernel (at most 10 minutes); says how many children it started
_UNTIL = r"""
import time
import numpy as np
from pan1_env.environment import parallel_env
from pan1_env.kernels import specialise
env = parallel_env("random", random_options=KIND)
env.reset(seed=0)
kinds, start = env.unwrapped.engine.kinds, time.monotonic()
while not all(kind.specialised for kind in kinds) and time.monotonic() - start < 600:
    env.step({a: np.zeros(env.action_space(a).shape) for a in env.agents})
    if not env.agents:
        env.reset(seed=0)
    time.sleep(0.05)
print([kind.specialised for kind in kinds], specialise._started, flush=True)
""".replace("KIND", repr(_ONE_KIND))


def _cache_env(tmp_path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"), PAN1_ENV_KERNELS="auto")
    return env


def _background_compilations(cache: str) -> list[int]:
    """The pids of the background compilations (:func:`pan1_env.kernels.specialise._main`) that compile
    into ``cache`` (their NUMBA_CACHE_DIR), found in /proc: detached, they are no test's children."""
    found = []
    for entry in os.listdir("/proc"):
        try:
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                command = f.read()
            with open(f"/proc/{entry}/environ", "rb") as f:
                environ = f.read().split(b"\0")
        except (OSError, ValueError):  # not a process, gone, or not ours to read
            continue
        if b"specialise import _main" in command and f"NUMBA_CACHE_DIR={cache}".encode() in environ:
            found.append(int(entry))
    return found


def _alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie does not count)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _wait_for(condition, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.2)
    return condition()


linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; detaches with fcntl")


@linux_only
@pytest.mark.slow
def test_a_short_script_leaves_the_kernel_cached(tmp_path) -> None:
    """A script that steps a new kind once (the quickstart) and exits at once starts its background
    compilation at its exit and neither waits for it nor ends it; that finishes on its own, and the
    next process steps the kind with its own kernel from the cache, starting no compilation and printing
    no notice."""
    env = _cache_env(tmp_path)
    run = subprocess.run([sys.executable, "-c", _EARLY], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split("\n")[0] == "[False] None", "generic kernel, no child before the exit: " + run.stdout
    assert "cached for later runs even if this process ends first" in run.stderr
    children = _background_compilations(env["NUMBA_CACHE_DIR"])
    assert len(children) == 1, f"one child started at the exit, found {children}"
    assert _wait_for(lambda: not _alive(children[0]), specialise.LIMIT + 60), "the child outlived its bound"
    again = subprocess.run([sys.executable, "-c", _NEXT], env=env, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-2000:]
    assert again.stdout.split("\n")[0] == "[True] 0", again.stdout + again.stderr[-2000:]
    assert "pan1_env:" not in again.stderr, "a notice after a finished compilation: " + again.stderr[-2000:]


def test_kinds_still_waiting_start_at_the_exit(monkeypatch, tmp_path) -> None:
    """The kinds asked for but not started when the process ends (a script that stepped once, or a
    second kind queued behind a running child) get one child at the exit, registered with atexit, which
    compiles them one after another; a kind another process's child holds the claim of is left to it."""
    if specialise.fcntl is None:
        pytest.skip("no detached children, hence nothing started at the exit, without fcntl")
    monkeypatch.setattr(specialise, "_index_file", lambda dispatcher: str(tmp_path / "group_advance-1.py3.nbi"))
    monkeypatch.setattr(specialise, "_in_disk_cache", lambda dispatcher, sig: False)
    spawned = []
    monkeypatch.setattr(specialise, "_spawn", lambda sigs, claim, limit=0: spawned.append(sigs) or object())
    running = object()
    for name, value in (("_pending", []), ("_requested", set()), ("_watching", {}), ("_child", running)):
        monkeypatch.setattr(specialise, name, value)
    waiting = [specialise._signature(_args(n, True)) for n in (5, 6, 7)]
    specialise._pending.extend(waiting)
    held = specialise._take_claim(specialise._claim_file(waiting[2]))  # another process's child compiles 7 links
    try:
        specialise._start_at_exit()
    finally:
        os.close(held)
    assert spawned == [[waiting[0], waiting[1]]] and specialise._pending == []


# a process that exits with a kind waiting for its background compilation (the spawn only reported)
_EXIT_WAITING = r"""
from pan1_env.kernels import specialise
specialise._spawn = lambda sigs, claims, limit=0: print("spawned", len(sigs), len(claims), limit, flush=True)
specialise._in_disk_cache = lambda dispatcher, sig: False
specialise._pending.extend(["a kind", "another kind"])
specialise._claim_file = lambda sig: None  # no claim: the cache of this test is not touched
"""


@linux_only
def test_the_exit_starts_the_kinds_left_waiting() -> None:
    run = subprocess.run([sys.executable, "-c", _EXIT_WAITING], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    # one child compiles both, one after the other, with a bound for each
    assert run.stdout == f"spawned 2 0 {2 * specialise.LIMIT}\n"


@linux_only
def test_the_child_is_detached_bounded_and_reaped(tmp_path, monkeypatch) -> None:
    """A background process runs in its own session, ends itself when its bound runs out, and is reaped
    by its parent at once (no zombie)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))  # nothing cached: it would compile
    # a bound long enough that the child is still there when its session is read, even on a busy machine
    # (it imports numba and then compiles for longer than that)
    child = specialise._spawn([specialise._signature(_args(5, True))], limit=10)
    try:
        assert os.getsid(child.pid) == child.pid
        assert _wait_for(lambda: child.returncode is not None, 120), "not reaped (a zombie, or still running)"
        assert child.returncode == -signal.SIGALRM
        assert not os.path.exists(f"/proc/{child.pid}")
    finally:
        if child.returncode is None:
            child.kill()


def test_a_kind_claimed_elsewhere_starts_no_child(monkeypatch, tmp_path) -> None:
    """While another process holds a kind's claim, asking for that kind starts no child but watches the
    claim; when it comes free the engine is told to look again, and the kind is queued here if the
    other compilation left nothing in the cache."""
    if specialise.fcntl is None:
        pytest.skip("no claims without fcntl")
    # the claims beside a stand-in index in tmp_path, not in the package's own cache
    monkeypatch.setattr(specialise, "_index_file", lambda dispatcher: str(tmp_path / "group_advance-1.py3.nbi"))
    spawned = []
    monkeypatch.setattr(specialise, "_spawn", lambda sigs, claim, limit=0: spawned.append(sigs))
    monkeypatch.setattr(specialise, "_in_disk_cache", lambda dispatcher, sig: False)
    for name, value in (("_pending", []), ("_requested", set()), ("_watching", {}), ("_next_watch", 0.0)):
        monkeypatch.setattr(specialise, name, value)
    monkeypatch.setattr(specialise, "_child", None)
    sig = specialise._signature(_args(6, True))
    held = specialise._take_claim(specialise._claim_file(sig))  # "another process's" child
    assert held is not None
    try:
        specialise._pending.append(sig)
        specialise.start_background()
        assert spawned == [] and list(specialise._watching) == [sig]
        generation = specialise.background_generation()
        assert specialise.background_generation() == generation, "nothing changed while it is held"
    finally:
        os.close(held)
    specialise._next_watch = 0.0
    assert specialise.background_generation() == generation + 1
    assert specialise._watching == {} and specialise._pending == [sig]
    specialise.start_background()
    assert spawned == [[sig]]


@linux_only
@pytest.mark.slow
def test_two_parents_asking_for_the_same_kind_start_one_compilation(tmp_path) -> None:
    """Two scripts stepping the same new kind at once into one cache: one of them starts a background
    compilation, the other waits for it, and both switch to the kind's own kernel."""
    env = _cache_env(tmp_path)
    runs = [subprocess.Popen([sys.executable, "-c", _UNTIL], env=env, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [run.communicate(timeout=900) for run in runs]
    for run, (_, err) in zip(runs, outs, strict=True):
        assert run.returncode == 0, err[-2000:]
    started = [out.split("\n")[0] for out, _ in outs]
    assert sorted(started) == ["[True] 0", "[True] 1"], outs


# a background process whose cache save first waits for the other's (a barrier in the directory argv[1])
# and then takes a second between loading numba's cache index and saving it: without the cache lock the
# two load-modify-saves overlap and one entry is lost
_RACING_CHILD = r"""
import os, signal, sys, time
signal.alarm(600)  # bounded even if the other dies before the barrier
from pan1_env.kernels import specialise
from pan1_env.kernels.substep import group_advance
barrier, cache = sys.argv[1], group_advance._cache
locked_save, save_index = cache.save_overload, cache._cache_file._save_index

def save_overload(sig, data):
    open(os.path.join(barrier, str(os.getpid())), "w").close()
    while len(os.listdir(barrier)) < 2:
        time.sleep(0.05)
    return locked_save(sig, data)

def slow_save_index(overloads):
    time.sleep(1.0)
    save_index(overloads)

cache.save_overload, cache._cache_file._save_index = save_overload, slow_save_index
sys.exit(specialise._main())
"""

_IN_CACHE = r"""
import pickle, sys
from pan1_env.kernels import specialise
from pan1_env.kernels.substep import group_advance
print([specialise._in_disk_cache(group_advance, sig) for sig in pickle.loads(sys.stdin.buffer.read())])
"""


@pytest.mark.slow
def test_two_children_of_different_kinds_both_land_in_the_index(tmp_path) -> None:
    """Two background processes saving different kinds into one cache at the same moment both keep
    their entry (the cache lock makes numba's load-modify-save of the index one step)."""
    if specialise.fcntl is None:
        pytest.skip("no cache lock without fcntl")
    env = _cache_env(tmp_path)
    barrier = tmp_path / "barrier"
    barrier.mkdir()
    sigs = [specialise._signature(_args(2, False)), specialise._signature(_args(3, True))]
    children = []
    try:
        for sig in sigs:
            child = subprocess.Popen([sys.executable, "-c", _RACING_CHILD, str(barrier)], stdin=subprocess.PIPE,
                                     stderr=subprocess.PIPE, env=env)
            children.append(child)
            child.stdin.write(pickle.dumps([sig]))
            child.stdin.close()
        for child in children:
            assert child.wait(timeout=900) == 0, child.stderr.read()[-2000:]
    finally:  # one failing leaves the other at the barrier: end it
        for child in children:
            if child.poll() is None:
                child.kill()
                child.wait()
    check = subprocess.run([sys.executable, "-c", _IN_CACHE], input=pickle.dumps(sigs), env=env,
                           capture_output=True, timeout=600)
    assert check.returncode == 0, check.stderr[-2000:]
    assert check.stdout.decode().split("\n")[0] == "[True, True]"


def test_a_file_system_without_locks_reads_the_cache_unlocked(monkeypatch) -> None:
    """Where flock fails with "no locks here" (NFS without lockd: ENOLCK), there is no lock rather than
    a lock never had: a cached kind reads as cached (else every process would start a child for ever)."""
    if specialise.fcntl is None:
        pytest.skip("no locks without fcntl")
    monkeypatch.delenv("PAN1_ENV_KERNELS", raising=False)
    compiled = _args(2, True)
    kernels.group_advance(*compiled)  # compiled or loaded: in the disk cache
    sig = specialise._signature(compiled)

    def no_locks(fd, mode):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(specialise.fcntl, "flock", no_locks)
    with specialise._cache_lock(kernels.group_advance, exclusive=False, wait=0.1) as held:
        assert held is None
    assert specialise._in_disk_cache(kernels.group_advance, sig)


def test_every_cached_kernel_saves_and_loads_under_its_lock(monkeypatch) -> None:
    """The parallel per-kind kernel and the generic kernel's _advance_arms (several signatures per
    index, like group_advance) take their cache lock too."""
    if specialise.fcntl is None:
        pytest.skip("no locks without fcntl")
    taken = []
    real = specialise._cache_lock

    def recording(dispatcher, exclusive, wait=specialise._LOCK_WAIT):
        taken.append((dispatcher, exclusive))
        return real(dispatcher, exclusive, wait)

    monkeypatch.setattr(specialise, "_cache_lock", recording)
    sig = specialise._signature(_args(4, True))  # not compiled in this test: load finds nothing or loads
    for dispatcher in (kernels.group_advance, kernels.group_advance_parallel, substep._advance_arms):
        dispatcher._cache.load_overload(sig, dispatcher.targetctx)
        assert taken[-1] == (dispatcher, False), dispatcher


def test_the_guard_survives_another_numba(monkeypatch, tmp_path) -> None:
    """A cache object without numba 0.68's private attributes is left alone, with one notice and no
    exception; and the wrappers pass whatever arguments numba gives them."""
    if specialise.fcntl is None:
        pytest.skip("no locks without fcntl")
    notices = []
    monkeypatch.setattr(specialise.compile_notice, "notify", notices.append)
    monkeypatch.setattr(specialise, "_noticed_unguarded", False)

    class Cache:  # numba's cache object, its index renamed
        _cache_path = str(tmp_path)
        calls = []

        def save_overload(self, *args, **kwargs):
            self.calls.append((args, kwargs))

        load_overload = save_overload

    class Dispatcher:
        __name__ = "kernel"
        targetctx = None
        _cache = Cache()

    other = Dispatcher()
    monkeypatch.setattr(specialise, "_cached_dispatchers", lambda: [other, other])
    specialise._guard_all()
    assert len(notices) == 1 and "without a lock" in notices[0]
    assert not hasattr(other._cache, "_pan1_env_locked")
    specialise._guard_all()
    assert len(notices) == 1, "said once"

    class File:
        _index_name = "kernel-1.py3.nbi"

    other._cache._cache_file = File()
    assert specialise._guard_cache(other)
    other._cache.save_overload("sig", "data", extra=1)  # a signature numba 0.68 does not have
    other._cache.load_overload("sig")
    assert Cache.calls == [(("sig", "data"), {"extra": 1}), (("sig",), {})]
    assert os.path.exists(tmp_path / "kernel-1.py3.nbi.lock")


def test_no_claim_key_and_no_readable_cache(monkeypatch) -> None:
    """numba's private index key gone: no exception into the step, a child without a claim; and where
    the cache cannot be read at all, the kind switches when its child exits cleanly."""
    monkeypatch.delenv("PAN1_ENV_KERNELS", raising=False)
    for name, value in (("_pending", []), ("_requested", set()), ("_watching", {}), ("_trusted", set()),
                        ("_child_sigs", []), ("_generation", 0), ("_started", 0)):
        monkeypatch.setattr(specialise, name, value)
    monkeypatch.setattr(specialise, "_child", None)

    def no_key(sig):
        raise AttributeError("'Cache' object has no attribute '_index_key'")

    class Child:
        returncode = None
        pid = 0

        def poll(self):
            return self.returncode

    child, spawned = Child(), []
    monkeypatch.setattr(specialise, "_claim_file", no_key)
    monkeypatch.setattr(specialise, "_spawn", lambda sigs, claim, limit=0: spawned.append((sigs, claim)) or child)
    monkeypatch.setattr(specialise, "_cached_state", lambda dispatcher, sig: None)  # cannot tell
    args = _args(6, True)
    sig = specialise._signature(args)
    assert not specialise.specialised_ready(args)
    specialise.start_background()
    assert spawned == [([sig], ())]
    assert not specialise.specialised_ready(args), "still compiling"
    child.returncode = 0
    specialise.background_generation()
    assert specialise.specialised_ready(args), "a clean exit is trusted where the cache cannot be read"
    assert specialise._child is None and len(spawned) == 1


@pytest.mark.skipif(not hasattr(os, "fork") or specialise.fcntl is None, reason="fork and flock")
def test_a_forked_worker_keeps_no_claim(tmp_path) -> None:
    """A claim (or lock) open when a worker forks is the parent's alone: once the parent lets go it is
    free, though the worker lives on (a flock belongs to the open file, which a fork shares)."""
    path = str(tmp_path / "kind.claim")
    held = specialise._take_claim(path)
    assert held is not None
    read, write = os.pipe()
    ready_read, ready_write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the worker (its at-fork hooks have run): says it is there, lives until told to end
        try:
            os.close(write)
            os.write(ready_write, b"r")
            os.read(read, 1)
        finally:
            os._exit(0)
    try:
        os.close(read)
        assert os.read(ready_read, 1) == b"r"
        specialise._close(held)
        assert specialise._claim_free(path), "the forked worker still holds the parent's claim"
    finally:
        for fd in (write, ready_read, ready_write):
            os.close(fd)
        os.waitpid(pid, 0)
