"""Which serial sub-step kernel an arm kind steps with: its own (per-kind) kernel once that is compiled
or in numba's disk cache, the generic kernel until then, and a background process that compiles the
per-kind kernel meanwhile and leaves it in the disk cache, even if the process that asked ends first.

A per-kind kernel (:func:`~pan1_env.kernels.group_advance`) takes 11–15 s to compile on a quiet
2-core machine (load average below 1), 16–31 s on a busy one, for every new arm kind; the generic
kernel (:func:`~pan1_env.kernels.group_advance_generic`) about 7 s once for all kinds of up to
:data:`GENERIC_MAX_LINKS` links, and it gives the same results bit for bit (tests/test_kernels.py),
3–4× slower per arm-sub-step. So the first step of a team of new kinds costs one compilation instead
of one per kind, and a long run gets the per-kind speed as soon as the background compilation has put
the kernel into the disk cache (:func:`specialised_ready` says so on the step after; the switch
changes no result).

``PAN1_ENV_KERNELS`` chooses: ``auto`` (the default, as above), ``specialised`` (always the per-kind
kernel, compiled in the process if need be: the behaviour before the generic kernel; ``pan1-env warmup``
uses it) or ``generic`` (always the generic kernel, where it applies; for tests).

**The background process** (:func:`_main`) reads the pickled signatures from its standard input
(closed after them) and compiles them into the same cache (``NUMBA_CACHE_DIR`` is inherited), one kind
per process, at a low CPU priority (nice 10; at 19 a busy machine starved it for minutes). It is
detached: its own session (so a Ctrl-C at the terminal does not reach it), no parent-death signal,
not ended when the asking process exits, which neither waits for it; a short script that steps a new
kind once and exits therefore still leaves the kernel cached for the next run. While the asking
process lives, a thread of it reaps the child as soon as it exits (no zombie); after, init does. The
child bounds itself: ``signal.alarm(LIMIT)`` (:data:`LIMIT`, 15 minutes, some 30 times the slowest
compilation measured) is set before it even imports the package, and SIGALRM's default action ends
it, inside LLVM too, so a stuck compilation never lingers longer.

**One compilation per kind, across processes.** Two files beside numba's cache index of
:func:`group_advance` (in the dispatcher's ``_cache._cache_path``, named after the index
``<function>-<line>.pyXY.nbi``), both held with ``fcntl.flock``, which the kernel releases when the
holder dies however it dies:

- a *claim* per signature, ``<index>.<hash>.claim`` (the hash of numba's index key: the signature, the
  CPU and the function's bytecode). A process takes it non-blocking before starting a child and hands
  the locked descriptor to the child (``pass_fds``), which holds it until it exits. A second process
  (another script, a vector env's forked worker) asking for the same kind finds it taken, starts no
  child and watches the claim instead (:func:`background_generation` tries it twice a second at most);
  when it comes free the engine looks at the cache again (and if the other compilation failed, this
  process starts its own). A process that takes a free claim looks at the cache first: a kind cached
  since it was asked for needs no child.
- the *cache lock*, ``<index>.lock``, held exclusively around every save of a :func:`group_advance`
  entry into the disk cache and shared around every read of it, in every process that imported this
  module (its numba cache object's ``save_overload`` and ``load_overload`` are wrapped here, so the
  children, in-process compilations and ``pan1-env warmup`` all take it, and so do
  :func:`_in_disk_cache` and a child's last look before compiling). It is not held during the
  compilation itself (which the claim serialises per kind), so that a reader waits at most for a save
  (pickling and writing a few MB), never for a compilation of tens of seconds.

The claim and lock files are empty and stay (one claim per kind and source version); deleting a file
others may have open would let two processes lock two different files of one name.

Why the lock, from numba 0.68's ``numba/core/caching.py``: ``IndexDataCacheFile.save`` loads the
index (one file per function, holding all its signatures), picks for a new key the first data name
``<index base>.<n>.nbc`` not in it, saves the index (``_save_index``), and only then pickles and saves
the data (``_save_data``). Each file is written to ``<file>.tmp.<uuid>`` and moved over the old one
with ``os.replace`` (``_open_for_write``): atomic, so a reader opens either the old or the new whole
file, never a torn one. But the sequence is not atomic. Two processes saving two new signatures at once
each load the same index, both pick the same number, and the last index saved drops the other's entry
— or keeps one key while the data file holds the other signature's code, which numba's loader would
then load under the wrong key. And between the index save and the data save, the index names a data
file that is not there yet (``load`` then meets ``FileNotFoundError``, says "not cached" and numba
compiles in the process) or, when the index had been stale (the source changed, numbering restarts at
1), a data file left from older code, which the loader would load. Under the lock a save is one step
for every reader that takes it: :func:`_in_disk_cache`, the gate before the engine calls
:func:`group_advance`, reads the index and checks the data file under the shared lock, so it says True
only for a complete entry; numba's own load under it sees the same; and an entry once complete keeps
its data name and file (a later save adds new names only), so a later concurrent save cannot disturb
it. If the lock cannot be had within a minute (a file system without ``flock``, a holder stuck), a
save or load goes ahead without it, as numba does on its own, and :func:`_in_disk_cache` says False.

Windows has no ``fcntl``: there the child is not detached, no claims or locks are taken, and the child
is ended at the interpreter's exit (the behaviour before); a process that ends before the
compilation does leaves the work to the next one. macOS has ``fcntl`` and ``signal.alarm``.
"""

