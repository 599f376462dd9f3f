"""Obstacle shapes: box, sphere, cylinder, capsule and triangle mesh, each with a pose.

Each obstacle answers, for batches in world coordinates (metres):

* :meth:`Obstacle.sdf` — signed distance of points (negative inside);
* :meth:`Obstacle.segment_sd` — minimum signed distance along segments
  (see :mod:`.primitives` for the exact meaning);
* :meth:`Obstacle.coal_geometry` / :meth:`Obstacle.coal_transform` — the same
  shape for coal, used for bodies other than points and segments and to
  cross-check the vectorised formulas;
* :meth:`Obstacle.to_trimesh` — a triangle mesh for figures and glTF export.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import coal
import numpy as np

from . import primitives as prim
from .mesh import MeshDistance, TriangleMesh
from .transforms import Pose, matrix_to_rpy


@dataclass(eq=False)
class Obstacle(ABC):
    """A named rigid obstacle. ``pose`` maps the shape's frame to the world."""

    name: str
    pose: Pose = field(default_factory=Pose)

    kind: str = "obstacle"

    # ------------------------------------------------------------------ distances
    def sdf(self, points) -> np.ndarray:
        """Signed distance (m) of world points (N, 3); negative inside."""
        return self._sdf_local(self._to_local(points))

    def segment_sd(self, a, b) -> np.ndarray:
        """Minimum signed distance (m) along world segments a[i] → b[i]."""
        return self._segment_sd_local(self._to_local(a), self._to_local(b))

    def _to_local(self, points) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return points if self.pose.is_identity else self.pose.apply_inverse(points)

    @abstractmethod
    def _sdf_local(self, points: np.ndarray) -> np.ndarray: ...

    @abstractmethod
    def _segment_sd_local(self, a: np.ndarray, b: np.ndarray) -> np.ndarray: ...

    # ------------------------------------------------------------------ bounds
    @abstractmethod
    def local_bounding_radius(self) -> float:
        """Radius of a sphere about the local origin that contains the shape."""

    def local_bounding_centre(self) -> np.ndarray:
        return np.zeros(3)

    @functools.cached_property
    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """World centre and radius of a sphere enclosing the obstacle."""
        return self.pose.apply(self.local_bounding_centre()), self.local_bounding_radius()

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """World axis-aligned bounds of the obstacle (from its triangle mesh)."""
        vertices = self.to_trimesh().vertices
        return vertices.min(axis=0), vertices.max(axis=0)

    # ------------------------------------------------------------------ coal and rendering
    @abstractmethod
    def coal_geometry(self) -> coal.CollisionGeometry:
        """The shape in its own frame, as a coal geometry."""

    def coal_transform(self) -> coal.Transform3s:
        return coal.Transform3s(self.pose.rotation, self.pose.translation)

    @abstractmethod
    def _local_trimesh(self):
        """The shape in its own frame as a trimesh (for figures and glTF)."""

    def to_trimesh(self):
        mesh = self._local_trimesh()
        mesh.apply_transform(self.pose.as_matrix())
        return mesh

    # ------------------------------------------------------------------ identity
    @abstractmethod
    def _shape_spec(self) -> dict: ...

    def spec(self) -> dict:
        """Canonical SI description (JSON-able), used for content hashes."""
        return {
            "name": self.name,
            "kind": self.kind,
            "shape": self._shape_spec(),
            "pose": {
                "xyz": [float(x) for x in self.pose.translation],
                "rpy": [float(x) for x in matrix_to_rpy(self.pose.rotation)],
            },
        }

    def __getstate__(self):
        state = self.__dict__.copy()
        for cached in ("bounding_sphere", "_coal", "_mesh_distance"):
            state.pop(cached, None)
        return state


@dataclass(eq=False)
class Box(Obstacle):
    """Box with ``size`` (x, y, z) in metres, centred at its frame's origin."""

    size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    kind: str = "box"

    @property
    def half_extents(self) -> np.ndarray:
        return 0.5 * np.asarray(self.size, dtype=float)

    def _sdf_local(self, points):
        return prim.box_sdf(points, self.half_extents)

    def _segment_sd_local(self, a, b):
        return prim.box_segment_sd(a, b, self.half_extents)

    def local_bounding_radius(self):
        return float(np.linalg.norm(self.half_extents))

    def coal_geometry(self):
        return coal.Box(*map(float, self.size))

    def _local_trimesh(self):
        import trimesh

        return trimesh.creation.box(extents=self.size)

    def _shape_spec(self):
        return {"size": [float(x) for x in self.size]}


