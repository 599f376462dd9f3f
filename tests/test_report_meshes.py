"""report.html draws any volume mesh a deformable model writes: tetrahedra, hexahedra, wedges, pyramids, linear or
quadratic, from the ``.vtu`` files meshio reads. Checked against closed forms: the boundary of a unit cube cut
into cells of each type is the cube's six faces (area 6, every triangle turned outward), whatever the cells."""

from __future__ import annotations

import itertools

import meshio
import numpy as np
import pytest
from surgiplan.outputs.report.meshes import boundary, simulate_mesh
from surgiplan.outputs.report.packing import Notes


def _unpack(p) -> np.ndarray:
    import base64

    return np.frombuffer(base64.b64decode(p["b64"]), dtype="<f4" if p["dtype"] == "f32" else "<u4").reshape(p["shape"])


def hex_grid(n: int):
    """A unit cube of n^3 hexahedra (VTK order: bottom 0-3 counter-clockwise, then the top)."""
    axis = np.linspace(0, 1, n + 1)
    points = np.array([[x, y, z] for z in axis for y in axis for x in axis])

    def node(i, j, k):
        return i + (n + 1) * (j + (n + 1) * k)

    cells = []
    for i, j, k in itertools.product(range(n), repeat=3):
        bottom = [node(i, j, k), node(i + 1, j, k), node(i + 1, j + 1, k), node(i, j + 1, k)]
        top = [node(i, j, k + 1), node(i + 1, j, k + 1), node(i + 1, j + 1, k + 1), node(i, j + 1, k + 1)]
        cells.append(bottom + top)
    return points, np.array(cells)


def cube_blocks(kind: str):
    corners = np.array(list(itertools.product([0.0, 1.0], repeat=3)))[:, ::-1]  # x fastest
    c = {tuple(p): i for i, p in enumerate(corners.tolist())}

    def at(x, y, z):
        return c[(float(x), float(y), float(z))]

    if kind == "hexahedron":
        return hex_grid(2)[0], [("hexahedron", hex_grid(2)[1])]
    if kind == "wedge":  # two prisms along z, split by the diagonal x = y
        prisms = [
            [at(0, 0, 0), at(1, 0, 0), at(1, 1, 0), at(0, 0, 1), at(1, 0, 1), at(1, 1, 1)],
            [at(0, 0, 0), at(1, 1, 0), at(0, 1, 0), at(0, 0, 1), at(1, 1, 1), at(0, 1, 1)],
        ]
        return corners, [("wedge", np.array(prisms))]
    # six pyramids, each face of the cube a base, the apex at the centre
    points = np.vstack([corners, [[0.5, 0.5, 0.5]]])
    faces = [
        [at(0, 0, 0), at(0, 1, 0), at(1, 1, 0), at(1, 0, 0)],
        [at(0, 0, 1), at(1, 0, 1), at(1, 1, 1), at(0, 1, 1)],
        [at(0, 0, 0), at(1, 0, 0), at(1, 0, 1), at(0, 0, 1)],
        [at(0, 1, 0), at(0, 1, 1), at(1, 1, 1), at(1, 1, 0)],
        [at(0, 0, 0), at(0, 0, 1), at(0, 1, 1), at(0, 1, 0)],
        [at(1, 0, 0), at(1, 1, 0), at(1, 1, 1), at(1, 0, 1)],
    ]
    return points, [("pyramid", np.array([[*f, 8] for f in faces]))]


@pytest.mark.parametrize("kind", ["hexahedron", "wedge", "pyramid"])
def test_the_boundary_of_a_cube_of_any_cells_is_its_six_faces_turned_outward(kind):
    points, blocks = cube_blocks(kind)
    triangles = boundary(blocks, points)
    corner = points[triangles[:, :3]]
    normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    assert 0.5 * np.linalg.norm(normal, axis=1).sum() == pytest.approx(6.0)  # the cube's area, no interior face
    outward = np.einsum("ij,ij->i", normal, corner.mean(axis=1) - 0.5)
    assert np.all(outward > 0)
    on_face = np.isclose(corner, 0.0) | np.isclose(corner, 1.0)
    assert np.all(np.any(np.all(on_face, axis=1), axis=1))  # every triangle lies in a face of the cube


def test_a_quadratic_mixed_vtu_is_drawn_with_each_triangle_coloured_by_its_cell(tmp_path):
    """Hexahedra and wedges in one file, the hexahedra quadratic (20 nodes: drawn by their corners)."""
    points, [(_, hexes)] = cube_blocks("hexahedron")
    # quadratic hexahedra: 12 edge mid-nodes each, appended (not drawn, only their corners are)
    edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
    mids = points[hexes[:, [e[0] for e in edges]]] * 0.5 + points[hexes[:, [e[1] for e in edges]]] * 0.5
    base = len(points)
    hex20 = np.hstack([hexes, base + np.arange(len(hexes) * 12).reshape(-1, 12)])
    points = np.vstack([points, mids.reshape(-1, 3)])
    # a prism on top of the cube (z 1 to 2 over x, y in [0, 0.5]), sharing no face with it
    top = len(points)
    points = np.vstack([points, [[0, 0, 1.5], [0.5, 0, 1.5], [0, 0.5, 1.5], [0, 0, 2], [0.5, 0, 2], [0, 0.5, 2]]])
    wedge = np.array([[top, top + 1, top + 2, top + 3, top + 4, top + 5]])
    stress = [np.arange(len(hexes), dtype=float) * 1e3, np.array([99e3])]
    path = tmp_path / "tissue.vtu"
    meshio.write(
        path,
        meshio.Mesh(points, [("hexahedron20", hex20), ("wedge", wedge)], cell_data={"max_principal_stress": stress}),
    )
    notes = Notes()
    mesh = simulate_mesh(tmp_path, {"name": "sim", "files": ["tissue.vtu"]}, notes)
    assert notes.items == [] and mesh is not None
    triangles = _unpack(mesh["triangles"]).astype(int)
    # the cube: 6 faces x 4 quads x 2 triangles; the prism: 2 triangles + 3 quads x 2
    assert len(triangles) == 48 + 8
    colours = _unpack(mesh["stress"])[0]
    prism = triangles.min(axis=1) >= top
    assert prism.sum() == 8 and np.all(colours[prism] == 99e3)  # the prism's triangles carry its stress
    assert set(np.round(colours[~prism] / 1e3).astype(int)) <= set(range(8)) and mesh["max_stress"] == [99e3]
