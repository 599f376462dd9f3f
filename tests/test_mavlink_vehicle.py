"""The mavlink_vehicle device in pipelines: flights through the hall, re-measured independently.

The simulated vehicle runs in a thread of the test on a free 127.0.0.1 UDP port
(faster than real time); the device connects to it as to any vehicle, so the
test can compare what the device reports with the simulator's ground truth,
and the flown path's clearance with coal's distances.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import CONFIGS, assert_error_record, write
from helpers import coal_scene_segment_distance, coal_segment_distance
from scipy.spatial import cKDTree
from surgiplan import load_pipeline, load_scene, run_pipeline
from surgiplan.errors import ConfigError, SurgiplanError
from surgiplan.plugins.devices.mavlink.conventions import LocalFrame
from surgiplan.plugins.devices.mavlink.gcs import GroundStation
from surgiplan.plugins.devices.mavlink.link import Endpoint, VehicleError, mavlink
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle
from surgiplan.registry import default_registry

HALL = CONFIGS / "scenes" / "hall.yaml"
ORIGIN = (2.0, 6.0, 0.0)  # the take-off pad: the vehicle's local NED origin in the hall
RADIUS = 0.25
MARGIN = 0.5


def _shipped_plan_stage() -> str:
    """The plan stage of configs/hall_flight.yaml, verbatim: every test pipeline plans as the shipped files do,
    so that one stored roadmap serves the whole session."""
    text = (CONFIGS / "hall_flight.yaml").read_text()
    stage = text[text.index("  - stage: plan") : text.index("  - stage: execute")]
    return stage.replace("{", "{{").replace("}", "}}").replace("out/hall-flight/roadmap.npz", "{artifact}")


PIPELINE = (
    """
name: {name}
length_unit: m
scene: {scene}
pipeline:
"""
    + _shipped_plan_stage()
    + """  - stage: execute
    name: flight
    plugin: mavlink_vehicle
    settings: {settings}
output: {{dir: {out}, figures: false, gltf: false}}
"""
)

#: a quick simulated vehicle: twenty times real time, a light breeze
QUICK = {"speed": 20.0, "wind": {"mean": [0.2, 0.3, 0.0], "gust": 0.2}, "seed": 1}


def session_file(factory, folder: str, name: str) -> Path:
    # a fixed place in the session's temporary directory, so that every test module shares it
    where = factory.getbasetemp() / folder
    where.mkdir(exist_ok=True)
    return where / name


@pytest.fixture(scope="session")
def roadmap(tmp_path_factory) -> Path:
    """One hall roadmap for the whole session, outside the repository's out/ (built once, then loaded)."""
    return session_file(tmp_path_factory, "hall-roadmap", "roadmap.npz")


def hall_pipeline(tmp_path: Path, roadmap: Path, settings: dict, name: str = "hall") -> Path:
    text = PIPELINE.format(
        name=name,
        scene=HALL,
        artifact=roadmap,
        settings=json.dumps(settings),
        out=tmp_path / "out",
    )
    return write(tmp_path / f"{name}.yaml", text)


def fly(tmp_path: Path, roadmap: Path, settings: dict):
    """Run the hall pipeline; returns the outcome, the execute stage's entry of result.json, and the flight log."""
    outcome = run_pipeline(load_pipeline(hall_pipeline(tmp_path, roadmap, settings)))
    document = json.loads((outcome.output_dir / "result.json").read_text())
    stage = document["stages"][1]
    log = outcome.output_dir / "flight.csv"
    table = np.loadtxt(log, delimiter=",", skiprows=1) if log.exists() else None
    return outcome, document, stage, table


@contextlib.contextmanager
def simulated(**settings):
    """The simulated vehicle in a thread on a free UDP port."""
    vehicle = SimulatedVehicle(SimSettings(**{**QUICK, **settings})).start()
    try:
        yield vehicle
    finally:
        vehicle.stop()


