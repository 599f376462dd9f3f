"""What a real-time loop of the master's process needs around it, in one place for the loops that are not the
control loop's trajectories (:meth:`.control.Controller.run` does the same inline): the pose source's observe and
assist loop of the CAST gimbal.

Inside :func:`realtime_section`, in real time:

* the cyclic garbage collector is off and what exists at entry is frozen out of its sight (a full collection of
  the master's heap stops every thread of the process for 50-230 ms, measured in ``benchmarks/bench_devices.py``:
  a run of missed SYNCs); what the loop frees goes by reference counting, and the collector is back on, the heap
  unfrozen, at exit;
* the GIL's switch interval is :data:`.control.SWITCH_INTERVAL` (a thread holding the GIL makes the awake loop wait
  at most that long, not Python's 5 ms);
* the calling thread's timer slack is 1 us (:meth:`.clock.RealTimeClock.precise`);
* with a ``priority`` (the user's ``realtime_priority``), the calling thread runs under SCHED_FIFO at it.

With a simulated clock nothing changes (a deterministic run has no deadline to keep).
"""

from __future__ import annotations

import contextlib
import gc
import sys

from .clock import Clock, restore_priority, set_realtime_priority
from .control import SWITCH_INTERVAL


@contextlib.contextmanager
def realtime_section(clock: Clock, priority: int | None = None):
    """Run the body as a real-time loop on ``clock`` (see the module); raises OSError if SCHED_FIFO at
    ``priority`` is not allowed (before anything else changes)."""
    if not clock.realtime:
        yield
        return
    previous = set_realtime_priority(priority)
    switch = sys.getswitchinterval()
    collecting = gc.isenabled()
    frozen = gc.get_freeze_count()
    try:
        clock.precise()
        gc.disable()
        gc.freeze()
        sys.setswitchinterval(SWITCH_INTERVAL)
        yield
    finally:
        sys.setswitchinterval(switch)
        if gc.get_freeze_count() > frozen and not frozen:  # frozen here, not by an activated device before
            gc.unfreeze()
        if collecting:
            gc.enable()
        restore_priority(previous)
