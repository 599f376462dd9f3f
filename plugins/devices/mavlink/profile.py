"""A timed path through waypoints that a multirotor can track: corners blended, speeds limited.

Geometry. A polyline's corners ask for an instant change of velocity, which
no vehicle can follow: tracking it, a multirotor overshoots each corner by
roughly its speed times its response time. Here every interior corner is
replaced by the circular arc tangent to both segments whose midpoint lies
``deviation`` from the corner (the *junction deviation* of the grbl CNC
planner, S. Jeon 2011, used as a geometric blend): with ``h`` half the
interior angle, the arc's radius is ``R = deviation * sin h / (1 - sin h)``
and it leaves each segment ``R / tan h`` before the corner (shrunk, with the
deviation, when that would overlap the neighbouring corner's blend). The
path is then C1 (lines and arcs) and never farther than ``deviation`` from
the polyline, so its clearance is at least the polyline's minus
``deviation``.

Timing. Along the path the speed is time-optimal under a speed limit (lower
on steep pieces when a vertical speed limit is given), a tangential
acceleration limit ``a``, and on arcs ``v <= sqrt(a R)`` (centripetal
acceleration at most ``a``): trapezoidal profiles per piece, the speeds at
the piece boundaries from the forward/backward passes
``v_{i+1}^2 <= v_i^2 + 2 a L_i`` written as running minima (vectorised):
``v_forward_i^2 = 2 a s_i + min_{j <= i}(v_limit_j^2 - 2 a s_j)``.
Samples give position, velocity and acceleration (tangential plus
centripetal), the feed-forward a position controller needs.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass, field

import numpy as np


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


@dataclass
class TimedPath:
    """Setpoints (m, m/s, m/s^2) at any time (s) along lines and corner arcs through waypoints."""

    waypoints: np.ndarray  # (n, 3) as given
    #: per piece: start point, unit direction (lines), arc centre, radius (0: a line), arc basis e1, e2
    start: np.ndarray
    direction: np.ndarray
    centre: np.ndarray
    radius: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    length: np.ndarray  # (k,) m
    knot_speed: np.ndarray  # (k+1,) m/s at the piece boundaries
    peak_speed: np.ndarray  # (k,)
    knot_time: np.ndarray  # (k+1,) s
    accelerate: np.ndarray  # (k,) s
    cruise: np.ndarray  # (k,) s
    acceleration: float
    #: (n,) time at which the path passes each waypoint (a corner: the middle of its arc)
    waypoint_time: np.ndarray
    _lists: dict = field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ construction
    @classmethod
    def along(
        cls,
        waypoints,
        speed: float,
        acceleration: float,
        deviation: float,
        vertical_speed: float | None = None,
    ) -> TimedPath:
        """The profile from rest at ``waypoints[0]`` to rest at ``waypoints[-1]``."""
        given = np.atleast_2d(np.asarray(waypoints, float))
        steps = np.linalg.norm(np.diff(given, axis=0), axis=1)
        keep = np.concatenate([[True], steps > 1e-9])
        index_of_given = np.cumsum(keep) - 1
        w = given[keep]
        a = float(acceleration)
        n = len(w)
        if n < 2:
            empty3 = np.zeros((0, 3))
            zero = np.zeros(0)
            return cls(
                given,
                empty3,
                empty3,
                empty3,
                zero,
                empty3,
                empty3,
                zero,
                np.zeros(1),
                zero,
                np.zeros(1),
                zero,
                zero,
                a,
                np.zeros(len(given)),
            )
        d = np.diff(w, axis=0)
        seg_length = np.linalg.norm(d, axis=1)
        u = d / seg_length[:, None]
        # corners: turn angle phi, half interior angle h, tangent length T, radius R
        u_in, u_out = u[:-1], u[1:]
        cos_phi = np.clip(np.sum(u_in * u_out, axis=1), -1.0, 1.0)
        phi = np.arccos(cos_phi)
        h = 0.5 * (np.pi - phi)
        sin_h, tan_h = np.sin(h), np.tan(h)
        turning = phi > 1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.where(turning, deviation * sin_h / np.maximum(1.0 - sin_h, 1e-300), 0.0)
            tangent = np.where(turning & (tan_h > 0), radius / np.where(tan_h > 0, tan_h, 1.0), 0.0)
        room = 0.5 * np.minimum(seg_length[:-1], seg_length[1:])
        tangent_limited = np.minimum(tangent, room)
        radius = np.where(tangent > 0, radius * tangent_limited / np.where(tangent > 0, tangent, 1.0), 0.0)
        tangent = tangent_limited
        arc = turning & (radius > 1e-9)
        tangent = np.where(arc, tangent, 0.0)
        corner = w[1:-1]
        t_in = corner - tangent[:, None] * u_in
        t_out = corner + tangent[:, None] * u_out
        bisector = _unit(u_out - u_in)
        centre = corner + (radius / np.where(sin_h > 0, sin_h, 1.0))[:, None] * bisector
        e1 = _unit(t_in - centre)
        # pieces interleaved: line 0, arc 1, line 1, arc 2, ..., line n-2; then drop absent arcs and empty lines
        m = 2 * n - 3
        line_start = np.vstack([w[:1], t_out])
        line_end = np.vstack([t_in, w[-1:]])
        start = np.zeros((m, 3))
        direction = np.zeros((m, 3))
        centres = np.zeros((m, 3))
        e1s = np.zeros((m, 3))
        e2s = np.zeros((m, 3))
        radii = np.zeros(m)
        length = np.zeros(m)
        start[0::2], direction[0::2] = line_start, u
        length[0::2] = np.linalg.norm(line_end - line_start, axis=1)
        start[1::2], direction[1::2], centres[1::2], e1s[1::2], e2s[1::2] = t_in, u_in, centre, e1, u_in
        radii[1::2] = np.where(arc, radius, 0.0)
        length[1::2] = np.where(arc, radius * phi, 0.0)
        present = np.ones(m, dtype=bool)
        present[1::2] = arc
        present[0::2] = length[0::2] > 1e-12
        kept = np.flatnonzero(present)
        start, direction, centres, e1s, e2s, radii, length = (
            x[kept] for x in (start, direction, centres, e1s, e2s, radii, length)
        )
        is_arc = radii > 0
        # speed caps per piece: the limit, the centripetal acceleration on arcs, the vertical speed
        cap = np.full(len(length), float(speed))
        cap = np.where(is_arc, np.minimum(cap, np.sqrt(a * radii)), cap)
        if vertical_speed is not None:
            rise = np.where(is_arc, np.hypot(e1s[:, 2], e2s[:, 2]), np.abs(direction[:, 2]))
            with np.errstate(divide="ignore"):
                cap = np.minimum(cap, np.where(rise > 1e-12, vertical_speed / rise, np.inf))
        limit = np.zeros(len(length) + 1)
        limit[1:-1] = np.minimum(cap[:-1], cap[1:])
        # two lines meeting at an angle (a corner too sharp for an arc) are joined at rest
        kink = ~is_arc[:-1] & ~is_arc[1:] & (np.sum(direction[:-1] * direction[1:], axis=1) < 1 - 1e-9)
        limit[1:-1][kink] = 0.0
        s = np.concatenate([[0.0], np.cumsum(length)])
        forward = 2 * a * s + np.minimum.accumulate(limit**2 - 2 * a * s)
        backward = -2 * a * s + np.minimum.accumulate((limit**2 + 2 * a * s)[::-1])[::-1]
        v = np.sqrt(np.clip(np.minimum(forward, backward), 0.0, None))
        v[0] = v[-1] = 0.0
        v0, v1 = v[:-1], v[1:]
        peak = np.minimum(cap, np.sqrt((2 * a * length + v0**2 + v1**2) / 2))
        peak = np.maximum(peak, np.maximum(v0, v1))
        accelerate = (peak - v0) / a
        decelerate = (peak - v1) / a
        cruise_length = np.clip(length - (peak**2 - v0**2) / (2 * a) - (peak**2 - v1**2) / (2 * a), 0.0, None)
        cruise = np.where(peak > 0, cruise_length / np.where(peak > 0, peak, 1.0), 0.0)
        knot_time = np.concatenate([[0.0], np.cumsum(accelerate + cruise + decelerate)])
        path = cls(
            given,
            start,
            direction,
            centres,
            radii,
            e1s,
            e2s,
            length,
            v,
            peak,
            knot_time,
            accelerate,
            cruise,
            a,
            np.zeros(len(given)),
        )
        # where each kept waypoint is passed: the ends; a corner at its arc's middle, or where its lines meet
        piece_s = np.full(m, np.nan)
        piece_s[kept] = s[:-1]
        middle = np.where(arc, piece_s[1::2] + 0.5 * radius * phi, np.nan)
        line_after = np.full(n - 2, np.nan)
        line_after[:] = piece_s[2::2][: n - 2]
        kept_s = np.concatenate([[0.0], np.where(arc, middle, line_after), [s[-1]]])
        path.waypoint_time = path.time_at(kept_s)[index_of_given]
        return path

    # ------------------------------------------------------------------ queries
    @property
    def duration(self) -> float:
        return float(self.knot_time[-1])

    @property
    def end(self) -> np.ndarray:
        return self.waypoints[-1]

    @property
    def total_length(self) -> float:
        return float(np.sum(self.length))

    def _progress(self, t: np.ndarray):
        """Per time: piece index, distance into it, speed and tangential acceleration."""
        k = len(self.length)
        i = np.clip(np.searchsorted(self.knot_time, t, side="right") - 1, 0, k - 1)
        a = self.acceleration
        v0, vp = self.knot_speed[i], self.peak_speed[i]
        ta, tc = self.accelerate[i], self.cruise[i]
        tau = np.clip(t - self.knot_time[i], 0.0, self.knot_time[i + 1] - self.knot_time[i])
        da = (vp**2 - v0**2) / (2 * a)
        in_acc = tau < ta
        in_cruise = ~in_acc & (tau < ta + tc)
        td = np.clip(tau - ta - tc, 0.0, None)
        s = np.where(
            in_acc,
            v0 * tau + 0.5 * a * tau**2,
            np.where(in_cruise, da + vp * (tau - ta), da + vp * tc + vp * td - 0.5 * a * td**2),
        )
        speed = np.where(in_acc, v0 + a * tau, np.where(in_cruise, vp, vp - a * td))
        along = np.where(in_acc, a, np.where(in_cruise, 0.0, -a))
        before, after = t < 0, t >= self.duration
        s = np.where(after, self.length[i], np.clip(s, 0.0, self.length[i]))
        speed = np.where(before | after, 0.0, np.clip(speed, 0.0, None))
        along = np.where(before | after, 0.0, along)
        return i, s, speed, along

    def sample(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations (each (m, 3)) at times ``t`` (m,); at rest outside [0, duration]."""
        t = np.atleast_1d(np.asarray(t, float))
        if len(self.length) == 0:
            p = np.repeat(self.waypoints[-1:], len(t), axis=0)
            return p, np.zeros_like(p), np.zeros_like(p)
        i, s, speed, along = self._progress(t)
        radius = self.radius[i]
        arc = radius > 0
        theta = np.where(arc, s / np.where(arc, radius, 1.0), 0.0)
        e1, e2, c = self.e1[i], self.e2[i], self.centre[i]
        cos, sin = np.cos(theta)[:, None], np.sin(theta)[:, None]
        p_arc = c + radius[:, None] * (cos * e1 + sin * e2)
        tangent_arc = -sin * e1 + cos * e2
        p_line = self.start[i] + self.direction[i] * s[:, None]
        position = np.where(arc[:, None], p_arc, p_line)
        tangent = np.where(arc[:, None], tangent_arc, self.direction[i])
        centripetal = np.where(arc, speed**2 / np.where(arc, radius, 1.0), 0.0)
        accel = tangent * along[:, None] - (cos * e1 + sin * e2) * centripetal[:, None] * arc[:, None]
        return position, tangent * speed[:, None], accel

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sample` for a single time, in plain floats: a simulated vehicle asks a hundred times a second."""
        if not self._lists:
            names = ("knot_time", "knot_speed", "peak_speed", "accelerate", "cruise", "length", "radius")
            self._lists.update({name: getattr(self, name).tolist() for name in names})
            for name in ("start", "direction", "centre", "e1", "e2"):
                self._lists[name] = getattr(self, name).tolist()
        c = self._lists
        k = len(c["length"])
        if k == 0 or t >= c["knot_time"][-1] or t <= 0:
            point = self.waypoints[-1] if k == 0 or t > 0 else self.waypoints[0]
            return np.array(point, float), np.zeros(3), np.zeros(3)
        i = min(max(bisect_right(c["knot_time"], t) - 1, 0), k - 1)
        a = self.acceleration
        v0, vp, ta, tc = c["knot_speed"][i], c["peak_speed"][i], c["accelerate"][i], c["cruise"][i]
        tau = t - c["knot_time"][i]
        if tau < ta:
            s, speed, along = v0 * tau + 0.5 * a * tau * tau, v0 + a * tau, a
        elif tau < ta + tc:
            s, speed, along = (vp * vp - v0 * v0) / (2 * a) + vp * (tau - ta), vp, 0.0
        else:
            td = tau - ta - tc
            s = (vp * vp - v0 * v0) / (2 * a) + vp * tc + vp * td - 0.5 * a * td * td
            speed, along = max(vp - a * td, 0.0), -a
        s = min(max(s, 0.0), c["length"][i])
        radius = c["radius"][i]
        if radius > 0:
            theta = s / radius
            cos, sin = math.cos(theta), math.sin(theta)
            e1, e2, centre = c["e1"][i], c["e2"][i], c["centre"][i]
            radial = [cos * e1[j] + sin * e2[j] for j in range(3)]
            tangent = [-sin * e1[j] + cos * e2[j] for j in range(3)]
            position = [centre[j] + radius * radial[j] for j in range(3)]
            inward = speed * speed / radius
            accel = [tangent[j] * along - radial[j] * inward for j in range(3)]
        else:
            tangent = c["direction"][i]
            position = [c["start"][i][j] + tangent[j] * s for j in range(3)]
            accel = [tangent[j] * along for j in range(3)]
        return np.array(position), np.array(tangent) * speed, np.array(accel)

    def arc_length(self, t) -> np.ndarray:
        """Distance along the path (m) covered at times ``t``."""
        t = np.atleast_1d(np.asarray(t, float))
        if len(self.length) == 0:
            return np.zeros(len(t))
        i, s, _, _ = self._progress(t)
        return np.concatenate([[0.0], np.cumsum(self.length)])[i] + s

    def time_at(self, s) -> np.ndarray:
        """The times (s) at which distances ``s`` (m) along the path are reached."""
        s = np.atleast_1d(np.asarray(s, float))
        if len(self.length) == 0:
            return np.zeros(len(s))
        bounds = np.concatenate([[0.0], np.cumsum(self.length)])
        i = np.clip(np.searchsorted(bounds, s, side="right") - 1, 0, len(self.length) - 1)
        local = np.clip(s - bounds[i], 0.0, self.length[i])
        a = self.acceleration
        v0, vp = self.knot_speed[i], self.peak_speed[i]
        da = (vp**2 - v0**2) / (2 * a)
        dc = self.cruise[i] * vp
        t_acc = (np.sqrt(v0**2 + 2 * a * np.minimum(local, da)) - v0) / a
        t_cruise = np.where(vp > 0, np.clip(local - da, 0.0, dc) / np.where(vp > 0, vp, 1.0), 0.0)
        rest = np.clip(local - da - dc, 0.0, None)
        t_dec = (vp - np.sqrt(np.clip(vp**2 - 2 * a * rest, 0.0, None))) / a
        return self.knot_time[i] + t_acc + t_cruise + t_dec
