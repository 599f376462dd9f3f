"""Distances of every obstacle shape, checked against coal on random points and segments."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from helpers import coal_point_distance, coal_segment_distance
from surgiplan.geometry.mesh import mesh_from_arrays
from surgiplan.geometry.shapes import Box, Capsule, Cylinder, Mesh, Sphere
from surgiplan.geometry.transforms import Pose


def random_pose(rng) -> Pose:
    return Pose.from_xyz_rpy(rng.uniform(-0.2, 0.2, 3), rng.uniform(-np.pi, np.pi, 3))


def primitive_obstacles(rng):
    return [
        Box("box", random_pose(rng), size=(0.4, 0.2, 0.6)),
        Sphere("sphere", random_pose(rng), radius=0.25),
        Cylinder("cylinder", random_pose(rng), radius=0.15, length=0.5),
        Capsule("capsule", random_pose(rng), radius=0.1, length=0.4),
    ]


def box_mesh_obstacle(pose) -> Mesh:
    box = trimesh.creation.box(extents=(0.4, 0.2, 0.6))
    return Mesh("box-mesh", pose, mesh=mesh_from_arrays(box.vertices, box.faces, source="box"))


@pytest.mark.parametrize("index", range(4))
def test_point_signed_distance_matches_coal(index, rng):
    obstacle = primitive_obstacles(rng)[index]
    points = obstacle.pose.translation + rng.uniform(-0.5, 0.5, (1500, 3))
    ours = obstacle.sdf(points)
    reference = coal_point_distance(obstacle, points)
    outside = reference > 0
    assert outside.sum() > 100 and (~outside).sum() > 10, "the sample must cover both sides"
    # outside coal's distance is exact; inside it is an EPA estimate, so compare signs there
    np.testing.assert_allclose(ours[outside], reference[outside], atol=1e-8)
    assert np.all(ours[~outside] <= 1e-9)
    if obstacle.kind in ("box", "sphere", "capsule"):  # polytopes and spheres: EPA is exact too
        np.testing.assert_allclose(ours[~outside], reference[~outside], atol=1e-6)


def test_cylinder_inside_distance_is_the_nearest_surface(rng):
    cylinder = Cylinder("c", Pose(), radius=0.15, length=0.5)
    points = rng.uniform([-0.1, -0.1, -0.25], [0.1, 0.1, 0.25], (500, 3))
    points = points[np.linalg.norm(points[:, :2], axis=1) < 0.15]
    expected = -np.minimum(0.15 - np.linalg.norm(points[:, :2], axis=1), 0.25 - np.abs(points[:, 2]))
    np.testing.assert_allclose(cylinder.sdf(points), expected, atol=1e-12)


@pytest.mark.parametrize("index", range(4))
def test_segment_distance_matches_coal_capsule(index, rng):
    obstacle = primitive_obstacles(rng)[index]
    a = obstacle.pose.translation + rng.uniform(-0.45, 0.45, (400, 3))
    b = a + rng.normal(0.0, 0.3, (400, 3))
    ours = obstacle.segment_sd(a, b)
    reference = coal_segment_distance(obstacle, a, b)
    clear = reference > 1e-9
    assert clear.sum() > 100 and (~clear).sum() > 20
    np.testing.assert_allclose(ours[clear], reference[clear], atol=1e-8)
    assert np.all(ours[~clear] <= 1e-9), "a segment coal finds touching must not be reported clear"


@pytest.mark.parametrize("index", range(4))
def test_segment_distance_is_the_minimum_along_the_segment(index, rng):
    """Including segments that enter the shape: the deepest point's signed distance."""
    obstacle = primitive_obstacles(rng)[index]
    a = obstacle.pose.translation + rng.uniform(-0.4, 0.4, (150, 3))
    b = a + rng.normal(0.0, 0.4, (150, 3))
    ours = obstacle.segment_sd(a, b)
    t = np.linspace(0.0, 1.0, 4001)
    dense = np.array([obstacle.sdf(p + t[:, None] * (q - p)).min() for p, q in zip(a, b, strict=True)])
    spacing = np.linalg.norm(b - a, axis=1) / 4000
    assert np.all(ours <= dense + 1e-12), "never larger than a sampled value"
    assert np.all(dense - ours <= spacing + 1e-12), "and within the sampling spacing of it"


