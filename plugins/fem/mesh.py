"""Tetrahedral meshes for the ``stvk`` model: structured boxes, files, surfaces.

A :class:`TetMesh` holds rest node positions (n, 3) in metres and linear
tetrahedra (m, 4) of node indices, every one positively oriented
(``det[x1 - x0, x2 - x0, x3 - x0] > 0``). Three ways to get one:

* :func:`box_mesh` — a structured mesh of an axis-aligned box (a tissue
  flap, a beam): ``divisions`` hexahedral cells per axis, each split into six
  tetrahedra around its main diagonal (Kuhn/Freudenthal, ``pattern="six"``)
  or into five (``pattern="five"``, alternating cells so faces match). The
  paper's flap (Patil & Alterovitz, §VI: 5 x 5 x 0.25 cm, about 1,300 nodes
  and 4,000 tetrahedra) is ``box_mesh((0.05, 0.05, 0.0025), (20, 20, 2),
  pattern="five")``: 1,323 nodes, 4,000 tetrahedra.
* :func:`read_tet_mesh` — any volume mesh meshio reads (``.vtu``, ``.msh``,
  ``.mesh``, ``.xdmf``, ...) with ``tetra`` cells.
* :func:`tetrahedralize_surface` — a closed triangle surface (``.stl``,
  ``.obj``, ``.ply``) filled with tetrahedra by TetGen through the optional
  ``tetgen`` package (``pip install tetgen``); the paper used TetGen too.

Linear tetrahedra are stiff in bending (shear locking): a plate one element
thick bends far too little. Use at least two layers through the thickness
of a flap, and check the answer under refinement (the tests show the
cantilever converging to the elastica as the mesh is refined).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from surgiplan.errors import ConfigError

#: vertices of each tetrahedron's faces, ordered so that normals point out of a positive tetrahedron
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


@dataclass
class TetMesh:
    """Rest nodes (n, 3) in metres and positively oriented tetrahedra (m, 4)."""

    nodes: np.ndarray
    tets: np.ndarray
    source: str = ""
    _surface: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.nodes = np.ascontiguousarray(self.nodes, dtype=float).reshape(-1, 3)
        self.tets = np.ascontiguousarray(self.tets, dtype=np.int64).reshape(-1, 4)
        where = self.source or "mesh"
        if len(self.tets) == 0:
            raise ConfigError(f"{where} has no tetrahedra")
        if self.tets.min() < 0 or self.tets.max() >= len(self.nodes):
            raise ConfigError(f"{where}: tetrahedra refer to nodes that do not exist")
        if not np.all(np.isfinite(self.nodes)):
            raise ConfigError(f"{where} has non-finite node coordinates")
        volumes = signed_volumes(self.nodes, self.tets)
        scale = np.ptp(self.nodes, axis=0).max() ** 3
        flat = np.abs(volumes) <= 1e-12 * scale
        if np.any(flat):
            raise ConfigError(f"{where} has {int(flat.sum())} degenerate (zero-volume) tetrahedra")
        negative = volumes < 0
        if np.any(negative):  # fix the orientation instead of rejecting the file
            self.tets[negative] = self.tets[negative][:, [0, 2, 1, 3]]
        used = np.zeros(len(self.nodes), dtype=bool)
        used[self.tets.ravel()] = True
        if not used.all():
            raise ConfigError(f"{where} has {int((~used).sum())} nodes that belong to no tetrahedron")

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_elements(self) -> int:
        return len(self.tets)

    @property
    def volumes(self) -> np.ndarray:
        """Rest volume (m,) of each tetrahedron in m^3."""
        return signed_volumes(self.nodes, self.tets)

    @property
    def centroids(self) -> np.ndarray:
        """Rest centroid (m, 3) of each tetrahedron in metres."""
        return self.nodes[self.tets].mean(axis=1)

    @property
    def surface(self) -> np.ndarray:
        """Boundary triangles (t, 3) of node indices, counter-clockwise seen from outside."""
        if self._surface is None:
            self._surface = boundary_faces(self.tets)
        return self._surface

    @property
    def mean_edge_length(self) -> float:
        """Mean length (m) of the tetrahedra's edges at rest."""
        pairs = np.array(list(itertools.combinations(range(4), 2)))
        edges = self.nodes[self.tets[:, pairs[:, 1]]] - self.nodes[self.tets[:, pairs[:, 0]]]
        return float(np.linalg.norm(edges, axis=-1).mean())

    def nodes_in_box(self, lower, upper, tolerance: float = 1e-9) -> np.ndarray:
        """Indices of the nodes whose rest position lies in the box [lower, upper] (m), sorted."""
        lower = np.asarray(lower, dtype=float) - tolerance
        upper = np.asarray(upper, dtype=float) + tolerance
        inside = np.all((self.nodes >= lower) & (self.nodes <= upper), axis=1)
        return np.flatnonzero(inside)

    def elements_in_box(self, lower, upper, tolerance: float = 1e-9) -> np.ndarray:
        """Boolean mask (m,) of the tetrahedra whose rest centroid lies in the box (m)."""
        lower = np.asarray(lower, dtype=float) - tolerance
        upper = np.asarray(upper, dtype=float) + tolerance
        c = self.centroids
        return np.all((c >= lower) & (c <= upper), axis=1)


