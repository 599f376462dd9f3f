"""Visibility of the area of interest A from the camera V (paper 002 §IV-B).

The paper renders the scene and counts A's pixels with GPU occlusion
queries. We cast rays on the CPU with trimesh (Embree through ``embreex``
when it is installed, else trimesh's R-tree ray-triangle test): A is sampled
on a square grid, and a sample point is visible when the *segment* from it
to the camera meets no occluder. Only hits between the point and the camera
count: a ray is cast from the point towards the camera and its first hit is
compared with the camera's distance, so triangles behind the camera never
occlude. Occluders are the deformed flap's boundary surface, the obstacles
and, optionally, the gripper.

A point of A lying under the resting flap is inside the flap's volume (A is
lifted a micrometre above its plane so that the flap's lower face, resting
on the same plane, is not grazed); its ray leaves through the flap's upper
face and is blocked, as it should be.
"""

from __future__ import annotations

import numpy as np
import trimesh
from matplotlib.path import Path as PolygonPath

from .settings import VisibilityModel

#: A is sampled this far above its plane (m)
LIFT = 1e-6


def area_points(settings: VisibilityModel) -> np.ndarray:
    """Sample points (p, 3) of A: the centres of the ``resolution`` grid cells inside the polygon."""
    polygon = np.asarray(settings.area, dtype=float)
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    h = settings.resolution
    xs = np.arange(lo[0] + 0.5 * h, hi[0], h)
    ys = np.arange(lo[1] + 0.5 * h, hi[1], h)
    grid = np.stack(np.meshgrid(xs, ys, indexing="xy"), axis=-1).reshape(-1, 2)
    inside = PolygonPath(polygon).contains_points(grid) if len(grid) else np.zeros(0, dtype=bool)
    points = grid[inside]
    if len(points) == 0:  # a polygon thinner than one cell: its vertices' centroid
        points = polygon.mean(axis=0, keepdims=True)
    return np.column_stack([points, np.full(len(points), settings.height + LIFT)])


class Visibility:
    """Visible fraction of A for a deformed flap, with fixed occluders (obstacles) and a movable gripper."""

    def __init__(self, settings: VisibilityModel, obstacles: list[trimesh.Trimesh], gripper: list[trimesh.Trimesh]):
        self.settings = settings
        self.points = area_points(settings)
        self.camera = np.asarray(settings.camera, dtype=float)
        offset = self.camera - self.points
        self.distance = np.linalg.norm(offset, axis=1)
        if np.any(self.distance <= 0):
            raise ValueError("the camera lies on the area of interest")
        self.directions = offset / self.distance[:, None]
        fixed = trimesh.util.concatenate(obstacles) if obstacles else None
        self._fixed = (np.asarray(fixed.vertices), np.asarray(fixed.faces)) if fixed is not None else None
        self._gripper = trimesh.util.concatenate(gripper) if gripper else None

    def visible(
        self, vertices: np.ndarray, triangles: np.ndarray, gripper_pose: np.ndarray | None = None
    ) -> np.ndarray:
        """Per point of A (p,) bool: no occluder between it and the camera.

        ``vertices`` (n, 3) and ``triangles`` (t, 3): the flap's surface;
        ``gripper_pose`` 4 x 4 (None: the gripper does not occlude).
        """
        parts_v = [np.asarray(vertices, dtype=float)]
        parts_f = [np.asarray(triangles, dtype=np.int64)]
        count = len(parts_v[0])
        if self._fixed is not None:
            parts_v.append(self._fixed[0])
            parts_f.append(self._fixed[1] + count)
            count += len(self._fixed[0])
        if gripper_pose is not None and self._gripper is not None and self.settings.gripper_occludes:
            placed = np.asarray(self._gripper.vertices) @ gripper_pose[:3, :3].T + gripper_pose[:3, 3]
            parts_v.append(placed)
            parts_f.append(np.asarray(self._gripper.faces) + count)
        faces = np.concatenate(parts_f)
        visible = np.ones(len(self.points), dtype=bool)
        if len(faces) == 0:
            return visible
        scene = trimesh.Trimesh(np.concatenate(parts_v), faces, process=False)
        locations, rays, _ = scene.ray.intersects_location(self.points, self.directions, multiple_hits=False)
        if len(rays):
            hit = np.linalg.norm(locations - self.points[rays], axis=1)
            # a hit beyond the camera is no occluder; the tolerance keeps the camera's own position clear
            blocked = hit < self.distance[rays] - 1e-9
            visible[rays[blocked]] = False
        return visible

    def fraction(self, vertices, triangles, gripper_pose=None) -> float:
        return float(np.mean(self.visible(vertices, triangles, gripper_pose)))
