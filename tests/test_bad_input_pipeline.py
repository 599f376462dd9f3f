"""Bad input, the pipeline file: malformed YAML, unknown keys, plugins and settings; every problem at once.

Each case exits 2 with a message naming what and where, no traceback, no output.
"""

from __future__ import annotations

import textwrap

import pytest
from bad_input_support import assert_clean_failure, pipeline_file
from conftest import CONFIGS

#: the example plugin package (via_point) is what the pipelines plan with
pytestmark = pytest.mark.usefixtures("with_example_plugin")


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


def test_negative_setting_length(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["margin"] = -1

    assert_clean_failure(
        cli("run", pipeline_file(tmp_path, change)),
        tmp_path,
        "pipeline[0].settings.margin: must be a non-negative length",
    )


def test_several_problems_are_reported_together(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["settings"]["via_points"] = -5
        d["pipeline"][0]["settings"]["seed"] = "x"

    code, _, err = cli("validate", pipeline_file(tmp_path, change))
    assert code == 2
    assert "2 problems" in err and "via_points" in err and "seed" in err


def test_every_problem_is_reported_in_one_pass_sorted_by_line(cli, tmp_path):
    """Mistakes of every pass at once: structure (a top-level typo, a stage's bad type), a plugin setting,
    the scene, a start: one `validate` lists them all, in file order."""
    text = textwrap.dedent("""\
        name: probe
        lenght_unit: mm
        length_unit: mm
        scene:
          bounds: {min: [0, 0, 0], max: [150, 100, 40]}
          obstacles:
            - {name: A1, box: {min: [35, 0, 0], max: [45, 47, 40]}}
            - {name: ball, sphere: {radius: -3}}
          points: {entry: [10, 50, 20], target: [140, 50, 20]}
        pipeline:
          - stage: plan
            plugin: via_point
            settings: {via_point: 10}
            start: entry
            goal: target
          - stage: plan
            plugin: via_point
            start: [40, 20, 20]
            goal: tagret
          - stage: plan
            plugin: via_point
            settings: {seed: many}
            start: entry
            goal: target
        """)
    code, _, err = cli("validate", pipeline_file(tmp_path, text=text))
    assert code == 2
    lines = [line.strip() for line in err.splitlines()]
    assert lines[0] == "error: 6 problems:", err
    expected = [
        "pipeline.yaml:2: lenght_unit: unknown key 'lenght_unit'",
        "pipeline.yaml:8: scene.obstacles[1].sphere.radius: must be a positive length",
        "pipeline.yaml:13: pipeline[0].settings.via_point: unknown key 'via_point'",
        # the scene had an error: its other obstacles still catch a start inside A1
        "pipeline.yaml:18: pipeline[1].start: start (40, 20, 20) mm lies inside obstacle 'A1'",
        "pipeline.yaml:19: pipeline[1].goal: no point named 'tagret'; did you mean 'target'?",
        "pipeline.yaml:22: pipeline[2].settings.seed: Input should be a valid integer",
    ]
    for fragment, line in zip(expected, lines[1:], strict=True):
        assert fragment in line, (fragment, line)


def test_shipped_configs_are_valid(cli):
    for path in sorted(CONFIGS.glob("*.yaml")):
        code, _, err = cli("validate", path)
        assert code == 0, f"{path}: {err}"