def signed_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (m,) of tetrahedra; positive when (x1-x0, x2-x0, x3-x0) is right-handed."""
    x = nodes[tets]
    return np.linalg.det(np.swapaxes(x[:, 1:] - x[:, :1], 1, 2)) / 6.0


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """Faces that belong to exactly one tetrahedron, outward-oriented (t, 3)."""
    faces = tets[:, TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 2):
        raise ConfigError("the mesh is not a valid volume mesh: a face is shared by more than two tetrahedra")
    return faces[np.sort(index[counts == 1])]


# ----------------------------------------------------------------------------- structured boxes


def _grid_index(divisions) -> np.ndarray:
    nx, ny, nz = divisions
    return np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nz + 1, ny + 1, nx + 1).transpose(2, 1, 0)


def box_mesh(
    size, divisions, origin=(0.0, 0.0, 0.0), pattern: Literal["six", "five"] = "six", source: str = ""
) -> TetMesh:
    """A structured tetrahedral mesh of the box ``origin + [0, size]`` (m).

    ``divisions`` (nx, ny, nz) cells per axis; nodes are numbered x fastest.
    ``pattern="six"``: six tetrahedra per cell around the diagonal from its
    lowest to its highest corner (the same in every cell, so faces match);
    ``"five"``: five per cell, corner cells alternating like a checkerboard.
    """
    size = np.asarray(size, dtype=float)
    divisions = tuple(int(d) for d in divisions)
    if len(divisions) != 3 or min(divisions) < 1 or np.any(size <= 0):
        raise ConfigError(f"a box mesh needs three positive sizes and divisions, got {size} and {divisions}")
    axes = [np.linspace(0.0, s, d + 1) + o for s, d, o in zip(size, divisions, origin, strict=True)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    grid = _grid_index(divisions)
    nx, ny, nz = divisions
    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))

    def corner(a: int, b: int, c: int) -> np.ndarray:
        return grid[i + a, j + b, k + c]

    if pattern == "six":
        offsets = np.eye(3, dtype=int)
        tets = []
        for perm in itertools.permutations(range(3)):
            p1 = offsets[perm[0]]
            p2 = p1 + offsets[perm[1]]
            tets.append(np.column_stack([corner(0, 0, 0), corner(*p1), corner(*p2), corner(1, 1, 1)]))
        cells = np.stack(tets, axis=1).reshape(-1, 4)
    elif pattern == "five":
        even = [
            [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)],
            [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)],
            [(1, 1, 0), (1, 0, 0), (0, 1, 0), (1, 1, 1)],
            [(1, 0, 1), (1, 0, 0), (0, 0, 1), (1, 1, 1)],
            [(0, 1, 1), (0, 1, 0), (0, 0, 1), (1, 1, 1)],
        ]
        odd = [[tuple(1 - np.array(v)) for v in tet] for tet in even]  # the point reflection of each cell
        parity = (i + j + k) % 2 == 1
        per_cell = []
        for t_even, t_odd in zip(even, odd, strict=True):
            a = np.column_stack([corner(*v) for v in t_even])
            b = np.column_stack([corner(*v) for v in t_odd])
            per_cell.append(np.where(parity[:, None], b, a))
        cells = np.stack(per_cell, axis=1).reshape(-1, 4)
    else:
        raise ConfigError(f"unknown box mesh pattern '{pattern}'; choose one of: six, five")
    return TetMesh(nodes, cells, source=source or f"box mesh {tuple(size)} m, {divisions} cells")


# ----------------------------------------------------------------------------- files


def read_tet_mesh(path: str | Path, scale: float = 1.0, *, location: str | None = None) -> TetMesh:
    """A volume mesh file with ``tetra`` cells (read by meshio), coordinates times ``scale`` (m).

    A surface file (``.stl``, ``.obj``, ``.ply``, ``.off``) is filled with
    tetrahedra by :func:`tetrahedralize_surface`.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"mesh file not found: {path}", location=location)
    if path.suffix.lower() in {".stl", ".obj", ".ply", ".off", ".glb", ".gltf"}:
        return tetrahedralize_surface(path, scale, location=location)
    import meshio

    try:
        data = meshio.read(path)
    except Exception as exc:  # meshio raises many types for bad files
        raise ConfigError(f"cannot read mesh {path}: {type(exc).__name__}: {exc}", location=location) from None
    blocks = [c.data for c in data.cells if c.type == "tetra"]
    if not blocks:
        kinds = sorted({c.type for c in data.cells}) or ["none"]
        raise ConfigError(
            f"mesh {path} has no linear tetrahedra ('tetra' cells); it has: {', '.join(kinds)}", location=location
        )
    tets = np.concatenate(blocks).astype(np.int64)
    nodes = np.asarray(data.points, dtype=float)[:, :3] * scale
    used, tets = np.unique(tets, return_inverse=True)  # drop nodes no tetrahedron uses (e.g. of surface cells)
    try:
        return TetMesh(nodes[used], tets.reshape(-1, 4), source=str(path))
    except ConfigError as exc:
        raise ConfigError(exc.message, location=location) from None


