"""A notice whenever numba compiles a sub-step kernel, so that a first use is never silent.

The sub-step kernel is specialised for each arm kind (number of links n, number of actuated joints k):
the first use of a kind compiles it (11–15 s and a few hundred MB on a quiet 2-core machine, 16–31 s
on a busy one) and numba caches the result on disk, so later processes load it instead. Until a kind's
own kernel is compiled, the engine steps it with the generic kernel (one compilation, about 16 s, 29 s with
whole-arm safety, for every kind; the same results, slower) and compiles the kind's own in a background process
(:mod:`pan1_env.kernels.specialise`, which says so when it asks for one), which finishes and caches it
even if the process that asked has ended. :func:`install` listens to
numba's compile events (``numba.core.event``, which fire only for a real compilation, not for a cache
load) and says which kernel is being compiled, that it happens once, how long it took and where the
cache lives; and, once, the whole-arm geometry helpers, the random-team draw (:mod:`pan1_env.draw_kernel`) and the
circulation term of ``action_mode="circulation"`` (:mod:`pan1_env.kernels.circulation`).

The notice goes to the ``pan1_env`` logger at level INFO when the application's logging shows that
logger's INFO messages, and to standard error otherwise (:func:`notify`).
``pan1-env warmup`` compiles the kinds ahead of time.
"""

from __future__ import annotations

import logging
import sys
import time

from numba.core import event as numba_event

from .kernel_groups import KERNEL_GROUPS

__all__ = ["KERNELS_PER_KIND", "describe_kind", "install", "notify"]

logger = logging.getLogger("pan1_env")

# the dispatchers specialised per arm kind: their first two arguments are kernel_sizes(n, k)
KERNELS_PER_KIND = ("group_advance", "group_advance_parallel")
# the sub-step kernel's body, called from Python (its fourth argument (n, k), not None) as the generic kernel
GENERIC = "_advance_arms"
# the engine's whole-arm geometry passes between kernel calls (pan1_env.kernels.team_geometry): a few seconds
# together on a first whole-arm step, announced once
GEOMETRY = ("kind_joints", "kind_joints_parallel", "obstacles_now", "refresh_capsules", "refresh_capsules_parallel",
            "inter_arm_clearance", "after_substep", "after_substep_parallel")


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
        self._geometry_told = False

    @staticmethod
    def _kind(event) -> tuple[str, str] | None:
        """What is being compiled, ``"arms of …"`` or ``"all arm kinds …"`` (the generic kernel), and the
        cache's place; None for any other compilation."""
        dispatcher = event.data.get("dispatcher")
        name = getattr(getattr(dispatcher, "py_func", None), "__name__", "")
        module = getattr(dispatcher.py_func, "__module__", "") if name in (*KERNELS_PER_KIND, GENERIC) else ""
        if not module.startswith("pan1_env.kernels"):
            return None
        args = event.data.get("args") or ()
        # the whole-arm group (after the groups: group_advance's size tuples, _advance_arms' size tuples, lanes,
        # run-time sizes, QP flag and arm bounds come first) is a tuple, else None; its branch about doubles the
        # compiled code (on_start's estimate)
        at = (2 if name in KERNELS_PER_KIND else 7) + len(KERNEL_GROUPS)
        whole = ", whole-arm safety" if len(args) > at and str(args[at]) != "none" else ""
        if name == GENERIC:  # compiled on its own only as the generic kernel (else inside a per-kind one)
            if len(args) < 4 or args[3] is None or "none" in str(args[3]).lower():
                return None
            return f"all arm kinds of up to {len(args[0])} links{whole}", _cache_dir(dispatcher)
        try:
            n, k = len(args[0]), len(args[1])
        except (IndexError, TypeError):
            return None
        threads = " (multi-threaded)" if name.endswith("_parallel") else ""
        return "arms of " + describe_kind(n, k) + threads + whole, _cache_dir(dispatcher)

    def _geometry(self, event) -> bool:
        """Whether the event compiles one of the whole-arm geometry helpers; says so at the first."""
        dispatcher = event.data.get("dispatcher")
        func = getattr(dispatcher, "py_func", None)
        if getattr(func, "__name__", "") not in GEOMETRY or getattr(func, "__module__", "") != \
                "pan1_env.kernels.team_geometry":
            return False
        if not self._geometry_told:
            self._geometry_told = True
            notify(f"compiling the whole-arm geometry helpers (joints, capsules, clearance between arms): once, "
                   f"a few seconds; cached in {_cache_dir(dispatcher)} for later runs")
        return True

    @staticmethod
    def _draw(event) -> bool:
        """Whether the event compiles the random-team draw (:mod:`pan1_env.draw_kernel`) or the circulation term
        (:mod:`pan1_env.kernels.circulation`); says so."""
        func = getattr(event.data.get("dispatcher"), "py_func", None)
        what = {("draw_teams", "pan1_env.draw_kernel"): "the random-team draw: once, about 7 s",
                ("group_circulation", "pan1_env.kernels.circulation"):
                    "the circulation term (action_mode='circulation'): once, a few seconds"}.get(
            (getattr(func, "__name__", ""), getattr(func, "__module__", "")))
        if what is None:
            return False
        notify(f"compiling {what} on a 2-core machine, longer on a busy one; "
               f"cached in {_cache_dir(event.data['dispatcher'])} for later runs")
        return True

    def on_start(self, event) -> None:
        if self._geometry(event) or self._draw(event):
            return
        found = self._kind(event)
        if found is None:
            return
        kind, cache = found
        self._started[id(event.data["dispatcher"])] = time.perf_counter()
        twice = "whole-arm safety" in kind
        if kind.startswith("all"):
            # measured 16 s (end-effector) and 28.5 s (whole-arm) beside two training runs at nice 15
            notify(f"compiling the generic sub-step kernel ({kind}): once, about {29 if twice else 16} s on a "
                   f"2-core machine; "
                   f"cached in {cache} for later runs. It steps new arm kinds at once, 3-4x slower than "
                   f"their own kernels, which compile in the background")
        else:
            # measured 11-15 s at a load average below 1 (kernels.specialise), 16-31 s on a busy machine
            notify(f"compiling the sub-step kernel for {kind}: once per arm kind, about "
                   f"{'20-30' if twice else '10-15'} s on a quiet 2-core machine, longer on a busy one; cached in "
                   f"{cache} for later runs (`pan1-env warmup` compiles ahead of time)")

    def on_end(self, event) -> None:
        found = self._kind(event)
        if found is None:
            return
        started = self._started.pop(id(event.data["dispatcher"]), None)
        # a failed compilation raises to the caller; numba 0.68's Event.is_failed reads inverted, so
        # look at the exception details the event carries
        if getattr(event, "_exc_details", None) is None:
            took = f" in {time.perf_counter() - started:.0f} s" if started is not None else ""
            what = f"the generic sub-step kernel ({found[0]})" if found[0].startswith("all") else \
                f"the sub-step kernel for {found[0]}"
            notify(f"compiled {what}{took}")


_INSTALLED = False


def install() -> None:
    """Register the notice with numba's compile events (once per process)."""
    global _INSTALLED
    if _INSTALLED:
        return
    numba_event.register("numba:compile", _KernelCompileNotice())
    _INSTALLED = True