def external(vehicle: SimulatedVehicle, **settings) -> dict:
    return {
        "connection": f"udpout:127.0.0.1:{vehicle.port}",
        "frame": {"local_origin": list(ORIGIN)},
        "cruise_speed": 2.0,
        **settings,
    }


def ground_truth(vehicle: SimulatedVehicle) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's own states (vehicle time, scene positions)."""
    rows = np.array(vehicle.trajectory)
    return rows[:, 0], LocalFrame(ORIGIN).from_ned(rows[:, 1:4])


def planned_path(document) -> np.ndarray:
    return np.array(document["stages"][0]["path"])


def dense(points: np.ndarray, spacing: float = 1e-3) -> np.ndarray:
    pieces = [
        a + np.linspace(0, 1, max(2, math.ceil(np.linalg.norm(b - a) / spacing) + 1))[:, None] * (b - a)
        for a, b in itertools.pairwise(points)
    ]
    return np.vstack(pieces)


def check_flight_against_independent_measures(document, stage, table, vehicle=None) -> dict:
    """Re-measure the flight: coal clearances, KD-tree deviations, and the simulator's ground truth."""
    metrics = stage["metrics"]
    scene = load_scene(HALL)
    flown = table[:, 1:4]
    assert np.asarray(stage["path"]) == pytest.approx(flown, abs=1e-5)  # result.json's path is the flight log's
    on_path = table[:, -1] > 0.5
    index = np.flatnonzero(on_path)
    a, b = flown[index[:-1]], flown[index[1:]]
    coal_clearance = coal_scene_segment_distance(scene, a, b, RADIUS)
    assert metrics["flown_min_clearance_m"] == pytest.approx(coal_clearance.min(), abs=1e-5)
    whole = coal_scene_segment_distance(scene, flown[:-1], flown[1:], RADIUS)
    assert metrics["flight_min_clearance_m"] == pytest.approx(whole.min(), abs=1e-5)
    assert whole.min() > 0  # never touched anything
    deviation, _ = cKDTree(dense(planned_path(document))).query(flown[on_path])
    assert metrics["tracking_error_max_m"] == pytest.approx(deviation.max(), abs=2e-3)
    assert metrics["tracking_error_rms_m"] == pytest.approx(np.sqrt(np.mean(deviation**2)), abs=2e-3)
    if vehicle is not None:
        times, truth = ground_truth(vehicle)
        where = {round(t, 3): i for i, t in enumerate(times)}
        matched = np.array([where[round(t, 3)] for t in table[:, 0]])
        assert truth[matched] == pytest.approx(flown, abs=1e-4)  # float32 on the wire
    return metrics


# ----------------------------------------------------------------------------- the plugin and its settings


def test_mavlink_vehicle_is_a_registered_device():
    info = default_registry().get("device", "mavlink_vehicle")
    assert info.package == "surgiplan" and info.cls.__name__ == "MavlinkVehicle"


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"connection": "udpin:127.0.0.1:14550", "sim": {"speed": 2}}, "remove one of them"),
        ({"connection": "localhost"}, "not a MAVLink connection string; use udpin:HOST:PORT"),
        ({"cruise_sped": 1.0}, "did you mean 'cruise_speed'"),
        ({"sim": {"reject_mission": "NO_ROOM"}}, "unknown MAV_MISSION_RESULT 'NO_ROOM'; choose one of"),
        ({"sim": {"stop_answering": "landing"}}, "sim.stop_answering"),
        ({"failsafe": "panic"}, "failsafe"),
        ({"signing": {"key": ""}}, "signing key is empty"),
    ],
)
def test_bad_settings_are_reported_with_their_yaml_path(tmp_path, roadmap, settings, message):
    with pytest.raises(ConfigError) as caught:
        load_pipeline(hall_pipeline(tmp_path, roadmap, settings))
    assert message in str(caught.value)
    assert "pipeline[1].settings" in str(caught.value)


# ----------------------------------------------------------------------------- flights


