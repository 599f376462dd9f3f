"""Bad input, the scene and what a stage asks of it: shapes, mesh files, points, spaces, the output directory.

Each case exits 2 with a message naming what and where, no traceback, no output.
"""

from __future__ import annotations

import pytest
import trimesh
from bad_input_support import assert_clean_failure, pipeline_file

#: the example plugin package (via_point) is what the pipelines plan with
pytestmark = pytest.mark.usefixtures("with_example_plugin")


@pytest.mark.parametrize(("value", "message"), [(-3, "must be a positive length"), (float("nan"), "finite")])
def test_negative_or_nan_length(cli, tmp_path, value, message):
    def change(d):
        d["scene"]["obstacles"].append({"name": "ball", "sphere": {"radius": value}})

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "scene.obstacles[1].sphere.radius:", message
    )


def test_missing_mesh_file(cli, tmp_path):
    def change(d):
        d["scene"]["obstacles"].append({"name": "liver", "mesh": "meshes/liver.stl"})

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "scene.obstacles[1].mesh: mesh file not found",
        "liver.stl",
    )


def test_unreadable_mesh(cli, tmp_path):
    (tmp_path / "liver.stl").write_bytes(b"solid nonsense\n this is not an STL file at all")

    def change(d):
        d["scene"]["obstacles"].append({"name": "liver", "mesh": "liver.stl"})

    assert_clean_failure(cli("run", pipeline_file(tmp_path, change)), tmp_path, "scene.obstacles[1].mesh:", "liver.stl")


def test_mesh_paths_resolve_relative_to_the_file_that_names_them(cli, tmp_path):
    (tmp_path / "meshes").mkdir()
    trimesh.creation.icosphere(radius=5.0).export(tmp_path / "meshes" / "ball.stl")

    def change(d):
        d["scene"]["obstacles"].append({"name": "ball", "mesh": "meshes/ball.stl", "pose": {"xyz": [100, 20, 20]}})

    elsewhere = tmp_path / "cwd"
    elsewhere.mkdir()
    import os

    cwd = os.getcwd()
    os.chdir(elsewhere)
    try:
        code, _, err = cli("validate", pipeline_file(tmp_path, change))
    finally:
        os.chdir(cwd)
    assert code == 0, err


@pytest.mark.parametrize("key", ["start", "goal"])
def test_start_or_goal_outside_the_bounds(cli, tmp_path, key):
    def change(d):
        d["pipeline"][0][key] = [200, 50, 20]

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        f"pipeline[0].{key}: {key} (200, 50, 20) mm is outside the scene bounds",
    )


@pytest.mark.parametrize("key", ["start", "goal"])
def test_start_or_goal_inside_an_obstacle(cli, tmp_path, key):
    def change(d):
        d["pipeline"][0][key] = [40, 20, 20]

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        f"pipeline[0].{key}: {key} (40, 20, 20) mm lies inside obstacle 'A1'",
        "clearance -5 mm",
    )


def test_point_name_that_does_not_exist(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["goal"] = "tagret"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].goal: no point named 'tagret'",
        "did you mean 'target'?",
    )


def test_gimbal_target_out_of_reach(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["space"] = {
            "kind": "cast_gimbal",
            "fulcrum": {"xyz": [75, -60, 120], "rpy": [0, 0, "90 deg"]},
            "insertion": {"min": 20, "max": 100},
        }

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "pipeline[0].start: out of the gimbal's reach: insertion"
    )


def test_unknown_space_kind(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["space"] = {"kind": "r4"}

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].space.kind: unknown space 'r4'",
        "did you mean 'r3'?",
    )


def test_output_directory_not_writable(cli, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a regular file where a directory should be")
    path = pipeline_file(tmp_path)
    code, _, err = cli("run", path, "--out", blocker / "out", "--quiet")
    assert code == 2
    assert "output.dir: cannot write to output directory" in err and "Traceback" not in err