def test_mesh_distance_equals_the_primitive_it_triangulates(rng):
    pose = random_pose(rng)
    mesh = box_mesh_obstacle(pose)
    box = Box("box", pose, size=(0.4, 0.2, 0.6))
    points = pose.translation + rng.uniform(-0.4, 0.4, (1500, 3))
    expected = box.sdf(points)
    assert (expected < 0).sum() > 50
    np.testing.assert_allclose(mesh.sdf(points), expected, atol=1e-9)


def test_mesh_sign_is_right_near_edges_and_corners(rng):
    """Points whose nearest feature is an edge or a vertex: where face normals alone get the sign wrong."""
    mesh = box_mesh_obstacle(Pose())
    box = Box("box", Pose(), size=(0.4, 0.2, 0.6))
    corners = np.array([[sx * 0.2, sy * 0.1, sz * 0.3] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    points = np.concatenate([c + rng.normal(0, 0.02, (60, 3)) for c in corners])
    np.testing.assert_allclose(mesh.sdf(points), box.sdf(points), atol=1e-9)


def test_mesh_segment_distance_matches_coal(rng):
    mesh = box_mesh_obstacle(random_pose(rng))
    a = rng.uniform(-0.8, 0.8, (200, 3))
    b = a + rng.normal(0.0, 0.3, (200, 3))
    ours = mesh.segment_sd(a, b)
    reference = coal_segment_distance(mesh, a, b)
    clear = reference > 1e-9
    np.testing.assert_allclose(ours[clear], reference[clear], atol=1e-8)
    inside_both = (mesh.sdf(a) < 0) & (mesh.sdf(b) < 0)
    assert np.all(ours[inside_both] < 0), "a segment inside a watertight mesh is not clear"


def test_open_mesh_counts_its_surface_only(caplog):
    plane = trimesh.creation.box(extents=(1, 1, 1))
    open_faces = plane.faces[2:]  # drop two triangles: a hole
    with caplog.at_level("WARNING"):
        mesh = mesh_from_arrays(plane.vertices, open_faces, source="open.stl")
    assert not mesh.watertight
    assert "not watertight" in caplog.text and "open.stl" in caplog.text
    obstacle = Mesh("open", Pose(), mesh=mesh)
    d = obstacle.sdf(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]))
    np.testing.assert_allclose(d, [0.5, 0.0], atol=1e-12)  # no inside: the centre is 0.5 m from the surface


@pytest.mark.parametrize("suffix", ["stl", "obj", "ply", "glb"])
def test_mesh_files_load_in_every_format(tmp_path, suffix):
    from surgiplan.geometry.mesh import load_mesh

    source = trimesh.creation.icosphere(subdivisions=2, radius=10.0)  # "mm"
    path = tmp_path / f"ball.{suffix}"
    source.export(path)
    mesh = load_mesh(path, scale=1e-3)
    assert mesh.watertight
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), 0.010, atol=1e-9)


def test_unreadable_and_empty_meshes_are_clear_errors(tmp_path):
    from surgiplan.errors import SceneError
    from surgiplan.geometry.mesh import load_mesh

    garbage = tmp_path / "liver.stl"
    garbage.write_bytes(b"\x00\x01 this is not a mesh")
    with pytest.raises(SceneError, match=r"liver\.stl"):
        load_mesh(garbage)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(SceneError, match=r"empty\.obj"):
        load_mesh(empty)
    with pytest.raises(SceneError, match="not found"):
        load_mesh(tmp_path / "missing.stl")