def test_mission_flight_through_the_hall(tmp_path, roadmap):
    with simulated() as vehicle:
        outcome, document, stage, table = fly(tmp_path, roadmap, external(vehicle))
        zones, breaches = list(vehicle.zones), list(vehicle.fence_breaches)
    assert outcome.ok and stage["status"] == "completed"
    # with the scene's fence on (the default): uploaded, verified, held by the vehicle, never breached
    assert stage["metrics"]["fence_items"] == 27 and len(zones) == 10 and breaches == []
    assert stage["metrics"]["fence_unfenced"].keys() == {"lintel"} and stage["metrics"]["fence_events"] == []
    metrics = check_flight_against_independent_measures(document, stage, table, vehicle)
    # the mission the vehicle flew is the one that was planned: change speed, take off to the path's first
    # waypoint, one waypoint per other (thinned) path point, land
    assert len(vehicle.mission) == metrics["mission_items"] == metrics["waypoints"] + 2
    commands = [i.command for i in vehicle.mission]
    assert commands[:2] == [mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_TAKEOFF]
    assert commands[-1] == mavlink.MAV_CMD_NAV_LAND
    waypoints = vehicle.mission[1:-1]
    # in the current global frame (3, not the deprecated 6), latitude/longitude about the EKF origin
    assert {i.frame for i in vehicle.mission[1:]} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT}
    scene_points = LocalFrame(ORIGIN).from_ned([vehicle._item_position(i) for i in waypoints])
    distance, _ = cKDTree(dense(planned_path(document))).query(scene_points)
    assert distance.max() <= 0.02 + 1e-4  # the waypoint tolerance
    # safe_prm's promise, kept in flight: outside the door the margin holds up to the tracking error
    assert metrics["clearance_threshold_m"] == MARGIN
    # (5 mm of slack: deviations are measured at the samples, clearances along the chords between them)
    outside = metrics["flown_min_clearance_outside_critical_m"]
    assert outside >= MARGIN - metrics["tracking_error_max_m"] - 0.005
    assert metrics["flown_min_clearance_in_critical_m"] > 0.2  # the door: 0.35 m at best
    assert metrics["tracking_error_max_m"] < 0.15
    # it took off from its pad, flew, landed on the other pad and disarmed
    _, truth = ground_truth(vehicle)
    assert truth[0] == pytest.approx([2, 6, 0], abs=1e-6)
    assert truth[-1] == pytest.approx([22, 6, 0], abs=0.15)
    assert not vehicle.armed
    assert {"flight.csv", "flight.png"} <= set(document["files"])
    assert metrics["upload_retransmissions"] == 0 and metrics["signed"] is False
    # the upload was verified by downloading it back (PX4 answers in frame 6; the same mission)
    # three downloads, each acknowledged: the fence and the rally points (before the mission), the mission
    assert metrics["mission_verified"] is True and vehicle.sender.completed == 3
    assert metrics["fence_verified"] is True and metrics["rally_verified"] is True
    assert (
        metrics["mission_frame"] == "MAV_FRAME_GLOBAL_RELATIVE_ALT" and metrics["mission_message"] == "MISSION_ITEM_INT"
    )
    assert {"MISSION_INT", "SET_POSITION_TARGET_LOCAL_NED", "MAVLINK2"} <= set(metrics["autopilot_capabilities"])
    # nothing lost on loopback; what the vehicle received is its own business (not simulated by the device)
    assert metrics["messages_dropped_in"] == 0 and metrics["messages_dropped_out"] is None


