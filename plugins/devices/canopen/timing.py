"""Time parameterisation: joint waypoints to a trajectory sampled at the control rate.

The geometric path is the shape-preserving piecewise-cubic Hermite
interpolant (PCHIP, Fritsch & Carlson 1980, "Monotone piecewise cubic
interpolation", SIAM J. Numer. Anal. 17(2)) through the waypoints, per
joint, over a path parameter ``s`` (the waypoints' cumulative distance in the
metric ``|dq / v_max|``). PCHIP is C1 and never overshoots the waypoints
between two of them, so a path whose waypoints respect the joint limits
respects them everywhere.

The speed along it is time-optimal under per-joint velocity and acceleration
limits, by reachability analysis (TOPP-RA: Pham & Pham 2018, "A new approach
to time-optimal path parameterization based on reachability analysis", IEEE
T-RO 34(3)): on a grid over ``s``, with ``x = sdot^2`` and ``u = sddot``
piecewise constant, the constraints are

    |q'(s) sdot| <= v_max                (a bound on x)
    |q'(s) u + q''(s) x| <= a_max        (linear in (x, u))
    x_{i+1} = x_i + 2 delta_i u_i

A backward pass computes the controllable sets ``[0, x_max_i]`` (each a 2-D
linear program, solved in closed form over the pairs of bounds on ``u``), a
greedy forward pass picks the largest feasible ``u``. The motion starts and
ends at rest.

What is guaranteed, and checked on the result rather than hoped: the
*samples at the control period T* that the drives receive satisfy, per joint,
``|q_{k+1} - q_k| / T <= v_max`` and ``|q_{k+1} - 2 q_k + q_{k-1}| / T^2 <=
a_max``. TOPP-RA enforces the limits at its grid points; between them (and at
PCHIP's knots, where q'' jumps) a sampled difference may exceed a limit
slightly, in which case the whole trajectory is slowed down uniformly (time
scaled by ``k`` scales velocities by 1/k and accelerations by 1/k^2) until
the samples pass. CiA 402 drives in cyclic synchronous position mode
interpolate linearly between those samples, so these differences *are* the
velocities and accelerations commanded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator


@dataclass
class JointTrajectory:
    """Joint positions ``q`` (m, nq) at times ``t`` = 0, T, 2T, ... (s); SI joint units."""

    t: np.ndarray
    q: np.ndarray
    period: float
    #: the time-optimal duration before any uniform slow-down (s)
    optimal_duration: float = 0.0
    #: uniform slow-down applied so that the samples respect the limits (1 = none)
    time_scale: float = 1.0
    #: path parameter of each sample, and of each (distinct) waypoint: sample k lies between the
    #: waypoints whose ``knots`` bracket ``s[k]`` (None for a single waypoint)
    s: np.ndarray | None = None
    knots: np.ndarray | None = None
    #: the distinct waypoints (one per knot)
    waypoints: np.ndarray | None = None

    def segment_of_samples(self) -> np.ndarray:
        """Index i of the waypoint segment [i, i+1] each sample lies on (shape-preserving in between)."""
        if self.knots is None or len(self.knots) < 2:
            return np.zeros(len(self.q), dtype=int)
        return np.clip(np.searchsorted(self.knots, self.s, side="right") - 1, 0, len(self.knots) - 2)

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0

    def velocity(self) -> np.ndarray:
        """Finite-difference joint velocities (m-1, nq) between samples."""
        return np.diff(self.q, axis=0) / self.period

    def acceleration(self) -> np.ndarray:
        """Second differences (m-2, nq) divided by T^2."""
        return np.diff(self.q, n=2, axis=0) / self.period**2

    def tip_deviation(self, tip_positions) -> float:
        """Largest distance (m) of a commanded tip sample from the straight tip segment between the
        waypoints it lies between (and their neighbours): how far the smooth timed path rounds the
        corners of the waypoint polyline (at most about ``path_resolution``). ``tip_positions``: the
        forward kinematics of joint rows to tip points."""
        if self.waypoints is None or len(self.waypoints) < 2:
            return 0.0
        corners = tip_positions(self.waypoints)
        tips = tip_positions(self.q)
        segment = self.segment_of_samples()
        best = np.full(len(tips), np.inf)
        for shift in (-1, 0, 1):  # a sample near a knot may be nearest to the neighbouring segment
            i = np.clip(segment + shift, 0, len(corners) - 2)
            a, d = corners[i], corners[i + 1] - corners[i]
            t = np.clip(np.sum((tips - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(tips - (a + t[:, None] * d), axis=1))
        return float(best.max())


def _path_parameter(waypoints: np.ndarray, velocity_limit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Waypoints without repeats, and their cumulative distance in the metric |dq / v_max|."""
    steps = np.linalg.norm(np.diff(waypoints, axis=0) / velocity_limit, axis=1)
    keep = np.concatenate([[True], steps > 1e-12])
    waypoints = waypoints[keep]
    s = np.concatenate([[0.0], np.cumsum(steps[keep[1:]])])
    return waypoints, s


