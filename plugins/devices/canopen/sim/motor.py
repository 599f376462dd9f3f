"""The motor model: how the reference a drive follows becomes where its axis actually goes.

The one seam between the drive's logic (state machine, operating modes,
:mod:`.statemachine`, :mod:`.modes`) and the physics: from the reference
(position and rate, :class:`.reference.Reference`) :meth:`MotorModel.integrate`
moves every axis through the substeps of a span of time, in one compiled
(numba) call: the simulated drives answer every SYNC, and numpy arithmetic
on four-element arrays, substep by substep, was most of their time per SYNC
(0.25-0.37 ms a 2 ms advance of four axes in torque mode with a hand, against
0.02-0.04 ms compiled).

Per substep: the encoder quantises the position to whole counts; the drive's
cascade is a proportional position loop (its correction capped at
``sqrt(a_peak |e|)``, so that it can always be braked) with the reference
rate as feed-forward, under the speed limit, and a proportional velocity loop
under the current limit (as the joint acceleration it allows); the motor is a
second-order model, inertia with viscous damping and an external load,
integrated with semi-implicit Euler steps of at most ``substep`` seconds.
The servo follows the reference at the substep's start; the following error
compares that command with the position at the substep's end. An unpowered
axis is held by its brake.

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

from .. import cia402
from .statemachine import OE, QS


class HandMotion:
    """Where a simulated trainee's hand holds the axes: ``joints`` (one row per time, one column per axis) at
    ``times`` (s after ``start``, a clock time; None: not started, where the first row is), linear in between and
    held beyond the ends (as ``np.interp``). Called with a clock time it gives the axes' positions, with an array
    of times one row per time. The motor model pulls axes in torque mode toward it (:meth:`MotorModel.integrate`)."""

    def __init__(self, times, joints, start: float | None = None) -> None:
        self.times = np.ascontiguousarray(times, dtype=float)
        self.joints = np.ascontiguousarray(joints, dtype=float)
        self.start = start

    def __call__(self, t) -> np.ndarray:
        u = np.asarray(t, dtype=float) - self.start if self.start is not None else np.zeros(np.shape(t))
        out = np.empty((*u.shape, self.joints.shape[1]))
        rows, where = out.reshape(-1, self.joints.shape[1]), u.reshape(-1)
        for k in range(len(where)):
            _hand_at(self.times, self.joints, where[k], rows[k])
        return out


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
        return max(1, math.ceil(span / self.substep - 1e-9))

    def integrate(self, axes, t0: float, span: float) -> np.ndarray:
        """Move the simulator's axes (``axes``: its ``pos``, ``vel``, following-error timers ``over_time`` and
        ``torque_actual``, changed in place) from time ``t0`` through ``span`` seconds, as their state (powered in
        OPERATION ENABLED and QUICK STOP ACTIVE, unless dead), mode, reference and targets say; returns per axis
        whether its following error (a position mode, enabled) outlasted 0x6066 (``window_time``) in a substep."""
        steps = self.substeps(span)
        hand = axes.hand
        pulled = hand is not None
        return _integrate(
            axes.pos, axes.vel, axes.over_time, axes.torque_actual, t0, span / steps, steps,
            axes.reference.t, axes.reference.p, axes.reference.v, axes.reference.a,
            axes.state, axes.alive, axes.mode, axes.target_torque, axes.max_torque, axes.torque_unit,
            axes.cpu, axes.vmax, axes.peak, axes.load, axes.window, axes.window_time,
            axes.inertia, axes.viscous, axes.coulomb, axes.hand_stiffness, axes.hand_damping,
            hand.times if pulled else _NO_TABLE[0], hand.joints if pulled else _NO_TABLE[1],
            hand.start if pulled and hand.start is not None else 0.0, pulled, pulled and hand.start is not None,
            self.position_gain, self.velocity_gain, self.damping,
        )  # fmt: skip


_NO_TABLE = (np.zeros(1), np.zeros((1, 1)))
_PP, _CSP, _CST = int(cia402.PP), int(cia402.CSP), int(cia402.CST)


@njit(cache=True, nogil=True)
def _hand_at(times, joints, u, out):  # pragma: no cover
    """``out`` = the table's row at ``u``, interpolated per column: ``np.interp``'s arithmetic (the same answers to
    the bit: ``times`` increasing, held at the ends)."""
    n = times.shape[0]
    if u > times[n - 1]:
        out[:] = joints[n - 1]
        return
    if u < times[0]:
        out[:] = joints[0]
        return
    j = np.searchsorted(times, u, side="right") - 1  # times[j] <= u < times[j + 1] (j = n - 1 at the end)
    if j == n - 1 or times[j] == u:
        out[:] = joints[j]
        return
    for k in range(joints.shape[1]):
        slope = (joints[j + 1, k] - joints[j, k]) / (times[j + 1] - times[j])
        out[k] = slope * (u - times[j]) + joints[j, k]
        if np.isnan(out[k]):
            out[k] = slope * (u - times[j + 1]) + joints[j + 1, k]
            if np.isnan(out[k]) and joints[j, k] == joints[j + 1, k]:
                out[k] = joints[j, k]


@njit(cache=True, nogil=True)
def _integrate(pos, vel, over_time, torque_actual, t0, dt, steps, ref_t, ref_p, ref_v, ref_a, state, alive, mode,
               target_torque, max_torque, torque_unit, cpu, vmax, peak, load, window, window_time, inertia, viscous,
               coulomb, hand_k, hand_c, hand_times, hand_joints, hand_start, pulled, started, position_gain,
               velocity_gain, damping):  # pragma: no cover  # fmt: skip
    """:meth:`MotorModel.integrate`'s substeps (the arithmetic, operation for operation, of the numpy model it
    replaced: the same answers to the bit)."""
    n = pos.shape[0]
    powered = np.zeros(n)
    monitored = np.zeros(n, dtype=np.bool_)
    torque_mode = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        on = (state[i] == OE or state[i] == QS) and alive[i]
        powered[i] = 1.0 if on else 0.0  # 0.0: the brake holds
        monitored[i] = state[i] == OE and alive[i] and (mode[i] == _PP or mode[i] == _CSP)
        torque_mode[i] = on and mode[i] == _CST
    # cyclic synchronous torque: the drive's torque within 0x6072 (none while quick-stopping), as a joint torque
    drive_torque = np.zeros(n)
    any_torque = torque_mode.any()
    for i in range(n):
        if any_torque:
            limit = min(max_torque[i], abs(target_torque[i]))
            drive = min(max(target_torque[i], -limit), limit) * (1.0 if state[i] == OE else 0.0)
            torque_actual[i] = drive * (1.0 if torque_mode[i] else 0.0)
            drive_torque[i] = torque_actual[i] * torque_unit[i]
        else:
            torque_actual[i] = 0.0
    hand = np.zeros(n)
    tripped = np.zeros(n, dtype=np.bool_)
    segments = ref_t.shape[1]
    for k in range(steps):
        t = t0 + dt * k
        if pulled and any_torque:  # where the hand pulls at the substep's start
            _hand_at(hand_times, hand_joints, t - hand_start if started else 0.0, hand)
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
                    external = external + hand_k[i] * (hand[i] - p) - hand_c[i] * w
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
            if monitored[i] and over_time[i] > window_time[i]:
                tripped[i] = True
    return tripped


def _compile() -> None:
    """Compile the kernels (or load them from numba's cache) for the types the simulator passes, on import: a
    drives' process pays it at start-up, not at its first SYNC."""
    one, yes, whole = np.ones(1), np.ones(1, dtype=np.bool_), np.ones(1, dtype=np.int64)
    segments = np.ones((1, 4))
    HandMotion(one, np.ones((1, 1)), 0.0)(0.0)
    axes = (one,) * 14  # target_torque .. hand_c
    _integrate(one.copy(), one.copy(), one.copy(), one.copy(), 0.0, 1e-3, 1, segments, segments, segments, segments,
               whole, yes, whole, *axes, _NO_TABLE[0], _NO_TABLE[1], 0.0, False, False, 1.0, 1.0, 1.0)  # fmt: skip


_compile()
