"""The motion reference a drive's operating mode gives its servo loops: piecewise quadratic, per axis.

Each axis' reference is up to four segments (start time, position, velocity,
acceleration), evaluated for every axis at once (:class:`Reference`); the
operating modes (:mod:`.modes`) build them from the profiles here: a stop at
a deceleration, a velocity ramp, and the time-optimal trapezoid of profile
position.
"""

from __future__ import annotations

import numpy as np


class Reference:
    """Per axis, a piecewise-quadratic position reference: segments (start time, p, v, a), vectorised."""

    K = 4

    def __init__(self, n: int, t: float, pos: np.ndarray) -> None:
        self.t = np.full((n, self.K), np.inf)
        self.p = np.zeros((n, self.K))
        self.v = np.zeros((n, self.K))
        self.a = np.zeros((n, self.K))
        self.t[:, 0] = t
        self.p[:, 0] = pos

    def set(self, i: int, segments: list[tuple[float, float, float, float]]) -> None:
        self.t[i] = np.inf
        for k, (t, p, v, a) in enumerate(segments[: self.K]):
            self.t[i, k], self.p[i, k], self.v[i, k], self.a[i, k] = t, p, v, a

    def hold(self, i: int, t: float, p: float) -> None:
        self.set(i, [(t, p, 0.0, 0.0)])

    def at(self, t) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity of every axis at time ``t`` (scalar, or (S, 1) for S times)."""
        t = np.asarray(t, dtype=float)
        if t.ndim == 0:
            k = np.maximum(np.sum(self.t <= t, axis=1) - 1, 0)
            rows = np.arange(len(k))
            tau = np.maximum(t - self.t[rows, k], 0.0)
            a, v = self.a[rows, k], self.v[rows, k]
            return self.p[rows, k] + v * tau + 0.5 * a * tau * tau, v + a * tau
        k = np.maximum(np.sum(self.t[None] <= t[..., None], axis=2) - 1, 0)  # (S, n)
        cols = np.arange(self.t.shape[0])[None]
        tau = np.maximum(t - self.t[cols, k], 0.0)
        a, v = self.a[cols, k], self.v[cols, k]
        return self.p[cols, k] + v * tau + 0.5 * a * tau * tau, v + a * tau

    def at_axis(self, i: int, t: float) -> tuple[float, float]:
        """Position and velocity of axis ``i`` at time ``t`` (scalar arithmetic: one axis, cheaply)."""
        starts = self.t[i].tolist()
        k = 0
        for j in range(1, self.K):
            if starts[j] <= t:
                k = j
        tau = max(t - starts[k], 0.0)
        a, v = self.a.item(i, k), self.v.item(i, k)
        return self.p.item(i, k) + v * tau + 0.5 * a * tau * tau, v + a * tau

    def end(self, i: int) -> float:
        """Start of the axis' last segment: from then on the reference is constant velocity (or still)."""
        finite = self.t[i][np.isfinite(self.t[i])]
        return float(finite[-1]) if len(finite) else -np.inf


def stop_segments(t: float, p: float, v: float, decel: float) -> list:
    """Decelerate from (p, v) at ``decel`` to rest, then hold."""
    if v == 0.0 or decel <= 0:
        return [(t, p, 0.0, 0.0)]
    a = -np.sign(v) * decel
    duration = abs(v) / decel
    return [(t, p, v, a), (t + duration, p + v * duration / 2, 0.0, 0.0)]


def velocity_segments(t: float, p: float, v: float, target: float, accel: float, decel: float) -> list:
    """Ramp from velocity v to ``target`` (accelerating at accel, slowing at decel), then constant."""
    if target == v:
        return [(t, p, v, 0.0)]
    slowing = abs(target) < abs(v) or np.sign(target) != np.sign(v)
    rate = decel if slowing else accel
    duration = abs(target - v) / rate
    a = np.sign(target - v) * rate
    return [(t, p, v, a), (t + duration, p + v * duration + 0.5 * a * duration**2, target, 0.0)]


def trapezoid(t: float, p: float, v: float, goal: float, vmax: float, accel: float, decel: float) -> list:
    """Time-optimal move from (p, v) to rest at ``goal``: speed up at accel to at most vmax, slow at decel."""
    segments = []
    # moving away from the goal, or too fast to stop before it: brake to rest first
    stop = v * abs(v) / (2 * decel)
    if v != 0 and (np.sign(v) != np.sign(goal - p) or abs(stop) > abs(goal - p) + 1e-12):
        braking = stop_segments(t, p, v, decel)
        segments += braking[:-1]
        t, p, v = braking[-1][0], braking[-1][1], 0.0
    distance = goal - p
    if abs(distance) < 1e-12:
        return [*segments, (t, goal, 0.0, 0.0)]
    s = np.sign(distance)
    d, u = abs(distance), abs(v)
    # peak speed w: (w^2 - u^2)/(2 accel) + w^2/(2 decel) = d
    w = np.sqrt((d + u * u / (2 * accel)) / (1 / (2 * accel) + 1 / (2 * decel)))
    w = max(min(w, vmax), u)
    t_up = (w - u) / accel
    d_up = (w * w - u * u) / (2 * accel)
    d_down = w * w / (2 * decel)
    t_cruise = max(0.0, (d - d_up - d_down) / w) if w > 0 else 0.0
    t_down = w / decel
    p1 = p + s * d_up
    p2 = p1 + s * w * t_cruise
    segments += [(t, p, s * u, s * accel), (t + t_up, p1, s * w, 0.0), (t + t_up + t_cruise, p2, s * w, -s * decel)]
    segments.append((t + t_up + t_cruise + t_down, goal, 0.0, 0.0))
    return [seg for k, seg in enumerate(segments) if k == len(segments) - 1 or seg[0] < segments[k + 1][0]]
