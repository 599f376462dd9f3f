"""Bad input: each case exits 2 with a message naming what and where, no traceback, no output."""

from __future__ import annotations

import copy
import textwrap

import pytest
import trimesh
import yaml
from conftest import CONFIGS

BASE = {
    "name": "probe",
    "length_unit": "mm",
    "scene": {
        "bounds": {"min": [0, 0, 0], "max": [150, 100, 40]},
        "obstacles": [{"name": "A1", "box": {"min": [35, 0, 0], "max": [45, 47, 40]}}],
        "points": {"entry": [10, 50, 20], "target": [140, 50, 20]},
    },
    "pipeline": [
        {"stage": "plan", "plugin": "via_point", "settings": {"via_points": 50}, "start": "entry", "goal": "target"}
    ],
}


def pipeline_file(tmp_path, change=None, text=None):
    data = copy.deepcopy(BASE)
    data["output"] = {"dir": str(tmp_path / "out")}
    if change:
        change(data)
    path = tmp_path / "pipeline.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(data, sort_keys=False))
    return path


def assert_clean_failure(result, tmp_path, *fragments):
    code, out, err = result
    assert code == 2, (code, out, err)
    assert "Traceback" not in err and "Traceback" not in out
    for fragment in fragments:
        assert fragment in err, f"{fragment!r} not in {err!r}"
    assert not (tmp_path / "out").exists(), "nothing may be written for bad input"


@pytest.fixture(autouse=True)
def _example(with_example_plugin):
    return with_example_plugin


def test_the_base_pipeline_is_valid(cli, tmp_path):
    code, out, err = cli("validate", pipeline_file(tmp_path))
    assert code == 0, err
    assert "ok" in out


def test_malformed_yaml(cli, tmp_path):
    text = "name: probe\npipeline: [\n  {stage: plan,\n"
    assert_clean_failure(
        cli("validate", pipeline_file(tmp_path, text=text)), tmp_path, "pipeline.yaml:", "invalid YAML"
    )


def test_unknown_top_level_key(cli, tmp_path):
    def change(d):
        d["nmae"] = d.pop("name")

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "nmae: unknown key 'nmae'",
        "did you mean 'name'?",
        "name: required key is missing",
    )


def test_unknown_plugin_name(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["plugin"] = "via_pont"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].plugin: unknown planner 'via_pont'",
        "did you mean 'via_point'?",
        "choose one of:",
    )


def test_plugin_of_the_wrong_kind(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["plugin"] = "r3"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "unknown planner 'r3' ('r3' is a space)"
    )


def test_misspelt_setting_with_line_number(cli, tmp_path):
    text = textwrap.dedent("""\
        name: probe
        length_unit: mm
        scene: {bounds: {min: [0, 0, 0], max: [150, 100, 40]}, points: {a: [1, 1, 1], b: [9, 9, 9]}}
        pipeline:
          - stage: plan
            plugin: via_point
            settings:
              via_point: 10
            start: a
            goal: b
        """)
    assert_clean_failure(
        cli("validate", pipeline_file(tmp_path, text=text)),
        tmp_path,
        "pipeline.yaml:8: pipeline[0].settings.via_point: unknown key 'via_point'",
        "did you mean 'via_points'?",
    )


def test_wrong_type(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["via_points"] = "many"

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].settings.via_points: Input should be a valid integer",
    )


@pytest.mark.parametrize(("value", "message"), [(-3, "must be a positive length"), (float("nan"), "finite")])
def test_negative_or_nan_length(cli, tmp_path, value, message):
    def change(d):
        d["scene"]["obstacles"].append({"name": "ball", "sphere": {"radius": value}})

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)), tmp_path, "scene.obstacles[1].sphere.radius:", message
    )


def test_negative_setting_length(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["margin"] = -1

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].settings.margin: must be a non-negative length",
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


def test_output_directory_not_writable(cli, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a regular file where a directory should be")
    path = pipeline_file(tmp_path)
    code, _, err = cli("run", path, "--out", blocker / "out", "--quiet")
    assert code == 2
    assert "output.dir: cannot write to output directory" in err and "Traceback" not in err


def test_several_problems_are_reported_together(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["via_points"] = -5
        d["pipeline"][0]["settings"]["seed"] = "x"

    code, _, err = cli("validate", pipeline_file(tmp_path, change))
    assert code == 2
    assert "2 problems" in err and "via_points" in err and "seed" in err


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


def test_shipped_configs_are_valid(cli):
    for path in sorted(CONFIGS.glob("*.yaml")):
        code, _, err = cli("validate", path)
        assert code == 0, f"{path}: {err}"
