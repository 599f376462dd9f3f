"""The simulated multirotor: a point mass under a PX4-like position controller, in wind.

State: position p and velocity v in local NED (m, m/s). The position
controller is PX4's cascade (``mc_pos_control``): a P loop on position gives
a velocity setpoint (plus the reference's velocity as feed-forward), clipped
to the airframe's horizontal speed, climb and descent limits; a PI loop on
velocity gives an acceleration (plus the reference's acceleration as
feed-forward and the known drag as compensation), clipped to the thrust
authority. The air pushes with ``drag * (wind - v)``: the controller knows
the ``-drag * v`` part, not the wind, which its integral has to learn, so
gusts show up as tracking error. The airframe cannot exceed its top speeds
(horizontal, climb, descent) whatever the controller asks.

Integration is semi-implicit Euler at a fixed step (default 10 ms). The
ground is the plane z = ground (NED, down positive): the vehicle cannot go
below it, and stands still on it when disarmed.

Gusts act only on a vehicle in the air, so their process advances only with
airborne time (it starts from its stationary distribution): a flight meets
the same gusts for the same seed however long the vehicle stood on its pad
first, which is wall-clock time for a simulation that runs faster than real
time while a ground station connects and uploads. Flights are reproducible.

Braking distance (:func:`braking_distance`): told to hold where it is, a
vehicle moving at ``v`` overshoots that point before the controller brings it
back; the overshoot is what the predictive geofence (:mod:`.geofence`) looks
ahead by. With the default gains (position 1/s, velocity 2/s) the loop is
x'' = -2 x' - 2 x, whose response to a start at speed v is v e^-t sin t: it
travels 0.32 v (m, v in m/s) before turning back (0.30 v with the velocity
integral, as integrated at 10 ms), as long as the braking (2 v at first)
stays within the thrust authority (MPC_ACC_HOR_MAX, 4 m/s^2: up to 2 m/s);
faster, the clipped acceleration makes it longer (v^2 / 8 m at 5 m/s). The
function integrates the loop as the simulation does (same step, gains,
limits, no wind), so it is exact for this model.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .settings import Airframe, Wind


def _clip_norm(x: float, y: float, z: float, limit: float) -> tuple[float, float, float]:
    norm = math.sqrt(x * x + y * y + z * z)
    if norm > limit:
        k = limit / norm
        return x * k, y * k, z * k
    return x, y, z


def _clip_horizontal(x: float, y: float, limit: float) -> tuple[float, float]:
    norm = math.hypot(x, y)
    if norm > limit:
        return x * limit / norm, y * limit / norm
    return x, y


@functools.lru_cache(maxsize=4096)
def _overshoot(
    speed: float, kp: float, kv: float, ki: float, speed_limit: float, authority: float, dt: float, bias: float
) -> float:
    p, v, integral = 0.0, speed, bias
    for _ in range(100_000):
        wanted = min(max(-kp * p, -speed_limit), speed_limit)
        error = wanted - v
        a = kv * error + integral
        saturated = abs(a) >= authority * 0.999
        a = min(max(a, -authority), authority)
        if not saturated:
            integral += ki * dt * error
        v = min(max(v + a * dt, -speed_limit), speed_limit)
        if v <= 0.0:
            return p
        p += v * dt
    return p


def braking_distance(
    airframe: Airframe, speed: float, dt: float = 0.01, vertical: bool = False, integral: float = 0.0
) -> float:
    """How far (m) the vehicle goes on from ``speed`` (m/s) along its motion when it is told to hold where it
    is (the position controller's overshoot; no wind). ``vertical``: with the vertical gains and climb limit;
    ``integral``: the velocity loop's integral along the motion (m/s^2; what it has learnt pushes on)."""
    speed = abs(float(speed))
    if speed < 1e-6:
        return 0.0
    bias = max(math.ceil(float(integral) * 100) / 100, 0.0)
    a = airframe
    gains = (
        (a.position_gain_z, a.velocity_gain_z, a.velocity_integral_z, a.max_climb)
        if vertical
        else (a.position_gain, a.velocity_gain, a.velocity_integral, a.max_speed)
    )
    # rounded up to the cm/s: cached, and never shorter than at the speed itself
    return _overshoot(math.ceil(speed * 100) / 100, *gains, a.max_acceleration, dt, bias)


class Gusts:
    """Wind (NED, m/s): the mean plus an Ornstein-Uhlenbeck process per axis (vertical at 30 %)."""

    def __init__(self, wind: Wind, seed: int) -> None:
        self.mean = tuple(float(x) for x in wind.mean)
        self.sigma = (wind.gust, wind.gust, 0.3 * wind.gust)
        self.tau = wind.gust_time
        self._rng = np.random.default_rng(seed)
        # a stationary start: the first seconds of a flight are as gusty as any later ones
        start = self._rng.standard_normal(3) if self.sigma[0] > 0 else np.zeros(3)
        self.state = tuple(float(sd * n) for sd, n in zip(self.sigma, start, strict=True))
        self._draws: list = []

    @property
    def wind(self) -> tuple[float, float, float]:
        """The wind now (NED, m/s), without advancing the process."""
        return tuple(m + x for m, x in zip(self.mean, self.state, strict=True))

    def step(self, dt: float) -> tuple[float, float, float]:
        """Advance the gusts ``dt`` s (exact Ornstein-Uhlenbeck transition); the wind after it."""
        if self.sigma[0] > 0:
            if not self._draws:  # normal draws in blocks: one generator call per thousand steps
                self._draws = self._rng.standard_normal((1000, 3)).tolist()[::-1]
            draw = self._draws.pop()
            decay = math.exp(-dt / self.tau)
            spread = math.sqrt(1 - decay * decay)
            self.state = tuple(
                x * decay + sd * spread * n for x, sd, n in zip(self.state, self.sigma, draw, strict=True)
            )
        return self.wind


class PointMassMultirotor:
    """Point-mass dynamics with the cascaded position controller; all NED SI."""

    def __init__(self, airframe: Airframe, home, wind: Wind, seed: int = 0) -> None:
        self.airframe = airframe
        self.p = np.asarray(home, float).copy()
        self.v = np.zeros(3)
        self.ground = float(self.p[2])
        self.integral = np.zeros(3)
        self.gusts = Gusts(wind, seed)
        self.wind = np.array(self.gusts.wind)
        self.airborne = False
        #: the acceleration the controller asks for beyond gravity (NED m/s^2): the attitude follows it
        self.thrust = (0.0, 0.0, 0.0)

    @property
    def on_ground(self) -> bool:
        return not self.airborne

    def step(self, dt: float, reference: tuple[np.ndarray, np.ndarray, np.ndarray] | None, armed: bool) -> None:
        """Advance ``dt`` s tracking ``(p_ref, v_ref, a_ref)``; ``None`` or disarmed: motors off.

        One instant of a sequential integration: plain floats, which is several times faster
        than numpy on 3-vectors (the simulation runs a hundred of these per simulated second).
        """
        a = self.airframe
        # gusts only in the air (see the module's docstring): reproducible flights
        wx, wy, wz = self.gusts.step(dt) if self.airborne else self.gusts.wind
        self.wind = np.array([wx, wy, wz])
        px, py, pz = (float(x) for x in self.p)
        vx, vy, vz = (float(x) for x in self.v)
        drag = a.drag
        if not armed or reference is None:
            self.integral = np.zeros(3)
            self.thrust = (0.0, 0.0, 0.0)
            if self.on_ground:
                self.v = np.zeros(3)
                return
            # motors off in the air: it falls (not expected to happen; kept physical)
            ax, ay, az = drag * (wx - vx), drag * (wy - vy), 9.81 + drag * (wz - vz)
        else:
            (rx, ry, rz), (ux, uy, uz), (fx, fy, fz) = (tuple(float(c) for c in x) for x in reference)
            # position P loop with velocity feed-forward, clipped to the airframe's speeds
            sx, sy = _clip_horizontal(ux + a.position_gain * (rx - px), uy + a.position_gain * (ry - py), a.max_speed)
            sz = min(max(uz + a.position_gain_z * (rz - pz), -a.max_climb), a.max_descent)
            ex, ey, ez = sx - vx, sy - vy, sz - vz
            ix, iy, iz = (float(x) for x in self.integral)
            k, kz = a.velocity_gain, a.velocity_gain_z
            cx, cy, cz = _clip_norm(
                fx + k * ex + ix + drag * vx,
                fy + k * ey + iy + drag * vy,
                fz + kz * ez + iz + drag * vz,
                a.max_acceleration,
            )
            self.thrust = (cx, cy, cz)
            # anti-windup: integrate only while the thrust is not saturated
            if math.sqrt(cx * cx + cy * cy + cz * cz) < a.max_acceleration * 0.999:
                ki, kiz = a.velocity_integral * dt, a.velocity_integral_z * dt
                self.integral = np.array([ix + ki * ex, iy + ki * ey, iz + kiz * ez])
            ax, ay, az = cx + drag * (wx - vx), cy + drag * (wy - vy), cz + drag * (wz - vz)
            if self.on_ground and cz >= 0:
                # thrust at or below hover: it stays on the ground, which holds it against the wind too
                # (an upward gust must not lift an idling vehicle off its pad)
                self.v = np.zeros(3)
                return
        # the airframe's top speeds: its motors can do no more, whatever the controller asks (motors off, it
        # falls: only the drag limits it)
        vx, vy, vz = vx + ax * dt, vy + ay * dt, vz + az * dt
        if armed:
            vx, vy = _clip_horizontal(vx, vy, a.max_speed)
            vz = min(max(vz, -a.max_climb), a.max_descent)
        px, py, pz = px + vx * dt, py + vy * dt, pz + vz * dt
        if pz >= self.ground:
            pz = self.ground
            vz = min(vz, 0.0)
            # a touchdown below 0.2 m/s, or any ground contact with the motors off (it falls: it stops there)
            if self.airborne and (math.sqrt(vx * vx + vy * vy + vz * vz) < 0.2 or not armed):
                self.airborne = False
                vx = vy = vz = 0.0
                self.integral = np.zeros(3)
        else:
            self.airborne = True
        self.p = np.array([px, py, pz])
        self.v = np.array([vx, vy, vz])

    def stopping_point(self) -> np.ndarray:
        """Where the vehicle comes to rest if it brakes at full authority now."""
        speed = float(np.linalg.norm(self.v))
        if speed < 1e-6:
            return self.p.copy()
        return self.p + self.v * (speed / (2 * self.airframe.max_acceleration))
