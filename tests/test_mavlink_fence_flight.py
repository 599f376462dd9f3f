"""The mavlink_vehicle device with the scene's fence: the rehearsal as shipped, refusals, rally points.

The simulated vehicle runs in a thread (its ground truth at hand); what the device reports is re-measured:
the vehicle's own positions against the obstacles with coal, its stored fence against the device's.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import yaml
from conftest import CONFIGS
from helpers import coal_point_distance
from surgiplan import load_pipeline, load_scene
from test_mavlink_vehicle import (
    HALL,
    RADIUS,
    device_on,
    external,
    fly,
    ground_truth,
    hall_trajectory,
    session_file,
    simulated,
)

THRESHOLD = 0.5


@pytest.fixture(scope="session")
def roadmap(tmp_path_factory):
    """The hall roadmap the whole session shares (test_mavlink_vehicle's)."""
    return session_file(tmp_path_factory, "hall-roadmap", "roadmap.npz")


def shipped_execute_settings(name: str) -> dict:
    """The execute stage's settings of a shipped pipeline file, and its simulated vehicle's."""
    document = yaml.safe_load((CONFIGS / name).read_text())
    return next(s for s in document["pipeline"] if s["stage"] == "execute")["settings"]


def test_rogue_setpoints_through_a_pillar_are_stopped_by_the_vehicle_at_its_fence(tmp_path, roadmap):
    """configs/hall_faults_fence.yaml: offboard setpoints from the path's start straight through pillar A1.
    The vehicle, on its own (GF_ACTION hold, GF_PREDICT 1), holds before A1's zone: its clearance never
    drops below the plan's threshold, measured with coal on its own positions."""
    settings = shipped_execute_settings("hall_faults_fence.yaml")
    sim = {**settings.pop("sim"), "speed": 20.0}
    settings.pop("frame")
    with simulated(**sim) as vehicle:
        outcome, _, stage, table = fly(tmp_path, roadmap, external(vehicle, **settings))
        events = [text for _, text in vehicle.events]
        breaches = list(vehicle.fence_breaches)
        zones = list(vehicle.zones)
        _, truth = ground_truth(vehicle)
    metrics = stage["metrics"]
    assert not outcome.ok and stage["status"] == "stopped"
    assert stage["message"].startswith("the vehicle's geofence stopped the flight: hold by itself (Geofence breached")
    # the vehicle acted once, on its own prediction, and said so; the device saw it (STATUSTEXT, SYS_STATUS)
    assert len(breaches) == 1 and breaches[0]["action"] == "hold" and breaches[0]["kind"] == "fence"
    assert "Geofence breached (fence): holding" in events and "mode hold (geofence)" in events
    # SYS_STATUS (1 Hz) shows the breach only if one falls while the vehicle still brakes: not every flight
    said = [e["message"] for e in metrics["fence_events"]]
    assert said[0] == "Geofence breached (fence): holding"
    assert set(said[1:]) <= {"SYS_STATUS: geofence not healthy (breached)"}
    # the device's own entry follows the vehicle's word, after any SYS_STATUS that came while it read it
    ours = next(f for f in metrics["faults"] if f["kind"] != "geofence")
    assert {"kind": "geofence_breach", "mode": "hold"}.items() <= ours.items()
    assert metrics["faults"][0]["message"] == said[0]
    # the fence the device derived is the one the vehicle holds: 10 zones (9 obstacles and the bounds)
    assert metrics["fence_verified"] is True and metrics["fence_items"] == 27 and len(zones) == 10
    assert metrics["parameters_set"]["GF_ACTION"] == 2 and metrics["parameters_set"]["GF_PREDICT"] == 1
    # measured on the vehicle's own states: never closer to A1 than the threshold (its radius 0.25 m off)
    scene = load_scene(HALL)
    a1 = scene.obstacles[scene.obstacle_names.index("A1")]
    clearance = coal_point_distance(a1, truth) - RADIUS
    assert clearance.min() >= THRESHOLD
    assert metrics["flight_min_clearance_m"] >= THRESHOLD
    # it holds at rest before the fence, at about the look-ahead (0.75 m at 1.5 m/s) from it
    assert 0 < metrics["final_fence_distance_m"] < 1.1 and metrics["final_clearance_m"] >= THRESHOLD
    assert np.linalg.norm(table[-1, 4:7]) < 0.05


def test_a_scene_beyond_the_fence_capacity_is_refused_before_any_motion(tmp_path, roadmap):
    with simulated() as vehicle:
        outcome, _, stage, _ = fly(tmp_path, roadmap, external(vehicle, fence={"capacity": 20}))
        uploads = list(vehicle.uploads)
    assert not outcome.ok and stage["status"] == "refused"
    assert "the scene's geofence needs 27 fence items" in stage["message"]
    assert "more than the vehicle's fence capacity of 20" in stage["message"]
    assert uploads == [] and not vehicle.armed


def test_the_fence_can_be_turned_off_and_rally_points_are_uploaded_and_verified(tmp_path):
    path = [[2.0, 6.0, 1.5], [5.0, 7.5, 1.5], [8.0, 7.8, 1.6]]
    with simulated() as vehicle, device_on(vehicle, tmp_path, rally_points=["pad_b", [2.0, 9.0, 0.0]]) as device:
        report = device.execute(hall_trajectory(path))
        rally = np.array(vehicle.rally_points)
    assert report.status == "completed", report.message
    assert report.metrics["rally_points"] == 2 and report.metrics["rally_verified"] is True
    # in the vehicle's local NED about the pad (2, 6, 0): pad_b (22, 6, 1.5) is 20 m east, 1.5 m up
    np.testing.assert_allclose(rally, [[0.0, 20.0, -1.5], [3.0, 0.0, 0.0]], atol=0.011)
    with simulated() as vehicle, device_on(vehicle, tmp_path, fence={"enabled": False}) as device:
        report = device.execute(hall_trajectory(path))
        kinds = {kind for kind, _ in vehicle.uploads}
        params = dict(vehicle.params.changes)
    assert report.status == "completed" and report.metrics["fence"] is False
    assert kinds == {0} and "GF_ACTION" not in params  # only the mission; the vehicle's fence untouched


@pytest.mark.slow
def test_the_shipped_rehearsal_runs_as_a_program_and_says_why_it_stopped(tmp_path, roadmap, cli, monkeypatch):
    """hall_faults_fence.yaml exactly as shipped (the simulated vehicle a subprocess at 4x): exit 1, the stage
    stopped, the breach in result.json and report.html's zones."""
    monkeypatch.chdir(tmp_path)
    if roadmap.exists():  # the file's artifact path is relative to the working directory
        (tmp_path / "out" / "hall-flight").mkdir(parents=True)
        shutil.copy(roadmap, tmp_path / "out" / "hall-flight" / "roadmap.npz")
    code, _, err = cli("run", CONFIGS / "hall_faults_fence.yaml", "--quiet")
    assert code == 1 and "the vehicle's geofence stopped the flight" in err
    document = json.loads((tmp_path / "out" / "hall-faults-fence" / "result.json").read_text())
    stage = document["stages"][1]
    assert stage["metrics"]["flight_min_clearance_m"] >= THRESHOLD
    assert len(stage["annotations"]["zones"]) == 10 and stage["annotations"]["zones"][0]["inclusion"] is True
    assert load_pipeline(CONFIGS / "hall_faults_fence.yaml").stages[1].settings.fence.predict is True
