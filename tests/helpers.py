"""Independent measurements for tests: everything here uses coal directly, not surgiplan's formulas."""

from __future__ import annotations

import coal
import numpy as np
from surgiplan.geometry.shapes import rotation_from_z


def _request() -> coal.DistanceRequest:
    request = coal.DistanceRequest()
    request.gjk_tolerance = 1e-11  # the default 1e-6 is coarser than what we compare
    return request


def coal_point_distance(obstacle, points) -> np.ndarray:
    """Distance of points to one obstacle, by coal (a sphere of radius 0 against the shape).

    Signed for primitives (EPA inside); for meshes coal gives the unsigned distance to the surface.
    """
    geometry, transform = obstacle.coal_geometry(), obstacle.coal_transform()
    request, result = _request(), coal.DistanceResult()
    out = []
    for p in np.atleast_2d(points):
        result.clear()
        out.append(
            coal.distance(geometry, transform, coal.Sphere(0.0), coal.Transform3s(np.eye(3), p), request, result)
        )
    return np.array(out)


def coal_segment_distance(obstacle, a, b, radius: float = 0.0) -> np.ndarray:
    """Distance from the capsule a→b of ``radius`` to one obstacle, by coal."""
    geometry, transform = obstacle.coal_geometry(), obstacle.coal_transform()
    request, result = _request(), coal.DistanceResult()
    out = []
    for p, q in zip(np.atleast_2d(a), np.atleast_2d(b), strict=True):
        d = q - p
        length = float(np.linalg.norm(d))
        rotation = rotation_from_z(d / length) if length > 0 else np.eye(3)
        result.clear()
        out.append(
            coal.distance(
                geometry,
                transform,
                coal.Capsule(radius, length),
                coal.Transform3s(rotation, 0.5 * (p + q)),
                request,
                result,
            )
        )
    return np.array(out)


def coal_scene_point_distance(scene, points) -> np.ndarray:
    return np.min([coal_point_distance(o, points) for o in scene.obstacles], axis=0)


def coal_scene_segment_distance(scene, a, b, radius: float = 0.0) -> np.ndarray:
    return np.min([coal_segment_distance(o, a, b, radius) for o in scene.obstacles], axis=0)


def dense_min_clearance(scene, a, b, spacing: float) -> np.ndarray:
    """Minimum coal point distance over points at most ``spacing`` apart on each segment."""
    out = []
    for p, q in zip(np.atleast_2d(a), np.atleast_2d(b), strict=True):
        n = max(2, int(np.ceil(np.linalg.norm(q - p) / spacing)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        out.append(coal_scene_point_distance(scene, p + t * (q - p)).min())
    return np.array(out)
