"""Compiled kernels side by side on a process's CPUs.

The compiled kernels (numba, ``nogil``) release the interpreter while they run, so two threads of one process run
two of them at once. :func:`in_parallel` runs a list of such calls, one on the caller's thread and the rest on a
small pool kept for the process (a thread's start costs about as much as a small kernel); :func:`cpu_threads` is
how many are worth it: the CPUs this process may run on, at most two (the work split this way comes in halves:
a roadmap's two landmark sets, a batch of points in two).

A call's answer never depends on the threads: each call writes its own outputs (or its own slice of one), and the
results come back in the order of the calls.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

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


def cpu_threads() -> int:
    """Threads worth splitting work into: 2 where this process may run on two CPUs or more, else 1."""
    return 2 if len(os.sched_getaffinity(0)) >= 2 else 1


def in_parallel(calls: Sequence[tuple[Callable, tuple]]) -> list[Any]:
    """Run ``calls`` (``(function, args)`` pairs; functions that spend their time in ``nogil`` kernels, so that
    they run at once) and return their results in order: the last on this thread, the others on the pool's. An
    exception of any call is raised here, after every call has ended."""
    global _POOL, _POOL_SIZE
    if len(calls) <= 1:
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
