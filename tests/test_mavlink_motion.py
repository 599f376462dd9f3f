"""Frames, PX4 modes, the timed path and the simulated airframe, checked against independent measures."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree
from surgiplan.plugins.devices.mavlink.conventions import (
    EARTH_RADIUS,
    PX4_MODES,
    LocalFrame,
    MapProjection,
    px4_custom_mode,
    px4_mode_command,
    px4_mode_from_command,
    px4_mode_name,
)
from surgiplan.plugins.devices.mavlink.profile import TimedPath
from surgiplan.plugins.devices.mavlink.sim.model import PointMassMultirotor
from surgiplan.plugins.devices.mavlink.sim.settings import Airframe, Wind


def dense_polyline(points: np.ndarray, spacing: float) -> np.ndarray:
    """The polyline sampled every ``spacing`` metres (an independent stand-in for point-to-polyline distance)."""
    pieces = []
    for a, b in itertools.pairwise(points):
        n = max(2, math.ceil(np.linalg.norm(b - a) / spacing) + 1)
        pieces.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    return np.vstack(pieces)


# ----------------------------------------------------------------------------- frames


def test_default_frame_is_enu_scene_to_ned():
    frame = LocalFrame(origin=(2.0, 6.0, 0.0))
    # 1 m east (scene +x), 2 m north (+y), 3 m up (+z) of the origin
    ned = frame.to_ned([3.0, 8.0, 3.0])
    assert ned == pytest.approx([2.0, 1.0, -3.0])
    assert frame.from_ned(ned) == pytest.approx([3.0, 8.0, 3.0])
    assert np.linalg.det(frame.rotation) == pytest.approx(1.0)


def test_frame_heading_turns_the_scene_about_the_vertical():
    frame = LocalFrame(heading=0.0)  # scene x points north
    assert frame.to_ned([1.0, 0.0, 0.0]) == pytest.approx([1.0, 0.0, 0.0])
    assert frame.to_ned([0.0, 1.0, 0.0]) == pytest.approx([0.0, -1.0, 0.0])  # y is then west
    rng = np.random.default_rng(0)
    points = rng.uniform(-10, 10, (50, 3))
    turned = LocalFrame((1.0, -2.0, 0.5), heading=1.1)
    assert turned.from_ned(turned.to_ned(points)) == pytest.approx(points)
    distances = np.linalg.norm(points[1:] - points[:-1], axis=1)
    ned = turned.to_ned(points)
    assert np.linalg.norm(ned[1:] - ned[:-1], axis=1) == pytest.approx(distances)


def test_map_projection_round_trip_and_great_circle_distances():
    projection = MapProjection(47.397742, 8.545594)
    north = np.array([0.0, 10.0, -250.0, 1234.5])
    east = np.array([0.0, -3.0, 400.0, -77.0])
    lat, lon = projection.reproject(north, east)
    back_n, back_e = projection.project(lat, lon)
    assert back_n == pytest.approx(north, abs=1e-6) and back_e == pytest.approx(east, abs=1e-6)
    # azimuthal equidistant: the distance from the origin is the great-circle distance (haversine)
    lat0, lon0 = np.radians(47.397742), np.radians(8.545594)
    phi, lam = np.radians(lat), np.radians(lon)
    h = np.sin((phi - lat0) / 2) ** 2 + np.cos(lat0) * np.cos(phi) * np.sin((lam - lon0) / 2) ** 2
    great_circle = 2 * EARTH_RADIUS * np.arcsin(np.sqrt(h))
    assert great_circle == pytest.approx(np.hypot(north, east), abs=1e-6)


def test_px4_modes_match_px4_custom_mode_numbers():
    # px4_custom_mode.h: AUTO = 4 with sub modes LOITER 3, MISSION 4, RTL 5, LAND 6; OFFBOARD = 6
    assert px4_custom_mode("mission") == (4 << 16) | (4 << 24)
    assert px4_custom_mode("land") == (4 << 16) | (6 << 24)
    assert px4_custom_mode("offboard") == 6 << 16
    for mode in PX4_MODES:
        assert px4_mode_name(px4_custom_mode(mode)) == mode
        _, main, sub = px4_mode_command(mode)
        assert px4_mode_from_command(main, sub) == mode
    assert px4_mode_from_command(42, 0) is None


# ----------------------------------------------------------------------------- the timed path

CORNERS = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [4, 3, 2], [8, 3, 2], [6, 3, 2], [6, 5, 2.5]], float)


def test_timed_path_stays_within_the_corner_deviation_and_ends_at_rest():
    deviation = 0.1
    path = TimedPath.along(CORNERS, 2.0, 1.0, deviation, vertical_speed=0.5)
    t = np.linspace(-1.0, path.duration + 1.0, 40001)
    p, v, _ = path.sample(t)
    distance, _ = cKDTree(dense_polyline(CORNERS, 1e-3)).query(p)
    assert distance.max() <= deviation + 1e-3
    assert p[0] == pytest.approx(CORNERS[0]) and p[-1] == pytest.approx(CORNERS[-1])
    assert np.abs(v[[0, -1]]).max() == 0.0
    # each corner is passed at its arc's middle, exactly the deviation from it
    at_corners = path.sample(path.waypoint_time)[0]
    gaps = np.linalg.norm(at_corners - CORNERS, axis=1)
    assert gaps[[0, -1]] == pytest.approx([0.0, 0.0], abs=1e-9)
    turns = [1, 2, 3, 5]  # the reversal at index 4 is passed at rest, through the point itself
    assert gaps[turns] == pytest.approx(deviation, abs=1e-9)
    assert gaps[4] == pytest.approx(0.0, abs=1e-9)


def test_timed_path_is_consistent_and_respects_its_limits():
    speed, accel, vertical = 2.0, 1.0, 0.5
    path = TimedPath.along(CORNERS, speed, accel, 0.1, vertical_speed=vertical)
    t = np.linspace(0.0, path.duration, 200001)
    dt = t[1] - t[0]
    p, v, a = path.sample(t)
    # velocity is the derivative of position, acceleration the derivative of velocity (finite differences)
    assert np.abs(np.diff(p, axis=0) / dt - 0.5 * (v[1:] + v[:-1])).max() < 1e-4
    numeric = np.diff(v, axis=0) / dt
    smooth = np.linalg.norm(numeric - 0.5 * (a[1:] + a[:-1]), axis=1)
    assert np.percentile(smooth, 99.9) < 1e-3  # away from the few instants where the acceleration switches
    assert np.linalg.norm(np.diff(v, axis=0), axis=1).max() < 2 * accel * dt  # C1: no velocity jumps
    assert np.linalg.norm(v, axis=1).max() <= speed + 1e-9
    assert np.abs(v[:, 2]).max() <= vertical + 1e-9
    assert np.linalg.norm(a, axis=1).max() <= math.sqrt(2) * accel + 1e-9


@pytest.mark.parametrize(("length", "expected"), [(10.0, 10.0 / 2.0 + 2.0 / 1.0), (2.0, 2 * math.sqrt(2.0 / 1.0))])
def test_single_segment_durations_are_the_trapezoid_and_triangle_formulas(length, expected):
    path = TimedPath.along([[0, 0, 0], [length, 0, 0]], 2.0, 1.0, 0.1)
    assert path.duration == pytest.approx(expected)
    assert path.time_at([length]) == pytest.approx([expected])
    assert path.arc_length([expected / 2]) == pytest.approx([length / 2])


def test_repeated_waypoints_and_single_points():
    path = TimedPath.along([[0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 0, 0]], 1.0, 1.0, 0.05)
    assert path.waypoint_time[0] == path.waypoint_time[1] == 0.0
    assert path.waypoint_time[2] == path.waypoint_time[3] == pytest.approx(path.duration)
    still = TimedPath.along([[1, 2, 3]], 1.0, 1.0, 0.05)
    assert still.duration == 0.0
    np.testing.assert_allclose(still.sample([0.0, 5.0])[0], [[1, 2, 3], [1, 2, 3]])


# ----------------------------------------------------------------------------- the airframe


def fly(model: PointMassMultirotor, reference, seconds: float, dt: float = 0.01):
    trace = []
    for _ in range(round(seconds / dt)):
        model.step(dt, reference, armed=True)
        trace.append((model.p.copy(), model.v.copy()))
    return np.array([x[0] for x in trace]), np.array([x[1] for x in trace])


def test_airframe_limits_speed_climb_and_acceleration():
    frame = Airframe(max_speed=3.0, max_climb=1.0, max_descent=0.8, max_acceleration=2.0)
    model = PointMassMultirotor(frame, (0, 0, 0), Wind())
    target = (np.array([40.0, 0.0, -10.0]), np.zeros(3), np.zeros(3))
    p, v = fly(model, target, 30.0)
    assert np.linalg.norm(v[:, :2], axis=1).max() <= 3.0 + 1e-6
    assert -v[:, 2].max() <= 0.8 + 1e-6 and -v[:, 2].min() <= 1.0 + 1e-6  # NED: up is negative z
    accel = np.linalg.norm(np.diff(v, axis=0), axis=1) / 0.01
    assert accel.max() <= 2.0 * (1 + 1e-6) + frame.drag * 3.2  # thrust authority plus what drag does
    assert p[-1] == pytest.approx([40.0, 0.0, -10.0], abs=0.05)


def test_airframe_rejects_a_steady_wind_by_its_integral():
    model = PointMassMultirotor(Airframe(), (0, 0, 0), Wind(mean=(2.0, -1.0, 0.0)))
    hover = (np.array([0.0, 0.0, -2.0]), np.zeros(3), np.zeros(3))
    p, _ = fly(model, hover, 40.0)
    drift = np.linalg.norm(p[:, :2], axis=1)
    assert drift.max() > 0.1  # the wind pushes it first ...
    assert drift[-1] < 0.01  # ... and the integral brings it back


def test_disarmed_vehicle_stays_on_the_ground():
    model = PointMassMultirotor(Airframe(), (1, 2, 0), Wind(mean=(3.0, 0.0, 0.0), gust=1.0))
    for _ in range(200):
        model.step(0.01, (np.array([5.0, 2.0, -3.0]), np.zeros(3), np.zeros(3)), armed=False)
    assert model.p == pytest.approx([1, 2, 0]) and not model.airborne


def test_armed_vehicle_idling_on_its_pad_stays_there_in_gusts():
    """The ground holds a vehicle whose thrust is at or below hover, against the wind too: an upward gust
    must not lift it (it used to drift up by micrometres, and how long it idled changed the flight)."""
    model = PointMassMultirotor(Airframe(), (1, 2, 0), Wind(mean=(0.5, 0.5, -0.4), gust=1.0), seed=3)
    pad = (np.array([1.0, 2.0, 0.0]), np.zeros(3), np.zeros(3))
    for _ in range(500):
        model.step(0.01, pad, armed=True)
    assert model.p.tolist() == [1.0, 2.0, 0.0] and model.v.tolist() == [0.0, 0.0, 0.0] and not model.airborne
    climb = (np.array([1.0, 2.0, -1.0]), np.zeros(3), np.zeros(3))
    model.step(0.01, climb, armed=True)
    assert model.airborne and model.p[2] < 0  # asked to climb, it leaves the ground


def test_gusts_depend_on_airborne_time_only():
    """Two vehicles with the same seed, one idling on its pad ten times longer: after take-off both meet
    the same gusts and fly the same flight, to the last bit (the pad time is wall-clock time in a
    simulation that runs faster than real time while a ground station connects)."""
    wind = Wind(mean=(0.3, -0.2, 0.0), gust=0.8, gust_time=1.5)
    climb = (np.array([0.0, 0.0, -2.0]), np.zeros(3), np.zeros(3))
    pad = (np.zeros(3), np.zeros(3), np.zeros(3))
    flights = []
    for idle in (20, 200):
        model = PointMassMultirotor(Airframe(), (0, 0, 0), wind, seed=7)
        for _ in range(idle):
            model.step(0.01, pad, armed=True)
        trace = []
        for _ in range(800):
            model.step(0.01, climb, armed=True)
            trace.append(np.concatenate([model.p, model.v, model.wind]))
        flights.append(np.array(trace))
    assert np.array_equal(flights[0], flights[1])
    # and the gusts are really there, at their standard deviation (loosely: 8 s of a 1.5 s process)
    gust = flights[0][:, 6:8] - [0.3, -0.2]
    assert 0.2 < gust.std() < 1.6 and np.ptp(gust[:, 0]) > 0.5
