"""Collision checks of deformed flap states: flap against obstacles, instrument against tissue (coal).

Paper 002 §IV-C: an edge (and a sample) is valid only if "both the mesh and
the gripper do not collide with any obstacles" (the paper used PQP; we use
coal, its successor's successor). The gripper's own motion is certified by
the ``se3`` space; here the *deformed flap*, a triangle surface that
changes with every state, is put into a coal BVH and tested against the
obstacles, and the instrument (the ``se3`` body) is tested against the
tissue away from its jaws (an instrument may not pass through the flap it
holds). A bounding-sphere test skips pairs that cannot touch, so far
obstacles cost nothing.

Everything here pickles (coal geometries do), so worker processes check
the states they solve.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import coal
import numpy as np
import trimesh
from surgiplan.geometry.shapes import rotation_from_z

from .grasp import pose_matrices


def boundary_faces(elements: np.ndarray) -> np.ndarray:
    """Boundary triangles (t, 3) of a tetrahedral mesh, outward for positively oriented tetrahedra."""
    faces = np.asarray(elements)[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3)
    _, index, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    return faces[np.sort(index[counts == 1])]


def instrument_parts(body) -> list[tuple[coal.CollisionGeometry, np.ndarray, trimesh.Trimesh]]:
    """The ``se3`` body parts as (coal geometry, 4 x 4 transform in the body frame, triangle mesh)."""
    parts = []
    for part in body:
        local = part.pose.to_pose().as_matrix()
        if part.sphere is not None:
            r = float(part.sphere.radius)
            if r <= 0:
                continue  # a point: nothing to collide or occlude
            parts.append((coal.Sphere(r), local, trimesh.creation.icosphere(2, r)))
        elif part.capsule is not None:
            a, b, r = np.asarray(part.capsule.a), np.asarray(part.capsule.b), float(part.capsule.radius)
            length = float(np.linalg.norm(b - a))
            frame = np.eye(4)
            frame[:3, :3] = rotation_from_z((b - a) / length) if length > 0 else np.eye(3)
            frame[:3, 3] = 0.5 * (a + b)
            parts.append((coal.Capsule(r, length), local @ frame, trimesh.creation.capsule(length, r, count=[8, 8])))
        else:
            size = [float(s) for s in part.box.size]
            parts.append((coal.Box(*size), local, trimesh.creation.box(size)))
    return parts


def _bvh(vertices: np.ndarray, triangles: np.ndarray) -> coal.BVHModelOBBRSS:
    model = coal.BVHModelOBBRSS()
    model.beginModel(len(triangles), len(vertices))
    model.addVertices(np.ascontiguousarray(vertices, dtype=float))
    model.addTriangles(np.ascontiguousarray(triangles, dtype=np.int64))
    model.endModel()
    return model


def _transform(matrix: np.ndarray) -> coal.Transform3s:
    return coal.Transform3s(np.ascontiguousarray(matrix[:3, :3]), np.ascontiguousarray(matrix[:3, 3]))


def _ring(triangles: np.ndarray, seeds: np.ndarray, rings: int) -> np.ndarray:
    """Boolean mask of the triangles within ``rings`` vertex rings of the seed nodes."""
    near_nodes = np.zeros(int(triangles.max()) + 1, dtype=bool)
    near_nodes[seeds[seeds <= triangles.max()]] = True
    mask = near_nodes[triangles].any(axis=1)
    for _ in range(rings - 1):
        near_nodes[triangles[mask].ravel()] = True
        mask = near_nodes[triangles].any(axis=1)
    return mask


@dataclass
class CollisionModel:
    """Obstacles (world), the instrument's parts (body frame) and the flap's surface."""

    obstacles: list[tuple[coal.CollisionGeometry, np.ndarray, np.ndarray, float]]  # geometry, pose, centre, radius
    obstacle_names: list[str]
    instrument: list[tuple[coal.CollisionGeometry, np.ndarray]]
    instrument_reach: float
    triangles: np.ndarray
    #: triangles the instrument may touch (near its jaws)
    near_jaws: np.ndarray
    margin: float = 0.0
    check_instrument: bool = True
    seconds: float = field(default=0.0)

    @classmethod
    def build(cls, scene, space, triangles, grasped, margin: float, check_instrument: bool) -> CollisionModel:
        obstacles = []
        for o in scene.obstacles:
            centre, radius = o.bounding_sphere
            obstacles.append((o.coal_geometry(), o.pose.as_matrix(), np.asarray(centre, float), float(radius)))
        parts = instrument_parts(space.settings.body)
        return cls(
            obstacles,
            [o.name for o in scene.obstacles],
            [(g, m) for g, m, _ in parts],
            float(space.reach),
            np.asarray(triangles, dtype=np.int64),
            _ring(np.asarray(triangles), np.asarray(grasped), 2),
            float(margin),
            bool(check_instrument) and bool(parts),
        )

    def check(self, positions: np.ndarray, q: np.ndarray) -> str:
        """'' when the state is clear, else why not (the flap touches an obstacle, the instrument the tissue)."""
        started = time.perf_counter()
        try:
            return self._check(np.asarray(positions, dtype=float), np.asarray(q, dtype=float))
        finally:
            self.seconds += time.perf_counter() - started

    def _check(self, x: np.ndarray, q: np.ndarray) -> str:
        used = x[np.unique(self.triangles)]
        lo, hi = used.min(axis=0), used.max(axis=0)
        flap = None
        request = coal.CollisionRequest()
        for (geometry, pose, centre, radius), name in zip(self.obstacles, self.obstacle_names, strict=True):
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - centre, centre - hi)))
            if gap > radius + self.margin:
                continue  # the flap's bounding box is farther than the obstacle's bounding sphere
            if flap is None:
                flap = _bvh(x, self.triangles)
            if self.margin > 0:
                result = coal.DistanceResult()
                d = coal.distance(flap, coal.Transform3s(), geometry, _transform(pose), coal.DistanceRequest(), result)
                if d < self.margin:
                    return f"the flap comes within {d * 1e3:.3g} mm of obstacle '{name}'"
            else:
                result = coal.CollisionResult()
                if coal.collide(flap, coal.Transform3s(), geometry, _transform(pose), request, result):
                    return f"the flap touches obstacle '{name}'"
        if self.check_instrument:
            body = pose_matrices(q)
            gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - q[:3], q[:3] - hi)))
            if gap <= self.instrument_reach:
                far = self.triangles[~self.near_jaws]
                tissue = _bvh(x, far)
                for geometry, local in self.instrument:
                    result = coal.CollisionResult()
                    if coal.collide(tissue, coal.Transform3s(), geometry, _transform(body @ local), request, result):
                        return "the instrument passes through the tissue"
        return ""
