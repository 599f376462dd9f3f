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

import heapq
import itertools
import threading
import time
from collections.abc import Callable

from surgiplan.scheduling import (  # noqa: F401  (where the device plugins import them)
    LOOP_SLICE,
    SchedAttr,
    precise_timer_slack,
    restore_priority,
    sched_attr,
    set_realtime_priority,
)


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
        return precise_timer_slack()

    @property
    def origin(self) -> float:
        """This clock's time 0 on ``time.perf_counter`` (CLOCK_MONOTONIC on Linux): where its times meet other
        records of the machine (a kernel trace, another process's perf_counter)."""
        return self._origin

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
