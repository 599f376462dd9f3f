"""A device's word is re-measured too: what it says it executed is measured on the scene, and a contact or a
pass inside its safety margin makes the stage ``unsafe`` (the run fails, exit 1), with where and how deep.
Pose sources' samples outside the scene, not finite, or going back in time are refused with their index.

The hostile package (``tests/plugins/surgiplan_hostile``) plays the third-party devices and sources; the
expected depths are worked out by hand from the block world (A1: y <= 47 mm, A2: y >= 53 mm, for x 35-45 mm)
and checked against coal's exact distances of the reported tips."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import coal_scene_segment_distance
from test_trust_boundaries import pipeline

MM = 1e-3


def run_device(cli, tmp_path, **settings):
    path = pipeline(
        tmp_path,
        "honest",
        extra=[
            {
                "name": "device",
                "stage": "execute",
                "plugin": "hostile_device",
                "path_from": "first",
                "settings": settings,
            }
        ],
    )
    code, out, err = cli("run", path)
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    return code, out, err, document


def test_a_device_that_swings_off_the_plan_through_a_block_is_unsafe(cli, tmp_path, hostile, block_world):
    code, out, err, document = run_device(cli, tmp_path, mode="swings")
    assert code == 1 and document["status"] == "failed" and "Traceback" not in err
    stage = document["stages"][-1]
    assert stage["status"] == "unsafe"
    tips = np.asarray(stage["path"])
    assert coal_scene_segment_distance(block_world, tips[:-1], tips[1:]).min() < 0  # coal: it does hit a block
    verified = stage["metrics"]["verified"]
    # by hand: the bulge crosses x = 40 mm (A2's middle) and x = 110 mm (C2's) 12.6 mm off the plan, y = 62.6 mm,
    # deep in both (y >= 53 and 53.5 mm): the deepest points are 5 mm from their x faces
    assert verified["min_clearance_m"] == pytest.approx(-5 * MM, abs=1e-9)
    assert verified["obstacle"] in ("A2", "C2") and verified["samples"] == 201
    assert (
        "the framework measured the executed motion (the tip, a sphere of 0 mm, along 201 executed "
        in (stage["message"])
    )
    assert f"it enters obstacle '{verified['obstacle']}' 5 mm deep (at sample" in stage["message"]
    assert "the device reported a least clearance of 5 mm" in stage["message"]
    assert "(the device said: completed)" in stage["message"]
    assert "unsafe" in out  # the summary table's status column; its details and stderr say where and how deep
    assert "execute stage 'device': unsafe: the framework measured the executed motion" in err
    assert f"enters obstacle '{verified['obstacle']}' 5 mm deep" in err


def test_a_device_that_lies_about_its_clearance_is_caught(cli, tmp_path, hostile, block_world):
    code, _, _, document = run_device(cli, tmp_path, mode="lies")
    stage = document["stages"][-1]
    assert code == 1 and stage["status"] == "unsafe"
    verified = stage["metrics"]["verified"]
    assert verified["min_clearance_m"] == pytest.approx(-4.8 * MM, abs=1e-9)
    assert verified["obstacle"] == "A1"
    # the timeline's times: x = 40 mm is 30/130 of the way from entry to target, over 2 s
    assert verified["at"]["t_s"] == pytest.approx(2 * 30 / 130, abs=0.011)
    assert "it enters obstacle 'A1' 4.8 mm deep" in stage["message"]
    assert stage["metrics"]["executed_min_clearance_m"] == 0.005  # what it said stays, beside what was measured


def test_a_device_inside_its_safety_margin_is_unsafe_and_outside_it_is_not(cli, tmp_path, hostile):
    # the honest straight line keeps 3 mm in the A gap (6 mm wide)
    code, _, _, document = run_device(cli, tmp_path, mode="grazes", safety_margin=0.004)
    stage = document["stages"][-1]
    assert code == 1 and stage["status"] == "unsafe"
    assert "it comes within 3 mm of obstacle 'A" in stage["message"]
    assert "below the device's safety margin of 4 mm" in stage["message"]
    code, _, err, document = run_device(cli, tmp_path, mode="grazes", safety_margin=0.002)
    stage = document["stages"][-1]
    assert code == 0, err
    assert stage["status"] == "completed" and stage["metrics"]["verified"]["min_clearance_m"] == pytest.approx(0.003)


def test_a_device_that_reports_no_motion_gets_a_warning(cli, tmp_path, hostile):
    code, _, err, document = run_device(cli, tmp_path, mode="silent")
    stage = document["stages"][-1]
    assert code == 0 and stage["status"] == "completed" and "verified" not in stage["metrics"]
    [warning] = stage["warnings"]
    assert "device 'hostile_device' reported no executed motion" in warning
    assert "warning: execute stage 'device': device 'hostile_device' reported no executed motion" in err
    html = (tmp_path / "out" / "report.html").read_text()
    assert "reported no executed motion" in html


def test_every_stage_records_the_package_and_version_that_ran_it(cli, tmp_path, hostile):
    _, _, _, document = run_device(cli, tmp_path, mode="grazes")
    assert [(s["plugin"], s["package"], s["version"]) for s in document["stages"]] == [
        ("hostile", "surgiplan-hostile", "1.0"),
        ("hostile", "surgiplan-hostile", "1.0"),
        ("hostile_device", "surgiplan-hostile", "1.0"),
    ]


@pytest.mark.parametrize(
    ("mode", "message"),
    [
        ("outside", "sample 3: its tip (10.7, 50, 479.7) mm is outside the scene bounds (0, 0, 0) mm to (150, 100"),
        ("nan", "sample 3: its tip [nan, 0.05, 0.02] is not 3 finite numbers"),
        ("backwards", "sample 3: sample time 0.05 s is before the previous sample's 0.2 s"),
    ],
)
def test_a_source_sample_outside_the_scene_or_not_finite_is_refused_with_its_index(
    cli, tmp_path, hostile, mode, message
):
    from test_guide import guide_pipeline

    path = guide_pipeline(tmp_path, source="hostile_source", settings={"mode": mode}, guidance={"silence_timeout": 2})
    code, _, err = cli("run", path, "--quiet")
    stage = json.loads((tmp_path / "out" / "result.json").read_text())["stages"][1]
    assert code == 1 and stage["status"] == "invalid_result" and "Traceback" not in err
    assert message in stage["message"], stage["message"]
    assert "plugin 'hostile_source' (surgiplan-hostile 1.0)" in stage["message"]
