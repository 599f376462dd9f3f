"""Bad input to the retraction planner: a clear message naming what and where, exit status 2, no traceback."""

from __future__ import annotations

import copy

import yaml
from conftest import assert_error_record
from test_retraction_plan import BASE


def pipeline(tmp_path, change):
    data = copy.deepcopy(BASE)
    data["output"] = {"dir": str(tmp_path / "out")}
    change(data)
    path = tmp_path / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def settings(data):
    return data["pipeline"][0]["settings"]


def failure(cli, command, path, *fragments):
    code, out, err = cli(command, path)
    assert code == 2, (code, out, err)
    assert "Traceback" not in err + out
    for fragment in fragments:
        assert fragment in err, f"{fragment!r} not in {err!r}"
    out = path.parent / "out"
    if command == "validate" or not out.exists():
        assert not out.exists()  # found before anything ran: nothing written
    else:  # found when the stage ran: the run's record says so
        assert_error_record(out, *[f.split(": ", 1)[-1] for f in fragments[-1:]])


def test_the_goal_may_be_omitted_but_not_for_planners_that_need_one(cli, tmp_path):
    code, _, err = cli("validate", pipeline(tmp_path, lambda d: None))
    assert code == 0, err

    def safe_prm(d):
        stage = d["pipeline"][0]
        stage.update(plugin="safe_prm", settings={}, space={"kind": "r3"}, start=[40, 25, 40])

    failure(cli, "validate", pipeline(tmp_path, safe_prm), "pipeline[0]", "a plan stage needs goal")


def test_unknown_deformable_model_lists_the_choices(cli, tmp_path):
    def change(d):
        settings(d)["deformable"]["plugin"] = "stvq"

    failure(
        cli,
        "validate",
        pipeline(tmp_path, change),
        "settings.deformable",
        "unknown deformable model 'stvq'",
        "did you mean 'stvk'",
    )


def test_deformable_settings_are_validated_by_the_models_own_settings(cli, tmp_path):
    def change(d):
        settings(d)["deformable"]["settings"]["material"]["youngs_modulus"] = -5

    failure(cli, "validate", pipeline(tmp_path, change), "settings.deformable", "material.youngs_modulus")


def test_anchors_belong_to_the_planner_not_the_model(cli, tmp_path):
    def change(d):
        settings(d)["deformable"]["settings"]["anchored"] = [{"region": {"min": [0, 0, 0], "max": [0, 50, 2.5]}}]

    failure(cli, "validate", pipeline(tmp_path, change), "remove anchored from the deformable model's settings")


def test_misspelt_setting_is_named(cli, tmp_path):
    def change(d):
        settings(d)["sampling"]["sample"] = 10

    failure(cli, "validate", pipeline(tmp_path, change), "settings.sampling.sample", "did you mean 'samples'")


def test_the_planner_needs_the_se3_space(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["space"] = {"kind": "r3"}
        d["pipeline"][0]["start"] = [50, 25, 10]

    failure(cli, "run", pipeline(tmp_path, change), "space.kind", "se3 space")


def test_jaws_that_hold_no_tissue(cli, tmp_path):
    def change(d):
        d["pipeline"][0]["start"] = {"xyz": [50, 25, 20]}  # 20 mm above the flap

    failure(cli, "run", pipeline(tmp_path, change), "settings.jaws", "start: the gripper jaws hold no node")


def test_guided_sampling_needs_the_surgeons_path(cli, tmp_path):
    def change(d):
        settings(d)["sampling"] = {"kind": "guided", "samples": 5}

    failure(cli, "run", pipeline(tmp_path, change), "settings.sampling", "give the stage a goal")
