"""The faults of issue 8, each rehearsed from its pipeline file (configs/hall_faults_*.yaml).

Each test loads the shipped file, keeps its fault settings, and runs the simulated
vehicle those settings describe in a thread on a free 127.0.0.1 UDP port (faster
than real time), so that the outcome can be checked against the simulator's own
state; one test runs a file exactly as shipped, through the command line.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import shutil
import time

import numpy as np
import pytest
from conftest import CONFIGS, assert_error_record
from helpers import coal_scene_segment_distance
from surgiplan import load_pipeline, load_scene, run_pipeline
from surgiplan.errors import SurgiplanError
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.sim.vehicle import SimulatedVehicle
from test_mavlink_vehicle import HALL, RADIUS, ground_truth, session_file


@pytest.fixture(scope="session")
def roadmap(tmp_path_factory):
    """The hall roadmap of the configs/hall_*.yaml files, shared with test_mavlink_vehicle (same place)."""
    return session_file(tmp_path_factory, "hall-roadmap", "roadmap.npz")


#: the ground station's heartbeat expectations in these tests: 2 Hz, lost after 5 missed (2.5 s)
QUICK_LIVENESS = {"period": 0.5, "missed": 5}
#: in flight: 6 missed (3 s); the vehicle at 4x real time and a slow cruise (0.5 m/s, some 60 s of
#: flight), so that the loss (6 s after arming) is detected about 18 s into the flight, with 40 s of
#: vehicle time (10 s of wall clock) to spare for a machine that is slow to notice
FLIGHT_LIVENESS = {"period": 0.5, "missed": 6}
FLIGHT_SIM = {"heartbeat_rate": 2.0, "speed": 4.0}
FLIGHT_SPEED = 0.5


@contextlib.contextmanager
def rehearse(name: str, tmp_path, roadmap, *, sim: dict | None = None, **settings):
    """configs/hall_faults_<name>.yaml with its simulated vehicle in a thread; overrides for speed only."""
    pipeline = load_pipeline(CONFIGS / f"hall_faults_{name}.yaml", output_dir=tmp_path / "out")
    pipeline.stages[0].artifact = roadmap
    flight = pipeline.stages[1]
    given = flight.settings.sim
    vehicle = SimulatedVehicle(type(given).model_validate({**given.model_dump(), **(sim or {})})).start()
    values = {**flight.settings.model_dump(), **settings, "sim": None, "connection": f"udpout:127.0.0.1:{vehicle.port}"}
    flight.settings = type(flight.settings).model_validate(values)
    try:
        yield pipeline, vehicle
    finally:
        vehicle.stop()


def stage_of(outcome):
    document = json.loads((outcome.output_dir / "result.json").read_text())
    return document["stages"][1]


def flight_log(outcome) -> np.ndarray:
    return np.loadtxt(outcome.output_dir / "flight.csv", delimiter=",", skiprows=1)


# ----------------------------------------------------------------------------- a poor link


@pytest.mark.slow
def test_twenty_percent_packet_loss_both_ways_still_uploads_and_flies(tmp_path, roadmap):
    """configs/hall_faults_packet_loss.yaml, its simulated vehicle started by the device (in a thread, faster),
    so that the report has both ends' counts. The ground station's timeouts a third of its defaults (the
    vehicle answers within milliseconds on loopback; what a lost message costs is a timeout waited out, most
    of this test's time): the same retries and re-requests recover the same losses, sooner."""
    pipeline = load_pipeline(CONFIGS / "hall_faults_packet_loss.yaml", output_dir=tmp_path / "out")
    pipeline.stages[0].artifact = roadmap
    flight = pipeline.stages[1].settings
    assert flight.sim.packet_loss == 0.2 and flight.heartbeat.missed == 10
    flight.sim_process, flight.sim.speed, flight.figure = "thread", 20.0, False
    flight.timeouts = type(flight.timeouts)(command=0.5, mission=0.5, mission_item=0.15)
    outcome = run_pipeline(pipeline)
    stage = stage_of(outcome)
    assert stage["status"] == "completed", stage.get("message")
    metrics = stage["metrics"]
    # the loss really happened, both ways, and the report says so (issue 21: these were 0): the vehicle's
    # messages lost, by the gaps in their sequence numbers as the ground station saw them ...
    vehicle = metrics["vehicle_link"]

    def binomial(lost: int, total: int) -> bool:  # within 4 standard deviations of 20 % of ``total`` draws
        return abs(lost / total - 0.2) <= 4 * math.sqrt(0.2 * 0.8 / total)

    lost_in, counted_in = metrics["messages_dropped_in"], metrics["messages_received"]
    assert lost_in > 100 and binomial(lost_in, lost_in + counted_in)
    # ... which the simulated vehicle confirms: it dropped at least that many on purpose (also some before the
    # ground station was listening), 20 % of what it sent
    assert metrics["messages_dropped_in"] <= vehicle["injected_drops_out"]
    assert binomial(vehicle["injected_drops_out"], vehicle["messages_sent"])  # (sent: every message tried)
    # ... and ours, as the simulated vehicle counted them (nothing lost on loopback but what it dropped)
    assert metrics["messages_dropped_out"] == vehicle["injected_drops_in"] > 5 and vehicle["lost_in"] == 0
    assert binomial(metrics["messages_dropped_out"], metrics["messages_sent"])
    assert metrics["link_loss_out"] == metrics["messages_dropped_out"] / metrics["messages_sent"]
    # the vehicle holds exactly the mission that was sent: downloaded back and compared
    assert metrics["mission_verified"] is True
    # ... after recovering what the loss cost the upload. Which side recovers depends on timing, not only on
    # the seeded drops (heartbeats and telemetry interleave with the transfer by wall clock): our re-send after
    # ``mission_item`` s, or the vehicle's repeated request when it waited out its own timeout first. With 2 x
    # (items + 1) messages each lost with p = 0.2, an upload without either would be a 1-in-10^5 draw.
    assert metrics["upload_requests"] >= metrics["mission_items"] > 10
    assert metrics["upload_repeated_requests"] + metrics["upload_retransmissions"] > 0
    flown = flight_log(outcome)[:, 1:4]
    assert coal_scene_segment_distance(load_scene(HALL), flown[:-1], flown[1:], RADIUS).min() > 0


# ----------------------------------------------------------------------------- a silent vehicle


@pytest.mark.parametrize(("step", "named"), [("mission_upload", "mission upload"), ("arming", "arming")])
def test_vehicle_that_stops_answering_is_a_clear_error_naming_the_step(tmp_path, roadmap, step, named):
    sim = {"speed": 20.0, "heartbeat_rate": 2.0, "stop_answering": {"step": step}}
    with rehearse("silent", tmp_path, roadmap, sim=sim, heartbeat=QUICK_LIVENESS) as (pipeline, vehicle):
        with pytest.raises(SurgiplanError) as caught:
            run_pipeline(pipeline)
    message = str(caught.value)
    assert f"{named}: the vehicle stopped answering: no HEARTBEAT for " in message
    assert "(5 missed at 2 Hz)" in message
    assert vehicle.silent and not vehicle.armed
    assert_error_record(tmp_path / "out", f"{named}: the vehicle stopped answering")


# ----------------------------------------------------------------------------- a refusing vehicle


@pytest.mark.slow
def test_rejected_mission_from_the_shipped_file_on_the_command_line(tmp_path, roadmap, cli, monkeypatch):
    """The file exactly as shipped: the simulated vehicle a subprocess, the error on stderr, exit 2."""
    monkeypatch.chdir(tmp_path)
    if roadmap.exists():  # the file's artifact path is relative to the working directory
        (tmp_path / "out" / "hall-flight").mkdir(parents=True)
        shutil.copy(roadmap, tmp_path / "out" / "hall-flight" / "roadmap.npz")
    code, _, err = cli("run", CONFIGS / "hall_faults_rejected.yaml", "--quiet")
    assert code == 2
    assert (
        "mission upload: the vehicle rejected the mission: MAV_MISSION_NO_SPACE (4): Mission items exceed storage space"
        in err
    )
    assert "Traceback" not in err
    assert_error_record(tmp_path / "out" / "hall-faults-rejected", "MAV_MISSION_NO_SPACE (4)")


@pytest.mark.parametrize(
    ("sim", "result"),
    [
        ({"reject_mission": None, "mission_capacity": 10}, "MAV_MISSION_NO_SPACE (4)"),
        ({"reject_mission": mavlink.MAV_MISSION_INVALID_PARAM5_X, "reject_at_item": 3}, "MAV_MISSION_INVALID_PARAM5_X"),
    ],
)
def test_rejected_mission_reports_the_vehicles_result(tmp_path, roadmap, sim, result):
    with rehearse("rejected", tmp_path, roadmap, sim={"speed": 20.0, **sim}) as (pipeline, vehicle):
        with pytest.raises(
            SurgiplanError, match=re.escape(f"mission upload: the vehicle rejected the mission: {result}")
        ):
            run_pipeline(pipeline)
    assert vehicle.mission == [] and not vehicle.armed


# ----------------------------------------------------------------------------- heartbeat lost in flight


@pytest.mark.slow
def test_heartbeat_lost_in_flight_commands_the_failsafe_and_the_vehicle_lands(tmp_path, roadmap):
    with rehearse(
        "heartbeat",
        tmp_path,
        roadmap,
        sim=FLIGHT_SIM,
        heartbeat=FLIGHT_LIVENESS,
        cruise_speed=FLIGHT_SPEED,
        figure=False,
    ) as (
        pipeline,
        vehicle,
    ):
        assert vehicle.settings.heartbeat_loss.at_s == 6 and pipeline.stages[1].settings.failsafe == "land"
        outcome = run_pipeline(pipeline)
        events = [text for _, text in vehicle.events]
        _, truth = ground_truth(vehicle)
    stage = stage_of(outcome)
    assert not outcome.ok and stage["status"] == "stopped"
    assert "no HEARTBEAT for" in stage["message"]
    assert stage["message"].endswith("commanded the failsafe: land (acknowledged, the vehicle landed)")
    faults = stage["metrics"]["faults"]
    assert [f["kind"] for f in faults] == ["heartbeat_lost", "failsafe"]
    assert faults[0]["step"] == "flight" and faults[0]["vehicle_time_s"] > 6
    assert faults[1] == {
        "kind": "failsafe",
        "action": "land",
        "reason": "heartbeat lost",
        "acknowledged": True,
        "landed": True,
    }
    # the simulator's own account: heartbeats stopped, then LAND, and it stands on the floor, short of the goal
    assert events.index("heartbeat lost (injected)") < events.index("mode land") < events.index("landed")
    assert truth[-1][2] == pytest.approx(0.0, abs=1e-9)
    assert np.linalg.norm(truth[-1][:2] - [22, 6]) > 3
    # the flight up to the landing is in the report, and clear of everything. It ends on the floor, where the
    # vehicle stands: "landed" can come before the report of the touchdown's last centimetres (a fresh-clone CI
    # run once logged the report before it, 21 mm up), so the ground station logs the report after it too
    flown = flight_log(outcome)[:, 1:4]
    assert np.linalg.norm(flown[-1] - truth[-1]) < 1e-4
    assert coal_scene_segment_distance(load_scene(HALL), flown[:-1], flown[1:], RADIUS).min() > 0


@pytest.mark.slow
def test_failsafe_is_commanded_even_when_the_vehicle_is_no_longer_heard(tmp_path, roadmap):
    sim = {**FLIGHT_SIM, "heartbeat_loss": {"at_s": 6, "all_telemetry": True}}
    timeouts = {"command": 0.5, "command_retries": 2}
    with rehearse(
        "heartbeat",
        tmp_path,
        roadmap,
        sim=sim,
        heartbeat=FLIGHT_LIVENESS,
        timeouts=timeouts,
        cruise_speed=FLIGHT_SPEED,
        figure=False,
    ) as (pipeline, vehicle):
        outcome = run_pipeline(pipeline)
        # the ground station could not hear it; the vehicle heard the LAND command and lands (simulated time)
        deadline = time.monotonic() + 60
        while vehicle.armed and time.monotonic() < deadline:
            time.sleep(0.05)
        events = [text for _, text in vehicle.events]
        landed = not vehicle.armed and not vehicle.model.airborne
    stage = stage_of(outcome)
    assert stage["status"] == "stopped"
    failsafe = stage["metrics"]["faults"][-1]
    assert failsafe["kind"] == "failsafe" and failsafe["acknowledged"] is False
    assert "no COMMAND_ACK for MAV_CMD_NAV_LAND after 3 attempts" in failsafe["error"]
    assert "(not acknowledged)" in stage["message"]
    assert "mode land" in events and landed
