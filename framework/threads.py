"""Compiled kernels side by side on a process's CPUs.

The compiled kernels (numba, ``nogil``) release the interpreter while they run, so two threads of one process run
two of them at once. :func:`in_parallel` runs a list of such calls, one on the caller's thread and the rest on a
small pool kept for the process (a thread's start costs about as much as a small kernel); :func:`cpu_threads` is
how many are worth it: the CPUs this process may run on, at most two (the work split this way comes in halves:
a roadmap's two landmark sets, a batch of points in two).

A caller limits the threads of everything below it with :func:`thread_budget` (``threads: 1`` in a planner's
settings keeps its whole build on the caller's thread). A real-time caller (SCHED_FIFO or SCHED_RR) always runs its
calls itself: the pool's threads run at ordinary priority, and a real-time thread waiting on them would wait for
whatever preempts them (a priority inversion).

A call's answer never depends on the threads: each call writes its own outputs (or its own slice of one), and the
results come back in the order of the calls.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

#: the threads a caller allowed the work below it (:func:`thread_budget`); None: as the CPUs allow
_BUDGET: ContextVar[int | None] = ContextVar("surgiplan_thread_budget", default=None)
#: scheduling policies under which this thread runs its calls itself (the pool's threads run at ordinary priority)
_REAL_TIME = frozenset(getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name))

#: the pool's threads (the caller's thread runs one call besides them), started on first use
_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0


def _forget_pool() -> None:
    """In a child made by fork: the parent's pool came without its threads (fork copies only the calling thread),
    and work handed to it would wait forever; the child starts a pool of its own when it needs one."""
    global _POOL, _POOL_SIZE
    _POOL, _POOL_SIZE = None, 0


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def _real_time() -> bool:
    """Whether the calling thread runs under a real-time policy (Linux: pid 0 names the calling thread)."""
    try:
        return os.sched_getscheduler(0) in _REAL_TIME
    except (AttributeError, OSError):  # no such call on this platform
        return False


def cpu_threads() -> int:
    """Threads worth splitting work into: the caller's :func:`thread_budget` if one is set, else 2 where this
    process may run on two CPUs or more and 1 otherwise; always 1 on a real-time thread."""
    if _real_time():
        return 1
    budget = _BUDGET.get()
    if budget is not None:
        return budget
    return 2 if len(os.sched_getaffinity(0)) >= 2 else 1


def threads_or_default(threads: int | None) -> int:
    """A setting's thread count: None is :func:`cpu_threads`, anything else at least 1."""
    return cpu_threads() if threads is None else max(int(threads), 1)


@contextmanager
def thread_budget(threads: int | None) -> Iterator[int]:
    """Within the block, :func:`cpu_threads` answers ``threads`` (None: as it would anyway) and
    :func:`in_parallel` runs its calls on this thread alone when that is 1. Yields the budget."""
    budget = threads_or_default(threads)
    token = _BUDGET.set(budget)
    try:
        yield budget
    finally:
        _BUDGET.reset(token)


def in_parallel(calls: Sequence[tuple[Callable, tuple]]) -> list[Any]:
    """Run ``calls`` (``(function, args)`` pairs; functions that spend their time in ``nogil`` kernels, so that
    they run at once) and return their results in order: the last on this thread, the others on the pool's. An
    exception of any call is raised here, after every call has ended. Under a budget of one thread, or on a
    real-time thread, every call runs on this thread, one after the other (the same results)."""
    global _POOL, _POOL_SIZE
    if len(calls) <= 1 or cpu_threads() == 1:
        return [function(*args) for function, args in calls]
    if _POOL is None or _POOL_SIZE < len(calls) - 1:
        _POOL_SIZE = len(calls) - 1
        _POOL = ThreadPoolExecutor(max_workers=_POOL_SIZE, thread_name_prefix="surgiplan-kernels")
    futures = [_POOL.submit(function, *args) for function, args in calls[:-1]]
    function, args = calls[-1]
    try:
        last = function(*args)
    finally:
        done = [future.exception() is None for future in futures]  # waits for every call
    if not all(done):
        raise next(future.exception() for future in futures if future.exception() is not None)
    return [future.result() for future in futures] + [last]
