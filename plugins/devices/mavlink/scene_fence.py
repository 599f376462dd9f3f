"""The scene's safety as the autopilot's geofence: exclusion zones from the obstacles, inclusion from the bounds.

Paper 000's safety model (Jain, Hong & Rozenblit 2019, §3): the planned path
keeps the clearance threshold d_thresh from every obstacle except in its
critical regions. For a vehicle whose position is a point (the fence is
about the vehicle's position; the vehicle is a sphere of the plan's
``tip_radius``), the obstacles inflated by ``tip_radius + d_thresh`` are
exactly where it must not be: its exclusion zones. The scene's bounds are
its inclusion zone. PX4 keeps such zones and enforces them itself
(:mod:`.sim.geofence` for the simulated vehicle), so the safety of a flight
no longer depends on the ground station's link.

How an obstacle becomes a zone (:func:`scene_fence`):

* its **footprint** in plan view, exactly or from outside: a circle for
  spheres and for cylinders and capsules standing upright; otherwise the
  convex hull of its projection (box corners as posed, a mesh's vertices,
  tilted cylinders and capsules by their end circles sampled on a
  circumscribed polygon);
* **inflated** by ``tip_radius + margin``: circles exactly (a fence circle),
  polygons by their Minkowski sum with that disc, each rounded corner
  replaced by the polygon circumscribing its arc with at most ``arc_step``
  of turn per vertex (so the zone contains the exact one: 8 vertices for a
  box at the default 45 deg);
* its **margin** is the threshold, except for an obstacle that closes a
  critical region: the plan keeps less than the threshold from it (there is
  no detour), and its zone keeps what the route keeps from it less
  ``critical_tolerance`` (the vehicle must fly the passage, and its tracking
  error must not breach the fence there);
* PX4's fence is two-dimensional (a zone is a prism without top or bottom;
  MAVLink's fence items have no altitude): an obstacle the route flies
  *over or under* (its footprint, inflated, meets the route in plan view: a
  lintel above a door, a low table) cannot be a zone without closing the
  route, and is left out, named in ``unfenced`` with its vertical extent.
  The altitude limit is the fence's ceiling: GF_MAX_VER_DIST, the scene's
  top above home (``ceiling``).

The number of fence items (one per polygon vertex, one per circle) is
checked against the vehicle's fence capacity (PX4 keeps 64 fence points):
a scene with more is refused before any motion, naming the count per zone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import Field
from surgiplan.errors import SurgiplanError
from surgiplan.geometry.primitives import segment_segment_distance
from surgiplan.models import StrictModel
from surgiplan.units import Angle, Length, Vec3

from .zones import Zone

#: GF_ACTION values (PX4's geofence_violation_action)
GF_ACTIONS = {"none": 0, "warning": 1, "hold": 2, "return": 3, "terminate": 4, "land": 5}
#: circles sampled this finely (circumscribed) for the hull of a tilted cylinder or capsule
CIRCLE_SAMPLES = 32


class FenceSettings(StrictModel):
    """The geofence the ground station derives from the scene and uploads before the flight."""

    #: derive, upload (verified by download) and enforce the fence; false: fly without one
    enabled: bool = True
    #: what the vehicle does on a breach (PX4 GF_ACTION)
    action: Literal["none", "warning", "hold", "return", "terminate", "land"] = "hold"
    #: act on a breach predicted a braking distance ahead (PX4 GF_PREDICT 1), so that it stops before the fence;
    #: off by default, as on PX4: turning into a narrow passage (a critical region) it predicts breaches that
    #: the path does not make
    predict: bool = False
    #: an obstacle that closes a critical region is fenced at the clearance the route keeps from it less this
    critical_tolerance: Length = 0.1
    #: rounded corners of polygon zones: at most this much turn per vertex
    arc_step: Angle = Field(default=math.radians(45.0), gt=math.radians(5.0), le=math.radians(90.0))
    #: fence items the vehicle stores (PX4 on NuttX: 64); more is refused before any motion
    capacity: int = Field(default=64, ge=4)
    #: the scene's top as the fence's ceiling (GF_MAX_VER_DIST above home); false: no altitude limit
    ceiling: bool = True


class FenceRefusal(SurgiplanError):
    """The scene cannot be fenced for this route (the message says why)."""


@dataclass
class SceneFence:
    """The zones (scene x, y in m), what each obstacle keeps, what could not be fenced, the ceiling (scene z)."""

    zones: list[Zone]
    margins: dict[str, float] = field(default_factory=dict)
    unfenced: dict[str, str] = field(default_factory=dict)
    ceiling: float | None = None
    ground: float = 0.0

    @property
    def item_count(self) -> int:
        return sum(zone.item_count for zone in self.zones)

    def describe(self) -> dict:
        """For ``result.json``: zones and items, margins kept, obstacles left out and why."""
        return {
            "fence_zones": len(self.zones),
            "fence_items": self.item_count,
            "fence_margins_m": {k: round(v, 6) for k, v in self.margins.items()},
            "fence_unfenced": dict(self.unfenced),
            "fence_ceiling_z_m": self.ceiling,
        }

    def annotation(self) -> list[dict]:
        """The zones as report.html draws them: outline (scene x, y) and the altitudes the vehicle enforces."""
        top = self.ceiling if self.ceiling is not None else self.ground + 10.0
        return [
            {
                "name": zone.name,
                "inclusion": zone.inclusion,
                "outline": np.round(zone.outline(48), 6).tolist(),
                "z": [self.ground, top],
            }
            for zone in self.zones
        ]


# ----------------------------------------------------------------------------- footprints


def _upright(rotation: np.ndarray) -> bool:
    return abs(float(rotation[2, 2])) > 1.0 - 1e-9


def _circle_points(centre: np.ndarray, radius: float, normal: np.ndarray) -> np.ndarray:
    """Vertices of the polygon circumscribing a circle in 3D (so its projection contains the circle's)."""
    normal = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    angles = np.linspace(0.0, 2 * np.pi, CIRCLE_SAMPLES, endpoint=False)
    r = radius / math.cos(math.pi / CIRCLE_SAMPLES)
    return centre + r * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)


