"""The operating modes of the simulated drives (0x6060, 0x6502): the reference each gives the servo loops.

* cyclic synchronous position (8): interpolates linearly to each SYNC's
  target over the interpolation period (0x60C2), the target rate as
  feed-forward;
* cyclic synchronous velocity (9): ramps to each SYNC's target velocity over
  one period;
* profile position (1): a trapezoid (0x6081, 0x6083, 0x6084), the set-point
  taken on the rising edge of controlword bit 4 (relative with bit 6), halt
  with bit 8;
* profile velocity (3): ramps to 0x60FF at 0x6083 up, 0x6084 down.

Any other mode is refused with abort 0x06090030; 0x6061 shows the mode in
force. A new mode starts from rest where the reference is.

Software position limits (0x607D) clamp position targets and brake the
velocity modes at 0x6085 so as to stop at the limit (statusword bit 11).
The references are :class:`.reference.Reference` segments.
"""

from __future__ import annotations

import numpy as np

from .. import cia402
from .reference import stop_segments, trapezoid, velocity_segments


class OperatingModes:
    """The simulator's operating modes (a part of :class:`.drives.DriveSimulator`: they set each axis'
    ``reference`` from its targets and parameters)."""

    def _latch_position(self, i: int, target_counts: int, now: float) -> None:
        """CSP: from the command now to the target over one interpolation period, then hold."""
        command, _ = self.reference.at_axis(i, now)
        target = target_counts / self.cpu.item(i)  # Python floats (the same arithmetic): cheaper at every SYNC
        clamped = min(max(target, self.limit_lo.item(i)), self.limit_hi.item(i))
        self.limit_active[i] = clamped != target
        period = self.period[i]
        rate = (clamped - command) / period
        self.reference.set(i, [(now, command, rate, 0.0), (now + period, clamped, 0.0, 0.0)])

    def _latch_velocity(self, i: int, now: float) -> None:
        """CSV: ramp to the target velocity over one interpolation period, then keep it."""
        p, v = self.reference.at(now)
        target = float(np.clip(self.target_velocity[i], -self.vmax[i], self.vmax[i]))
        period = self.period[i]
        a = (target - v[i]) / period
        segments = [(now, p[i], v[i], a), (now + period, p[i] + (v[i] + target) * period / 2, target, 0.0)]
        self.reference.set(i, segments)
        self._respect_limits(i, now)

    def _plan_velocity(self, i: int, now: float) -> None:
        """PV: ramp to 0x60FF (at 0x6083 up, 0x6084 down), limited by 0x607F; halt keeps it at rest."""
        p, v = self.reference.at(now)
        target = 0.0 if self.controlword[i] & cia402.CW_HALT else self.target_velocity[i]
        target = float(np.clip(target, -self.vmax[i], self.vmax[i]))
        self.inside_since[i] = np.inf
        segments = velocity_segments(now, p[i], v[i], target, self.profile_accel[i], self.profile_decel[i])
        self.reference.set(i, segments)
        self._respect_limits(i, now)

    def _profile_position_bits(self, i: int, controlword: int, previous: int, now: float) -> None:
        """PP: a new set-point on the rising edge of bit 4 (acknowledged in statusword bit 12)."""
        if controlword & cia402.CW_NEW_SET_POINT and not previous & cia402.CW_NEW_SET_POINT:
            node = self.nodes[self.ids[i]]
            target = int(node.value(0x607A)) / self.cpu[i]
            if controlword & cia402.CW_RELATIVE:
                target += self.target[i]
            self.target[i] = target
            self.set_point_ack[i] = True
            self.moving_to_target[i] = True
            if not controlword & cia402.CW_HALT:
                self._plan_position(i, now)
        elif not controlword & cia402.CW_NEW_SET_POINT:
            self.set_point_ack[i] = False

    def _plan_position(self, i: int, now: float) -> None:
        p, v = self.reference.at(now)
        goal = min(max(self.target[i], self.limit_lo[i]), self.limit_hi[i])
        self.limit_active[i] = goal != self.target[i]
        vmax = min(self.profile_velocity[i], self.vmax[i])
        segments = trapezoid(now, p[i], v[i], goal, vmax, self.profile_accel[i], self.profile_decel[i])
        self.reference.set(i, segments)
        self.inside_since[i] = np.inf

    def _respect_limits(self, i: int, now: float) -> None:
        """Keep the reference inside the software position limits: a target beyond them is clamped (position
        modes); a velocity mode brakes at 0x6085 so as to stop at the limit."""
        if not (np.isfinite(self.limit_lo[i]) or np.isfinite(self.limit_hi[i])):
            return
        if self.mode[i] == cia402.PP and self.moving_to_target[i]:
            self._plan_position(i, now)
            return
        if self.mode[i] == cia402.CSP:
            end = self.reference.p[i][np.isfinite(self.reference.t[i])][-1]
            if not self.limit_lo[i] <= end <= self.limit_hi[i]:
                self._latch_position(i, round(end * self.cpu[i]), now)
            return
        if self.mode[i] not in cia402.VELOCITY_MODES:
            return
        # velocity modes: find the first time the stopping point (p + v|v|/2d) reaches a limit
        decel = self.qs_decel[i]
        ref = self.reference
        times = ref.t[i][np.isfinite(ref.t[i])]
        horizon = max(times[-1], now) + 3600.0
        grid = np.concatenate([np.linspace(t0, t1, 65) for t0, t1 in zip(times, [*times[1:], horizon], strict=True)])
        grid = grid[grid >= now]
        p, v = ref.at(grid[:, None])
        p, v = p[:, i], v[:, i]
        stop_at = p + v * np.abs(v) / (2 * decel)
        beyond = (stop_at > self.limit_hi[i]) | (stop_at < self.limit_lo[i])
        if not np.any(beyond):
            self.limit_active[i] = False
            return
        k = int(np.argmax(beyond))
        if k == 0:
            t_brake = now
        else:
            lo, hi = grid[k - 1], grid[k]
            for _ in range(40):  # bisection on the crossing
                mid = 0.5 * (lo + hi)
                pm, vm = ref.at(np.array([[mid]]))
                s = pm[0, i] + vm[0, i] * abs(vm[0, i]) / (2 * decel)
                if self.limit_lo[i] <= s <= self.limit_hi[i]:
                    lo = mid
                else:
                    hi = mid
            t_brake = lo
        pb, vb = ref.at(np.array([[t_brake]]))
        kept = [(t, ref.p[i, j], ref.v[i, j], ref.a[i, j]) for j, t in enumerate(ref.t[i]) if t < t_brake]
        ref.set(i, kept[-2:] + stop_segments(t_brake, pb[0, i], vb[0, i], decel))
        self.limit_active[i] = True
