"""Geofence zones in a horizontal plane, as PX4 keeps them, and their MAVLink items: one module for both ends.

MAVLink (``MAV_MISSION_TYPE_FENCE``, the mission protocol) carries a geofence
as items: MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION / _EXCLUSION (5001,
5002; one item per vertex, param1 the polygon's vertex count, sent in order),
MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION / _EXCLUSION (5003, 5004; param1 the
radius in m) and MAV_CMD_NAV_FENCE_RETURN_POINT (5000); latitude and
longitude in x and y, param7 "reserved" (the spec gives fence items no
altitude: PX4's zones are vertical prisms without top or bottom, and its
altitude limit is the fence-wide GF_MAX_VER_DIST above home). Rally points
are MAV_CMD_NAV_RALLY_POINT (5100) items of ``MAV_MISSION_TYPE_RALLY`` with
an altitude.

PX4's rules (``src/modules/navigator/geofence.cpp``), which :func:`inside_fence`
and :func:`path_clear` follow:

* a point is inside the fence when it is inside *every* inclusion zone and
  outside every exclusion zone (``isInsidePolygonOrCircle``);
* inside a polygon: the PNPOLY crossing test (W. R. Franklin), points on an
  edge counted as PNPOLY counts them; inside a circle: strictly closer than
  the radius to its centre;
* a mission's waypoints, and (PX4 1.16's feasibility checker) the straight
  legs between them, must stay inside the fence.

Coordinates here are metres in any right-handed horizontal plane; the
ground station builds zones in scene coordinates (:mod:`.scene_fence`) and
maps them to the vehicle's local north/east (:meth:`Zone.mapped`), the
vehicle keeps them in its local north/east; :func:`fence_items` and
:func:`zones_from_items` convert to and from latitude/longitude with PX4's
projection (:class:`~.conventions.MapProjection`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from surgiplan.errors import SurgiplanError

from .conventions import MapProjection
from .link import enum_name, mavlink
from .mission import MissionItem

C = mavlink
POLYGON_COMMANDS = {
    C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True,
    C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False,
}
CIRCLE_COMMANDS = {C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}
GLOBAL_RELATIVE = {C.MAV_FRAME_GLOBAL_RELATIVE_ALT, C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}


@dataclass(frozen=True)
class Zone:
    """An inclusion or exclusion zone: a polygon (``vertices``, (n, 2) m) or a circle (``centre``, ``radius``)."""

    inclusion: bool
    vertices: np.ndarray | None = None
    centre: np.ndarray | None = None
    radius: float = 0.0
    #: what it stands for (an obstacle's name, ``bounds``); not sent to the vehicle
    name: str = ""
    #: the ground station's notes on it (margin kept, vertical extent of the obstacle); not sent either
    notes: dict = field(default_factory=dict, compare=False)

    @property
    def kind(self) -> str:
        return "circle" if self.vertices is None else "polygon"

    @property
    def item_count(self) -> int:
        """Fence items the zone takes: one per vertex, one for a circle."""
        return 1 if self.vertices is None else len(self.vertices)

    @classmethod
    def polygon(cls, vertices, inclusion: bool = False, name: str = "", **notes) -> Zone:
        vertices = np.asarray(vertices, float).reshape(-1, 2)
        if len(vertices) < 3:
            raise ValueError(f"zone '{name}': a fence polygon needs 3 vertices at least, got {len(vertices)}")
        return cls(inclusion, vertices, None, 0.0, name, dict(notes))

    @classmethod
    def circle(cls, centre, radius: float, inclusion: bool = False, name: str = "", **notes) -> Zone:
        if not radius > 0:
            raise ValueError(f"zone '{name}': a fence circle needs a positive radius, got {radius}")
        return cls(inclusion, None, np.asarray(centre, float).reshape(2), float(radius), name, dict(notes))

    def mapped(self, transform: Callable[[np.ndarray], np.ndarray]) -> Zone:
        """The zone with its points mapped by ``transform`` ((n, 2) -> (n, 2), a rigid motion of the plane)."""
        if self.vertices is None:
            return Zone(self.inclusion, None, transform(self.centre[None])[0], self.radius, self.name, self.notes)
        return Zone(self.inclusion, transform(self.vertices), None, 0.0, self.name, self.notes)

    # ------------------------------------------------------------------ geometry
    def contains(self, points) -> np.ndarray:
        """Whether each point (..., 2) is inside (PNPOLY for a polygon, strictly within the radius for a circle)."""
        p = np.asarray(points, float).reshape(-1, 2)
        if self.vertices is None:
            return np.sum((p - self.centre) ** 2, axis=1) < self.radius**2
        v = self.vertices
        x, y = p[:, 0:1], p[:, 1:2]
        xi, yi = v[:, 0][None], v[:, 1][None]
        xj, yj = np.roll(v[:, 0], 1)[None], np.roll(v[:, 1], 1)[None]
        # PX4's loop: (lon_i >= lon) != (lon_j >= lon) and lat <= (lat_j - lat_i)(lon - lon_i)/(lon_j - lon_i) + lat_i
        straddles = (yi >= y) != (yj >= y)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = (xj - xi) * (y - yi) / (yj - yi) + xi
        return np.logical_xor.reduce(straddles & (x <= at), axis=1)

    def boundary_distance(self, points) -> np.ndarray:
        """Distance (m) of each point to the zone's boundary (positive on either side)."""
        p = np.asarray(points, float).reshape(-1, 2)
        if self.vertices is None:
            return np.abs(np.linalg.norm(p - self.centre, axis=1) - self.radius)
        a = self.vertices
        b = np.roll(a, -1, axis=0)
        ab = b - a
        t = np.einsum("pkd,kd->pk", p[:, None, :] - a[None], ab) / np.maximum(np.einsum("kd,kd->k", ab, ab), 1e-300)
        foot = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
        return np.min(np.linalg.norm(p[:, None, :] - foot, axis=2), axis=1)

    def segment_enters(self, a, b) -> bool:
        """Whether the straight segment a -> b has a point strictly inside the zone."""
        a, b = np.asarray(a, float).reshape(2), np.asarray(b, float).reshape(2)
        if self.vertices is None:
            d = b - a
            t = float(np.clip(np.dot(self.centre - a, d) / max(float(np.dot(d, d)), 1e-300), 0.0, 1.0))
            return float(np.sum((a + t * d - self.centre) ** 2)) < self.radius**2
        # cut the segment where it meets the polygon's edges; each piece is wholly inside or outside
        cuts = [0.0, 1.0]
        v = self.vertices
        w = np.roll(v, -1, axis=0)
        d = b - a
        e = w - v
        denominator = d[0] * e[:, 1] - d[1] * e[:, 0]
        ok = np.abs(denominator) > 1e-15
        rel = v - a
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (rel[:, 0] * e[:, 1] - rel[:, 1] * e[:, 0]) / denominator
            s = (rel[:, 0] * d[1] - rel[:, 1] * d[0]) / denominator
        hit = ok & (t > 0) & (t < 1) & (s >= -1e-12) & (s <= 1 + 1e-12)
        cuts += t[hit].tolist()
        cuts = np.unique(np.clip(cuts, 0.0, 1.0))
        middles = a + 0.5 * (cuts[:-1] + cuts[1:])[:, None] * d
        inside = self.contains(middles) & (self.boundary_distance(middles) > 1e-9)
        ends = np.array([a, b])
        return bool(np.any(inside) or np.any(self.contains(ends) & (self.boundary_distance(ends) > 1e-9)))

    def outline(self, segments: int = 64) -> np.ndarray:
        """The boundary as a closed polyline (k, 2) (a circle sampled with ``segments`` points)."""
        if self.vertices is not None:
            return np.vstack([self.vertices, self.vertices[:1]])
        angles = np.linspace(0.0, 2 * np.pi, segments + 1)
        return self.centre + self.radius * np.column_stack([np.cos(angles), np.sin(angles)])