from __future__ import annotations

import atexit
import contextlib
import hashlib
import os
import pickle
import signal
import subprocess
import sys
import threading
import time

try:
    import fcntl
except ImportError:  # Windows: no claims, no locks (module docstring)
    fcntl = None

from .. import compile_notice
from .substep import GENERIC_MAX_LINKS, group_advance

__all__ = ["POLICIES", "LIMIT", "policy", "specialised_ready", "start_background", "background_generation",
           "stop_background"]

POLICIES = ("auto", "specialised", "generic")
_ENV = "PAN1_ENV_KERNELS"
#: s: a background process ends itself after this long (SIGALRM), compiled or not
LIMIT = 900
_LOCK_WAIT = 60.0  # s: how long a save or load waits for the cache lock before going on without it
_WATCH_EVERY = 0.5  # s: how often a claim another process holds is tried

_pending: list = []  # signatures waiting for a background compilation
_requested: set = set()  # every signature ever handed to (or waiting for) a child: compiled at most once
_watching: dict = {}  # signature -> claim file another process's child holds: looked at again when free
_next_watch = 0.0
_child: subprocess.Popen | None = None
_child_sigs: list = []
_generation = 0  # background compilations finished (successfully or not), here or in another process
_started = 0  # background processes this process started


def policy() -> str:
    """The ``PAN1_ENV_KERNELS`` setting (read at every call, so a test may change it)."""
    value = os.environ.get(_ENV, "auto").strip().lower() or "auto"
    if value not in POLICIES:
        raise ValueError(f"{_ENV}={value!r}: expected one of {POLICIES}")
    return value


def _signature(args) -> tuple:
    return tuple(group_advance.typeof_pyval(a) for a in args)


# ------------------------------------------------------------------ lock files beside numba's cache
def _index_file(dispatcher) -> str | None:
    """The path of the dispatcher's numba cache index (private numba 0.68 objects), or None."""
    try:
        cache = dispatcher._cache
        return os.path.join(cache._cache_path, cache._cache_file._index_name)
    except AttributeError:  # no disk cache, another numba
        return None


def _open_lock_file(path: str) -> int:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    return os.open(path, os.O_RDWR | os.O_CREAT, 0o666)


def _flock(fd: int, mode: int, wait: float) -> bool:
    """Take ``flock`` ``mode`` on ``fd`` within ``wait`` s (non-blocking tries, so a stuck holder cannot
    hang the caller); False if it could not."""
    deadline = time.monotonic() + wait
    while True:
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)
        except OSError:  # a file system without flock
            return False


