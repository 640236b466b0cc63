"""Which serial sub-step kernel an arm kind steps with: its own (per-kind) kernel once that is compiled
or in numba's disk cache, the generic kernel until then, and a background process that compiles the
per-kind kernel meanwhile and leaves it in the disk cache, even if the process that asked ends first.

A per-kind kernel (:func:`~pan1_env.kernels.group_advance`) takes 11–15 s to compile on a quiet
2-core machine (load average below 1), 16–31 s on a busy one, for every new arm kind; the generic
kernel (:func:`~pan1_env.kernels.group_advance_generic`) about 16 s (29 s with whole-arm safety) once for all
kinds of up to :data:`GENERIC_MAX_LINKS` links, and it gives the same results bit for bit (tests/test_kernels.py),
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
not ended when the asking process exits, which neither waits for it. A kind's child starts at the
asking process's next step (:func:`start_background`), or at its exit if none comes
(:func:`_start_at_exit`: before it, a script that stepped a new kind once, as the quickstart does, never
started one, and the next process stepped on the generic kernel again); so a short script that steps a
new kind and exits still leaves the kernel cached for the next run (not one killed by a signal: no
exit handler runs then, and the next process asks again). While the asking
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
it. Every other ``cache=True`` kernel of the package (``group_advance_parallel``, the generic kernel's
``_advance_arms``, the helpers they call, the geometry and observation kernels) has its own lock, the
same way (:func:`_cached_dispatchers` says why). If a lock cannot be had within a minute (a holder
stuck), a save or load goes ahead without it, as numba does on its own, and :func:`_in_disk_cache`
says False; on a file system without ``flock`` (NFS without lockd, some FUSE or CIFS mounts) there
is no lock at all: saves and loads go ahead at once, as numba's own, and :func:`_in_disk_cache` reads
the index unlocked. Where numba's private cache objects are not as expected (another numba), no lock
is taken (one notice says so), no claims either, and a kind switches to its own kernel when its
child exits cleanly, the only word left.

Windows has no ``fcntl``: there the child is not detached, no claims or locks are taken, and the child
is ended at the interpreter's exit (the behaviour before); a process that ends before the
compilation does leaves the work to the next one. macOS has ``fcntl`` and ``signal.alarm``.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
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
from . import capsules, observe, outcome, physics, qp, substep, team_geometry
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
_trusted: set = set()  # kinds whose child exited cleanly where the disk cache cannot be read (_cached_state)
_open_fds: set = set()  # lock and claim descriptors this process holds open: closed in a forked child
_noticed_unguarded = False


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
    except Exception:  # noqa: BLE001 -- no disk cache (NullCache), another numba's layout
        return None


def _open_lock_file(path: str) -> int:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    _open_fds.add(fd)  # a forked child closes its copy (_forget_in_fork)
    return fd


def _close(fd: int) -> None:
    """Close a descriptor of :func:`_open_lock_file` (releasing its lock), unless a fork closed it."""
    if fd in _open_fds:
        _open_fds.discard(fd)
        os.close(fd)


# flock's answers meaning "this file system has no locks" (NFS without lockd, some FUSE and CIFS
# mounts), not "someone holds it"; any other OSError but "would block" is read the same way
_NO_LOCKS = {errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.ENOSYS, errno.EINVAL}


def _flock(fd: int, mode: int, wait: float) -> bool | None:
    """Take ``flock`` ``mode`` on ``fd`` within ``wait`` s (non-blocking tries, so a stuck holder cannot
    hang the caller); False if another holder kept it that long, None if the file system has no locks
    (then waiting would never help, and a False would read as "a save in progress" for ever)."""
    deadline = time.monotonic() + wait
    while True:
        try:
            fcntl.flock(fd, mode | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.005)
        except OSError:  # _NO_LOCKS, or an error no waiting cures: no lock here
            return None


@contextlib.contextmanager
def _cache_lock(dispatcher, exclusive: bool, wait: float = _LOCK_WAIT):
    """Hold the dispatcher's cache lock (module docstring) for the block; yields True when held, False
    when it could not be had in ``wait`` s, None where there is no lock (no fcntl, no disk cache, a file
    system without flock). Never nest it in one thread: a second descriptor's request would wait for
    the first."""
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
        _close(fd)  # releases the lock


def _guard_cache(dispatcher) -> bool:
    """Make every save of ``dispatcher``'s entries into numba's disk cache hold the cache lock
    exclusively and every load hold it shared, in this process (module docstring). False (and the
    dispatcher left as numba made it) where numba's private cache objects are not as expected."""
    if fcntl is None:
        return False
    cache = getattr(dispatcher, "_cache", None)
    if getattr(cache, "_pan1_env_locked", False):
        return True
    save, load = getattr(cache, "save_overload", None), getattr(cache, "load_overload", None)
    if _index_file(dispatcher) is None or not callable(save) or not callable(load):
        return False

    # (*args, **kwargs): numba's private signatures may change; the lock does not depend on them
    def save_overload(*args, **kwargs):
        with _cache_lock(dispatcher, exclusive=True):
            return save(*args, **kwargs)

    def load_overload(*args, **kwargs):
        with _cache_lock(dispatcher, exclusive=False):
            return load(*args, **kwargs)

    try:
        cache.save_overload, cache.load_overload = save_overload, load_overload
        cache._pan1_env_locked = True
    except Exception:  # noqa: BLE001 -- a cache object that takes no attributes: leave it as it is
        return False
    return True