def inside_fence(zones: Sequence[Zone], points) -> np.ndarray:
    """PX4's test: inside every inclusion zone and outside every exclusion zone (no zones: everywhere)."""
    p = np.asarray(points, float).reshape(-1, 2)
    ok = np.ones(len(p), dtype=bool)
    for zone in zones:
        inside = zone.contains(p)
        ok &= inside if zone.inclusion else ~inside
    return ok


def path_clear(zones: Sequence[Zone], a, b) -> bool:
    """Whether the straight segment a -> b stays inside the fence (ends included)."""
    a, b = np.asarray(a, float).reshape(2), np.asarray(b, float).reshape(2)
    if not inside_fence(zones, np.array([a, b])).all():
        return False
    for zone in zones:
        if zone.inclusion:
            # inside at both ends: the segment leaves a zone only where it enters its complement
            if _leaves(zone, a, b):
                return False
        elif zone.segment_enters(a, b):
            return False
    return True


def _leaves(zone: Zone, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether a segment with both ends inside ``zone`` has a point outside it (sampled at its edge crossings)."""
    if zone.vertices is None:
        return False  # a disc is convex
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / 0.05)) + 1)
    samples = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    return not bool(zone.contains(samples).all())


# ----------------------------------------------------------------------------- items


def fence_items(zones: Sequence[Zone], projection: MapProjection, frame: int = C.MAV_FRAME_GLOBAL) -> list[MissionItem]:
    """The zones (local north, east in m about ``projection``'s reference) as fence items, in order."""
    items: list[MissionItem] = []
    for zone in zones:
        if zone.vertices is None:
            lat, lon = projection.reproject(zone.centre[0], zone.centre[1])
            command = C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if zone.inclusion else C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
            items.append(MissionItem(command, frame, float(lat), float(lon), 0.0, param1=zone.radius))
            continue
        command = C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
        if zone.inclusion:
            command = C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
        lat, lon = projection.reproject(zone.vertices[:, 0], zone.vertices[:, 1])
        n = float(len(zone.vertices))
        items += [MissionItem(command, frame, float(a), float(o), 0.0, param1=n) for a, o in zip(lat, lon, strict=True)]
    return items


class FenceFormatError(SurgiplanError, ValueError):
    """A fence list that does not describe zones (a polygon whose vertices disagree on their count, ...)."""


def zones_from_items(items: Sequence[MissionItem], projection: MapProjection) -> tuple[list[Zone], int]:
    """Zones (local north, east in m) from fence items, and how many return points there were;
    :class:`FenceFormatError` names the first item that does not fit."""
    zones: list[Zone] = []
    returns = 0
    seq = 0
    while seq < len(items):
        item = items[seq]
        if item.command == C.MAV_CMD_NAV_FENCE_RETURN_POINT:
            returns += 1
            seq += 1
            continue
        if item.command in CIRCLE_COMMANDS:
            north, east = projection.project(item.x, item.y)
            zones.append(Zone.circle((float(north), float(east)), item.param1, CIRCLE_COMMANDS[item.command]))
            seq += 1
            continue
        if item.command not in POLYGON_COMMANDS:
            raise FenceFormatError(f"item {seq}: {enum_name('MAV_CMD', item.command)} is not a fence item")
        count = round(item.param1)
        group = items[seq : seq + count]
        if count < 3 or len(group) < count:
            raise FenceFormatError(f"item {seq}: a polygon of {count} vertices, {len(group)} items left")
        for k, vertex in enumerate(group):
            if vertex.command != item.command or round(vertex.param1) != count:
                raise FenceFormatError(
                    f"item {seq + k}: vertex {k} of a {count}-vertex polygon that began at item {seq} is "
                    f"{enum_name('MAV_CMD', vertex.command)} with param1 {vertex.param1:g}"
                )
        north, east = projection.project([v.x for v in group], [v.y for v in group])
        zones.append(Zone.polygon(np.column_stack([north, east]), POLYGON_COMMANDS[item.command]))
        seq += count
    return zones, returns


def rally_items(points, projection: MapProjection, heights) -> list[MissionItem]:
    """Rally points (local north, east in m; ``heights`` above home in m) as MAV_CMD_NAV_RALLY_POINT items in
    MAV_FRAME_GLOBAL_RELATIVE_ALT."""
    points = np.asarray(points, float).reshape(-1, 2)
    lat, lon = projection.reproject(points[:, 0], points[:, 1])
    return [
        MissionItem(C.MAV_CMD_NAV_RALLY_POINT, C.MAV_FRAME_GLOBAL_RELATIVE_ALT, float(a), float(o), float(h))
        for a, o, h in zip(np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(heights), strict=True)
    ]
