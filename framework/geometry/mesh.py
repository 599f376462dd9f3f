"""Triangle meshes as obstacles: loading, checks, and signed distance.

Meshes are read with trimesh (STL, OBJ, PLY, GLB/GLTF, OFF, ...). Distances are
exact point-to-triangle distances from coal's BVH; the sign comes from the
angle-weighted pseudo-normal of the nearest feature (face, edge or vertex),
which decides inside/outside exactly for a closed, consistently oriented mesh
(Bærentzen & Aanæs, "Signed distance computation using the angle weighted
pseudonormal", IEEE TVCG 11(3), 2005).

A mesh that is not watertight has no inside: it loads with a warning and only
its surface counts (distances are unsigned, never negative).
"""

from __future__ import annotations

import hashlib
import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import coal
import numpy as np

from ..errors import SceneError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TriangleMesh:
    """Vertices (V, 3) in metres and triangles (F, 3) of vertex indices."""

    vertices: np.ndarray
    faces: np.ndarray
    watertight: bool
    source: str = ""

    @property
    def digest(self) -> str:
        """Content hash of the geometry (for artifact keys)."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(self.faces, dtype=np.int64).tobytes())
        return h.hexdigest()


#: coordinates beyond this (m) are not a surgical or robotics scene: a unit mistake or a damaged file
MAX_COORDINATE = 1e4


def load_mesh(path: str | Path, scale: float = 1.0, *, location: str | None = None) -> TriangleMesh:
    """Read a mesh file, scale its coordinates to metres and check it.

    Raises :class:`SceneError` naming the file when it is missing, unreadable,
    has no triangles, has non-finite or absurd coordinates (a damaged or
    random file: the raw data is checked before any repair could hide it),
    faces that name missing vertices, or only degenerate (zero-area)
    triangles. Warns (through logging) when it is not watertight.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}", location=location)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):  # damaged files: judged below, not warned
            warnings.simplefilter("ignore", RuntimeWarning)
            raw = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise SceneError(f"cannot read mesh {path}: {exc}", location=location) from None
    if not isinstance(raw, trimesh.Trimesh) or len(raw.faces) == 0:
        raise SceneError(f"mesh {path} contains no triangles", location=location)
    vertices = np.asarray(raw.vertices, dtype=float)
    faces = np.asarray(raw.faces)
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if np.any(bad):
        raise SceneError(
            f"mesh {path} has {int(bad.sum())} of {len(vertices)} vertices with non-finite coordinates "
            "(NaN or infinity): the file is damaged or not a mesh",
            location=location,
        )
    vertices = vertices * scale
    largest = float(np.max(np.abs(vertices))) if len(vertices) else 0.0
    if largest > MAX_COORDINATE:
        raise SceneError(
            f"mesh {path} has coordinates up to {largest:.3g} m after scaling: beyond {MAX_COORDINATE:g} m, so "
            "the file is damaged or its unit is wrong (mesh: {unit: mm} or scale:)",
            location=location,
        )
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= len(vertices):
        raise SceneError(f"mesh {path} has faces that name vertices it does not have", location=location)
    corners = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    if not np.any(area > 1e-18):
        raise SceneError(
            f"mesh {path} has only degenerate triangles ({len(faces)}, all of zero area)", location=location
        )
    degenerate = int(np.count_nonzero(~(area > 1e-18)))
    if degenerate:
        log.warning(
            "%smesh %s: %d of %d triangles have zero area and are dropped",
            f"{location}: " if location else "",
            path,
            degenerate,
            len(faces),
        )
        faces = faces[area > 1e-18]
    return mesh_from_arrays(vertices, faces, source=str(path), location=location)


def mesh_from_arrays(vertices, faces, *, source: str = "", location: str | None = None) -> TriangleMesh:
    """Build a checked :class:`TriangleMesh` from arrays (metres)."""
    import trimesh

    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, float), faces=np.asarray(faces, np.int64), process=True)
    if len(mesh.faces) == 0:
        raise SceneError(f"mesh {source or '(arrays)'} contains no triangles", location=location)
    watertight = bool(mesh.is_watertight and mesh.is_winding_consistent)
    if watertight and mesh.volume < 0:
        mesh.invert()  # outward normals, so pseudo-normals point out
    if not watertight:
        log.warning(
            "%s%s is not watertight: it has no inside, only its surface counts as an obstacle",
            f"{location}: " if location else "",
            source or "mesh",
        )
    return TriangleMesh(
        vertices=np.array(mesh.vertices, dtype=float),
        faces=np.array(mesh.faces, dtype=np.int64),
        watertight=watertight,
        source=source,
    )