def _cached_dispatchers() -> list:
    """Every dispatcher of this package with a disk cache (``cache=True``): the per-kind kernels, the
    generic kernel's :func:`~pan1_env.kernels.substep._advance_arms`, and all the helpers they call.
    Each may hold several signatures in its one index (a helper called from kernels of different kinds,
    a parallel kernel at several argument types), so two processes saving at once can lose an entry or
    file one under the wrong key; and even a function with one signature can, after a source change
    (numbering restarts at 1), read an older data file in the moment between the index save and the
    data save. So all of them save and load under their own lock."""
    found = {}
    for module in (physics, qp, substep, capsules, team_geometry, observe, outcome):
        for value in vars(module).values():
            if hasattr(value, "targetctx") and hasattr(value, "_cache") and id(value) not in found:
                found[id(value)] = value
    return list(found.values())


def _guard_all() -> None:
    global _noticed_unguarded
    if fcntl is None:
        return
    missing = [d for d in _cached_dispatchers() if type(d._cache).__name__ != "NullCache" and not _guard_cache(d)]
    if missing and not _noticed_unguarded:  # another numba: lose the lock, not the kernels
        _noticed_unguarded = True
        compile_notice.notify(f"numba's cache objects are not as this version expects, so {len(missing)} kernels "
                              f"(e.g. {getattr(missing[0], '__name__', missing[0])}) are cached without a lock; "
                              f"processes compiling at the same time may compile a kernel again")


_guard_all()


def _cached_state(dispatcher, sig) -> bool | None:
    """Whether numba would load ``sig`` from the disk cache instead of compiling it: its key is in the
    function's cache index (a small pickle; a stale index reads as empty) and the data file exists, read
    under the shared cache lock, so that an entry being saved reads as absent until it is complete
    (read without it where the file system has no locks). Reads numba's private cache objects (numba
    0.68); None if they are not there (cannot tell), False if the cache cannot be read."""
    cache = getattr(dispatcher, "_cache", None)
    try:
        key = cache._index_key(sig, dispatcher.targetctx.codegen())
        load_index, data_path = cache._cache_file._load_index, cache._cache_file._data_path
    except Exception:  # noqa: BLE001 -- another numba's layout: cannot tell
        return None
    try:
        with _cache_lock(dispatcher, exclusive=False, wait=10.0) as held:
            if held is False:  # a save still going on (or stuck): not yet
                return False
            name = load_index().get(key)
            return name is not None and os.path.exists(data_path(name))
    except Exception:  # noqa: BLE001 -- a cache that cannot be read: treat as absent
        return False


def _in_disk_cache(dispatcher, sig) -> bool:
    """Whether ``sig`` can be loaded from the disk cache (:func:`_cached_state`; False if it cannot tell)."""
    return _cached_state(dispatcher, sig) is True


def _claim_file(sig) -> str | None:
    """The claim file of ``sig`` (module docstring), or None where there are no claims."""
    index = _index_file(group_advance) if fcntl is not None else None
    if index is None:
        return None
    key = group_advance._cache._index_key(sig, group_advance.targetctx.codegen())
    return f"{index}.{hashlib.sha256(repr(key).encode()).hexdigest()[:16]}.claim"


def _take_claim(path: str) -> int | None:
    """A descriptor holding the claim ``path`` exclusively, or None if another process holds it.
    Raises OSError if the file cannot be used at all (a file system without flock included)."""
    fd = _open_lock_file(path)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        _close(fd)
        return None
    except OSError:
        _close(fd)
        raise
    return fd


def _claim_free(path: str) -> bool:
    try:
        fd = _take_claim(path)
    except OSError:
        return True  # the file went away or cannot be used: stop watching it
    if fd is not None:
        _close(fd)
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
    if sig in group_advance.overloads or sig in _trusted or _in_disk_cache(group_advance, sig):
        return True
    if sig not in _requested:
        _requested.add(sig)
        _pending.append(sig)
        compile_notice.notify(f"the arms of {compile_notice.describe_kind(len(args[0]), len(args[1]))} step with "
                              f"the generic kernel (same results, slower) while their own kernel compiles in "
                              f"a background process (11-15 s on a quiet 2-core machine, 16-31 s measured on a "
                              f"busy one); they switch to it when it is ready, and it is cached for later runs "
                              f"even if this process ends first")
    return False


