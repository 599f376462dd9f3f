"""Clocks and timers: a simulated clock for deterministic runs, and real time.

With :class:`SimulatedClock` time moves only when the control loop sleeps;
timers (the simulated drives' heartbeat producers, watchdogs, injected
faults) fire in time order as it does, and CAN frames are delivered at once
(see :class:`~surgiplan.plugins.devices.canopen.cia402.SimulationLink`). A run is then
deterministic and as fast as the computer allows: tests use it.

With :class:`RealTimeClock` the loop sleeps on the monotonic clock (a coarse
``time.sleep`` followed by a short spin for the last fraction of a
millisecond, for a steady period), and simulated drives run in a thread of
their own.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections.abc import Callable


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
    """Monotonic wall time (s) since construction; sleeps coarse, then spins the last ``spin`` s."""

    realtime = True

    def __init__(self, spin: float = 0.0003) -> None:
        self._origin = time.perf_counter()
        self.spin = spin

    def now(self) -> float:
        return time.perf_counter() - self._origin

    def sleep_until(self, t: float) -> None:
        remaining = t - self.now()
        if remaining > self.spin:
            time.sleep(remaining - self.spin)
        while self.now() < t:
            pass
