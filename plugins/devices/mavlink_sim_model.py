"""The simulated multirotor: a point mass under a PX4-like position controller, in wind.

State: position p and velocity v in local NED (m, m/s). The position
controller is PX4's cascade (``mc_pos_control``): a P loop on position gives
a velocity setpoint (plus the reference's velocity as feed-forward), clipped
to the airframe's horizontal speed, climb and descent limits; a PI loop on
velocity gives an acceleration (plus the reference's acceleration as
feed-forward and the known drag as compensation), clipped to the thrust
authority. The air pushes with ``drag * (wind - v)``: the controller knows
the ``-drag * v`` part, not the wind, which its integral has to learn, so
gusts show up as tracking error.

Integration is semi-implicit Euler at a fixed step (default 10 ms). The
ground is the plane z = ground (NED, down positive): the vehicle cannot go
below it, and stands still on it when disarmed.
"""

from __future__ import annotations

import math

import numpy as np

from .mavlink_sim_settings import Airframe, Wind


def _clip_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    norm = math.sqrt(float(vector @ vector))
    return vector * (limit / norm) if norm > limit else vector


class Gusts:
    """Wind (NED, m/s): the mean plus an Ornstein-Uhlenbeck process per axis (vertical at 30 %)."""

    def __init__(self, wind: Wind, seed: int) -> None:
        self.mean = np.asarray(wind.mean, float)
        self.sigma = wind.gust * np.array([1.0, 1.0, 0.3])
        self.tau = wind.gust_time
        self.state = np.zeros(3)
        self._rng = np.random.default_rng(seed)

    def step(self, dt: float) -> np.ndarray:
        if np.any(self.sigma > 0):
            decay = math.exp(-dt / self.tau)
            self.state = self.state * decay + self.sigma * math.sqrt(1 - decay**2) * self._rng.standard_normal(3)
        return self.mean + self.state


class PointMassMultirotor:
    """Point-mass dynamics with the cascaded position controller; all NED SI."""

    def __init__(self, airframe: Airframe, home, wind: Wind, seed: int = 0) -> None:
        self.airframe = airframe
        self.p = np.asarray(home, float).copy()
        self.v = np.zeros(3)
        self.ground = float(self.p[2])
        self.integral = np.zeros(3)
        self.gusts = Gusts(wind, seed)
        self.wind = self.gusts.mean.copy()
        self.airborne = False

    @property
    def on_ground(self) -> bool:
        return not self.airborne

    def _velocity_setpoint(self, p_ref, v_ref) -> np.ndarray:
        a = self.airframe
        v = v_ref + a.position_gain * (p_ref - self.p)
        horizontal = _clip_norm(v[:2], a.max_speed)
        vertical = min(max(v[2], -a.max_climb), a.max_descent)
        return np.array([horizontal[0], horizontal[1], vertical])

    def step(self, dt: float, reference: tuple[np.ndarray, np.ndarray, np.ndarray] | None, armed: bool) -> None:
        """Advance ``dt`` s tracking ``(p_ref, v_ref, a_ref)``; ``None`` or disarmed: motors off."""
        self.wind = self.gusts.step(dt)
        a = self.airframe
        if not armed or reference is None:
            self.integral[:] = 0.0
            if self.on_ground:
                self.v[:] = 0.0
                return
            # motors off in the air: it falls (not expected to happen; kept physical)
            accel = np.array([0.0, 0.0, 9.81]) + a.drag * (self.wind - self.v)
        else:
            p_ref, v_ref, a_ref = reference
            v_sp = self._velocity_setpoint(p_ref, v_ref)
            error = v_sp - self.v
            command = a_ref + a.velocity_gain * error + self.integral + a.drag * self.v
            command = _clip_norm(command, a.max_acceleration)
            # anti-windup: integrate only while the thrust is not saturated
            if np.linalg.norm(command) < a.max_acceleration * 0.999:
                self.integral += a.velocity_integral * error * dt
            accel = command + a.drag * (self.wind - self.v)
            if self.on_ground and accel[2] >= 0:
                self.v[:] = 0.0  # thrust below hover: it stays on the ground
                return
        self.v = self.v + accel * dt
        self.p = self.p + self.v * dt
        if self.p[2] >= self.ground:
            self.p[2] = self.ground
            self.v[2] = min(self.v[2], 0.0)
            if self.airborne and np.linalg.norm(self.v) < 0.2:
                self.airborne = False
                self.v[:] = 0.0
                self.integral[:] = 0.0
        else:
            self.airborne = True

    def stopping_point(self) -> np.ndarray:
        """Where the vehicle comes to rest if it brakes at full authority now."""
        speed = float(np.linalg.norm(self.v))
        if speed < 1e-6:
            return self.p.copy()
        return self.p + self.v * (speed / (2 * self.airframe.max_acceleration))