def start_background() -> None:
    """Start the background compilation of the next kind asked for, unless one is running. The engine
    calls it at the start of a step, so the first child starts at a new kind's second step and its
    start (an interpreter importing numba) does not compete with the first step's compilation; later
    children start as earlier ones end, and those still waiting when the process ends start then
    (:func:`_start_at_exit`)."""
    _start_next()


def _start_at_exit() -> None:
    """At the interpreter's exit, start one child for every kind still waiting, compiling them one after
    another: a script that steps a new kind once (the quickstart) never reached the step that would have
    started its child, nor one that stepped several new kinds the steps that would have started the later
    ones, and the notice promised them a kernel cached for the next run. One child, not one per kind: side
    by side they would share the cores and each hold a compiler's memory. It is detached and outlives this
    process (a running child goes on too); a kind another process's child holds the claim of is left to it."""
    sigs, claims = [], []
    try:
        while _pending:
            sig = _pending.pop(0)
            path, claim = _claim(sig)
            if (path is not None and claim is None) or (claim is not None and _in_disk_cache(group_advance, sig)):
                if claim is not None:
                    _close(claim)
                continue  # compiling elsewhere, or cached since it was asked for
            sigs.append(sig)
            claims.extend([] if claim is None else [claim])
        if sigs:
            _spawn(sigs, tuple(claims), limit=LIMIT * len(sigs))
    except OSError:
        pass  # nothing to tell at exit: the next process compiles in the background again
    finally:
        for claim in claims:
            _close(claim)  # the child holds its own copies, or nobody


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
    else:  # where the cache cannot be read (another numba), a clean exit is the only word: trust it
        _trusted.update(sig for sig in _child_sigs if _cached_state(group_advance, sig) is None)
    _generation += 1
    _start_next()


def _start_next() -> None:
    global _child, _child_sigs, _generation, _started
    while _child is None and _pending:
        sig = _pending.pop(0)  # one kind per child: each switches when it is ready
        path, claim = _claim(sig)
        if path is not None and claim is None:  # another process's child compiles it
            _watching[sig] = path
            continue
        try:
            if claim is not None and _in_disk_cache(group_advance, sig):  # cached since it was asked for
                _generation += 1
                continue
            _child_sigs = [sig]
            _child = _spawn(_child_sigs, () if claim is None else (claim,))
            _started += 1
        except OSError as error:
            compile_notice.notify(f"could not start the background compilation ({error}); the generic kernel "
                                  f"goes on")
            _child = None
        finally:
            if claim is not None:
                _close(claim)  # the child holds it now (its own copy of the descriptor), or nobody


def _claim(sig) -> tuple[str | None, int | None]:
    """The claim file of kind ``sig`` and, if this process took it, its descriptor: ``(path, None)`` when
    another process's child holds it, ``(None, None)`` where there are no claims or one cannot be used."""
    try:
        path = _claim_file(sig)
        return path, (_take_claim(path) if path is not None else None)
    except Exception:  # noqa: BLE001 -- a claim file we cannot use (OSError) or numba's private key gone
        # (AttributeError, …): compile without a claim, as where there are none; never raise into Engine.step
        return None, None


def _spawn(sigs: list, claims: tuple[int, ...] = (), limit: int = LIMIT) -> subprocess.Popen:
    """Start a background process compiling ``sigs``, holding the claim descriptors ``claims``, ending
    itself after ``limit`` s; a daemon thread reaps it when it exits (no zombie while this process
    lives, and none waits for it at exit)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    detach = {"start_new_session": True, "pass_fds": claims} if fcntl is not None else {}
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(int(limit))], stdin=subprocess.PIPE,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, **detach)
    with contextlib.suppress(RuntimeError):  # no new thread at interpreter shutdown (newer Pythons): init reaps it
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
    compiling the same kind). Nor its parent's locks and claims: a flock belongs to the open file,
    which the fork shares, so a worker keeping its copy would hold the parent's cache lock or claim
    after the parent let go, for as long as the worker lives. Only closed, never unlocked: an unlock
    here would release the parent's lock too."""
    global _child
    _child = None
    _pending.clear()
    _requested.clear()
    _watching.clear()
    for fd in list(_open_fds):
        _open_fds.discard(fd)
        with contextlib.suppress(OSError):
            os.close(fd)


if fcntl is None:  # not detached (Windows): ended with its process, as before
    atexit.register(stop_background)
else:
    atexit.register(_start_at_exit)
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
