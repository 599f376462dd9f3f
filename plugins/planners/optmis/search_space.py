"""optMIS search space: a Delaunay tetrahedralization of the free space (paper 001 §3.1).

optMIS (Napalkova et al. 2014, as used by paper 001 §3.1) splits the
workspace into tetrahedra with a Delaunay triangulation and searches their
edges for shortest paths. Shortest paths bend around obstacles and run
straight elsewhere, so the vertices are seeded where paths bend and where
the space is tight:

1. *surface vertices*: a lattice of spacing ``surface_spacing`` on every face
   of every obstacle's surface mesh (edges and corners included), pushed out
   along the surface normal (at an edge along the bisector of its faces, at a
   corner along the vertex normal) by the tip radius, the margin and
   ``surface_gap``: shortest paths wrap around obstacles there;
2. *workspace vertices*: a grid of spacing ``grid_spacing`` over the bounds,
   each vertex jittered by up to 15 % of the spacing (seeded) so that no two
   paths tie in length, which keeps the shortest paths unique and consistent
   from either end;
3. *tight-space vertices*: a jittered grid of half the spacing wherever the
   clearance is below ``grid_spacing`` (narrow passages, close to walls);
4. the *points of interest* themselves, exactly.

Vertices where the tip sphere (diameter ``w_tip``) would come closer than the
margin to an obstacle, or that lie outside the bounds, are dropped. The edges
are those of the Delaunay tetrahedralization (``scipy.spatial.Delaunay``)
plus each vertex's ``neighbours`` nearest neighbours (chords that shorten the
zig-zag of pure Delaunay paths); an edge is kept only if the tip sphere is
*certified* clear along it (the exact swept-capsule distance, or two covering
balls). Edge weights are lengths in metres.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import Delaunay, cKDTree
from surgiplan.errors import PlanningInputError
from surgiplan.paths import certify_edges
from surgiplan.spaces.r3 import R3Space

#: relative jitter of the workspace grids (breaks ties between equally long paths)
JITTER = 0.15


@dataclass
class SearchGraph:
    """The optMIS search space C'.

    ``vertices`` (V, 3) m and their ``clearance`` (m, of the tip sphere);
    ``edges`` (E, 2) int32 index pairs with i < j, all certified;
    ``poi_vertex``: the vertex index of each point of interest.
    """

    vertices: np.ndarray
    clearance: np.ndarray
    edges: np.ndarray
    poi_vertex: np.ndarray
    margin: float = 0.0

    def __post_init__(self) -> None:
        self._graph: csr_matrix | None = None
        self._tree: cKDTree | None = None

    @property
    def n(self) -> int:
        return len(self.vertices)

    @property
    def graph(self) -> csr_matrix:
        """Symmetric CSR matrix of edge lengths (m), built on first use."""
        if self._graph is None:
            self._graph = edge_graph(self.vertices, self.edges)
        return self._graph

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.vertices)
        return self._tree

    def digest(self) -> str:
        """Content hash of the graph (vertices and edges)."""
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(self.vertices).tobytes())
        h.update(np.ascontiguousarray(self.edges).tobytes())
        return h.hexdigest()

    def stats(self) -> dict:
        return {"search_vertices": int(self.n), "search_edges": len(self.edges)}


def edge_graph(vertices: np.ndarray, edges: np.ndarray) -> csr_matrix:
    """Both directions of every edge, weighted by its length (m)."""
    n = len(vertices)
    i, j = edges[:, 0].astype(np.int64), edges[:, 1].astype(np.int64)
    length = np.maximum(np.linalg.norm(vertices[i] - vertices[j], axis=1), 1e-15)  # scipy drops explicit zeros
    graph = csr_matrix((np.concatenate([length, length]), (np.concatenate([i, j]), np.concatenate([j, i]))), (n, n))
    graph.sort_indices()
    return graph


# ----------------------------------------------------------------------------- seeding


def _edge_normals(mesh) -> np.ndarray:
    """(F, 3, 3): for each face, the mean normal of the faces sharing each of its edges (v1v2, v2v0, v0v1)."""
    faces = mesh.faces
    pairs = np.stack([faces[:, [1, 2]], faces[:, [2, 0]], faces[:, [0, 1]]], axis=1).reshape(-1, 2)
    pairs = np.sort(pairs, axis=1).astype(np.int64)
    _, inverse = np.unique(pairs[:, 0] * len(mesh.vertices) + pairs[:, 1], return_inverse=True)
    summed = np.zeros((inverse.max() + 1, 3))
    np.add.at(summed, inverse, np.repeat(mesh.face_normals, 3, axis=0))
    summed /= np.maximum(np.linalg.norm(summed, axis=1), 1e-12)[:, None]
    return summed[inverse].reshape(-1, 3, 3)


def surface_vertices(scene, spacing: float, offset: float) -> np.ndarray:
    """A lattice of spacing ``spacing`` (m) on every obstacle surface, pushed out by ``offset`` (m).

    Each triangle gets a barycentric lattice with as many divisions as its
    longest edge needs. A point inside a face moves along the face normal; a
    point on an edge along the mean normal of the faces that share the edge
    (the bisector, where shortest paths wrap round a block's edge); a corner
    along the mesh's vertex normal. The distance to a convex obstacle is then
    ``offset`` everywhere.
    """
    points, normals = [], []
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        triangles = mesh.vertices[mesh.faces]  # (F, 3, 3)
        longest = np.max(np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2), axis=1)
        divisions = np.maximum(1, np.ceil(longest / spacing).astype(np.int64))
        edge_normals = _edge_normals(mesh)
        vertex_normals = mesh.vertex_normals[mesh.faces]  # (F, 3, 3)
        for n in np.unique(divisions):
            faces = np.flatnonzero(divisions == n)
            a, b = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
            keep = a + b <= n
            lattice = np.stack([a[keep], b[keep], n - a[keep] - b[keep]], axis=1)  # integer barycentrics (K, 3)
            weights = lattice / n
            points.append(np.einsum("kc,fcd->fkd", weights, triangles[faces]).reshape(-1, 3))
            zero = lattice == 0
            # per lattice point: which normal (face, edge k = the one opposite vertex k, or vertex k)
            normal = np.repeat(mesh.face_normals[faces][:, None, :], len(lattice), axis=1)
            on_edge = zero.sum(axis=1) == 1
            if np.any(on_edge):
                k = np.argmax(zero[on_edge], axis=1)
                normal[:, on_edge] = edge_normals[faces][:, k]
            at_vertex = zero.sum(axis=1) == 2
            if np.any(at_vertex):
                k = np.argmin(zero[at_vertex], axis=1)  # the one non-zero weight
                normal[:, at_vertex] = vertex_normals[faces][:, k]
            normals.append(normal.reshape(-1, 3))
    if not points:
        return np.zeros((0, 3))
    points = np.concatenate(points)
    normals = np.concatenate(normals)
    # merge the copies of shared points (1 um grid) and average their normals
    _, first, inverse = np.unique(
        np.round(points / 1e-6).astype(np.int64), axis=0, return_index=True, return_inverse=True
    )
    inverse = inverse.reshape(-1)
    summed = np.zeros((len(first), 3))
    np.add.at(summed, inverse, normals)
    # opposite normals (a zero-thickness sheet) cancel: keep one of them there
    norm = np.linalg.norm(summed, axis=1)
    flat = norm < 1e-9
    summed[flat] = normals[first[flat]]
    norm[flat] = 1.0
    return points[first] + summed / norm[:, None] * offset


def jittered_grid(lo: np.ndarray, hi: np.ndarray, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Cell centres of a grid of ``spacing`` (m) over [lo, hi], each moved by up to ``JITTER`` of the spacing."""
    axes = [np.arange(lo[k] + spacing / 2, hi[k], spacing) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid + rng.uniform(-JITTER * spacing, JITTER * spacing, grid.shape)


def seed_vertices(
    space: R3Space, *, grid_spacing: float, surface_spacing: float, surface_gap: float, margin: float, seed: int
) -> np.ndarray:
    """Candidate vertices (before the clearance filter): surfaces, workspace grid, tight-space grid."""
    scene = space.scene
    rng = np.random.default_rng(seed)
    lo, hi = scene.bounds_min, scene.bounds_max
    grid = jittered_grid(lo, hi, grid_spacing, rng)
    fine = jittered_grid(lo, hi, grid_spacing / 2, rng)
    fine = fine[space.clearance(fine, cutoff=grid_spacing) < grid_spacing]
    surface = surface_vertices(scene, surface_spacing, space.tip_radius + margin + surface_gap)
    return np.concatenate([grid, fine, surface])


def check_points_of_interest(space: R3Space, names: list[str], pois: np.ndarray, margin: float) -> None:
    """A :class:`PlanningInputError` naming every point of interest the tip cannot be at."""
    scene = space.scene
    problems = []
    inside = scene.in_bounds(pois)
    clearance = space.clearance(pois)
    nearest = scene.signed_distance(pois)[1]
    for k, name in enumerate(names):
        where = f"point of interest '{name}' {scene.describe_point(pois[k])}"
        if not inside[k]:
            problems.append(f"{where} is outside the scene bounds")
        elif not (clearance[k] > margin if margin <= 0 else clearance[k] >= margin):
            obstacle = scene.obstacles[nearest[k]].name if nearest[k] >= 0 else "an obstacle"
            problems.append(
                f"{where} is not free for the instrument tip: clearance {clearance[k] * 1e3:.3g} mm "
                f"from obstacle '{obstacle}' (tip radius {space.tip_radius * 1e3:.3g} mm, margin {margin * 1e3:.3g} mm)"
            )
    if problems:
        raise PlanningInputError("; ".join(problems), location="points")


def build_search_graph(
    space: R3Space,
    pois: np.ndarray,
    *,
    grid_spacing: float,
    surface_spacing: float,
    surface_gap: float,
    neighbours: int,
    margin: float = 0.0,
    seed: int = 0,
    names: list[str] | None = None,
) -> SearchGraph:
    """The optMIS search space for the tip sphere of ``space`` (its ``tip_radius`` is w_tip / 2).

    ``pois`` (N, 3) m become vertices exactly; ``margin`` (m) is the clearance
    beyond the tip's own radius that vertices and edges must keep.
    """
    scene = space.scene
    pois = np.asarray(pois, dtype=float).reshape(-1, 3)
    names = names or [f"#{k}" for k in range(len(pois))]
    check_points_of_interest(space, names, pois, margin)
    candidates = seed_vertices(
        space,
        grid_spacing=grid_spacing,
        surface_spacing=surface_spacing,
        surface_gap=surface_gap,
        margin=margin,
        seed=seed,
    )
    candidates = candidates[scene.in_bounds(candidates)]
    clearance = space.clearance(candidates)
    keep = clearance > margin if margin <= 0 else clearance >= margin
    candidates, clearance = candidates[keep], clearance[keep]
    # a seeded vertex that coincides with a point of interest would make the tetrahedralization degenerate
    if len(candidates):
        close = cKDTree(pois).query(candidates, distance_upper_bound=1e-6)[0] < 1e-6
        candidates, clearance = candidates[~close], clearance[~close]
    # the points of interest first, so that poi_vertex is simply 0..N-1 (duplicates share one vertex)
    unique_pois, poi_vertex = np.unique(pois, axis=0, return_inverse=True)
    vertices = np.concatenate([unique_pois, candidates])
    clearance = np.concatenate([space.clearance(unique_pois), clearance])
    if len(vertices) < 5:
        raise PlanningInputError("the free space is too small to seed a search space", location="settings")

    triangulation = Delaunay(vertices)
    simplices = triangulation.simplices
    pairs = [simplices[:, [a, b]] for a in range(4) for b in range(a + 1, 4)]
    k = min(neighbours + 1, len(vertices))
    _, knn = cKDTree(vertices).query(vertices, k=k)
    pairs.append(np.stack([np.repeat(np.arange(len(vertices)), k - 1), knn[:, 1:].ravel()], axis=1))
    pairs = np.sort(np.concatenate(pairs), axis=1).astype(np.int64)
    n = len(vertices)
    keys = np.unique(pairs[:, 0] * n + pairs[:, 1])  # 1-D keys: far faster than unique(axis=0)
    pairs = np.stack([keys // n, keys % n], axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    slack = clearance - margin
    ok, _ = certify_edges(
        space, vertices[pairs[:, 0]], vertices[pairs[:, 1]], slack[pairs[:, 0]], slack[pairs[:, 1]], margin
    )
    return SearchGraph(vertices, clearance, pairs[ok].astype(np.int32), poi_vertex.astype(np.int64).reshape(-1), margin)