@contextlib.contextmanager
def _cache_lock(dispatcher, exclusive: bool, wait: float = _LOCK_WAIT):
    """Hold the dispatcher's cache lock (module docstring) for the block; yields True when held, False
    when it could not be had in ``wait`` s, None where there is no lock (no fcntl or no disk cache).
    Never nest it in one thread: a second descriptor's request would wait for the first."""
    index = _index_file(dispatcher) if fcntl is not None else None
    fd = None
    if index is not None:
        try:
            fd = _open_lock_file(index + ".lock")
        except OSError:  # a cache directory we cannot write: numba's own behaviour
            fd = None
    if fd is None:
        yield None
        return
    try:
        yield _flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH, wait)
    finally:
        os.close(fd)  # releases the lock


def _guard_cache(dispatcher) -> None:
    """Make every save of ``dispatcher``'s entries into numba's disk cache hold the cache lock
    exclusively and every load hold it shared, in this process (module docstring)."""
    cache = getattr(dispatcher, "_cache", None)
    if fcntl is None or _index_file(dispatcher) is None or getattr(cache, "_pan1_env_locked", False):
        return
    save, load = cache.save_overload, cache.load_overload

    def save_overload(sig, data):
        with _cache_lock(dispatcher, exclusive=True):
            return save(sig, data)

    def load_overload(sig, target_context):
        with _cache_lock(dispatcher, exclusive=False):
            return load(sig, target_context)

    cache.save_overload, cache.load_overload = save_overload, load_overload
    cache._pan1_env_locked = True


_guard_cache(group_advance)


def _in_disk_cache(dispatcher, sig) -> bool:
    """Whether numba would load ``sig`` from the disk cache instead of compiling it: its key is in the
    function's cache index (a small pickle; a stale index reads as empty) and the data file exists, read
    under the shared cache lock, so that an entry being saved reads as absent until it is complete.
    Reads numba's private cache objects (numba 0.68); if they are not there, says False."""
    cache = getattr(dispatcher, "_cache", None)
    try:
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        with _cache_lock(dispatcher, exclusive=False, wait=10.0) as held:
            if held is False:  # a save still going on (or stuck): not yet
                return False
            name = cache._cache_file._load_index().get(key)
            return name is not None and os.path.exists(cache._cache_file._data_path(name))
    except Exception:  # noqa: BLE001 -- another numba, a cache that cannot be read: treat as absent
        return False


def _claim_file(sig) -> str | None:
    """The claim file of ``sig`` (module docstring), or None where there are no claims."""
    index = _index_file(group_advance) if fcntl is not None else None
    if index is None:
        return None
    key = group_advance._cache._index_key(sig, group_advance.targetctx.codegen())
    return f"{index}.{hashlib.sha256(repr(key).encode()).hexdigest()[:16]}.claim"


def _take_claim(path: str) -> int | None:
    """A descriptor holding the claim ``path`` exclusively, or None if another process holds it.
    Raises OSError if the file cannot be used at all."""
    fd = _open_lock_file(path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    except OSError:
        os.close(fd)
        raise
    return fd


def _claim_free(path: str) -> bool:
    try:
        fd = _take_claim(path)
    except OSError:
        return True  # the file went away or cannot be used: stop watching it
    if fd is not None:
        os.close(fd)
    return fd is not None


# ------------------------------------------------------------------ the engine's side
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
                              f"a background process (about 15-30 s, longer on a busy machine); they switch to "
                              f"it when it is ready, and it is cached for later runs even if this process "
                              f"ends first")
    return False


def start_background() -> None:
    """Start the background compilation of the next kind asked for, unless one is running. The engine
    calls it at the start of a step, so the first child starts at a new kind's second step and its
    start (an interpreter importing numba) does not compete with the first step's compilation; later
    children start as earlier ones end."""
    _start_next()