def test_offboard_flight_streams_setpoints_on_the_vehicle_clock(tmp_path, roadmap):
    with simulated() as vehicle:
        settings = external(vehicle, mode="offboard", acceleration=1.0, corner_deviation=0.05, figure=False)
        # at 2 m/s it passes B3 a few cm inside the threshold: the fence only warns here (it holds by default)
        settings["fence"] = {"action": "warning"}
        outcome, document, stage, table = fly(tmp_path, roadmap, settings)
    assert outcome.ok and stage["status"] == "completed"
    metrics = check_flight_against_independent_measures(document, stage, table, vehicle)
    assert metrics["setpoint_error_max_m"] < 0.15
    # the setpoint path rounds corners by at most 5 cm: deviation from the plan = that plus tracking
    assert metrics["tracking_error_max_m"] <= metrics["setpoint_error_max_m"] + 0.05 + 0.02 + 1e-9
    # the stream never lapsed: no offboard loss on the vehicle, one setpoint per 50 ms of its clock (PX4 asks
    # for 2 Hz at least), every one stamped on that clock and applied at its stamp (lockstep: the error above
    # is the same on a loaded machine; tests/test_mavlink_sim.py proves it with a stalling ground station)
    assert not any("setpoints lost" in text for _, text in vehicle.events)
    assert metrics["setpoints_sent"] >= 20 * metrics["path_time_s"]
    assert vehicle.offboard.unstamped == 0 and vehicle.offboard.received >= metrics["setpoints_sent"] * 0.99
    assert any(text == "mode offboard" for _, text in vehicle.events)
    assert not vehicle.armed


def test_offboard_flight_in_strong_gusts_arrives_in_the_air_and_lands_vertically(tmp_path, roadmap):
    """Gusts of 0.9 m/s: the setpoints end at the path's end in the air, where the vehicle can still correct
    until it arrives; then NAV_LAND. (Streaming the landing leg too, a touchdown the gusts put more than the
    acceptance radius beside the goal never arrived: the flight timed out on the ground.)"""
    with simulated(wind={"mean": [0.3, 0.4, 0.0], "gust": 0.9}) as vehicle:
        # gusts that push it through the fence (tests/test_mavlink_fence.py): flown here without one
        settings = external(vehicle, mode="offboard", cruise_speed=1.5, figure=False, fence={"enabled": False})
        outcome, _, stage, _ = fly(tmp_path, roadmap, settings)
        events = [text for _, text in vehicle.events]
        touchdown = np.array(vehicle.trajectory)[-1, 1:4]
    assert outcome.ok and stage["status"] == "completed", stage.get("message")
    assert "mode land" in events and "landed" in events and not vehicle.armed
    assert not stage["metrics"].get("faults")
    # it arrived within the acceptance radius (0.1 m) of the path's end in the air, then came down on the
    # spot: the gusts move it during the descent no more than they move it in flight
    assert touchdown[2] == pytest.approx(0.0, abs=1e-6)  # on the ground (NED down 0)
    assert stage["metrics"]["final_position_error_m"] <= 0.1 + stage["metrics"]["tracking_error_max_m"]


def test_flight_is_refused_when_the_approach_crosses_a_wall(tmp_path, roadmap):
    # the vehicle stands in room B (scene 14, 3): the straight approach to room A's pad crosses the wall
    # and, deepest, pillar A1 (the message names the obstacle it comes closest to)
    with simulated(home=(-3.0, 12.0, 0.0)) as vehicle:
        outcome, _, stage, _ = fly(tmp_path, roadmap, external(vehicle))
    assert not outcome.ok and stage["status"] == "refused"
    assert stage["message"].startswith(
        "refused before any motion: the approach leg from [14.0, 3.0, 1.5] to [2.0, 6.0, 1.5] m "
        "passes -0.453 m from 'A1'"
    )
    scene = load_scene(HALL)
    start, end = np.array([[14.0, 3, 1.5]]), np.array([[2.0, 6, 1.5]])
    assert coal_scene_segment_distance(scene, start, end, RADIUS)[0] < 0  # coal agrees: it would collide
    a1 = scene.obstacles[scene.obstacle_names.index("A1")]
    assert coal_segment_distance(a1, start, end, RADIUS)[0] < 0
    assert not any(text == "armed" for _, text in vehicle.events) and vehicle.mission == []


