"""Scheduling a thread that paces real time: SCHED_FIFO where allowed, or a short slice at ordinary priority.

A loop that must wake on time (a CiA 402 control loop, a guide stage following samples paced at 100 per second)
competes for the CPU with whatever else runs: a browser rendering the live view, a simulated bus. At ordinary
priority, Linux's EEVDF scheduler (6.12 and later) lets a thread ask for a shorter slice: its wake-ups then get an
earlier deadline and preempt a task that has run longer, with the same share of the CPU as before. Under
SCHED_FIFO (CAP_SYS_NICE) it preempts every ordinary task.

A thread woken on time is not yet running: an idle CPU that was halted must come out of its idle state first, and
on a virtual machine a halted virtual CPU is the hypervisor's to run again (``benchmarks/schedtrace.py`` measures
that delivery: 0.5 ms and more, often). A paced section can ask the kernel, through its PM QoS interface
(``/dev/cpu_dma_latency``, as ``cyclictest`` from rt-tests does), for a CPU wake-up latency: with 0, idle CPUs
poll instead of halting for as long as the section runs. It does not by default (:data:`CPU_LATENCY_US`): set
:data:`CPU_LATENCY_ENV` to ask. On the 2-CPU KVM guest the benchmarks run on, polling CPUs were preempted by the
host several times a second (the host sees them always busy): in interleaved runs of 10 s, 0 of 20 were free of
missed cycles with the request, 8 of 20 without, though the request cut the wake-up jitter's p99 from 0.15-2.1 ms
to 0.04-0.07 ms. On a machine of one's own (no hypervisor), deep idle states are what delay a wake-up, and the
request is the usual cure.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
import struct
import sys
from typing import NamedTuple

#: the slice (s) a real-time loop's threads ask of the scheduler at ordinary priority (SCHED_OTHER): Linux's EEVDF
#: scheduler (6.12 and later) gives a waking task with a short slice an earlier deadline, so that it preempts a
#: task that has run longer instead of waiting for that one's slice (1.4 ms by default here) to end; its share of
#: the CPU is unchanged. 0.1 ms is the shortest the kernel grants.
LOOP_SLICE = 1e-4

#: the CPU wake-up latency (us) a paced section asks for (:func:`cpu_latency_request`) unless :data:`CPU_LATENCY_ENV`
#: says otherwise: None, no request (see the module: on a virtual machine it cost more clean runs than it saved)
CPU_LATENCY_US: int | None = None

#: the environment variable that overrides :data:`CPU_LATENCY_US` for every paced section of a run: a whole number
#: of microseconds (0: idle CPUs poll while a paced section runs), or ``off`` for no request
CPU_LATENCY_ENV = "SURGIPLAN_CPU_LATENCY_US"

#: the kernel's PM QoS CPU latency interface: a request holds while its file stays open
#: (the kernel's Documentation/power/pm_qos_interface.rst)
CPU_LATENCY_FILE = "/dev/cpu_dma_latency"

#: struct sched_attr, its first version
_SCHED_ATTR = struct.Struct("<IIQiIQQQ")


class SchedAttr(NamedTuple):
    """A thread's scheduling attributes (Linux's struct sched_attr; ``runtime``: its slice at ordinary priority, ns)."""

    size: int
    policy: int
    flags: int
    nice: int
    priority: int
    runtime: int
    deadline: int
    period: int


#: sched_setattr and sched_getattr (Linux system call numbers per architecture)
_SCHED_ATTR_CALLS = {"x86_64": (314, 315), "aarch64": (274, 275)}


def set_realtime_priority(priority: int | None, thread_id: int = 0) -> tuple[int, int] | SchedAttr | None:
    """Run a thread (``thread_id``: its native id; 0: the calling thread) under SCHED_FIFO at ``priority``
    (1-99), as a controller with real-time scheduling runs its control loop (Linux; needs CAP_SYS_NICE).
    ``priority`` None: ordinary scheduling, an ordinary thread asking for a short slice (:data:`LOOP_SLICE`;
    where the system has no such request, or the thread is not ordinary, nothing changes).

    Returns what to restore with :func:`restore_priority` (None: nothing changed). Raises PermissionError or
    OSError where SCHED_FIFO is not allowed.
    """
    if priority is None:
        return _ask_slice(thread_id, LOOP_SLICE)
    previous = (os.sched_getscheduler(thread_id), os.sched_getparam(thread_id).sched_priority)
    os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(priority))
    return previous


def restore_priority(previous: tuple[int, int] | SchedAttr | None, thread_id: int = 0) -> None:
    if previous is None:
        return
    if isinstance(previous, SchedAttr):  # a slice asked for: the attributes as they were
        sched_attr(thread_id, previous)
    else:
        os.sched_setscheduler(thread_id, previous[0], os.sched_param(previous[1]))


@contextlib.contextmanager
def helpers_scheduled(priority: int | None, thread_ids):
    """For the body, the threads ``thread_ids`` (native ids) that a paced loop depends on (a live feed's sender)
    under its scheduling: SCHED_FIFO one below ``priority`` (at least 1), so that the loop still preempts them, and
    so that no ordinary task preempts them while they hold Python's GIL, which the loop would wait for until they
    ran again; ``priority`` None: the short slice the loop asks for. Restored at exit; a thread that has ended
    meanwhile is left alone."""
    helper = None if priority is None else max(1, priority - 1)
    previous = []
    try:
        for tid in thread_ids:
            try:
                previous.append((tid, set_realtime_priority(helper, tid)))
            except ProcessLookupError:  # ended already
                continue
        yield
    finally:
        for tid, before in previous:
            with contextlib.suppress(ProcessLookupError):
                restore_priority(before, tid)


def sched_attr(thread_id: int = 0, attr: SchedAttr | None = None) -> SchedAttr | None:
    """A thread's scheduling attributes (``attr`` None), or set them to ``attr``; None where the system cannot."""
    calls = _SCHED_ATTR_CALLS.get(os.uname().machine) if hasattr(os, "uname") else None
    if calls is None:
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if attr is not None:
            done = libc.syscall(calls[0], thread_id, ctypes.create_string_buffer(_SCHED_ATTR.pack(*attr)), 0) == 0
            return attr if done else None
        buffer = ctypes.create_string_buffer(_SCHED_ATTR.size)
        if libc.syscall(calls[1], thread_id, buffer, _SCHED_ATTR.size, 0) != 0:
            return None
    except (OSError, AttributeError):
        return None
    return SchedAttr(*_SCHED_ATTR.unpack(buffer.raw))


def _ask_slice(thread_id: int, slice_s: float) -> SchedAttr | None:
    """An ordinary thread's slice set to ``slice_s``; returns its attributes before, None if nothing changed."""
    previous = sched_attr(thread_id)
    if previous is None or previous.policy != os.SCHED_OTHER:
        return None
    wanted = previous._replace(size=_SCHED_ATTR.size, flags=0, runtime=round(slice_s * 1e9))
    return previous if sched_attr(thread_id, wanted) is not None else None


#: :class:`SlackCollector`: how many times the collector's first threshold a loop with samples always waiting may
#: let its young generation grow before a pass runs anyway (a bound on memory, should the loop never be idle)
BACKLOG_FACTOR = 8


class SlackCollector:
    """The cyclic garbage collector's passes over the young generations, run where a paced loop has time to spare
    (after a cycle's work, before the next one is due) instead of wherever an allocation happens to cross the
    collector's threshold, in the middle of a cycle, in whichever thread made it (a pass holds the GIL: every thread
    of the process waits for it; 0.25 ms a generation-0 pass of a guide attempt, 1-2 ms beside a live page, 2-8 ms a
    generation-1 pass).

    For a loop in :func:`paced_section` with ``pause_collector`` (the automatic passes off): call it once a cycle,
    when the cycle's work is done. It follows CPython's own rule for when a pass is due and which: a pass once
    ``gc.get_count()[0]`` (allocations less deallocations of tracked objects since the last pass) exceeds the
    first threshold, of generation 1 instead of 0 once more than the second threshold of generation-0 passes have
    run since the last generation-1 pass. ``idle`` False (work is already waiting): the pass waits until the young
    generation has grown to :data:`BACKLOG_FACTOR` times the threshold. The oldest generation is left to the end of
    the section, so the loop may run for hours: what a full pass finds (cycles of objects that outlived two young
    passes, then became garbage) waits for it."""

    def __init__(self) -> None:
        self.threshold, self.every, _ = gc.get_threshold()
        #: the passes this collector ran, per generation (0 and 1)
        self.passes = [0, 0]

    def __call__(self, idle: bool = True) -> int | None:
        """Run the pass that is due, if one is; returns its generation (None: none due)."""
        young, middle, _ = gc.get_count()
        if young <= (self.threshold if idle else BACKLOG_FACTOR * self.threshold) or self.threshold == 0:
            return None
        generation = 1 if middle > self.every else 0
        gc.collect(generation)
        self.passes[generation] += 1
        return generation


#: the GIL's switch interval (s) while a paced loop runs (Python's default: 5 ms): a thread that runs Python keeps the
#: GIL up to this long while the loop, awake, waits for it
SWITCH_INTERVAL = 0.0002


def precise_timer_slack() -> bool:
    """Timer slack 1 us for the calling thread (Linux; the default 50 us lets the kernel wake a sleeper up to 50 us
    late to batch wake-ups); False where not available."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(29, 1000, 0, 0, 0) == 0  # PR_SET_TIMERSLACK, in ns
    except (OSError, AttributeError):
        return False


@contextlib.contextmanager
def cpu_latency_request(microseconds: int | None = None):
    """Hold a PM QoS CPU latency request of ``microseconds`` for the body (Linux's :data:`CPU_LATENCY_FILE`; the
    kernel keeps the lowest request of all its holders, and drops one when its holder closes the file, or dies):
    no CPU enters an idle state slower than that to leave. None: :data:`CPU_LATENCY_ENV` if set, else
    :data:`CPU_LATENCY_US`. Yields whether the request holds: False where the file cannot be opened (not Linux,
    or not root: the file is root's, mode 0600) or the environment says ``off``, and then nothing changed.
    Raises :class:`surgiplan.errors.ConfigError` for a malformed :data:`CPU_LATENCY_ENV`."""
    if microseconds is None:
        microseconds = cpu_latency_setting()
    if microseconds is None:
        yield False
        return
    try:
        fd = os.open(CPU_LATENCY_FILE, os.O_WRONLY | os.O_CLOEXEC)
    except OSError:
        yield False
        return
    try:
        held = os.write(fd, struct.pack("i", microseconds)) == 4
    except OSError:
        held = False
    try:
        yield held
    finally:
        os.close(fd)


def cpu_latency_setting() -> int | None:
    """The CPU wake-up latency (us) paced sections ask for: :data:`CPU_LATENCY_ENV` if set (None for ``off``),
    else :data:`CPU_LATENCY_US`. Raises :class:`surgiplan.errors.ConfigError` naming the variable when it is
    neither a whole number of microseconds (0 or more) nor ``off``."""
    text = os.environ.get(CPU_LATENCY_ENV, "").strip()
    if not text:
        return CPU_LATENCY_US
    if text.lower() == "off":
        return None
    # ASCII digits only: str.isdigit also takes '²', which int() refuses with a ValueError instead of this message
    if not (text.isascii() and text.isdigit()) or int(text) > 2_000_000_000:
        from .errors import ConfigError

        raise ConfigError(
            f"environment variable {CPU_LATENCY_ENV}={text!r}: expected a whole number of microseconds "
            "(0 to 2000000000; 0 keeps idle CPUs polling) or 'off' (no request)"
        )
    return int(text)


def cpu_latency_now() -> int | None:
    """The CPU latency (us) the kernel keeps now, the lowest of every holder's request (its default where nobody
    asks: 2,000 s); None where it cannot be read."""
    try:
        with open(CPU_LATENCY_FILE, "rb") as f:
            return struct.unpack("i", f.read(4))[0]
    except (OSError, struct.error):
        return None


@contextlib.contextmanager
def paced_section(
    priority: int | None = None,
    *,
    pause_collector: bool = False,
    switch_interval: float | None = SWITCH_INTERVAL,
):
    """Run the body as a loop that keeps real time, on the calling thread:

    * with a ``priority``, under SCHED_FIFO at it (raises OSError where not allowed, before anything changes);
      without, a short slice at ordinary priority (:data:`LOOP_SLICE`);
    * the thread's timer slack 1 us (:func:`precise_timer_slack`);
    * the GIL's switch interval ``switch_interval`` (process-wide, restored at exit; None: Python's). A loop that
      mostly sleeps wants it short (woken, it waits at most that long for a thread running Python); a loop that
      computes as long as the other threads wants it long (a short one makes its own work hand the GIL over
      every 0.2 ms);
    * a CPU wake-up latency of :data:`CPU_LATENCY_US` (none by default; :data:`CPU_LATENCY_ENV` sets one, where
      allowed: :func:`cpu_latency_request`; a malformed value raises ConfigError before anything changes);
    * ``pause_collector``: the cyclic garbage collector off and what exists at entry frozen out of its sight (a full
      collection of a large heap stops every thread of the process for tens of milliseconds); what the loop frees
      goes by reference counting; the collector back on and the heap unfrozen at exit. For bounded loops (a
      trajectory, a device's session), or for a loop of any length that runs a :class:`SlackCollector` in its idle
      time.
    """
    latency_us = cpu_latency_setting()  # a malformed setting is refused before anything changes
    previous = set_realtime_priority(priority)
    switch = sys.getswitchinterval()
    collecting = gc.isenabled()
    # freeze here only a heap not frozen already (a device's, at activation, stays as its owner froze it)
    freezing = pause_collector and not gc.get_freeze_count()
    latency = contextlib.ExitStack()
    try:
        if latency_us is not None:
            latency.enter_context(cpu_latency_request(latency_us))
        precise_timer_slack()
        if pause_collector:
            gc.disable()
        if freezing:
            gc.freeze()
        if switch_interval is not None:
            sys.setswitchinterval(switch_interval)
        yield
    finally:
        latency.close()
        sys.setswitchinterval(switch)
        if freezing:  # frozen here, not by someone before
            gc.unfreeze()
        if pause_collector:
            if collecting:
                gc.enable()
        restore_priority(previous)