def background_generation() -> int:
    """A count that grows when a background compilation ends, this process's (checked without waiting)
    or another process's that held the claim of a kind asked for here (tried every
    ``_WATCH_EVERY`` s)."""
    global _generation, _next_watch
    if _child is not None and _child.poll() is not None:
        _finished()
    if _watching and time.monotonic() >= _next_watch:
        _next_watch = time.monotonic() + _WATCH_EVERY
        for sig, path in list(_watching.items()):
            if _claim_free(path):
                del _watching[sig]
                _generation += 1
                if not _in_disk_cache(group_advance, sig):  # the other compilation failed: try here
                    _pending.append(sig)
    return _generation


def _finished() -> None:
    global _child, _generation
    child, _child = _child, None
    alarm = getattr(signal, "SIGALRM", None)  # none on Windows
    if alarm is not None and child.returncode == -alarm:  # its bound (LIMIT) ran out
        compile_notice.notify(f"the background compilation of a sub-step kernel took longer than {LIMIT} s and "
                              f"was stopped; the generic kernel goes on")
    elif child.returncode != 0:
        compile_notice.notify(f"the background compilation of a sub-step kernel failed (exit status "
                              f"{child.returncode}); the generic kernel goes on")
    _generation += 1
    _start_next()


def _start_next() -> None:
    global _child, _child_sigs, _generation, _started
    while _child is None and _pending:
        sig = _pending.pop(0)  # one kind per child: each switches when it is ready
        claim = path = None
        try:
            path = _claim_file(sig)
            claim = _take_claim(path) if path is not None else None
        except OSError:  # a claim file we cannot use: compile without one, as where there are none
            path = None
        if path is not None and claim is None:  # another process's child compiles it
            _watching[sig] = path
            continue
        try:
            if claim is not None and _in_disk_cache(group_advance, sig):  # cached since it was asked for
                _generation += 1
                continue
            _child_sigs = [sig]
            _child = _spawn(_child_sigs, claim)
            _started += 1
        except OSError as error:
            compile_notice.notify(f"could not start the background compilation ({error}); the generic kernel "
                                  f"goes on")
            _child = None
        finally:
            if claim is not None:
                os.close(claim)  # the child holds it now (its own copy of the descriptor), or nobody


def _spawn(sigs: list, claim: int | None, limit: int = LIMIT) -> subprocess.Popen:
    """Start a background process compiling ``sigs``, holding the claim descriptor ``claim``, ending
    itself after ``limit`` s; a daemon thread reaps it when it exits (no zombie while this process
    lives, and none waits for it at exit)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    detach = {"start_new_session": True, "pass_fds": () if claim is None else (claim,)} if fcntl is not None else {}
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(int(limit))], stdin=subprocess.PIPE,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, **detach)
    threading.Thread(target=child.wait, name="pan1_env background compilation", daemon=True).start()
    try:
        child.stdin.write(pickle.dumps(sigs))
    finally:
        child.stdin.close()
    return child


def stop_background() -> None:
    """End a running background compilation and reap it (tests; and at interpreter exit where the child
    is not detached, on Windows). Forgets the kinds waiting for one or watched elsewhere."""
    global _child
    child, _child = _child, None
    _pending.clear()
    _watching.clear()
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
    wait for it nor end it; it asks for its own if it needs one (and the claims keep the two from
    compiling the same kind)."""
    global _child
    _child = None
    _pending.clear()
    _requested.clear()
    _watching.clear()


if fcntl is None:  # not detached (Windows): ended with its process, as before
    atexit.register(stop_background)
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_in_fork)


# the bound comes first, before the imports (numba's alone take seconds)
_CHILD = ("import signal, sys; getattr(signal, 'alarm', int)(int(sys.argv[1])); "
          "from pan1_env.kernels.specialise import _main; sys.exit(_main())")


def _main() -> int:
    """The background process: compile the signatures read from standard input into the disk cache, at
    a low priority (its caller set the bound); a kind already cached when it gets there is skipped."""
    sigs = pickle.loads(sys.stdin.buffer.read())
    sys.stdin.close()
    if hasattr(os, "nice"):
        os.nice(10)
    for sig in sigs:
        if not _in_disk_cache(group_advance, sig):  # another process may have saved it meanwhile
            group_advance.compile(sig)  # its save holds the cache lock (_guard_cache)
    return 0
