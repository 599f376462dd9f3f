"""Clocks and timers: a simulated clock for deterministic runs, and real time.

With :class:`SimulatedClock` time moves only when the control loop sleeps;
timers (the simulated drives' heartbeat producers, watchdogs, injected
faults) fire in time order as it does, and CAN frames are delivered at once
(see :class:`~surgiplan.plugins.devices.canopen.network.SimulationLink`). A run is then
deterministic and as fast as the computer allows: tests use it.

With :class:`RealTimeClock` the loop sleeps on the monotonic clock to each
deadline (with a 1 us timer slack, :meth:`RealTimeClock.precise`), and
simulated drives run in a thread of their own.
"""

from __future__ import annotations

import ctypes
import heapq
import itertools
import os
import struct
import threading
import time
from collections.abc import Callable
from typing import NamedTuple

#: the slice (s) a real-time loop's threads ask of the scheduler at ordinary priority (SCHED_OTHER): Linux's EEVDF
#: scheduler (6.12 and later) gives a waking task with a short slice an earlier deadline, so that it preempts a
#: task that has run longer instead of waiting for that one's slice (1.4 ms by default here) to end; its share of
#: the CPU is unchanged. 0.1 ms is the shortest the kernel grants.
LOOP_SLICE = 1e-4

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


class Timer:
    """A scheduled call, one-shot or periodic; also stands in for canopen's periodic CAN tasks."""

    def __init__(self, scheduler: Scheduler, due: float, period: float | None, action: Callable[[], None]) -> None:
        self.scheduler = scheduler
        self.due = due
        self.period = period
        self.action = action
        self.active = True

    def stop(self, *_args) -> None:
        self.active = False


class PeriodicFrame(Timer):
    """A CAN frame sent every ``period`` seconds (canopen's heartbeat producer uses it)."""

    def __init__(self, scheduler: Scheduler, due: float, period: float, send: Callable[[bytes], None], data) -> None:
        self.data = bytes(data or b"")
        super().__init__(scheduler, due, period, lambda: send(self.data))

    def update(self, data) -> None:
        self.data = bytes(data)


class Scheduler:
    """Timers in time order (ties in the order they were scheduled)."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Timer]] = []
        self._counter = itertools.count()
        self._lock = threading.Lock()

    def add(self, timer: Timer) -> Timer:
        with self._lock:
            heapq.heappush(self._heap, (timer.due, next(self._counter), timer))
        return timer

    def call_at(self, due: float, action: Callable[[], None]) -> Timer:
        return self.add(Timer(self, due, None, action))

    def call_every(self, period: float, action: Callable[[], None], first: float) -> Timer:
        return self.add(Timer(self, first, period, action))

    def next_due(self) -> float | None:
        with self._lock:
            while self._heap and not self._heap[0][2].active:
                heapq.heappop(self._heap)
            return self._heap[0][0] if self._heap else None

    def pop_due(self, now: float) -> Timer | None:
        """The next active timer due at or before ``now`` (rescheduled if periodic), or None."""
        with self._lock:
            while self._heap:
                due, _, timer = self._heap[0]
                if due > now:
                    return None
                heapq.heappop(self._heap)
                if not timer.active:
                    continue
                if timer.period is not None:
                    timer.due = due + timer.period
                    heapq.heappush(self._heap, (timer.due, next(self._counter), timer))
                return timer
            return None


class Clock:
    realtime: bool = False

    def now(self) -> float:
        raise NotImplementedError

    def sleep_until(self, t: float) -> None:
        raise NotImplementedError

    def sleep(self, seconds: float) -> None:
        self.sleep_until(self.now() + seconds)

    def precise(self) -> bool:
        """Prepare the calling thread to pace a loop (real time); nothing to do for a simulated clock."""
        return False


class SimulatedClock(Clock):
    """Deterministic time (s), starting at 0; ``sleep_until`` runs the timers due on the way."""

    realtime = False

    def __init__(self) -> None:
        self._now = 0.0
        self.scheduler = Scheduler()

    def now(self) -> float:
        return self._now

    def sleep_until(self, t: float) -> None:
        while True:
            due = self.scheduler.next_due()
            if due is None or due > t:
                break
            timer = self.scheduler.pop_due(due)
            if timer is None:
                continue
            self._now = max(self._now, due)
            timer.action()
        self._now = max(self._now, t)


class RealTimeClock(Clock):
    """Monotonic wall time (s) since construction.

    ``sleep_until`` sleeps to the deadline (and spins the last ``spin`` s, none by default). A thread that
    paces a loop calls :meth:`precise` first: on Linux it lowers the thread's timer slack from the default
    50 us to 1 us (``prctl(PR_SET_TIMERSLACK)``), so that the kernel wakes it when asked, not up to 50 us
    later. Spinning was measured worse than sleeping on a loaded machine: a thread that spins is a CPU hog
    the scheduler preempts (1 kHz with 4 runnable jobs on 2 cores: period p99 6.8 ms spinning 0.3 ms, 1.07
    ms sleeping with a 1 us slack), and a spinning thread holds the GIL the receive thread needs.
    """

    realtime = True

    def __init__(self, spin: float = 0.0) -> None:
        self._origin = time.perf_counter()
        self.spin = spin

    @staticmethod
    def precise() -> bool:
        """Timer slack 1 us for the calling thread (Linux); False where not available."""
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            return libc.prctl(29, 1000, 0, 0, 0) == 0  # PR_SET_TIMERSLACK, in ns
        except (OSError, AttributeError):
            return False

    def now(self) -> float:
        return time.perf_counter() - self._origin

    def sleep_until(self, t: float) -> None:
        for _ in range(3):  # time.sleep does not return early (an absolute monotonic deadline on Linux)
            remaining = t - self.now() - self.spin
            if remaining <= 0:
                break
            time.sleep(remaining)
        while self.spin > 0 and self.now() < t:
            pass
