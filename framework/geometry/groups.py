"""Obstacles of one kind evaluated together: one vectorised call for many (point, obstacle) pairs.

The scene's broad phase decides which (point, obstacle) or (segment,
obstacle) pairs need an exact distance; a :class:`ShapeGroup` computes all
pairs of its kind at once, each point moved into its own obstacle's frame
with that obstacle's parameters. Meshes (and any other shape) fall back to
their obstacle's own methods, one obstacle at a time.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from . import primitives as prim
from .shapes import Box, Capsule, Cylinder, Obstacle, Sphere


class ShapeGroup:
    """Obstacles ``members`` (indices in the scene) of one primitive kind."""

    def __init__(self, members: np.ndarray, obstacles: Sequence[Obstacle]) -> None:
        self.members = np.asarray(members, dtype=np.int64)
        self.rotation = np.stack([o.pose.rotation for o in obstacles])
        self.translation = np.stack([o.pose.translation for o in obstacles])
        self.kind = obstacles[0].kind
        if isinstance(obstacles[0], Box):
            self.half = np.stack([o.half_extents for o in obstacles])
        elif isinstance(obstacles[0], Sphere):
            self.radius = np.array([o.radius for o in obstacles], dtype=float)
        elif isinstance(obstacles[0], Cylinder | Capsule):
            self.radius = np.array([o.radius for o in obstacles], dtype=float)
            self.half_length = np.array([0.5 * o.length for o in obstacles], dtype=float)

    def _local(self, points: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.einsum("mi,mij->mj", points - self.translation[rows], self.rotation[rows])

    def sdf(self, points: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Signed distance of ``points[i]`` to group member ``rows[i]``."""
        p = self._local(points, rows)
        if self.kind == "box":
            return prim.box_sdf(p, self.half[rows])
        if self.kind == "sphere":
            return prim.sphere_sdf(p, self.radius[rows])
        if self.kind == "cylinder":
            return prim.cylinder_sdf(p, self.radius[rows], self.half_length[rows])
        return prim.capsule_sdf(p, self.radius[rows], self.half_length[rows])

    def segment_sd(self, a: np.ndarray, b: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Minimum signed distance along segment ``a[i] → b[i]`` to group member ``rows[i]``."""
        la, lb = self._local(a, rows), self._local(b, rows)
        if self.kind == "box":
            return prim.box_segment_sd(la, lb, self.half[rows])
        if self.kind == "sphere":
            return prim.sphere_segment_sd(la, lb, self.radius[rows])
        if self.kind == "cylinder":
            return prim.cylinder_segment_sd(la, lb, self.radius[rows], self.half_length[rows])
        return prim.capsule_segment_sd(la, lb, self.radius[rows], self.half_length[rows])


class SingleGroup:
    """One obstacle of any other kind (meshes, third-party shapes): its own methods."""

    def __init__(self, member: int, obstacle: Obstacle) -> None:
        self.members = np.array([member], dtype=np.int64)
        self.obstacle = obstacle

    def sdf(self, points: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return self.obstacle.sdf(points)

    def segment_sd(self, a: np.ndarray, b: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return self.obstacle.segment_sd(a, b)


VECTORISED = (Box, Sphere, Cylinder, Capsule)


def group_obstacles(obstacles: Sequence[Obstacle]) -> list[ShapeGroup | SingleGroup]:
    """Primitives grouped by exact type first; then everything else, one group per obstacle."""
    singles: list[SingleGroup] = []
    by_type: dict[type, list[int]] = {}
    for i, obstacle in enumerate(obstacles):
        if type(obstacle) in VECTORISED:
            by_type.setdefault(type(obstacle), []).append(i)
        else:
            singles.append(SingleGroup(i, obstacle))
    groups: list[ShapeGroup | SingleGroup] = [
        ShapeGroup(np.array(members), [obstacles[i] for i in members]) for members in by_type.values()
    ]
    return groups + singles


def centre_inside(obstacle: Obstacle) -> bool:
    """Whether the obstacle's bounding-sphere centre lies inside it (true for the centred primitives)."""
    return type(obstacle) in VECTORISED
