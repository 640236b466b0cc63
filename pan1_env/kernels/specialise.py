"""Which serial sub-step kernel an arm kind steps with: its own (per-kind) kernel once that is compiled
or in numba's disk cache, the generic kernel until then, and a background process that compiles the
per-kind kernel meanwhile.

A per-kind kernel (:func:`~pan1_env.kernels.group_advance`) takes about 8 s to compile on a 2-core
machine, for every new arm kind; the generic kernel (:func:`~pan1_env.kernels.group_advance_generic`)
about 7 s once for all kinds of up to :data:`GENERIC_MAX_LINKS` links, and it gives the same results
bit for bit (tests/test_kernels.py), 3–4× slower per arm-sub-step. So the first step of a team of new kinds costs one
compilation instead of one per kind, and a long run gets the per-kind speed as soon as the background
compilation has put the kernel into the disk cache (:func:`specialised_ready` says so on the step
after; the switch changes no result).

``PAN1_ENV_KERNELS`` chooses: ``auto`` (the default, as above), ``specialised`` (always the per-kind
kernel, compiled in the process if need be: the behaviour before the generic kernel; ``pan1-env warmup``
uses it) or ``generic`` (always the generic kernel, where it applies; for tests).

The background process (:func:`_main`) reads the pickled signature from its standard input and
compiles it into the same cache (``NUMBA_CACHE_DIR`` is inherited), one kind per process, at a low CPU
priority (nice 10; at 19 a busy machine starved it for minutes). Numba replaces each cache file
atomically but writes a new entry's index before its data, so this process looks at the cache only
after the child has exited: it never reads a half-written entry. The child dies with its parent
(``PR_SET_PDEATHSIG`` on Linux; at interpreter exit it is terminated and reaped), so it leaves no
orphan or zombie (a thread reaps it as soon as it exits): a process that ends before the compilation does
leaves the work to the next one.
"""

from __future__ import annotations

import atexit
import os
import pickle
import signal
import subprocess
import sys
import threading

from .. import compile_notice
from .substep import GENERIC_MAX_LINKS, group_advance

__all__ = ["POLICIES", "policy", "specialised_ready", "start_background", "background_generation", "stop_background"]

POLICIES = ("auto", "specialised", "generic")
_ENV = "PAN1_ENV_KERNELS"

_pending: list = []  # signatures waiting for a background compilation
_requested: set = set()  # every signature ever handed to (or waiting for) a child: compiled at most once
_child: subprocess.Popen | None = None
_child_sigs: list = []
_generation = 0  # background compilations finished (successfully or not)


def policy() -> str:
    """The ``PAN1_ENV_KERNELS`` setting (read at every call, so a test may change it)."""
    value = os.environ.get(_ENV, "auto").strip().lower() or "auto"
    if value not in POLICIES:
        raise ValueError(f"{_ENV}={value!r}: expected one of {POLICIES}")
    return value


def _signature(args) -> tuple:
    return tuple(group_advance.typeof_pyval(a) for a in args)


def _in_disk_cache(dispatcher, sig) -> bool:
    """Whether numba would load ``sig`` from the disk cache instead of compiling it: its key is in the
    function's cache index (a small pickle; a stale index reads as empty) and the data file exists.
    Reads numba's private cache objects (numba 0.68); if they are not there, says False."""
    cache = getattr(dispatcher, "_cache", None)
    try:
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        name = cache._cache_file._load_index().get(key)
        return name is not None and os.path.exists(cache._cache_file._data_path(name))
    except Exception:  # noqa: BLE001 -- another numba, a cache that cannot be read: treat as absent
        return False


def specialised_ready(args) -> bool:
    """Whether the engine should call :func:`group_advance` with ``args`` (its arguments): True when
    the policy says so, for kinds beyond the generic kernel, or when the per-kind kernel is compiled in
    this process or can be loaded from the disk cache; else False, after asking for a background
    compilation (policy ``auto``)."""
    mode = policy()
    if mode == "specialised" or len(args[0]) > GENERIC_MAX_LINKS:
        return True
    if mode == "generic":
        return False
    sig = _signature(args)
    if sig in group_advance.overloads or _in_disk_cache(group_advance, sig):
        return True
    if sig not in _requested:
        _requested.add(sig)
        _pending.append(sig)
        compile_notice.notify(f"the arms of {compile_notice.describe_kind(len(args[0]), len(args[1]))} step with "
                              f"the generic kernel (same results, slower) while their own kernel compiles in "
                              f"a background process (about 10 s); they switch to it when it is ready")
    return False


def start_background() -> None:
    """Start the background compilation of the next kind asked for, unless one is running. The engine
    calls it at the start of a step, so the first child starts at a new kind's second step and its
    start (an interpreter importing numba) does not compete with the first step's compilation; later
    children start as earlier ones end."""
    _start_next()


def background_generation() -> int:
    """A count that grows when a background compilation ends (checks the child without waiting)."""
    if _child is not None and _child.poll() is not None:
        _finished()
    return _generation


def _finished() -> None:
    global _child, _generation
    child, _child = _child, None
    if child.returncode != 0:
        compile_notice.notify(f"the background compilation of a sub-step kernel failed (exit status "
                              f"{child.returncode}); the generic kernel goes on")
    _generation += 1
    _start_next()


def _start_next() -> None:
    global _child, _child_sigs
    if _child is not None or not _pending:
        return
    _child_sigs, _pending[:] = _pending[:1], _pending[1:]  # one kind per child: each switches when it is ready
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    try:
        _child = subprocess.Popen([sys.executable, "-c", _CHILD, str(os.getpid())], stdin=subprocess.PIPE,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        _child.stdin.write(pickle.dumps(_child_sigs))
        _child.stdin.close()
        # reaped as soon as it exits, even if no step asks (no zombie while the process idles)
        threading.Thread(target=_child.wait, name="pan1_env background compilation", daemon=True).start()
    except OSError as error:
        compile_notice.notify(f"could not start the background compilation ({error}); the generic kernel goes on")
        _child = None


def stop_background() -> None:
    """End a running background compilation and reap it (at interpreter exit; tests)."""
    global _child
    child, _child = _child, None
    _pending.clear()
    if child is None:
        return
    if child.poll() is None:
        child.terminate()
        try:
            child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _forget_in_fork() -> None:
    """A forked process (a vector env's worker) does not own its parent's child: it must neither
    wait for it nor end it; it asks for its own if it needs one."""
    global _child
    _child = None
    _pending.clear()
    _requested.clear()


atexit.register(stop_background)
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_fork)


_CHILD = "import sys; from pan1_env.kernels.specialise import _main; sys.exit(_main(int(sys.argv[1])))"


def _main(parent: int) -> int:
    """The background process: compile the signatures read from standard input into the disk cache, at
    a low priority, and die with the process that started it."""
    sigs = pickle.loads(sys.stdin.buffer.read())
    os.nice(10)
    if sys.platform.startswith("linux"):
        import ctypes

        ctypes.CDLL(None).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG: SIGTERM when the parent dies
    if os.getppid() != parent:  # the parent died before prctl took effect
        return 1
    for sig in sigs:
        group_advance.compile(sig)
    return 0
