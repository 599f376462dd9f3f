"""Conventions both ends of the link share: frames (scene, local NED, geodetic) and PX4's flight modes.

Frames. A scene is drawn with z up; MAVLink vehicles report and take local
positions in NED (x north, y east, z down, metres) about their local origin
(the EKF origin). :class:`LocalFrame` maps scene coordinates to NED given
where the local origin is in the scene and which way the scene's x axis
points (its heading, clockwise from north; the default 90 deg makes the scene
x east, y north, z up: ENU).

Mission items in global frames carry latitude and longitude; PX4 converts
them to its local frame with an azimuthal equidistant projection about the
EKF origin on a sphere of radius 6371 km (PX4 ``lib/geo``, ``MapProjection``).
:class:`MapProjection` is the same projection, so a waypoint sent as
latitude/longitude lands on the local point it was computed from (up to the
1e-7 deg quantisation of MISSION_ITEM_INT, about 1.1 cm).

Flight modes. PX4 encodes its modes in HEARTBEAT.custom_mode (main mode in
bits 16-23, sub mode in bits 24-31) and sets them with MAV_CMD_DO_SET_MODE
(param1 base mode, param2 main mode, param3 sub mode); pymavlink's
``px4_map`` and ``interpret_px4_mode`` hold the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .link import mavutil

#: PX4's Earth radius for the local projection (m), CONSTANTS_RADIUS_OF_EARTH
EARTH_RADIUS = 6371000.0

#: surgiplan's names for the modes it uses -> PX4's names (pymavlink px4_map keys)
PX4_MODES = {
    "mission": "MISSION",
    "offboard": "OFFBOARD",
    "land": "LAND",
    "return": "RTL",
    "hold": "LOITER",
    "takeoff": "TAKEOFF",
    "position": "POSCTL",
}


@dataclass(frozen=True)
class LocalFrame:
    """Scene coordinates <-> local NED.

    Attributes:
        origin: the local NED origin in scene coordinates (m).
        heading: direction of the scene's +x axis, clockwise from north (rad).
    """

    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    heading: float = np.pi / 2

    @property
    def rotation(self) -> np.ndarray:
        """Columns: the scene's x, y, z axes expressed in NED (a proper rotation)."""
        c, s = np.cos(self.heading), np.sin(self.heading)
        return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])

    def to_ned(self, points) -> np.ndarray:
        """Scene points (..., 3) to local NED (m)."""
        return (np.asarray(points, float) - np.asarray(self.origin)) @ self.rotation.T

    def from_ned(self, points) -> np.ndarray:
        """Local NED points (..., 3) to scene coordinates (m)."""
        return np.asarray(points, float) @ self.rotation + np.asarray(self.origin)

    def vector_to_ned(self, vectors) -> np.ndarray:
        return np.asarray(vectors, float) @ self.rotation.T

    def vector_from_ned(self, vectors) -> np.ndarray:
        return np.asarray(vectors, float) @ self.rotation


@dataclass(frozen=True)
class MapProjection:
    """PX4's azimuthal equidistant projection about a reference (degrees); x north, y east (m)."""

    latitude: float
    longitude: float

    def project(self, latitude, longitude) -> tuple[np.ndarray, np.ndarray]:
        """Latitude, longitude (deg) to local north, east (m)."""
        lat0, lon0 = np.radians(self.latitude), np.radians(self.longitude)
        lat, lon = np.radians(np.asarray(latitude, float)), np.radians(np.asarray(longitude, float))
        cos_d_lon = np.cos(lon - lon0)
        arg = np.clip(np.sin(lat0) * np.sin(lat) + np.cos(lat0) * np.cos(lat) * cos_d_lon, -1.0, 1.0)
        c = np.arccos(arg)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(np.abs(c) > 1e-12, c / np.sin(c), 1.0)
        north = k * (np.cos(lat0) * np.sin(lat) - np.sin(lat0) * np.cos(lat) * cos_d_lon) * EARTH_RADIUS
        east = k * np.cos(lat) * np.sin(lon - lon0) * EARTH_RADIUS
        return north, east

    def reproject(self, north, east) -> tuple[np.ndarray, np.ndarray]:
        """Local north, east (m) to latitude, longitude (deg)."""
        lat0, lon0 = np.radians(self.latitude), np.radians(self.longitude)
        x = np.asarray(north, float) / EARTH_RADIUS
        y = np.asarray(east, float) / EARTH_RADIUS
        c = np.hypot(x, y)
        sin_c, cos_c = np.sin(c), np.cos(c)
        with np.errstate(invalid="ignore", divide="ignore"):
            lat = np.where(c > 0, np.arcsin(cos_c * np.sin(lat0) + x * sin_c * np.cos(lat0) / c), lat0)
        lon = np.where(c > 0, lon0 + np.arctan2(y * sin_c, c * np.cos(lat0) * cos_c - x * np.sin(lat0) * sin_c), lon0)
        return np.degrees(lat), np.degrees(lon)


def px4_mode_command(mode: str) -> tuple[float, float, float]:
    """MAV_CMD_DO_SET_MODE params 1-3 for one of :data:`PX4_MODES`."""
    base, main, sub = mavutil.px4_map[PX4_MODES[mode]]
    return float(base), float(main), float(sub)


def px4_custom_mode(mode: str) -> int:
    """HEARTBEAT.custom_mode of a PX4 mode."""
    _, main, sub = mavutil.px4_map[PX4_MODES[mode]]
    return (int(main) << 16) | (int(sub) << 24)


def px4_mode_name(custom_mode: int) -> str:
    """surgiplan's name of the PX4 mode in a HEARTBEAT (the PX4 name, lower case, when it has none)."""
    name = mavutil.interpret_px4_mode(0, int(custom_mode))
    for ours, theirs in PX4_MODES.items():
        if theirs == name:
            return ours
    return name.lower()


def px4_mode_from_command(main: float, sub: float) -> str | None:
    """The mode a DO_SET_MODE (param2 main, param3 sub) asks for, or None when PX4 has no such mode."""
    name = px4_mode_name((int(main) << 16) | (int(sub) << 24))
    return name if name in PX4_MODES else None
