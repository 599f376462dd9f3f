"""stvk meshes and materials: structured boxes, meshio files, regions and image maps."""

from __future__ import annotations

import itertools

import meshio
import numpy as np
import pytest
from surgiplan.errors import ConfigError
from surgiplan.plugins.fem.material import ImageMap, MaterialField, lame_parameters
from surgiplan.plugins.fem.mesh import TetMesh, box_mesh, read_tet_mesh


@pytest.mark.parametrize(("pattern", "per_cell"), [("six", 6), ("five", 5)])
def test_box_mesh_fills_the_box_with_a_conforming_mesh(pattern, per_cell):
    size, divisions = (0.05, 0.04, 0.0025), (5, 4, 2)
    mesh = box_mesh(size, divisions, origin=(0.01, 0, 0), pattern=pattern)
    assert mesh.n_nodes == 6 * 5 * 3
    assert mesh.n_elements == per_cell * 5 * 4 * 2
    assert np.all(mesh.volumes > 0)
    assert mesh.volumes.sum() == pytest.approx(np.prod(size), rel=1e-12)
    surface = mesh.surface
    edges = np.sort(np.concatenate([surface[:, [0, 1]], surface[:, [1, 2]], surface[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)  # closed: faces of neighbouring cells match
    # outward orientation: the divergence theorem gives back the volume
    corners = mesh.nodes[surface]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) / 2
    assert np.einsum("ij,ij->", corners.mean(axis=1), normals) / 3 == pytest.approx(np.prod(size), rel=1e-12)
    # the surface is exactly the box's boundary
    lo, hi = np.array([0.01, 0, 0]), np.array([0.06, 0.04, 0.0025])
    on_boundary = np.isclose(mesh.nodes, lo) | np.isclose(mesh.nodes, hi)
    assert set(np.unique(surface)) == set(np.flatnonzero(on_boundary.any(axis=1)))


def test_the_papers_flap_has_about_1300_nodes_and_4000_elements():
    mesh = box_mesh((0.05, 0.05, 0.0025), (20, 20, 2), pattern="five")
    assert (mesh.n_nodes, mesh.n_elements) == (1323, 4000)


def test_mesh_files_round_trip_through_meshio_and_get_fixed_orientation(tmp_path):
    mesh = box_mesh((1.0, 2.0, 3.0), (2, 2, 2))
    flipped = mesh.tets.copy()
    flipped[::2] = flipped[::2][:, [1, 0, 2, 3]]  # half the tetrahedra inside out
    extra = np.vstack([mesh.nodes, [[9.0, 9.0, 9.0]]])  # a node of no tetrahedron (e.g. of a surface cell)
    path = tmp_path / "part.vtu"
    meshio.write(path, meshio.Mesh(extra, [("tetra", flipped), ("vertex", np.array([[len(extra) - 1]]))]))
    loaded = read_tet_mesh(path, scale=0.001)
    assert loaded.n_nodes == mesh.n_nodes
    assert np.all(loaded.volumes > 0)
    assert loaded.volumes.sum() == pytest.approx(6e-9, rel=1e-12)


def test_bad_mesh_files_are_clear_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        read_tet_mesh(tmp_path / "missing.vtu", location="settings.mesh.file")
    path = tmp_path / "surface.vtu"
    meshio.write(path, meshio.Mesh(np.eye(3), [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(ConfigError, match=r"no tetrahedra.*triangle"):
        read_tet_mesh(path)
    with pytest.raises(ConfigError, match="degenerate"):
        TetMesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0.0]]), np.array([[0, 1, 2, 3]]))


def test_lame_parameters_give_back_youngs_modulus_and_poisson_ratio():
    for e, nu in itertools.product([1e4, 1e6], [0.0, 0.3, 0.45, 0.49]):
        lam, mu = lame_parameters(e, nu)
        assert mu * (3 * lam + 2 * mu) / (lam + mu) == pytest.approx(e, rel=1e-12)
        assert lam / (2 * (lam + mu)) == pytest.approx(nu, abs=1e-12)


def test_image_map_selects_dark_pixels_under_element_centroids(tmp_path):
    import matplotlib.image

    image = np.ones((10, 20))
    image[2:4, :] = 0.0  # a dark horizontal vein, rows 2-3 of 10 (top row first)
    path = tmp_path / "veins.png"
    matplotlib.image.imsave(path, image, cmap="gray", vmin=0, vmax=1)
    veins = ImageMap.read(path, [0.0, 0.0], [0.02, 0.01])
    points = np.array([[0.005, 0.0075, 0], [0.005, 0.0025, 0], [0.03, 0.0075, 0], [0.019, 0.0065, 0]])
    assert veins.select(points).tolist() == [True, False, False, True]
    field = MaterialField.uniform(4, 2.5e5, 0.45, 1000.0)
    field.override(veins.select(points), youngs_modulus=1e6)
    assert field.youngs_modulus.tolist() == [1e6, 2.5e5, 2.5e5, 1e6]
    assert field.penalty_modulus[0] == pytest.approx(0.1 * 1e6 / (3 * (1 - 2 * 0.45)), rel=1e-12)
