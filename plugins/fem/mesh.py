"""Tetrahedral meshes for the ``stvk`` model: structured boxes, files, surfaces.

A :class:`TetMesh` holds rest node positions (n, 3) in metres and
tetrahedra of node indices, linear (m, 4) or quadratic (m, 10: the four
vertices, then the mid-edge nodes of edges 0-1, 1-2, 0-2, 0-3, 1-3, 2-3, the
VTK/meshio ``tetra10`` order), every one positively oriented
(``det[x1 - x0, x2 - x0, x3 - x0] > 0``). Three ways to get one:

* :func:`box_mesh` — a structured mesh of an axis-aligned box (a tissue
  flap, a beam): ``divisions`` hexahedral cells per axis, each split into six
  tetrahedra around its main diagonal (Kuhn/Freudenthal, ``pattern="six"``)
  or into five (``pattern="five"``, alternating cells so faces match). The
  paper's flap (Patil & Alterovitz, §VI: 5 x 5 x 0.25 cm, about 1,300 nodes
  and 4,000 tetrahedra) is ``box_mesh((0.05, 0.05, 0.0025), (20, 20, 2),
  pattern="five")``: 1,323 nodes, 4,000 tetrahedra.
* :func:`read_tet_mesh` — any volume mesh meshio reads (``.vtu``, ``.msh``,
  ``.mesh``, ``.xdmf``, ...) with ``tetra`` or ``tetra10`` cells.
* :func:`tetrahedralize_surface` — a closed triangle surface (``.stl``,
  ``.obj``, ``.ply``) filled with tetrahedra by TetGen through the optional
  ``tetgen`` package (``pip install 'surgiplan[tetmesh]'``); the paper used
  TetGen too.

:meth:`TetMesh.quadratic` (or ``order=2``) adds a node at the middle of
every edge: 10-node tetrahedra.

Linear tetrahedra are stiff in bending (locking: a constant-strain element
cannot represent the linear variation of strain through a bent plate's
thickness, so it stores spurious shear and membrane energy): a plate one
element thick bends far too little, and even with several layers the
deflection converges from below, slowly. Use at least two layers through
the thickness of a flap and check the answer under refinement, or use
quadratic tetrahedra, which do not lock (the tests and
``benchmarks/bench_fem.py`` show both on a cantilever against the elastica).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from surgiplan.errors import ConfigError

from .shape import EDGE_NODE, EDGES, SWAP_1_2

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
        tets = np.asarray(self.tets, dtype=np.int64)
        width = tets.shape[-1] if tets.ndim == 2 else 4
        where = self.source or "mesh"
        if width not in (4, 10):
            raise ConfigError(f"{where}: tetrahedra have 4 (linear) or 10 (quadratic) nodes, not {width}")
        self.tets = np.ascontiguousarray(tets).reshape(-1, width)
        if len(self.tets) == 0:
            raise ConfigError(f"{where} has no tetrahedra")
        if self.tets.min() < 0 or self.tets.max() >= len(self.nodes):
            raise ConfigError(f"{where}: tetrahedra refer to nodes that do not exist")
        if not np.all(np.isfinite(self.nodes)):
            raise ConfigError(f"{where} has non-finite node coordinates")
        volumes = signed_volumes(self.nodes, self.tets[:, :4])
        scale = np.ptp(self.nodes, axis=0).max() ** 3
        flat = np.abs(volumes) <= 1e-12 * scale
        if np.any(flat):
            raise ConfigError(f"{where} has {int(flat.sum())} degenerate (zero-volume) tetrahedra")
        negative = volumes < 0
        if np.any(negative):  # fix the orientation instead of rejecting the file
            self.tets[negative] = self.tets[negative][:, SWAP_1_2[width]]
        used = np.zeros(len(self.nodes), dtype=bool)
        used[self.tets.ravel()] = True
        if not used.all():
            raise ConfigError(f"{where} has {int((~used).sum())} nodes that belong to no tetrahedron")

    @property
    def order(self) -> int:
        """Polynomial order of the elements: 1 (4-node) or 2 (10-node tetrahedra)."""
        return 1 if self.tets.shape[1] == 4 else 2

    @property
    def vertices(self) -> np.ndarray:
        """The corner nodes (m, 4) of each tetrahedron."""
        return self.tets[:, :4]

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_elements(self) -> int:
        return len(self.tets)

    @property
    def volumes(self) -> np.ndarray:
        """Rest volume (m,) of each tetrahedron in m^3 (of its vertices' straight-sided tetrahedron)."""
        return signed_volumes(self.nodes, self.vertices)

    @property
    def centroids(self) -> np.ndarray:
        """Rest centroid (m, 3) of each tetrahedron (of its vertices) in metres."""
        return self.nodes[self.vertices].mean(axis=1)

    @property
    def surface_elements(self) -> np.ndarray:
        """The tetrahedron (t,) each triangle of :attr:`surface` belongs to."""
        if getattr(self, "_surface_elements", None) is None:
            self._surface_elements = boundary_faces(self.tets, elements=True)[1]
        return self._surface_elements

    @property
    def surface(self) -> np.ndarray:
        """Boundary triangles (t, 3) of node indices, counter-clockwise seen from outside.

        Quadratic meshes: each 6-node boundary face split into four
        triangles through its mid-edge nodes (for drawing, output and the
        self-intersection check).
        """
        if self._surface is None:
            self._surface = boundary_faces(self.tets)
        return self._surface

    @property
    def mean_edge_length(self) -> float:
        """Mean length (m) of the tetrahedra's edges (vertex to vertex) at rest."""
        pairs = np.array(list(itertools.combinations(range(4), 2)))
        edges = self.nodes[self.tets[:, pairs[:, 1]]] - self.nodes[self.tets[:, pairs[:, 0]]]
        return float(np.linalg.norm(edges, axis=-1).mean())

    def quadratic(self) -> TetMesh:
        """The same mesh with 10-node tetrahedra: a new node at the middle of every edge."""
        if self.order == 2:
            return self
        local = self.tets[:, EDGES]  # (m, 6, 2) global vertices of each element edge
        key = np.sort(local, axis=2).reshape(-1, 2)
        unique, inverse = np.unique(key, axis=0, return_inverse=True)
        middle = 0.5 * (self.nodes[unique[:, 0]] + self.nodes[unique[:, 1]])
        edge_nodes = self.n_nodes + inverse.reshape(-1, 6)
        source = f"{self.source} (quadratic)" if self.source else ""
        return TetMesh(np.vstack([self.nodes, middle]), np.hstack([self.tets, edge_nodes]), source=source)

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


def boundary_faces(tets: np.ndarray, elements: bool = False):
    """Faces that belong to exactly one tetrahedron, outward-oriented (t, 3) (and, if asked, their elements (t,)).

    Quadratic tetrahedra (m, 10): each boundary face (a, b, c) with mid-edge
    nodes ab, bc, ca becomes the four triangles (a, ab, ca), (ab, b, bc),
    (ca, bc, c), (ab, bc, ca), oriented like the face.
    """
    tets = np.asarray(tets)
    faces = tets[:, TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.any(counts > 2):
        raise ConfigError("the mesh is not a valid volume mesh: a face is shared by more than two tetrahedra")
    outer = np.sort(index[counts == 1])
    element, slot = np.divmod(outer, 4)
    if tets.shape[1] == 4:
        return (faces[outer], element) if elements else faces[outer]
    local = TET_FACES[slot]  # (t, 3) local vertices a, b, c
    a, b, c = local[:, 0], local[:, 1], local[:, 2]
    row = tets[element]
    vertex = row[np.arange(len(row))[:, None], local]
    ab = row[np.arange(len(row)), EDGE_NODE[a, b]]
    bc = row[np.arange(len(row)), EDGE_NODE[b, c]]
    ca = row[np.arange(len(row)), EDGE_NODE[c, a]]
    split = np.stack(
        [
            np.column_stack([vertex[:, 0], ab, ca]),
            np.column_stack([ab, vertex[:, 1], bc]),
            np.column_stack([ca, bc, vertex[:, 2]]),
            np.column_stack([ab, bc, ca]),
        ],
        axis=1,
    )
    return (split.reshape(-1, 3), np.repeat(element, 4)) if elements else split.reshape(-1, 3)


# ----------------------------------------------------------------------------- structured boxes


def _grid_index(divisions) -> np.ndarray:
    nx, ny, nz = divisions
    return np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nz + 1, ny + 1, nx + 1).transpose(2, 1, 0)


def box_mesh(
    size,
    divisions,
    origin=(0.0, 0.0, 0.0),
    pattern: Literal["six", "five"] = "six",
    source: str = "",
    order: Literal[1, 2] = 1,
) -> TetMesh:
    """A structured tetrahedral mesh of the box ``origin + [0, size]`` (m).

    ``divisions`` (nx, ny, nz) cells per axis; nodes are numbered x fastest.
    ``pattern="six"``: six tetrahedra per cell around the diagonal from its
    lowest to its highest corner (the same in every cell, so faces match);
    ``"five"``: five per cell, corner cells alternating like a checkerboard.
    ``order=2``: quadratic (10-node) tetrahedra, mid-edge nodes appended
    after the grid's nodes.
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
    if order not in (1, 2):
        raise ConfigError(f"element order must be 1 or 2, not {order}")
    mesh = TetMesh(nodes, cells, source=source or f"box mesh {tuple(size)} m, {divisions} cells")
    return mesh.quadratic() if order == 2 else mesh


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
    kinds = sorted({c.type for c in data.cells}) or ["none"]
    if "tetra" in kinds and "tetra10" in kinds:
        raise ConfigError(f"mesh {path} mixes linear and quadratic tetrahedra", location=location)
    cell_type = "tetra10" if "tetra10" in kinds else "tetra"
    blocks = [c.data for c in data.cells if c.type == cell_type]
    if not blocks:
        raise ConfigError(
            f"mesh {path} has no tetrahedra ('tetra' or 'tetra10' cells); it has: {', '.join(kinds)}",
            location=location,
        )
    tets = np.concatenate(blocks).astype(np.int64)
    width = tets.shape[1]
    nodes = np.asarray(data.points, dtype=float)[:, :3] * scale
    used, tets = np.unique(tets, return_inverse=True)  # drop nodes no tetrahedron uses (e.g. of surface cells)
    try:
        return TetMesh(nodes[used], tets.reshape(-1, width), source=str(path))
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
            f"meshing the closed surface {path} needs TetGen: pip install 'surgiplan[tetmesh]' "
            "(or give a volume mesh file with tetrahedra: .vtu, .msh, ...)",
            location=location,
        ) from None
    import trimesh

    surface = trimesh.load(Path(path), force="mesh", process=True)
    if not isinstance(surface, trimesh.Trimesh) or not surface.is_watertight:
        raise ConfigError(f"surface {path} is not a closed (watertight) triangle mesh", location=location)
    generator = tetgen.TetGen(np.asarray(surface.vertices, float) * scale, np.asarray(surface.faces, np.int32))
    options = {"quality": True, "minratio": 1.5}
    if max_volume is not None:  # TetGen ignores maxvolume unless fixedvolume ("-a") is on
        options.update(maxvolume=float(max_volume), fixedvolume=True)
    nodes, tets = generator.tetrahedralize(**options)[:2]
    return TetMesh(nodes, tets, source=str(path))
