"""Many obstacles are drawn merged (``surgiplan.outputs.merged``): one mesh a group in scene.glb (read back by
trimesh's glTF loader) and in report.html's data, with every box's triangles (volumes and corners checked
against trimesh's own boxes); a few obstacles are drawn one by one, as before."""

from __future__ import annotations

import numpy as np
import trimesh
from surgiplan.geometry.shapes import Box, Sphere
from surgiplan.geometry.transforms import Pose
from surgiplan.outputs.gltf import write_scene_glb
from surgiplan.outputs.merged import MAX_SEPARATE, box_triangles, drawn_meshes
from surgiplan.outputs.report.data import scene_data
from surgiplan.scene import Scene


def boxes(count: int, prefix: str = "b", seed: int = 0) -> list[Box]:
    rng = np.random.default_rng(seed)
    return [
        Box(f"{prefix}{i}", Pose.from_xyz_rpy(rng.uniform(0, 0.1, 3), rng.uniform(-3, 3, 3)), size=tuple(s))
        for i, s in enumerate(rng.uniform(0.001, 0.01, (count, 3)))
    ]


def test_box_triangles_are_trimesh_boxes():
    some = boxes(20)
    vertices, faces = box_triangles(some)
    for n, box in enumerate(some):
        mine = trimesh.Trimesh(vertices[8 * n : 8 * n + 8], faces[12 * n : 12 * n + 12] - 8 * n)
        reference = box.to_trimesh()
        assert mine.is_watertight and mine.is_winding_consistent
        np.testing.assert_allclose(mine.volume, np.prod(box.size), rtol=1e-9)  # positive: the faces point outward
        np.testing.assert_allclose(np.sort(mine.vertices, axis=0), np.sort(reference.vertices, axis=0), atol=1e-15)


def test_few_obstacles_are_drawn_one_by_one_many_merged_by_group():
    few = drawn_meshes(boxes(MAX_SEPARATE))
    assert [d.name for d in few] == [f"b{i}" for i in range(MAX_SEPARATE)] and {d.count for d in few} == {1}
    grid = boxes(150, prefix="scan#", seed=1)
    others = [*boxes(30, seed=2), Sphere("ball", Pose.from_xyz_rpy([0.05, 0.05, 0.05]), radius=0.01)]
    merged = {d.name: d for d in drawn_meshes(grid + others)}
    assert set(merged) == {"scan", "obstacles"}
    assert merged["scan"].count == 150 and merged["obstacles"].count == 31
    assert len(merged["scan"].faces) == 12 * 150
    sphere_faces = len(others[-1].to_trimesh().faces)
    assert len(merged["obstacles"].faces) == 12 * 30 + sphere_faces
    assert len(merged["scan"].quads) == 6 * 150 and merged["scan"].quad_triangles == 12 * 150


def test_scene_glb_and_report_hold_one_mesh_a_group(tmp_path):
    many = boxes(200)
    scene = Scene([0, 0, 0], [0.1, 0.1, 0.1], many)
    write_scene_glb(tmp_path / "scene.glb", scene, [("p", np.array([[0.0, 0, 0], [0.1, 0.1, 0.1]]))])
    loaded = trimesh.load(tmp_path / "scene.glb")
    obstacles = [name for name in loaded.geometry if name.startswith("obstacle:")]
    assert obstacles == ["obstacle:obstacles"]
    mesh = loaded.geometry["obstacle:obstacles"]
    assert len(mesh.faces) == 12 * 200
    np.testing.assert_allclose(mesh.volume, sum(np.prod(b.size) for b in many), rtol=1e-6)
    data = scene_data(scene)
    assert [(o["name"], o["count"], o["kind"]) for o in data["obstacles"]] == [("obstacles", 200, "merged")]
