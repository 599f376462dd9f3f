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


def test_a_closed_surface_is_filled_by_tetgen_and_behaves_like_the_analytic_bar(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("tetgen")
    from fem_support import uniaxial_stvk
    from surgiplan.plugins.fem import AxisConstraints, StVKModel, StVKSettings

    path = tmp_path / "bar.stl"
    bar = trimesh.creation.box(extents=(20.0, 10.0, 10.0))  # mm, centred on the origin
    bar.apply_translation((10.0, 5.0, 5.0))
    bar.export(path)
    coarse = StVKModel(
        StVKSettings.model_validate(
            {"mesh": {"file": str(path), "unit": "mm"}, "gravity": [0, 0, 0]},
        )
    )
    fine = StVKSettings.model_validate({"mesh": {"file": str(path), "unit": "mm", "max_tet_volume": 2e-8}})
    refined = StVKModel(fine).mesh
    assert refined.n_elements > 2 * coarse.mesh.n_elements  # max_tet_volume refines
    assert refined.volumes.mean() < 2e-8 and refined.volumes.sum() == pytest.approx(2e-6, rel=1e-9)
    m = coarse
    assert np.all(m.mesh.volumes > 0)
    assert m.mesh.volumes.sum() == pytest.approx(2e-6, rel=1e-9)  # 20 x 10 x 10 mm
    # an unstructured mesh stretched with rollers on three faces reproduces the homogeneous StVK answer
    a = 1.2
    nodes, targets, axes = [], [], []
    for axis in range(3):
        ids = m.nodes_in_region([0, 0, 0], np.where(np.arange(3) == axis, 0.0, [0.02, 0.01, 0.01]))
        held = np.zeros((len(ids), 3), dtype=bool)
        held[:, axis] = True
        nodes.append(ids), axes.append(held), targets.append(m.rest_nodes[ids])
    end = m.nodes_in_region([0.02, 0, 0], [0.02, 0.01, 0.01])
    held = np.zeros((len(end), 3), dtype=bool)
    held[:, 0] = True
    nodes.append(end), axes.append(held), targets.append(m.rest_nodes[end] * [a, 1, 1])
    state = m.solve(AxisConstraints(np.concatenate(nodes), np.concatenate(targets), None, np.concatenate(axes)))
    assert state.converged and state.valid
    b, nominal = uniaxial_stvk(a, 1e6, 0.45, m.material.penalty_modulus[0])
    assert state.data["reaction_field"][end, 0].sum() == pytest.approx(nominal * 1e-4, rel=1e-6)
    lateral = m.nodes_in_region([0, 0.01, 0], [0.02, 0.01, 0.01])
    assert np.allclose(state.positions[lateral, 1], b * 0.01, rtol=1e-7)


def test_an_open_surface_is_refused_with_its_name(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    pytest.importorskip("tetgen")
    from surgiplan.plugins.fem.mesh import tetrahedralize_surface

    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2])  # one side missing
    path = tmp_path / "open.stl"
    open_box.export(path)
    with pytest.raises(ConfigError, match=r"open.stl is not a closed \(watertight\)"):
        tetrahedralize_surface(path)


@pytest.mark.parametrize("pattern", ["six", "five"])
def test_quadratic_meshes_put_a_node_at_the_middle_of_every_edge(tmp_path, pattern):
    linear = box_mesh((0.03, 0.02, 0.01), (3, 2, 1), pattern=pattern)
    mesh = box_mesh((0.03, 0.02, 0.01), (3, 2, 1), pattern=pattern, order=2)
    assert mesh.order == 2 and mesh.tets.shape == (linear.n_elements, 10)
    edges = np.unique(np.sort(linear.tets[:, list(itertools.combinations(range(4), 2))].reshape(-1, 2), axis=1), axis=0)
    assert mesh.n_nodes == linear.n_nodes + len(edges)
    from surgiplan.plugins.fem.shape import EDGES

    middle = 0.5 * (mesh.nodes[mesh.tets[:, EDGES[:, 0]]] + mesh.nodes[mesh.tets[:, EDGES[:, 1]]])
    assert np.allclose(mesh.nodes[mesh.tets[:, 4:]], middle, atol=1e-15)
    # the split boundary is closed, outward and covers the box
    surface = mesh.surface
    corners = mesh.nodes[surface]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]) / 2
    assert np.einsum("ij,ij->", corners.mean(axis=1), normals) / 3 == pytest.approx(6e-6, rel=1e-12)
    e = np.sort(np.concatenate([surface[:, [0, 1]], surface[:, [1, 2]], surface[:, [2, 0]]]), axis=1)
    assert np.all(np.unique(e, axis=0, return_counts=True)[1] == 2)
    # a tetra10 file round-trips, and inside-out elements are turned (with their mid-edge nodes)
    flipped = mesh.tets.copy()
    from surgiplan.plugins.fem.shape import SWAP_1_2

    flipped[::3] = flipped[::3][:, SWAP_1_2[10]]
    path = tmp_path / "quadratic.vtu"
    meshio.write(path, meshio.Mesh(mesh.nodes, [("tetra10", flipped)]))
    loaded = read_tet_mesh(path)
    assert loaded.order == 2 and np.array_equal(np.sort(loaded.tets, axis=1), np.sort(mesh.tets, axis=1))
    assert np.array_equal(loaded.tets, mesh.tets)