@pytest.mark.slow
def test_the_hall_pipeline_file_flies_its_mission(tmp_path, roadmap):
    """configs/hall_flight.yaml as shipped, its mission flight (the simulated vehicle in a thread, faster;
    test_mavlink_faults runs a shipped file with the simulator as the separate program it is by default)."""
    pipeline = load_pipeline(CONFIGS / "hall_flight.yaml", output_dir=tmp_path / "out")
    pipeline.stages = pipeline.stages[:2]
    pipeline.stages[0].artifact = roadmap
    flight = pipeline.stages[1]
    assert flight.settings.connection is None and flight.settings.sim_process == "subprocess"
    flight.settings.sim_process = "thread"
    flight.settings.sim.speed = 20.0
    outcome = run_pipeline(pipeline)
    document = json.loads((outcome.output_dir / "result.json").read_text())
    stage = document["stages"][1]
    assert stage["status"] == "completed", stage.get("message")
    metrics = stage["metrics"]
    assert metrics["simulated"] and metrics["connection"].startswith("udpout:127.0.0.1:")
    assert metrics["flown_min_clearance_m"] > 0.2
    assert metrics["flown_min_clearance_outside_critical_m"] >= 0.5 - metrics["tracking_error_max_m"]
    assert (outcome.output_dir / "flight-mission.png").stat().st_size > 10_000
    assert {"route.png", "flight-mission.png", "flight-mission.csv", "scene.glb"} <= set(document["files"])


# ----------------------------------------------------------------------------- signing


def test_signed_link_works_and_strangers_are_told_why_they_are_ignored():
    key = "correct horse battery staple"
    with simulated(signing_key=key) as vehicle:
        target = f"udpout:127.0.0.1:{vehicle.port}"
        signed = Endpoint(
            target, system_id=255, component_id=190, key=__import__("hashlib").sha256(key.encode()).digest()
        )
        try:
            station = GroundStation(signed)
            station.connect(10)
            station.step = "telemetry setup"
            assert station.set_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20)
            assert signed.signature_rejections == 0
        finally:
            signed.close()
        unsigned = Endpoint(target, system_id=254, component_id=190)
        try:
            with pytest.raises(VehicleError, match=r"signs its messages .* give the shared key in signing\.key"):
                GroundStation(unsigned).connect(10)
        finally:
            unsigned.close()
        wrong = Endpoint(target, system_id=253, component_id=190, key=b"x" * 32)
        try:
            with pytest.raises(VehicleError, match=r"frames were rejected .* check the signing key"):
                GroundStation(wrong).connect(1.5)
        finally:
            wrong.close()
        assert vehicle.endpoint.signature_rejections > 0  # the vehicle ignored the unsigned ones


def test_no_vehicle_is_a_clear_connect_error(tmp_path, roadmap):
    # a port nobody listens on
    with simulated() as vehicle:
        port = vehicle.port
    settings = {"connection": f"udpout:127.0.0.1:{port}", "timeouts": {"connect": 1}}
    with pytest.raises(
        SurgiplanError, match=r"connect: no HEARTBEAT from a vehicle on 'udpout:127.0.0.1:\d+' within 1 s"
    ):
        run_pipeline(load_pipeline(hall_pipeline(tmp_path, roadmap, settings)))
    assert_error_record(tmp_path / "out", "connect: no HEARTBEAT from a vehicle")


def test_paths_of_other_spaces_are_refused_with_the_reason():
    from types import SimpleNamespace

    from surgiplan.devices import Trajectory
    from surgiplan.plugins.devices.mavlink.device import MavlinkVehicle

    device = MavlinkVehicle(MavlinkVehicle.Settings())
    gimbal = SimpleNamespace(kind="cast_gimbal")
    with pytest.raises(ConfigError, match=r"flies paths of the r3 space .* plan stage 'plan' planned in 'cast_gimbal'"):
        device.run(Trajectory(np.zeros((2, 4)), gimbal, "plan"))


# ----------------------------------------------------------------------------- refusals before any motion, capabilities


