"""The simulated vehicle's offboard setpoints: which one is in force, and the lockstep with the ground station.

A SET_POSITION_TARGET_LOCAL_NED carries ``time_boot_ms``. surgiplan's ground
station (:mod:`.mavlink_flight`) stamps each setpoint with the *vehicle*
time it is for (the vehicle's clock as its LOCAL_POSITION_NED reports it),
on a fixed grid of that clock, a little ahead of the newest report. The
simulated vehicle honours the stamps:

* **in force**: at vehicle time t the reference is the setpoint with the
  latest stamp s <= t, extrapolated to t with its own velocity and
  acceleration; setpoints for later times wait until the clock reaches them.
  The reference is then a function of the vehicle's clock alone, never of
  when a datagram happened to arrive.
* **lockstep** (as PX4 SITL's lockstep with its simulator, here with the
  ground station that closes the loop): in offboard mode the physics never
  advances past the newest stamp received. A machine too loaded to serve the
  ground station in time slows the flight down; it cannot change it. With
  the grid stream, the same seed gives the same flight, bit for bit, however
  the two processes are scheduled (``tests/test_mavlink_sim.py`` flies one
  with a ground station that stalls at random and compares).

Stamps that are not on the vehicle's clock (a ground station that sends its
own uptime, as MAVSDK does, or none) are recognised by being far from it:
such a setpoint applies on receipt, as PX4 applies every setpoint, and takes
no part in the lockstep. A real PX4 ignores ``time_boot_ms`` altogether; the
ground station's lead (0.1 s) is then the latency it allows for.

Offboard loss (PX4's COM_OF_LOSS_T): with lockstep the vehicle's clock stops
when the stream stops, so the loss is judged on the wall clock (no setpoint
received for ``offboard_timeout`` s); without it, on the vehicle's clock.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

#: a stamp more than this ahead of the vehicle's clock is not on it (s); surgiplan leads by 0.1 s
FUTURE = 0.5
#: ... or more than this behind it (s of vehicle time: a free-running simulation at 20x real time
#: gets this far ahead of a ground station that stalls for half a second)
PAST = 10.0
#: extrapolation of a setpoint beyond its stamp is limited to this (s): a stream that stalls
#: without lockstep holds near its last setpoint instead of flying off along its velocity
EXTRAPOLATION = 0.5


@dataclass(frozen=True)
class Setpoint:
    """A position target for vehicle time ``time`` (s): position (m), velocity (m/s), acceleration (m/s^2), NED."""

    time: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class OffboardSetpoints:
    """The setpoints a ground station streams, as the simulated vehicle uses them (see the module docstring)."""

    def __init__(self, timeout: float, lockstep: bool = True, horizon: float = 0.0) -> None:
        #: offboard loss after this many seconds without a setpoint (wall s with lockstep, else vehicle s)
        self.timeout = timeout
        self.lockstep = lockstep
        #: how far (s) the lockstepped clock may run past the newest stamp (0: never; deterministic)
        self.horizon = horizon
        self.current: Setpoint | None = None
        self._pending: list[Setpoint] = []  # stamped for later vehicle times, in time order
        #: the newest stamp on the vehicle's clock (s); what the lockstep waits for
        self.newest = -math.inf
        #: wall time (s, time.monotonic) of the last setpoint received
        self.received_wall = -math.inf
        self.received = 0
        #: setpoints whose stamp was not on the vehicle's clock (applied on receipt)
        self.unstamped = 0

    # ------------------------------------------------------------------ receiving
    def receive(self, setpoint: Setpoint, t: float, now: float) -> None:
        """Take a setpoint that arrived at vehicle time ``t`` (s) and wall time ``now`` (s)."""
        self.received += 1
        self.received_wall = now
        if not (t - PAST <= setpoint.time <= t + FUTURE):
            # not our clock: in force from now on, as PX4 takes every setpoint
            self.unstamped += 1
            self._pending.clear()
            self.newest = -math.inf  # nothing to lockstep to
            self.current = Setpoint(t, setpoint.position, setpoint.velocity, setpoint.acceleration)
            return
        self.newest = max(self.newest, setpoint.time)
        if self.current is not None and setpoint.time <= self.current.time:
            if setpoint.time == self.current.time:
                self.current = setpoint  # sent again (a keep-alive): the newer word counts
            return  # late: a newer one is already in force
        times = [s.time for s in self._pending]
        i = bisect.bisect_left(times, setpoint.time)
        if i < len(times) and times[i] == setpoint.time:
            self._pending[i] = setpoint
        else:
            self._pending.insert(i, setpoint)

    # ------------------------------------------------------------------ using
    def in_force(self, t: float) -> Setpoint | None:
        """The setpoint in force at vehicle time ``t`` (s): the latest stamped at or before it."""
        pending = self._pending
        while pending and pending[0].time <= t + 1e-9:
            self.current = pending.pop(0)
        if self.current is None and pending:
            return pending[0]  # none due yet (the stream has just begun): the earliest, extrapolated back
        return self.current

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration references at vehicle time ``t``: the setpoint in force,
        extrapolated from its stamp at constant acceleration (at most :data:`EXTRAPOLATION` s)."""
        s = self.in_force(t)
        h = min(max(t - s.time, -EXTRAPOLATION), EXTRAPOLATION)
        return (
            s.position + s.velocity * h + 0.5 * s.acceleration * h * h,
            s.velocity + s.acceleration * h,
            s.acceleration,
        )

    def lockstep_limit(self) -> float:
        """The vehicle time (s) the physics may advance to now: the newest stamp (plus the horizon)."""
        if not self.lockstep or self.newest == -math.inf:
            return math.inf
        return self.newest + self.horizon

    def fresh(self, now: float) -> bool:
        """A setpoint came within the timeout (wall clock): PX4's condition for offboard mode and arming."""
        return self.received > 0 and now - self.received_wall < self.timeout

    def stale(self, t: float, now: float) -> bool:
        """Offboard loss: no setpoint for longer than the timeout (see the module docstring)."""
        if self.lockstep:
            return now - self.received_wall > self.timeout
        last = max(self.newest, self.current.time if self.current is not None else -math.inf)
        return t - last > self.timeout
