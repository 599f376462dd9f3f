"""Time parameterisation: limits respected at the control-rate samples, time-optimal where known."""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan.plugins.devices.canopen.timing import time_parameterize


def trapezoid_duration(distance: float, vmax: float, amax: float) -> float:
    """Rest-to-rest minimum time along a line (bang-coast-bang), the classical closed form."""
    if distance > vmax**2 / amax:
        return distance / vmax + vmax / amax
    return 2.0 * np.sqrt(distance / amax)


@pytest.mark.parametrize("distance", [0.02, 0.3, 1.5])
def test_straight_line_is_the_optimal_trapezoid(distance):
    vmax, amax, period = np.array([1.0, 2.0]), np.array([4.0, 4.0]), 0.004
    # joint 2 moves half as far with twice the speed limit: joint 1 is the binding one
    trajectory = time_parameterize([[0.0, 0.0], [distance, distance / 2]], vmax, amax, period)
    exact = trapezoid_duration(distance, 1.0, 4.0)
    assert trajectory.optimal_duration == pytest.approx(exact, rel=1e-4)
    assert exact <= trajectory.duration <= exact * 1.01 + period
    np.testing.assert_allclose(trajectory.q[0], [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(trajectory.q[-1], [distance, distance / 2], atol=1e-15)


def test_samples_respect_velocity_and_acceleration_limits_on_a_winding_path(rng):
    waypoints = np.cumsum(rng.normal(0.0, 0.3, size=(15, 4)), axis=0)
    vmax = np.array([1.0, 1.0, 0.1, 3.0])
    amax = np.array([4.0, 4.0, 0.5, 10.0])
    trajectory = time_parameterize(waypoints, vmax, amax, 0.004)
    assert np.all(np.abs(trajectory.velocity()) <= vmax * (1 + 1e-12))
    assert np.all(np.abs(trajectory.acceleration()) <= amax * (1 + 1e-12))
    # at rest at both ends, and it reaches the last waypoint
    np.testing.assert_allclose(trajectory.velocity()[[0, -1]], 0.0, atol=amax.max() * 0.004)
    np.testing.assert_allclose(trajectory.q[-1], waypoints[-1], atol=1e-12)
    # time-optimal along the path up to the discretisation: little uniform slow-down was needed
    assert trajectory.time_scale < 1.05
    # and no faster than the slowest joint moving at its limit the whole way
    lower_bound = np.max(np.sum(np.abs(np.diff(waypoints, axis=0)), axis=0) / vmax)
    assert trajectory.duration >= lower_bound


def test_sampled_path_never_overshoots_waypoints_at_a_joint_limit():
    """PCHIP is shape preserving: waypoints on a limit give samples within it."""
    limit = 1.0
    waypoints = np.array([[0.0, 0.0], [0.6, limit], [1.2, limit], [1.8, 0.2], [2.0, limit]])
    trajectory = time_parameterize(waypoints, np.array([1.0, 1.0]), np.array([5.0, 5.0]), 0.002)
    assert trajectory.q[:, 1].max() <= limit + 1e-12
    assert trajectory.q[:, 0].min() >= -1e-12


def test_control_rate_samples_are_evenly_spaced():
    trajectory = time_parameterize([[0.0], [1.0], [0.5]], [1.0], [2.0], 0.005)
    np.testing.assert_allclose(np.diff(trajectory.t), 0.005)
    assert len(trajectory.t) == len(trajectory.q)


def test_a_single_waypoint_is_a_single_sample():
    trajectory = time_parameterize([[0.3, 0.1]], [1.0, 1.0], [1.0, 1.0], 0.004)
    assert trajectory.q.shape == (1, 2)
    assert trajectory.duration == 0.0