@dataclass(eq=False)
class Sphere(Obstacle):
    radius: float = 1.0
    kind: str = "sphere"

    def _sdf_local(self, points):
        return prim.sphere_sdf(points, self.radius)

    def _segment_sd_local(self, a, b):
        return prim.sphere_segment_sd(a, b, self.radius)

    def local_bounding_radius(self):
        return float(self.radius)

    def coal_geometry(self):
        return coal.Sphere(float(self.radius))

    def _local_trimesh(self):
        import trimesh

        return trimesh.creation.icosphere(subdivisions=3, radius=self.radius)

    def _shape_spec(self):
        return {"radius": float(self.radius)}


@dataclass(eq=False)
class Cylinder(Obstacle):
    """Solid cylinder of ``radius`` and ``length`` along its local z axis, centred."""

    radius: float = 1.0
    length: float = 1.0
    kind: str = "cylinder"

    def _sdf_local(self, points):
        return prim.cylinder_sdf(points, self.radius, 0.5 * self.length)

    def _segment_sd_local(self, a, b):
        return prim.cylinder_segment_sd(a, b, self.radius, 0.5 * self.length)

    def local_bounding_radius(self):
        return float(np.hypot(self.radius, 0.5 * self.length))

    def coal_geometry(self):
        return coal.Cylinder(float(self.radius), float(self.length))

    def _local_trimesh(self):
        import trimesh

        return trimesh.creation.cylinder(radius=self.radius, height=self.length, sections=48)

    def _shape_spec(self):
        return {"radius": float(self.radius), "length": float(self.length)}


@dataclass(eq=False)
class Capsule(Obstacle):
    """Capsule: the points within ``radius`` of a segment of ``length`` along local z, centred."""

    radius: float = 1.0
    length: float = 1.0
    kind: str = "capsule"

    def _sdf_local(self, points):
        return prim.capsule_sdf(points, self.radius, 0.5 * self.length)

    def _segment_sd_local(self, a, b):
        return prim.capsule_segment_sd(a, b, self.radius, 0.5 * self.length)

    def local_bounding_radius(self):
        return float(self.radius + 0.5 * self.length)

    def coal_geometry(self):
        return coal.Capsule(float(self.radius), float(self.length))

    def _local_trimesh(self):
        import trimesh

        return trimesh.creation.capsule(height=self.length, radius=self.radius, count=[24, 24])

    def _shape_spec(self):
        return {"radius": float(self.radius), "length": float(self.length)}


@dataclass(eq=False)
class Mesh(Obstacle):
    """A triangle mesh (vertices in its own frame, metres).

    Distances are exact (coal's BVH). For a watertight mesh they are signed;
    otherwise only the surface counts. Along a segment that reaches inside a
    watertight mesh the value returned is negative but only an upper bound of
    the deepest penetration (enough for every clear / not clear decision).
    """

    mesh: TriangleMesh | None = None
    kind: str = "mesh"

    @functools.cached_property
    def _mesh_distance(self) -> MeshDistance:
        return MeshDistance(self.mesh)

    def _sdf_local(self, points):
        return self._mesh_distance.distance(points)

    def _segment_sd_local(self, a, b):
        n = len(a)
        out = np.empty(n)
        bvh = self._mesh_distance.bvh
        request = self._mesh_distance._request
        result = coal.DistanceResult()
        identity = coal.Transform3s()
        for i in range(n):
            transform, length = _segment_transform(a[i], b[i])
            result.clear()
            out[i] = coal.distance(bvh, identity, coal.Capsule(0.0, length), transform, request, result)
        out = np.abs(out)
        if self.mesh.watertight:
            ends = np.minimum(self._sdf_local(a), self._sdf_local(b))
            out = np.where(ends < 0, np.minimum(ends, -out), out)
        return out

    def local_bounding_centre(self):
        lo, hi = self.mesh.vertices.min(axis=0), self.mesh.vertices.max(axis=0)
        return 0.5 * (lo + hi)

    def local_bounding_radius(self):
        centre = self.local_bounding_centre()
        return float(np.max(np.linalg.norm(self.mesh.vertices - centre, axis=1)))

    def coal_geometry(self):
        return self._mesh_distance.bvh

    def _local_trimesh(self):
        import trimesh

        return trimesh.Trimesh(self.mesh.vertices.copy(), self.mesh.faces.copy(), process=False)

    def _shape_spec(self):
        return {
            "source": self.mesh.source,
            "digest": self.mesh.digest,
            "watertight": self.mesh.watertight,
        }


def _segment_transform(a: np.ndarray, b: np.ndarray) -> tuple[coal.Transform3s, float]:
    """Transform placing a z-axis capsule of the returned length on segment a→b."""
    d = b - a
    length = float(np.linalg.norm(d))
    rotation = rotation_from_z(d / length) if length > 0 else np.eye(3)
    return coal.Transform3s(rotation, 0.5 * (a + b)), length


def rotation_from_z(direction: np.ndarray) -> np.ndarray:
    """A rotation matrix taking the z axis to the unit vector ``direction``."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, direction)
    s = np.linalg.norm(v)
    c = float(z @ direction)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * ((1 - c) / s**2)
