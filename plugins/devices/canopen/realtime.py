"""What a real-time loop of the master's process needs around it: the control loop's trajectories
(:meth:`.control.Controller.run`) and the pose source's observe and assist loop of the CAST gimbal. In real time,
the body runs in :func:`surgiplan.scheduling.paced_section` with the garbage collector paused (a full collection
of the master's heap stops every thread of the process for 50-230 ms, measured in ``benchmarks/bench_devices.py``:
a run of missed SYNCs); with a simulated clock nothing changes (a deterministic run has no deadline to keep).
"""

from __future__ import annotations

import contextlib

from surgiplan.scheduling import paced_section

from .clock import Clock


@contextlib.contextmanager
def realtime_section(clock: Clock, priority: int | None = None, *, pause_collector: bool = True):
    """Run the body as a real-time loop on ``clock`` (see the module); raises OSError if SCHED_FIFO at
    ``priority`` is not allowed (before anything else changes). ``pause_collector`` False: the garbage collector
    keeps running (a benchmark measuring what it costs)."""
    if not clock.realtime:
        yield
        return
    with paced_section(priority, pause_collector=pause_collector):
        yield
