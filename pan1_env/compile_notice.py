"""A notice whenever numba compiles a sub-step kernel for an arm kind, so that a first use is never silent.

The sub-step kernel is specialised for each arm kind (number of links n, number of actuated joints k):
the first use of a kind compiles it (about 10 s and a few hundred MB on a 2-core machine) and numba
caches the result on disk, so later processes load it instead. :func:`install` listens to numba's
compile events (``numba.core.event``, which fire only for a real compilation, not for a cache load) and
says which kind is being compiled, that it happens once, how long it took and where the cache lives.

The notice goes to the ``pan1_env`` logger at level INFO when the application's logging shows that
logger's INFO messages, and to standard error otherwise (:func:`notify`).
``pan1-env warmup`` compiles the kinds ahead of time.
"""

from __future__ import annotations

import logging
import sys
import time

from numba.core import event as numba_event

__all__ = ["KERNELS_PER_KIND", "describe_kind", "install", "notify"]

logger = logging.getLogger("pan1_env")

# the dispatchers specialised per arm kind: their first two arguments are kernel_sizes(n, k)
KERNELS_PER_KIND = ("group_advance", "group_advance_parallel")


def notify(message: str) -> None:
    """Tell the user ``message``: through logging if the application configured it to show INFO from
    ``pan1_env``, else on stderr (a root handler at WARNING, as a library's first ``logging.warning``
    sets up, would otherwise swallow it)."""
    if logger.hasHandlers() and logger.isEnabledFor(logging.INFO):
        logger.info(message)
    else:
        print(f"pan1_env: {message}", file=sys.stderr, flush=True)


def describe_kind(n: int, k: int) -> str:
    """A person's name for arms of ``n`` links and ``k`` actuated joints, e.g. ``"4 links, passive first
    joint (PA3)"`` or ``"2 links, fully actuated"``."""
    return f"{n} links, passive first joint (PA{k})" if k < n else f"{n} links, fully actuated"


def _cache_dir(dispatcher) -> str:
    path = getattr(getattr(dispatcher, "_cache", None), "cache_path", None)
    return str(path) if path else "numba's cache (NUMBA_CACHE_DIR)"


class _KernelCompileNotice(numba_event.Listener):
    """Listens to numba's compile events and speaks up for the per-kind kernels."""

    def __init__(self) -> None:
        self._started: dict[int, float] = {}

    @staticmethod
    def _kind(event) -> tuple[str, str] | None:
        dispatcher = event.data.get("dispatcher")
        name = getattr(getattr(dispatcher, "py_func", None), "__name__", "")
        module = getattr(dispatcher.py_func, "__module__", "") if name in KERNELS_PER_KIND else ""
        if not module.startswith("pan1_env.kernels"):
            return None
        args = event.data.get("args") or ()
        try:
            n, k = len(args[0]), len(args[1])
        except (IndexError, TypeError):
            return None
        threads = " (multi-threaded)" if name.endswith("_parallel") else ""
        return describe_kind(n, k) + threads, _cache_dir(dispatcher)

    def on_start(self, event) -> None:
        found = self._kind(event)
        if found is not None:
            kind, cache = found
            self._started[id(event.data["dispatcher"])] = time.perf_counter()
            notify(f"compiling the sub-step kernel for arms of {kind}: once per arm kind, about 10 s "
                   f"on a 2-core machine; cached in {cache} for later runs "
                   f"(`pan1-env warmup` compiles ahead of time)")

    def on_end(self, event) -> None:
        found = self._kind(event)
        if found is None:
            return
        started = self._started.pop(id(event.data["dispatcher"]), None)
        # a failed compilation raises to the caller; numba 0.68's Event.is_failed reads inverted, so
        # look at the exception details the event carries
        if getattr(event, "_exc_details", None) is None:
            took = f" in {time.perf_counter() - started:.0f} s" if started is not None else ""
            notify(f"compiled the sub-step kernel for arms of {found[0]}{took}")


_INSTALLED = False


def install() -> None:
    """Register the notice with numba's compile events (once per process)."""
    global _INSTALLED
    if _INSTALLED:
        return
    numba_event.register("numba:compile", _KernelCompileNotice())
    _INSTALLED = True
