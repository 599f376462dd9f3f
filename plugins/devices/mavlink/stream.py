"""The offboard setpoint stream of the ground station: the timed path, on a grid of the vehicle's clock.

Offboard control (PX4: setpoints at 2 Hz at least, and flowing before the
switch to offboard mode) sends SET_POSITION_TARGET_LOCAL_NED with position,
velocity and acceleration feed-forward. Each setpoint is the timed path
(:class:`~.mavlink_profile.TimedPath`) sampled at a vehicle time on a fixed
grid (every ``period``, 50 ms by default) and stamped with that time in
``time_boot_ms``; the stream keeps the grid filled up to ``lead`` (0.1 s)
beyond the newest LOCAL_POSITION_NED time stamp, every grid time once and in
order, so the vehicle has the setpoint for each instant before it gets
there, at any simulation speed.

Why a grid and not "answer each report": which reports arrive in one
pump of the link depends on scheduling; which grid times exist does not.
The simulated vehicle applies each setpoint at its stamp and waits for the
next (lockstep, :mod:`.mavlink_sim_offboard`), so the flight is a function
of the vehicle's clock alone. A real PX4 applies a setpoint on receipt
(the lead is then the link's latency allowed for).

A wall-clock keep-alive (every ``keepalive`` s) repeats the newest setpoint
when the vehicle's clock does not advance (a stalled simulation, lost
telemetry), so that the vehicle never sees the stream lapse.

The profile is sampled at its own time since the start, computed in whole
grid periods (``(index - start index) * period``), never as the difference
of two absolute vehicle times: that difference carries rounding that
depends on *when* the profile started, and the timed path's acceleration
jumps at its phase boundaries (a climb at 1 m/s^2 to 0.5 m/s ends exactly at
0.5 s, a grid time), so a boundary sampled at 0.4999999999999998 s instead
of 0.5 s sent a = 1 m/s^2 instead of 0 with that setpoint, and the vehicle,
extrapolating it over the next 50 ms, flew a different flight.
"""

from __future__ import annotations

import math

import numpy as np

from .profile import TimedPath

#: grid of setpoint times (ms of vehicle time; 20 Hz) and how far the stream runs ahead of the vehicle (ms)
PERIOD_MS = 50
LEAD_MS = 100
#: wall-clock keep-alive (s)
KEEPALIVE = 0.05
#: at most this many grid times per pump: more are due only when the vehicle ran ahead of us (not in
#: lockstep), and then the older ones are past anyway
BURST = 8


class SetpointStream:
    """A ticker for :attr:`GroundStation.tickers`: holds at ``hold`` (NED m), then flies ``profile`` from
    :meth:`begin` on."""

    def __init__(self, gcs, profile: TimedPath, hold, period_ms: int = PERIOD_MS, lead_ms: int = LEAD_MS) -> None:
        self.gcs = gcs
        self.profile = profile
        self.hold = np.asarray(hold, float)
        self.period_ms = int(period_ms)
        self.lead_ms = int(lead_ms)
        #: vehicle time (s) at which the profile starts (a grid time)
        self.start = math.inf
        #: ... as a grid index (the profile's own time is counted from it in whole periods)
        self.start_index: int | None = None
        self._last_index: int | None = None  # grid index of the newest setpoint sent
        self._last_wall = -math.inf
        self.sent = 0
        #: the vehicle's newest reported time (ms) when the first setpoint went out
        self._first_ms: int | None = None

    def _now_ms(self) -> int:
        return round(self.gcs.vehicle.vehicle_time * 1000)

    def flowing(self) -> float:
        """How long (s of vehicle time, by its newest report) setpoints have been going out; 0 before the first.

        What PX4's rule (setpoints flowing before the switch to offboard) is measured by: the time since the
        stream's first setpoint, not since some earlier report. Reports that queued while nobody pumped arrive
        in one burst; a wait on the vehicle's clock alone ends on such a burst with a single setpoint sent.
        """
        return 0.0 if self._first_ms is None else (self._now_ms() - self._first_ms) / 1000

    def begin(self) -> float:
        """Start the profile at the first grid time two leads after the vehicle's newest report (vehicle s):
        every setpoint already sent (at most one lead ahead) is still the hold."""
        self.start_index = -(-(self._now_ms() + 2 * self.lead_ms) // self.period_ms)
        self.start = self.start_index * self.period_ms / 1000
        return self.start

    def setpoints(self, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and acceleration (NED; m, m/s, m/s^2) at grid indices ``indices``
        (vehicle time ``index * period``)."""
        indices = np.atleast_1d(np.asarray(indices, np.int64))
        p = np.repeat(self.hold[None], len(indices), axis=0)
        v = np.zeros_like(p)
        a = np.zeros_like(p)
        if self.start_index is not None:
            flying = indices >= self.start_index
            if np.any(flying):
                since = (indices[flying] - self.start_index) * self.period_ms / 1000  # exact: see the docstring
                p[flying], v[flying], a[flying] = self.profile.sample(since)
        return p, v, a

    def __call__(self, messages, now: float) -> None:
        newest = (self._now_ms() + self.lead_ms) // self.period_ms
        first = newest if self._last_index is None else self._last_index + 1
        indices = np.arange(max(first, newest - BURST + 1), newest + 1)
        if not len(indices):
            if now - self._last_wall < KEEPALIVE or self._last_index is None:
                return
            indices = np.array([self._last_index])
        times = indices * self.period_ms / 1000
        p, v, a = self.setpoints(indices)
        gcs = self.gcs
        gcs.send([gcs.position_target(t, *x) for t, *x in zip(times, p, v, a, strict=True)])
        if self._first_ms is None:
            self._first_ms = self._now_ms()
        self._last_index = int(max(indices[-1], self._last_index if self._last_index is not None else indices[-1]))
        self._last_wall = now
        self.sent += len(indices)