def tetrahedralize_surface(
    path: str | Path, scale: float = 1.0, *, max_volume: float | None = None, location: str | None = None
) -> TetMesh:
    """Fill a closed triangle surface with tetrahedra (TetGen via the optional ``tetgen`` package).

    ``max_volume`` (m^3) bounds the tetrahedra's volume; quality meshing
    (radius-edge ratio 1.5) is always on.
    """
    try:
        import tetgen
    except ImportError:
        raise ConfigError(
            f"meshing the closed surface {path} needs TetGen: pip install tetgen "
            "(or give a volume mesh file with tetrahedra: .vtu, .msh, ...)",
            location=location,
        ) from None
    import trimesh

    surface = trimesh.load(Path(path), force="mesh", process=True)
    if not isinstance(surface, trimesh.Trimesh) or not surface.is_watertight:
        raise ConfigError(f"surface {path} is not a closed (watertight) triangle mesh", location=location)
    generator = tetgen.TetGen(np.asarray(surface.vertices, float) * scale, np.asarray(surface.faces, np.int32))
    options = {"quality": True, "minratio": 1.5}
    if max_volume is not None:
        options["maxvolume"] = float(max_volume)
    nodes, tets = generator.tetrahedralize(**options)[:2]
    return TetMesh(nodes, tets, source=str(path))