def footprint(obstacle) -> tuple[np.ndarray | None, np.ndarray | None, float, float, float]:
    """An obstacle in plan view: (hull vertices (n, 2) counter-clockwise, or None; circle centre (2,), or None;
    circle radius; bottom z; top z), containing its exact projection."""
    kind = type(obstacle).__name__
    pose = obstacle.pose
    centre = np.asarray(pose.translation, float)
    radius = float(getattr(obstacle, "radius", 0.0))
    if kind == "Sphere":
        return None, centre[:2], radius, centre[2] - radius, centre[2] + radius
    if kind in ("Cylinder", "Capsule"):
        half = 0.5 * float(obstacle.length)
        axis = pose.rotation[:, 2]
        ends = np.array([centre - half * axis, centre + half * axis])
        cap = radius if kind == "Capsule" else radius * math.sqrt(max(0.0, 1.0 - axis[2] ** 2))
        bottom, top = float(ends[:, 2].min() - cap), float(ends[:, 2].max() + cap)
        if _upright(pose.rotation):
            return None, centre[:2], radius, bottom, top
        if kind == "Capsule":  # the end spheres project to circles
            points = np.vstack([_circle_points(end, radius, np.array([0.0, 0.0, 1.0])) for end in ends])
        else:
            points = np.vstack([_circle_points(end, radius, axis) for end in ends])
    elif kind == "Box":
        half = 0.5 * np.asarray(obstacle.size, float)
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        points = pose.apply(signs * half)
    else:  # meshes, and any other shape: its triangle mesh (a mesh's hull is exact)
        points = np.asarray(obstacle.to_trimesh().vertices, float)
    return _hull(points[:, :2]), None, 0.0, float(points[:, 2].min()), float(points[:, 2].max())


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull, counter-clockwise (two points for collinear input, one for a single point)."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.unique(np.round(points, 12), axis=0)
    if len(points) >= 3:
        try:
            hull = ConvexHull(points)
            return points[hull.vertices]  # counter-clockwise in 2D
        except QhullError:
            pass  # collinear
    if len(points) == 1:
        return points
    direction = points[-1] - points[0]
    along = points @ direction
    return points[[int(np.argmin(along)), int(np.argmax(along))]]


def inflate(vertices: np.ndarray, distance: float, arc_step: float) -> np.ndarray:
    """The polygon circumscribing the Minkowski sum of a convex counter-clockwise polygon (or a segment, 2
    points) and a disc of ``distance``: each corner's arc replaced by tangent segments, ``arc_step`` of turn at
    most per vertex."""
    out = []
    n = len(vertices)
    for i in range(n):
        previous, corner, following = vertices[i - 1], vertices[i], vertices[(i + 1) % n]
        e_in, e_out = corner - previous, following - corner
        a1 = math.atan2(-e_in[0], e_in[1])  # outward normal of the incoming edge (right of its direction)
        a2 = math.atan2(-e_out[0], e_out[1])
        sweep = (a2 - a1) % (2 * math.pi)
        if n == 2:
            sweep = math.pi
        steps = max(1, math.ceil(sweep / arc_step - 1e-9))
        delta = sweep / steps
        r = distance / math.cos(0.5 * delta)
        for j in range(steps):
            angle = a1 + (j + 0.5) * delta
            out.append(corner + r * np.array([math.cos(angle), math.sin(angle)]))
    return np.array(out)


def _segments_polygon_distance(a: np.ndarray, b: np.ndarray, polygon: np.ndarray) -> float:
    """Least distance (m) in the plane from segments a[i] -> b[i] to a convex polygon, a segment (2 points) or a
    point (1): 0 when one meets it."""
    if len(polygon) >= 3 and Zone.polygon(polygon).contains(a).any():
        return 0.0
    flat = lambda x: np.concatenate([x, np.zeros((*x.shape[:-1], 1))], axis=-1)  # noqa: E731
    edges_a = flat(polygon)[None]
    edges_b = flat(np.roll(polygon, -1, axis=0))[None]
    return float(segment_segment_distance(flat(a)[:, None], flat(b)[:, None], edges_a, edges_b).min())