@contextlib.contextmanager
def device_on(vehicle: SimulatedVehicle, tmp_path: Path, **settings):
    """The mavlink_vehicle device, configured and active, on the simulated vehicle (no planner involved)."""
    from surgiplan.plugins.devices.mavlink.device import MavlinkVehicle
    from surgiplan.results import StageContext

    device = MavlinkVehicle(MavlinkVehicle.Settings.model_validate(external(vehicle, figure=False, **settings)))
    try:
        device.configure(StageContext("flight", load_scene(HALL), tmp_path, tmp_path))
        device.activate()
        yield device
    finally:
        device.shutdown()


def hall_trajectory(points, source="third-party-planner"):
    from surgiplan.devices import Trajectory
    from surgiplan.spaces.r3 import R3Space

    return Trajectory(np.asarray(points, float), R3Space(load_scene(HALL), RADIUS), source)


#: what a ground station sends while it connects (heartbeats, requests, parameter reads): nothing that moves
CONNECTING = {"HEARTBEAT", "COMMAND_LONG", "PARAM_REQUEST_READ"}


def assert_nothing_but_the_connection(vehicle: SimulatedVehicle) -> None:
    assert set(vehicle.received) <= CONNECTING, vehicle.received
    assert {c for c, _ in vehicle.commands_answered} <= {
        mavlink.MAV_CMD_REQUEST_MESSAGE,
        mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
    }
    assert not vehicle.armed and vehicle.uploads == [] and vehicle.params.changes == []
    truth = np.array(vehicle.trajectory)
    assert np.all(truth[:, 1:4] == truth[0, 1:4])  # it never moved


def test_a_path_through_an_obstacle_is_refused_before_any_motion_whatever_produced_it(tmp_path):
    """Issue 14: a third-party planner may return a colliding path; the device measures it (the vehicle a
    sphere of the plan's radius along each segment) and refuses it, naming the segment and the clearance."""
    path = [[2.0, 6.0, 1.5], [4.0, 5.5, 1.5], [9.0, 4.6, 1.5], [11.0, 4.6, 1.5]]  # segment 1 crosses pillar A1
    with simulated() as vehicle, device_on(vehicle, tmp_path) as device:
        report = device.execute(hall_trajectory(path))
        assert_nothing_but_the_connection(vehicle)
    assert report.status == "refused" and report.metrics["refused"] is True
    scene = load_scene(HALL)
    a, b = np.array([path[1]]), np.array([path[2]])
    measured = coal_scene_segment_distance(scene, a, b, RADIUS)[0]
    assert measured < 0  # coal agrees: segment 1 collides
    assert report.message.startswith(
        "refused before any motion: segment 1 of the planned path (waypoints 1 to 2: [4.0, 5.5, 1.5] to "
        f"[9.0, 4.6, 1.5] m) collides with 'A1': certified clearance {measured:.3f} m for the vehicle's 0.25 m radius"
    )
    assert "plan stage 'third-party-planner'" in report.message


def test_a_path_below_the_safety_margin_is_refused(tmp_path):
    """Straight through the door: 0.35 m from its jambs, refused with safety_margin 0.4 m, flown with 0.3 m."""
    path = [[10.0, 6.0, 1.5], [14.0, 6.0, 1.5]]
    with simulated() as vehicle, device_on(vehicle, tmp_path, safety_margin=0.4) as device:
        report = device.execute(hall_trajectory(path))
        assert_nothing_but_the_connection(vehicle)
    door = coal_scene_segment_distance(load_scene(HALL), np.array([path[0]]), np.array([path[1]]), RADIUS)[0]
    assert door == pytest.approx(0.35, abs=1e-9)
    assert report.status == "refused" and "segment 0" in report.message
    assert f"passes 'wall-south': certified clearance {door:.3f} m" in report.message or "passes 'wall-north'" in (
        report.message
    )
    assert "below safety_margin 0.4 m" in report.message


