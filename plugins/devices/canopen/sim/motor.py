"""The motor model: how the reference a drive follows becomes where its axis actually goes.

The one seam between the drive's logic (state machine, operating modes,
:mod:`.statemachine`, :mod:`.modes`) and the physics: given the reference
(position and rate) at the start of an integration substep,
:meth:`MotorModel.step` gives the axes' positions and velocities at its end,
vectorised over the axes.

Per substep: the encoder quantises the position to whole counts; the drive's
cascade (:meth:`MotorModel.servo`) is a proportional position loop (its
correction capped at ``sqrt(a_peak |e|)``, so that it can always be braked)
with the reference rate as feed-forward, under the speed limit, and a
proportional velocity loop under the current limit (as the joint
acceleration it allows); the motor (:meth:`MotorModel.move`) is a
second-order model, inertia with viscous damping and an external load,
integrated with semi-implicit Euler steps of at most ``substep`` seconds.
An unpowered axis is held by its brake.

In cyclic synchronous torque (CiA 402 mode 10) there is no servo loop: the
drive's torque (``0x6071`` within ``0x6072``, thousandths of the motor's rated
torque ``0x6076``) times the gear ratio is a joint torque (N·m, or N on a
linear axis), and :meth:`MotorModel.torque_step` integrates the axis under it
and any external torque (a hand on the instrument):

    J q'' = τ_drive + τ_ext − b q' − c sign(q')

with the joint's inertia ``J`` (the motor's reflected through the gearing and
the link's), viscous friction ``b`` and Coulomb friction ``c``; Coulomb
friction never reverses a motion within a step, and holds a still axis whose
torque is below it (stiction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    def servo(
        self, command: np.ndarray, rate: np.ndarray, measured: np.ndarray, vel: np.ndarray, vmax, peak
    ) -> np.ndarray:
        """The drive's cascade: the acceleration its current commands (position loop with the rate as
        feed-forward, speed limit ``vmax``, velocity loop, current limit ``peak``)."""
        # proportional position loop whose correction can always be braked within the current
        # limit (the square-root law of drives' position controllers), plus the feed-forward
        error = command - measured
        magnitude = np.abs(error)
        correction = np.sign(error) * np.minimum(self.position_gain * magnitude, np.sqrt(peak * magnitude))
        velocity_command = np.minimum(np.maximum(rate + correction, -vmax), vmax)
        return np.minimum(np.maximum(self.velocity_gain * (velocity_command - vel), -peak), peak)

    def move(self, pos, vel, torque, load, powered, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One semi-implicit Euler step of the motors under ``torque`` and the external ``load`` (both as
        accelerations); ``powered`` is 0.0 where the holding brake keeps an axis still."""
        vel = (vel + (torque - self.damping * vel + load) * dt) * powered
        return pos + vel * dt, vel

    @staticmethod
    def torque_step(pos, vel, torque, inertia, viscous, coulomb, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """One semi-implicit Euler step of axes under the joint ``torque`` (drive and external, N·m or N), with
        ``inertia`` (kg·m² or kg), viscous (``viscous``) and Coulomb (``coulomb``) friction."""
        vel = vel + (torque - viscous * vel) / inertia * dt
        slip = coulomb / inertia * dt  # Coulomb friction: brakes at most to rest within the step
        vel = np.sign(vel) * np.maximum(np.abs(vel) - slip, 0.0)
        return pos + vel * dt, vel

    def step(
        self, pos, vel, command: np.ndarray, rate: np.ndarray, dt: float, powered, cpu, vmax, peak, load
    ) -> tuple[np.ndarray, np.ndarray]:
        """The axes' positions and velocities after one substep of ``dt`` from (``pos``, ``vel``), following
        ``command`` and ``rate`` (the reference at the substep's start); ``cpu``: encoder counts per unit."""
        measured = np.rint(pos * cpu) * (1.0 / cpu)  # the encoder
        torque = self.servo(command, rate, measured, vel, vmax, peak)
        return self.move(pos, vel, torque, load, powered, dt)