def _lower_upper(alpha: np.ndarray, beta: np.ndarray, gamma: np.ndarray):
    """Split rows ``alpha u + beta x <= gamma`` into bounds on u (affine in x) and pure bounds on x.

    Returns ``(lower_c, lower_d, upper_c, upper_d, x_only_beta, x_only_gamma)``, per grid row, with
    ``u >= c + d x`` for the lower bounds and ``u <= c + d x`` for the upper ones; absent entries are
    ``-inf`` / ``+inf`` constants.
    """
    small = np.abs(alpha) < 1e-12
    safe = np.where(small, 1.0, alpha)
    c = gamma / safe
    d = -beta / safe
    lower = (alpha < 0) & ~small
    upper = (alpha > 0) & ~small
    lower_c = np.where(lower, c, -np.inf)
    lower_d = np.where(lower, d, 0.0)
    upper_c = np.where(upper, c, np.inf)
    upper_d = np.where(upper, d, 0.0)
    return lower_c, lower_d, upper_c, upper_d, np.where(small, beta, 0.0), np.where(small, gamma, np.inf)


def topp_ra(
    left: tuple[np.ndarray, np.ndarray],
    right: tuple[np.ndarray, np.ndarray],
    x_velocity: np.ndarray,
    delta: np.ndarray,
    acceleration_limit,
) -> np.ndarray:
    """Time-optimal squared path speeds ``x = sdot^2`` on a grid (TOPP-RA, Pham & Pham 2018).

    Step i (from s_i to s_{i+1} = s_i + delta_i, constant u) must meet the acceleration limits at
    both of its ends (TOPP-RA's "interpolation" discretisation, §VI-A): with ``left = (q'(s_i+),
    q''(s_i+))`` and ``right = (q'(s_{i+1}-), q''(s_{i+1}-))``, each (N, nq),

        |q'_L u + q''_L x_i| <= a_max,   |q'_R u + q''_R (x_i + 2 delta u)| <= a_max.

    ``x_velocity`` (N+1,) bounds x at each grid point (the velocity limits). Returns x (N+1,),
    zero at both ends.
    """
    n = len(delta)
    amax = np.asarray(acceleration_limit, dtype=float)
    d_left, c_left = left
    d_right, c_right = right
    h2 = (2.0 * delta)[:, None]
    # rows alpha u + beta x <= gamma, for every joint and both signs, at both ends of each step
    alpha = np.concatenate([d_left, -d_left, d_right + h2 * c_right, -(d_right + h2 * c_right)], axis=1)
    beta = np.concatenate([c_left, -c_left, c_right, -c_right], axis=1)
    gamma = np.broadcast_to(np.tile(amax, 4), alpha.shape)
    lower_c, lower_d, upper_c, upper_d, xb, xg = _lower_upper(alpha, beta, gamma)

    # the static part of each controllable-set bound: pairs (lower k, upper m) with L_k(x) <= U_m(x)
    den = lower_d[:, :, None] - upper_d[:, None, :]
    num = upper_c[:, None, :] - lower_c[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        pair = np.where(den > 1e-15, num / np.where(den > 1e-15, den, 1.0), np.inf)
        pure = np.where(xb > 1e-15, xg / np.where(xb > 1e-15, xb, 1.0), np.inf)
    static = np.minimum(x_velocity[:-1], np.minimum(pair.min(axis=(1, 2)), pure.min(axis=1)))
    static = np.maximum(static, 0.0)

    # backward pass: x + 2 delta u <= x_max[i+1] is one more upper bound on u, and
    # x + 2 delta u >= 0 one more lower bound; pair them with the joints' bounds
    x_max = np.zeros(n + 1)
    for i in range(n - 1, -1, -1):
        h = 2.0 * delta[i]
        # U(x) = (x_next - x) / h against the lower bounds L_k(x) = c + d x
        d_k = lower_d[i] + 1.0 / h
        bound = static[i]
        positive = d_k > 1e-15
        if np.any(positive):
            bound = min(bound, float(np.min((x_max[i + 1] / h - lower_c[i][positive]) / d_k[positive])))
        # L(x) = -x / h against the upper bounds U_m(x) = c + d x:  x (-1/h - d) <= c
        d_m = -1.0 / h - upper_d[i]
        positive = d_m > 1e-15
        if np.any(positive):
            bound = min(bound, float(np.min(upper_c[i][positive] / d_m[positive])))
        x_max[i] = max(bound, 0.0)
    x_max[0] = 0.0  # start at rest

    # forward pass: the largest u that keeps x inside the controllable sets
    x = np.zeros(n + 1)
    for i in range(n):
        h = 2.0 * delta[i]
        xi = x[i]
        u_hi = min(float(np.min(upper_c[i] + upper_d[i] * xi)), (x_max[i + 1] - xi) / h)
        u_lo = max(float(np.max(lower_c[i] + lower_d[i] * xi)), -xi / h)
        u = u_hi if u_hi >= u_lo else u_lo  # numerical slack only: TOPP-RA keeps this feasible
        x[i + 1] = min(max(xi + h * u, 0.0), x_max[i + 1])
    return x


def time_parameterize(
    waypoints,
    velocity_limit,
    acceleration_limit,
    period: float,
    *,
    max_grid: int = 4000,
) -> JointTrajectory:
    """A rest-to-rest joint trajectory through ``waypoints`` (n, nq), sampled every ``period`` s.

    Limits are per joint (rad/s, m/s; rad/s^2, m/s^2). See the module docstring for what the
    result guarantees.
    """
    waypoints = np.atleast_2d(np.asarray(waypoints, dtype=float))
    vmax = np.asarray(velocity_limit, dtype=float)
    amax = np.asarray(acceleration_limit, dtype=float)
    if np.any(vmax <= 0) or np.any(amax <= 0):
        raise ValueError("velocity and acceleration limits must be positive")
    waypoints, s = _path_parameter(waypoints, vmax)
    if len(waypoints) == 1:
        return JointTrajectory(np.zeros(1), waypoints.copy(), period)
    total = float(s[-1])
    path = PchipInterpolator(s, waypoints, axis=0)
    first, second = path.derivative(1), path.derivative(2)
    # a uniform grid plus PCHIP's knots (where q'' jumps) and three points inside every knot
    # interval (where q'' varies linearly), so each step sees a short stretch of one cubic piece
    count = int(np.clip(np.ceil(2.0 * total / period), 50, max_grid))
    inside = (s[:-1, None] + np.diff(s)[:, None] * np.array([0.25, 0.5, 0.75])).ravel()
    grid = np.union1d(np.union1d(np.linspace(0.0, total, count + 1), s), inside)
    grid = grid[np.concatenate([[True], np.diff(grid) > 1e-9 * total])]
    grid[-1] = total
    n = len(grid) - 1
    eps = 1e-9 * total
    inner_left, inner_right = grid[:-1] + eps, grid[1:] - eps
    speed = np.abs(first(grid))
    with np.errstate(divide="ignore"):
        x_velocity = np.min(np.where(speed > 1e-12, (vmax / np.maximum(speed, 1e-12)) ** 2, np.inf), axis=1)
    x = topp_ra(
        (first(inner_left), second(inner_left)),
        (first(inner_right), second(inner_right)),
        x_velocity,
        np.diff(grid),
        amax,
    )

    sdot = np.sqrt(x)
    delta = np.diff(grid)
    # time per grid step with constant u: delta = (sdot_i + sdot_{i+1}) / 2 * dt
    dt = 2.0 * delta / np.maximum(sdot[:-1] + sdot[1:], 1e-300)
    times = np.concatenate([[0.0], np.cumsum(dt)])
    accel = (x[1:] - x[:-1]) / (2.0 * delta)

    def sample(scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        end = times[-1] * scale
        count = int(np.ceil(end / period - 1e-9)) + 1
        t = np.arange(count) * period
        tau_global = np.minimum(t / scale, times[-1])
        i = np.clip(np.searchsorted(times, tau_global, side="right") - 1, 0, n - 1)
        tau = tau_global - times[i]
        s_t = np.clip(grid[i] + sdot[i] * tau + 0.5 * accel[i] * tau**2, grid[i], grid[i + 1])
        s_t[-1] = total
        return t, s_t, path(s_t)

    scale = 1.0
    for _ in range(20):
        t, s_samples, q = sample(scale)
        ratio_v = float(np.max(np.abs(np.diff(q, axis=0)) / (vmax * period))) if len(q) > 1 else 0.0
        ratio_a = float(np.max(np.abs(np.diff(q, n=2, axis=0)) / (amax * period**2))) if len(q) > 2 else 0.0
        worst = max(ratio_v, np.sqrt(ratio_a))
        if worst <= 1.0:
            break
        scale *= worst * 1.0005
    else:  # pragma: no cover - the scaling converges in a few rounds
        raise RuntimeError("time parameterisation did not meet the limits")
    return JointTrajectory(t, q, period, float(times[-1]), scale, s_samples, s, waypoints)
