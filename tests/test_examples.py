"""The example third-party package (examples/surgiplan-hello): one plugin of each kind, checked on numbers.

These are the README's plugin guide, run: a planner in a space plugin, a deformable model against its
closed form, a device that refuses a path closer than its safety margin and otherwise tracks it with
the lag its model predicts, and a pose source whose deviation has a closed form. Its stage kind,
``export``, is tested in tests/test_stage_kinds.py.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from conftest import CONFIGS


def run_file(cli, tmp_path, stages, name="example"):
    data = {
        "name": name,
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": stages,
        "output": {"dir": str(tmp_path / "out"), "figures": False, "gltf": False},
    }
    path = tmp_path / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    code, _, err = cli("run", path, "--quiet")
    return code, err, json.loads((tmp_path / "out" / "result.json").read_text())


PLAN_IN_THE_PLANE = {
    "stage": "plan",
    "name": "plane",
    "plugin": "via_point",
    "settings": {"via_points": 300, "seed": 2},
    "clearance_threshold": 1,
    "space": {"kind": "planar", "height": 20, "tip_radius": 0.5},
    "start": "entry",
    "goal": "target",
}


def test_a_planner_in_a_space_plugin(cli, tmp_path, with_example_plugin):
    from surgiplan import load_scene

    code, err, document = run_file(cli, tmp_path, [PLAN_IN_THE_PLANE])
    assert code == 0, err
    stage = document["stages"][0]
    assert stage["status"] == "solved" and stage["space"] == "planar"
    path = np.asarray(stage["path"])
    assert path.shape[1] == 2
    tips = np.asarray(stage["tip_path"])
    np.testing.assert_allclose(tips[:, 2], 0.020)  # every tip in the plane
    np.testing.assert_allclose(tips[[0, -1]], [[0.010, 0.050, 0.020], [0.140, 0.050, 0.020]])
    # the 1 mm margin, measured independently of the space: exact capsule clearances of the tip sphere
    scene = load_scene(CONFIGS / "scenes" / "block_world.yaml")
    clearance = scene.motion_clearance(tips[:-1], tips[1:], 0.0005)
    assert clearance.min() >= 0.001 - 1e-12
    assert stage["metrics"]["min_clearance_m"] == pytest.approx(clearance.min(), abs=1e-12)


def test_a_deformable_model_against_its_closed_form(cli, tmp_path, with_example_plugin):
    stage = {
        "stage": "simulate",
        "plugin": "spring_chain",
        "settings": {"start": [10, 50, 30], "end": [140, 50, 30], "nodes": 31, "stiffness": 50, "node_mass": 0.002},
    }
    code, err, document = run_file(cli, tmp_path, [stage])
    assert code == 0, err
    metrics = document["stages"][0]["metrics"]
    n, m, g, k = 31, 0.002, 9.81, 50.0
    assert metrics["max_sag_m"] == pytest.approx(m * g / (2 * k) * 15 * 15, rel=1e-12)  # the middle node
    assert metrics["sag_error_m"] < 1e-15
    # the energy at equilibrium: minus half the work of the loads (a linear system)
    i = np.arange(n)
    sag = m * g / (2 * k) * i * (n - 1 - i)
    assert metrics["energy_J"] == pytest.approx(-0.5 * m * g * sag.sum(), rel=1e-12)


def test_a_device_tracks_with_the_lag_its_model_predicts(cli, tmp_path, with_example_plugin):
    settings = {"speed": 40, "lag": 0.05, "rate": 400, "tool_radius": 0.5}
    robot = {"stage": "execute", "plugin": "point_robot", "settings": settings}
    code, err, document = run_file(cli, tmp_path, [PLAN_IN_THE_PLANE, robot])
    assert code == 0, err
    plan, execute = document["stages"]
    assert execute["status"] == "completed"
    metrics = execute["metrics"]
    # a first-order lag following a ramp at speed v, the command held over each period dt, settles to an
    # error of v dt / (1 - exp(-dt / lag)) on straight stretches (v * lag as dt -> 0)
    dt = 1 / 400
    assert metrics["tracking_error_max_m"] == pytest.approx(0.040 * dt / (1 - np.exp(-dt / 0.05)), rel=1e-3)
    executed = np.asarray(execute["path"])
    np.testing.assert_allclose(executed[-1], plan["tip_path"][-1], atol=2e-5)  # settled at the goal
    assert metrics["planned_min_clearance_m"] == pytest.approx(plan["metrics"]["min_clearance_m"], abs=1e-12)


def test_a_device_refuses_a_path_closer_than_its_safety_margin(cli, tmp_path, with_example_plugin):
    robot = {"stage": "execute", "plugin": "point_robot", "settings": {"safety_margin": 5}}
    code, _, document = run_file(cli, tmp_path, [PLAN_IN_THE_PLANE, robot])
    assert code == 1
    _, execute = document["stages"]
    assert execute["status"] == "refused" and execute["path"] == []
    assert "refused before any motion" in execute["message"] and "the safety margin is 5 mm" in execute["message"]
    assert execute["metrics"]["planned_min_clearance_m"] < 0.005


STRAIGHT_PLAN = {  # a straight, horizontal recommended path along x, clear of every block
    "stage": "plan",
    "name": "straight",
    "plugin": "via_point",
    "settings": {"via_points": 50, "seed": 1},
    "start": [50, 50, 20],
    "goal": [85, 50, 20],
}


def test_a_pose_source_whose_deviation_has_a_closed_form(cli, tmp_path, with_example_plugin):
    """A vertical tremor of 0.3 mm at 10 Hz, sampled at 200 Hz (a crest every 20 samples), on a straight path:
    the stage measures a deviation of |0.3 sin(2 pi 10 t)| mm, largest 0.3 mm, RMS 0.3 / sqrt(2) mm."""
    hand = {
        "stage": "guide",
        "name": "hand",
        "plugin": "steady_hand",
        "settings": {"speed": 35, "tremor": 0.3, "frequency": 10, "rate": 200},  # 35 mm in 1 s: 10 periods
        "guidance": {"deviation_tolerance": 1},
    }
    code, err, document = run_file(cli, tmp_path, [STRAIGHT_PLAN, hand])
    assert code == 0, err
    plan, guide = document["stages"]
    assert np.asarray(plan["path"]).shape == (2, 3)  # the straight line itself
    m = guide["metrics"]
    assert guide["status"] == "completed" and m["events"].get("deviation", 0) == 0
    assert m["deviation_max_m"] == pytest.approx(0.0003, abs=1e-9)
    t = np.arange(201) / 200
    expected = np.sqrt(np.mean((0.0003 * np.sin(2 * np.pi * 10 * t)) ** 2))
    assert m["deviation_rms_m"] == pytest.approx(expected, rel=1e-6)
    assert expected == pytest.approx(0.0003 / np.sqrt(2), rel=0.01)
    assert m["duration_s"] == pytest.approx(1.0)


def test_a_pose_source_that_goes_silent_ends_the_attempt_stopped(cli, tmp_path, with_example_plugin):
    hand = {
        "stage": "guide",
        "plugin": "steady_hand",
        "settings": {"speed": 35, "silent_after": 0.5},
        "guidance": {"silence_timeout": 0.3},
    }
    code, _, document = run_file(cli, tmp_path, [STRAIGHT_PLAN, hand])
    guide = document["stages"][1]
    assert code == 1 and guide["status"] == "stopped"
    assert "source 'steady_hand' sent no pose for 0.3 s (guidance.silence_timeout)" in guide["message"]
