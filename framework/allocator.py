"""The C allocator's policy for a surgiplan process: keep freed memory for the next allocation.

glibc hands large freed blocks back to the kernel: a block over its mmap threshold is a mapping of its own,
unmapped when freed, and free memory at the heap's top beyond the trim threshold is released. The next
allocation of that size then faults on every 4 KiB page it touches, and a fault is not cheap: 2.4 us a page on
the virtual machine our CI runs on, about 1,600 of them (near 4 ms) in a safe_prm build of R and R_safe at
5,000 milestones, where every array is new. Both thresholds adapt (each mapping freed raises them to its size),
but not far enough for a process that allocates and frees tens of megabytes per stage.

:func:`keep_freed_memory` sets them once for the whole process: blocks up to :data:`MMAP_THRESHOLD` come from
the heap, and up to :data:`TRIM_THRESHOLD` of free memory stays mapped for the next allocation. That is what
the Linux real-time community advises for latency-sensitive processes (keep the allocator from returning memory
to the kernel; "HOWTO build a simple RT application", the Linux Foundation's real-time wiki), at the cost of a
resident size that does not shrink back after a peak. ``surgiplan`` (the command line) applies it at start;
a program that embeds surgiplan decides for itself (the benchmarks apply it to the whole process, so surgiplan
and its peers run under the same policy). Elsewhere than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

#: glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: blocks up to this size come from the heap (glibc's largest allowed threshold on 64-bit systems)
MMAP_THRESHOLD = 32 << 20
#: free memory kept at the heap's top (and in each thread's arena) before any goes back to the kernel
TRIM_THRESHOLD = 256 << 20

_applied: str | None = None


def keep_freed_memory() -> str | None:
    """Apply the policy (once a process; later calls only answer). Returns what was set, as
    :func:`policy` says it, or None where the C library is not glibc or refused it."""
    global _applied
    if _applied is not None:
        return _applied
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return None
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    if mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) != 1 or mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) != 1:
        return None
    _applied = (
        f"glibc mallopt: M_MMAP_THRESHOLD {MMAP_THRESHOLD >> 20} MiB, M_TRIM_THRESHOLD {TRIM_THRESHOLD >> 20} MiB"
    )
    return _applied


def policy() -> str:
    """The allocator policy of this process, for a results file's provenance."""
    return _applied or "the C library's default"