# ----------------------------------------------------------------------------- the fence


def scene_fence(scene, route, radius: float, threshold: float | None, settings: FenceSettings) -> SceneFence:
    """The geofence of ``scene`` for a vehicle of ``radius`` flying ``route`` ((n, 3) scene points; see the
    module's docstring); :class:`FenceRefusal` when the route leaves the bounds or the ceiling, or the fence
    is beyond the vehicle's capacity."""
    route = np.asarray(route, float).reshape(-1, 3)
    thr = 0.0 if threshold is None else float(threshold)
    a, b = (route[:-1], route[1:]) if len(route) >= 2 else (route, route)
    lo, hi = np.asarray(scene.bounds_min, float), np.asarray(scene.bounds_max, float)
    outside = np.flatnonzero(~scene.in_bounds(route))
    if len(outside):
        p = np.round(route[outside[0]], 3).tolist()
        raise FenceRefusal(
            f"route point {p} m is outside the scene's bounds {lo.tolist()} to {hi.tolist()} m, the fence's inclusion "
            "zone: the vehicle would breach its own geofence (fly within the scene, or set fence.enabled: false)"
        )
    zones = [Zone.polygon([lo[:2], (hi[0], lo[1]), hi[:2], (lo[0], hi[1])], inclusion=True, name="bounds")]
    fence = SceneFence(zones, ground=float(lo[2]), ceiling=float(hi[2]) if settings.ceiling else None)
    for obstacle in scene.obstacles:
        kept = float(np.min(obstacle.segment_sd(a, b))) - radius
        margin = thr if kept >= thr - 1e-9 else max(kept - settings.critical_tolerance, 0.0)
        hull, centre, circle, bottom, top = footprint(obstacle)
        distance = radius + margin
        extent = f"its extent z {bottom:.3g} to {top:.3g} m"
        if hull is None:
            zone = Zone.circle(centre, circle + distance, name=obstacle.name, margin=margin, z=[bottom, top])
            near = float(np.min(np.linalg.norm(_segment_foot(a[:, :2], b[:, :2], centre) - centre, axis=1)))
            overflown = near < circle + distance - 1e-9
        else:
            overflown = _segments_polygon_distance(a[:, :2], b[:, :2], hull) < distance - 1e-9
            zone = None
            step = settings.arc_step
            while not overflown and zone is None:
                outline = inflate(hull, distance, step)
                candidate = Zone.polygon(outline, name=obstacle.name, margin=margin, z=[bottom, top])
                if not any(candidate.segment_enters(p, q) for p, q in zip(a[:, :2], b[:, :2], strict=True)):
                    zone = candidate
                elif step < math.radians(5.0):
                    overflown = True  # the route grazes the exact zone: finer corners would not clear it
                else:
                    step /= 2  # the route passes a corner closer than the circumscribing polygon: finer there
        if overflown:
            fence.unfenced[obstacle.name] = (
                f"the route passes over or under it ({extent}): PX4's fence zones have no top or bottom"
            )
            continue
        fence.zones.append(zone)
        fence.margins[obstacle.name] = margin
    if fence.ceiling is not None and float(route[:, 2].max()) >= fence.ceiling:
        raise FenceRefusal(
            f"the route reaches z {route[:, 2].max():.3f} m, the scene's top {fence.ceiling:.3f} m is the fence's "
            "ceiling (GF_MAX_VER_DIST): lower the route, or set fence.ceiling: false"
        )
    if fence.item_count > settings.capacity:
        counts = ", ".join(f"{z.name} {z.item_count}" for z in sorted(fence.zones, key=lambda z: -z.item_count)[:8])
        raise FenceRefusal(
            f"the scene's geofence needs {fence.item_count} fence items ({counts}, ...), more than the vehicle's "
            f"fence capacity of {settings.capacity} (fence.capacity; PX4 stores 64 fence points): fewer or "
            "simpler obstacles, a coarser fence.arc_step, or fence.enabled: false"
        )
    return fence


def _segment_foot(a: np.ndarray, b: np.ndarray, point: np.ndarray) -> np.ndarray:
    """The point of each segment a[i] -> b[i] (plane) nearest to ``point``."""
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    return a + t[:, None] * d


def rally_positions(scene, entries: list[str | Vec3]) -> np.ndarray:
    """Rally points (scene coordinates, m) from scene point names or coordinates; :class:`FenceRefusal` for an
    unknown name."""
    out = []
    for k, entry in enumerate(entries):
        if isinstance(entry, str):
            if entry not in scene.points:
                known = ", ".join(sorted(scene.points)) or "none"
                raise FenceRefusal(f"rally_points[{k}]: the scene has no point '{entry}' (its points: {known})")
            out.append(np.asarray(scene.points[entry], float))
        else:
            out.append(np.asarray(entry, float))
    return np.array(out, float).reshape(-1, 3)
