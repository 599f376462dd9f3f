"""Occupancy grids as obstacles: greedy meshing covers exactly the occupied voxels, distances are the voxels',
files (``.npy``, ``.npz``, PLY point clouds) load in the scene's unit, bad files are refused with file, line and
key, and the shipped example (configs/scanned_trainer.yaml) is what its generator writes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from bad_input_support import assert_clean_failure, pipeline_file
from helpers import coal_scene_point_distance
from surgiplan import load_scene
from surgiplan.geometry.occupancy import greedy_boxes
from surgiplan.geometry.shapes import Box
from surgiplan.geometry.transforms import Pose
from surgiplan.scene import Scene

ROOT = Path(__file__).resolve().parent.parent


def filled(boxes: np.ndarray, shape) -> np.ndarray:
    """How many boxes cover each voxel."""
    count = np.zeros(shape, dtype=int)
    for i0, j0, k0, i1, j1, k1 in boxes:
        count[i0:i1, j0:j1, k0:k1] += 1
    return count


@pytest.mark.parametrize("density", [0.1, 0.5, 0.9])
def test_greedy_boxes_cover_the_occupied_voxels_once(density):
    grid = np.random.default_rng(int(density * 10)).random((9, 7, 6)) < density
    boxes = greedy_boxes(grid)
    assert np.array_equal(filled(boxes, grid.shape), grid.astype(int))
    assert len(boxes) <= grid.sum()


def test_a_solid_block_is_one_box_and_a_slab_with_a_hole_a_few():
    grid = np.zeros((10, 10, 10), dtype=bool)
    grid[2:7, 1:9, 3:5] = True
    assert greedy_boxes(grid).tolist() == [[2, 1, 3, 7, 9, 5]]
    grid[4, 4, 3:5] = False  # a hole through the slab
    boxes = greedy_boxes(grid)
    assert np.array_equal(filled(boxes, grid.shape), grid.astype(int)) and len(boxes) <= 4


def write_scene(tmp_path: Path, grid_entry: dict, unit: str = "mm") -> Path:
    path = tmp_path / "scene.yaml"
    path.write_text(
        yaml.safe_dump(
            {
                "length_unit": unit,
                "bounds": {"min": [-5, -5, -5], "max": [30, 30, 30]},
                "obstacles": [{"name": "scan", "occupancy_grid": grid_entry, "pose": {"xyz": [1, 2, 3]}}],
            }
        )
    )
    return path


def test_distances_are_the_voxels_distances(tmp_path):
    """The scene of a grid's boxes against coal's distance to every voxel as its own box (independent of the
    meshing): the same distance outside to 1e-9 m, inside where a voxel is."""
    rng = np.random.default_rng(3)
    grid = rng.random((6, 5, 4)) < 0.4
    np.save(tmp_path / "grid.npy", grid)
    scene = load_scene(write_scene(tmp_path, {"file": "grid.npy", "voxel_size": [2, 3, 4], "origin": [-1, 0, 1]}))
    assert all(o.name.startswith("scan#") for o in scene.obstacles) and len(scene.obstacles) < grid.sum()
    voxel, origin = np.array([2e-3, 3e-3, 4e-3]), np.array([1e-3 - 1e-3, 2e-3, 3e-3 + 1e-3])
    voxels = Scene(
        scene.bounds_min,
        scene.bounds_max,
        [
            Box(f"v{n}", Pose(np.eye(3), origin + (np.array(ijk) + 0.5) * voxel), size=tuple(voxel))
            for n, ijk in enumerate(np.argwhere(grid))
        ],
    )
    points = rng.uniform(-2e-3, 0.025, (400, 3))
    ours = scene.signed_distance(points)[0]
    reference = coal_scene_point_distance(voxels, points)
    outside = reference > 1e-7
    assert outside.sum() > 200 and (~outside).sum() > 10
    np.testing.assert_allclose(ours[outside], reference[outside], rtol=0, atol=1e-9)
    assert np.all(ours[reference < -1e-7] < 0)


def test_npz_threshold_and_a_point_cloud(tmp_path):
    values = np.zeros((4, 4, 4))
    values[1, 2, 3] = 0.7
    values[0, 0, 0] = 0.2
    np.savez(tmp_path / "grid.npz", probability=values, other=np.zeros(3))
    scene = load_scene(
        write_scene(tmp_path, {"file": "grid.npz", "key": "probability", "threshold": 0.5, "voxel_size": 2})
    )
    (only,) = scene.obstacles
    np.testing.assert_allclose(only.pose.translation, np.array([1 + 3, 2 + 5, 3 + 7]) * 1e-3, atol=1e-15)
    np.testing.assert_allclose(only.size, [2e-3] * 3, atol=1e-15)
    # a point cloud (PLY, written by trimesh, read back through the maintained reader): the voxels holding points
    points = np.array([[0.5, 0.5, 0.5], [0.9, 0.2, 0.1], [2.5, 0.5, 0.5], [7.9, 5.5, 1.0]])
    trimesh.PointCloud(points).export(tmp_path / "scan.ply")
    scene = load_scene(write_scene(tmp_path, {"points": "scan.ply", "unit": "cm", "voxel_size": 10}))
    centres = sorted(tuple(np.round(o.pose.translation * 1e3, 9)) for o in scene.obstacles)
    # cm points in 10 mm voxels: (0,0,0) twice, (2,0,0), (7,5,1); the first two runs along x merge nothing
    assert len(scene.obstacles) == 3
    assert centres[0] == (1 + 5.0, 2 + 5.0, 3 + 5.0)


@pytest.mark.parametrize(
    ("entry", "prepare", "fragments"),
    [
        ({"file": "missing.npy", "voxel_size": 1}, None, ["occupancy_grid.file: occupancy grid file not found"]),
        ({"file": "two.npz", "voxel_size": 1}, "two", ["occupancy_grid.key:", "holds 2 arrays (a, b)"]),
        ({"file": "two.npz", "key": "c", "voxel_size": 1}, "two", ["occupancy_grid.key:", "no array 'c'"]),
        ({"file": "flat.npy", "voxel_size": 1}, "flat", ["occupancy_grid.file:", "is a 3D array", "(4, 4)"]),
        ({"file": "empty.npy", "voxel_size": 1}, "empty", ["occupancy_grid: the occupancy grid has no occupied"]),
        ({"file": "junk.npy", "voxel_size": 1}, "junk", ["occupancy_grid.file: cannot read occupancy grid"]),
        ({"voxel_size": 1}, None, ["occupancy_grid:", "give either file"]),
        ({"file": "a.npy", "voxel_size": -1}, None, ["occupancy_grid.voxel_size"]),
    ],
)
@pytest.mark.usefixtures("with_example_plugin")
def test_bad_grids_are_refused_with_file_line_and_key(cli, tmp_path, entry, prepare, fragments):
    if prepare == "two":
        np.savez(tmp_path / "two.npz", a=np.ones((2, 2, 2)), b=np.ones((2, 2, 2)))
    elif prepare == "flat":
        np.save(tmp_path / "flat.npy", np.ones((4, 4)))
    elif prepare == "empty":
        np.save(tmp_path / "empty.npy", np.zeros((3, 3, 3), dtype=bool))
    elif prepare == "junk":
        (tmp_path / "junk.npy").write_bytes(b"\x93NUMPY this is not an array")

    def change(d):
        d["scene"]["obstacles"].append({"name": "scan", "occupancy_grid": entry})

    path = pipeline_file(tmp_path, change)
    line = next(n for n, text in enumerate(path.read_text().splitlines(), 1) if "occupancy_grid" in text)
    result = cli("run", path)
    assert_clean_failure(result, tmp_path, "scene.obstacles[1].occupancy_grid", *fragments)
    # the line of the key named (or of the occupancy_grid entry), inside this obstacle's lines
    assert any(f"pipeline.yaml:{n}:" in result[2] for n in range(line, line + 7)), result[2]


def test_the_shipped_scan_is_what_its_generator_writes():
    spec = importlib.util.spec_from_file_location("scanned_trainer", ROOT / "configs/scenes/scanned_trainer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    shipped = np.load(ROOT / "configs/scenes/scanned_trainer.npz")["occupancy"]
    assert np.array_equal(shipped, module.trainer())
    assert (ROOT / "configs/scenes/scanned_trainer.npz").stat().st_size < 10_000
    scene = load_scene(ROOT / "configs/scenes/scanned_trainer.yaml")
    assert 50 < len(scene.obstacles) < shipped.sum() / 100  # greedy meshing: a box per ~300 voxels
    # every occupied voxel's centre is inside the scene, every free one's outside
    centres = (np.argwhere(np.ones(shipped.shape, dtype=bool)) + 0.5) * 2e-3
    inside = scene.signed_distance(centres)[0] < 0
    assert np.array_equal(inside, shipped.reshape(-1))
