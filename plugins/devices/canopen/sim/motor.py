"""The motor model: how the reference a drive follows becomes where its axis actually goes.

The one seam between the drive's logic (state machine, operating modes,
:mod:`.statemachine`, :mod:`.modes`) and the physics: from the reference
(position and rate, :class:`.reference.Reference`) :meth:`MotorModel.integrate`
moves every axis through the substeps of a span of time, in one compiled
(numba) call: the simulated drives answer every SYNC, and Python arithmetic
on four-element arrays, substep by substep, cost them most of their time per
SYNC (about 0.3 ms at 500 Hz, measured in the drives' process).

Per substep: the encoder quantises the position to whole counts; the drive's
cascade is a proportional position loop (its correction capped at
``sqrt(a_peak |e|)``, so that it can always be braked) with the reference
rate as feed-forward, under the speed limit, and a proportional velocity loop
under the current limit (as the joint acceleration it allows); the motor is a
second-order model, inertia with viscous damping and an external load,
integrated with semi-implicit Euler steps of at most ``substep`` seconds.
The reference and the position compared with it for the following error are
those at the substep's start. An unpowered axis is held by its brake.

In cyclic synchronous torque (CiA 402 mode 10) there is no servo loop: the
drive's torque (``0x6071`` within ``0x6072``, thousandths of the motor's rated
torque ``0x6076``) times the gear ratio is a joint torque (N·m, or N on a
linear axis), and the axis is integrated under it and any external torque (a
hand on the instrument: a spring and damper toward where it is at the
substep's start):

    J q'' = τ_drive + τ_ext − b q' − c sign(q')

with the joint's inertia ``J`` (the motor's reflected through the gearing and
the link's), viscous friction ``b`` and Coulomb friction ``c``; Coulomb
friction never reverses a motion within a step, and holds a still axis whose
torque is below it (stiction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass
class MotorModel:
    """Servo loop and motor constants shared by the simulated axes."""

    #: position loop gain (1/s)
    position_gain: float = 150.0
    #: velocity loop gain (1/s)
    velocity_gain: float = 1000.0
    #: viscous damping over inertia (1/s)
    damping: float = 2.0
    #: largest integration step (s)
    substep: float = 5e-4
    #: an enabled drive in a cyclic synchronous mode without SYNC for this long performs 0x6007 (s);
    #: the power-on value of 0x2000
    sync_timeout: float = 0.05

    @classmethod
    def of(cls, simulation) -> MotorModel:
        """The model a device's ``simulation`` settings (:class:`..settings.SimulationSettings`) give."""
        return cls(simulation.position_gain, simulation.velocity_gain, sync_timeout=simulation.sync_timeout)

    def substeps(self, span: float) -> int:
        """How many integration steps cover ``span`` seconds (steps of at most ``substep``)."""
        return max(1, int(np.ceil(span / self.substep - 1e-9)))

    def integrate(self, axes, t0: float, span: float, reference, powered, torque_mode, monitored, drive_torque,
                  hand) -> np.ndarray:  # fmt: skip
        """Move ``axes`` (the simulator: its ``pos``, ``vel`` and following-error timers ``over_time``, changed in
        place) from time ``t0`` through ``span`` seconds; returns per axis whether its following error outlasted
        0x6066 (``window_time``) in a substep. ``powered`` (0.0 or 1.0: the brake holds where 0.0),
        ``torque_mode`` (cyclic synchronous torque, powered) and ``monitored`` (a position mode, enabled) per
        axis; ``drive_torque``: the drives' joint torques (torque mode); ``hand``: where the hand pulls the axes
        in torque mode (a :class:`.drives.HandMotion`: joint positions at an array of times), or None."""
        steps = self.substeps(span)
        dt = span / steps
        pulled = hand is not None
        where = hand(t0 + dt * np.arange(steps)) if pulled else _NO_HAND  # at each substep's start
        return _integrate(
            axes.pos, axes.vel, axes.over_time, t0, dt, steps,
            reference.t, reference.p, reference.v, reference.a,
            powered, torque_mode, monitored, axes.cpu, axes.vmax, axes.peak, axes.load, axes.window,
            axes.window_time, drive_torque, axes.inertia, axes.viscous, axes.coulomb,
            where, axes.hand_stiffness, axes.hand_damping, pulled,
            self.position_gain, self.velocity_gain, self.damping,
        )  # fmt: skip


_NO_HAND = np.zeros((1, 1))


@njit(cache=True, nogil=True)
def _integrate(pos, vel, over_time, t0, dt, steps, ref_t, ref_p, ref_v, ref_a, powered, torque_mode, monitored,
               cpu, vmax, peak, load, window, window_time, drive_torque, inertia, viscous, coulomb, hand, hand_k,
               hand_c, pulled, position_gain, velocity_gain, damping):  # pragma: no cover  # fmt: skip
    """:meth:`MotorModel.integrate`'s substeps (the arithmetic, operation for operation, of the numpy model it
    replaced: the same answers to the bit)."""
    n = pos.shape[0]
    tripped = np.zeros(n, dtype=np.bool_)
    segments = ref_t.shape[1]
    for k in range(steps):
        t = t0 + dt * k
        for i in range(n):
            # the reference at the substep's start: the last segment begun by then
            count = 0
            for j in range(segments):
                if ref_t[i, j] <= t:
                    count += 1
            s = max(count - 1, 0)
            tau = max(t - ref_t[i, s], 0.0)
            a, v = ref_a[i, s], ref_v[i, s]
            command = ref_p[i, s] + v * tau + 0.5 * a * tau * tau
            rate = v + a * tau
            p, w = pos[i], vel[i]
            if torque_mode[i]:
                external = load[i] * inertia[i]
                if pulled:
                    external = external + hand_k[i] * (hand[k, i] - p) - hand_c[i] * w
                torque = drive_torque[i] + external
                w = w + (torque - viscous[i] * w) / inertia[i] * dt
                slip = coulomb[i] / inertia[i] * dt
                w = np.sign(w) * max(abs(w) - slip, 0.0)
                p = p + w * dt
            else:
                measured = np.rint(p * cpu[i]) * (1.0 / cpu[i])  # the encoder
                error = command - measured
                magnitude = abs(error)
                correction = np.sign(error) * min(position_gain * magnitude, math.sqrt(peak[i] * magnitude))
                velocity_command = min(max(rate + correction, -vmax[i]), vmax[i])
                accel = min(max(velocity_gain * (velocity_command - w), -peak[i]), peak[i])
                w = (w + (accel - damping * w + load[i]) * dt) * powered[i]
                p = p + w * dt
            pos[i], vel[i] = p, w
            # following error (position modes): outside the window 0x6065 for longer than 0x6066
            if monitored[i] and abs(command - p) > window[i]:
                over_time[i] = over_time[i] + dt
            else:
                over_time[i] = 0.0
            if over_time[i] > window_time[i]:
                tripped[i] = True
    return tripped


def _compile() -> None:
    """Compile :func:`_integrate` (or load it from numba's cache) for the types the simulator passes, on import:
    a drives' process pays it at start-up, not at its first SYNC."""
    one, yes, segments = np.ones(1), np.ones(1, dtype=np.bool_), np.ones((1, 4))
    axes = (one, one, one, one, one, one, one, one, one, one)  # cpu .. coulomb
    _integrate(one.copy(), one.copy(), one.copy(), 0.0, 1e-3, 1, segments, segments, segments, segments, one, yes, yes,
               *axes, _NO_HAND, one, one, False, 1.0, 1.0, 1.0)  # fmt: skip


_compile()