class MeshDistance:
    """Signed (watertight) or unsigned distance from points to a mesh, in the mesh frame."""

    def __init__(self, mesh: TriangleMesh) -> None:
        self.mesh = mesh
        bvh = coal.BVHModelOBBRSS()
        bvh.beginModel(len(mesh.faces), len(mesh.vertices))
        bvh.addVertices(np.asarray(mesh.vertices, dtype=float))
        bvh.addTriangles(np.asarray(mesh.faces, dtype=np.int64))
        bvh.endModel()
        self.bvh = bvh
        self._point = coal.Sphere(0.0)
        self._request = coal.DistanceRequest()
        # coal's default GJK tolerance (1e-6) leaves micrometre errors; ours are certified distances
        self._request.gjk_tolerance = 1e-11
        if mesh.watertight:
            self._face_normals, self._edge_normals, self._vertex_normals = _pseudo_normals(mesh)

    def distance(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        n = len(points)
        distances = np.empty(n)
        nearest = np.empty((n, 3))
        triangles = np.empty(n, dtype=np.int64)
        identity = coal.Transform3s()
        eye = np.eye(3)
        result = coal.DistanceResult()
        for i in range(n):
            result.clear()  # a reused result keeps the smallest distance seen
            distances[i] = coal.distance(
                self.bvh, identity, self._point, coal.Transform3s(eye, points[i]), self._request, result
            )
            nearest[i] = result.getNearestPoint1()
            triangles[i] = result.b1
        distances = np.abs(distances)
        if not self.mesh.watertight:
            return distances
        normals = self._feature_normals(nearest, triangles)
        inside = np.einsum("ij,ij->i", points - nearest, normals) < 0
        return np.where(inside, -distances, distances)

    def _feature_normals(self, nearest: np.ndarray, triangles: np.ndarray) -> np.ndarray:
        faces = self.mesh.faces[triangles]
        corners = self.mesh.vertices[faces]  # (N, 3, 3)
        bary = _barycentric(nearest, corners)
        tol = 1e-9
        zero = bary < tol  # which barycentric coordinates vanish
        count = zero.sum(axis=1)
        normals = self._face_normals[triangles].copy()
        # on an edge: one coordinate zero -> the edge opposite that corner
        on_edge = count == 1
        if np.any(on_edge):
            opposite = np.argmax(zero[on_edge], axis=1)
            v0 = faces[on_edge, (opposite + 1) % 3]
            v1 = faces[on_edge, (opposite + 2) % 3]
            normals[on_edge] = self._edge_normal(v0, v1)
        on_vertex = count >= 2
        if np.any(on_vertex):
            corner = np.argmax(~zero[on_vertex], axis=1)
            normals[on_vertex] = self._vertex_normals[faces[on_vertex, corner]]
        return normals

    def _edge_normal(self, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
        lo = np.minimum(v0, v1)
        hi = np.maximum(v0, v1)
        keys = lo * len(self.mesh.vertices) + hi
        index = np.searchsorted(self._edge_normals[0], keys)
        return self._edge_normals[1][index]


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    denom = d00 * d11 - d01 * d01
    denom = np.where(np.abs(denom) > 0, denom, 1.0)
    v = (d11 * d20 - d01 * d21) / denom
    w = (d00 * d21 - d01 * d20) / denom
    u = 1.0 - v - w
    return np.stack([u, v, w], axis=1)


def _pseudo_normals(mesh: TriangleMesh):
    vertices, faces = mesh.vertices, mesh.faces
    corners = vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face_normals = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)

    # vertex pseudo-normals: face normals weighted by the incident angle
    vertex_normals = np.zeros_like(vertices)
    for k in range(3):
        p = corners[:, k]
        e1 = corners[:, (k + 1) % 3] - p
        e2 = corners[:, (k + 2) % 3] - p
        cos = np.einsum("ij,ij->i", e1, e2) / np.maximum(
            np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300
        )
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(vertex_normals, faces[:, k], angle[:, None] * face_normals)

    # edge pseudo-normals: sum of the two adjacent face normals
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    lo = edges.min(axis=1)
    hi = edges.max(axis=1)
    keys = lo * len(vertices) + hi
    unique, inverse = np.unique(keys, return_inverse=True)
    edge_normals = np.zeros((len(unique), 3))
    np.add.at(edge_normals, inverse, face_normals[owner])
    return face_normals, (unique, edge_normals), vertex_normals