def test_vehicle_limits_tighter_than_the_profile_refuse_the_flight_naming_the_parameter(tmp_path):
    path = [[2.0, 6.0, 1.5], [4.0, 6.0, 1.5]]
    with simulated(params={"MPC_XY_VEL_MAX": 1.2}) as vehicle, device_on(vehicle, tmp_path) as device:
        report = device.execute(hall_trajectory(path))
        assert_nothing_but_the_connection(vehicle)
    assert report.status == "refused"
    assert report.message == (
        "refused before any motion: the vehicle's MPC_XY_VEL_MAX is 1.2 m/s, below the flight's cruise_speed 2 m/s: "
        "it cannot fly the profile as planned (lower cruise_speed, or raise MPC_XY_VEL_MAX)"
    )
    assert report.metrics["vehicle_parameters"]["MPC_XY_VEL_MAX"] == pytest.approx(1.2)
    with simulated(params={"MPC_Z_VEL_MAX_DN": 0.3}) as vehicle, device_on(vehicle, tmp_path, mode="offboard") as d:
        report = d.execute(hall_trajectory(path))
    assert "the vehicle's MPC_Z_VEL_MAX_DN is 0.3 m/s, below the flight's vertical_speed 0.5 m/s" in report.message


def test_offboard_is_refused_by_a_vehicle_without_the_capability_and_missions_fall_back_to_mission_item(tmp_path):
    with simulated(capabilities_withheld=["SET_POSITION_TARGET_LOCAL_NED"]) as vehicle:
        lacks = "MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED, which mode offboard needs"
        with pytest.raises(VehicleError, match=r"capabilities: the vehicle's AUTOPILOT_VERSION lacks " + lacks):
            with device_on(vehicle, tmp_path, mode="offboard"):
                pass
        assert set(vehicle.received) <= CONNECTING
    # a vehicle without MISSION_INT: the mission goes as the deprecated MISSION_ITEM, verified the same way
    path = [[2.0, 6.0, 1.5], [5.0, 7.5, 1.5], [8.0, 7.8, 1.6]]
    with simulated(capabilities_withheld=["MISSION_INT"]) as vehicle, device_on(vehicle, tmp_path) as device:
        report = device.execute(hall_trajectory(path))
        received = dict(vehicle.received)
    assert report.status == "completed", report.message
    assert report.metrics["mission_message"] == "MISSION_ITEM" and report.metrics["mission_verified"] is True
    # ... and so do the fence and the rally points uploaded before it
    assert received.get("MISSION_ITEM", 0) >= report.metrics["mission_items"] + report.metrics["fence_items"]
    assert "MISSION_ITEM_INT" not in received and report.metrics["fence_verified"] is True
    assert "MISSION_INT" not in report.metrics["autopilot_capabilities"]


def test_failsafe_parameters_are_set_and_read_back_before_the_flight(tmp_path):
    """failsafe: return: RTL_RETURN_ALT (60 m on PX4) lowered to the route's top above home, so that a return
    stays below the hall's ceiling; offboard: COM_OBL_RC_ACT set to the same failsafe (3, return)."""
    path = [[2.0, 6.0, 1.5], [5.0, 7.5, 1.8], [8.0, 7.8, 1.6]]
    with simulated() as vehicle, device_on(vehicle, tmp_path, mode="offboard", failsafe="return") as device:
        report = device.execute(hall_trajectory(path))
        changes = dict(vehicle.params.changes)
        settings = vehicle.settings
    assert report.status == "completed", report.message
    # and the geofence's: GF_ACTION 2 (hold, the default fence.action), GF_MAX_VER_DIST the hall's top above
    # home (4 m; GF_PREDICT stays PX4's 0, fence.predict being off)
    wanted = {"RTL_RETURN_ALT": pytest.approx(1.8), "COM_OBL_RC_ACT": 3, "GF_ACTION": 2, "GF_MAX_VER_DIST": 4.0}
    assert report.metrics["parameters_set"] == wanted
    assert changes == wanted
    assert settings.rtl_return_altitude == pytest.approx(1.8) and settings.offboard_loss_action == 3
    assert report.metrics["vehicle_parameters"]["MPC_XY_VEL_MAX"] == 5.0
