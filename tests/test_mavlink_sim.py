"""The simulated vehicle as a MAVLink peer: commands, refusals, global missions, its command line."""

from __future__ import annotations

import contextlib
import hashlib
import math

import numpy as np
import pytest
from surgiplan.plugins.devices.mavlink_conventions import EARTH_RADIUS, LocalFrame, MapProjection
from surgiplan.plugins.devices.mavlink_flight import Flight, Route
from surgiplan.plugins.devices.mavlink_gcs import GroundStation
from surgiplan.plugins.devices.mavlink_link import Endpoint, VehicleError, mavlink, signing_key
from surgiplan.plugins.devices.mavlink_mission import MissionItem
from surgiplan.plugins.devices.mavlink_sim import SimulatedVehicle, main
from surgiplan.plugins.devices.mavlink_sim_settings import SimSettings
from surgiplan.plugins.devices.mavlink_vehicle import MavlinkVehicleSettings
from surgiplan.progress import NullProgress


@contextlib.contextmanager
def station(**settings):
    """A simulated vehicle in a thread and a ground station connected to it."""
    vehicle = SimulatedVehicle(SimSettings(**{"speed": 10.0, "heartbeat_rate": 4.0, **settings})).start()
    link = Endpoint(f"udpout:127.0.0.1:{vehicle.port}", system_id=255, component_id=190)
    try:
        gcs = GroundStation(link, heartbeat_period=0.25, missed_heartbeats=20, command_timeout=0.5)
        gcs.connect(10)
        gcs.step = "test"
        yield gcs, vehicle
    finally:
        link.close()
        vehicle.stop()


def test_vehicle_identifies_as_a_px4_quadrotor_and_reports_its_origin():
    with station(origin=(46.5, 6.6, 372.0)) as (gcs, _):
        assert gcs.vehicle.autopilot == mavlink.MAV_AUTOPILOT_PX4
        assert gcs.vehicle.vehicle_type == mavlink.MAV_TYPE_QUADROTOR
        assert gcs.vehicle.mode == "position" and not gcs.vehicle.armed
        origin = gcs.request_message("GPS_GLOBAL_ORIGIN", mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 5)
        assert (origin.latitude, origin.longitude, origin.altitude) == (465000000, 66000000, 372000)


def test_refusals_come_with_their_result_and_the_vehicles_reason():
    with station(refuse_arming="battery too low") as (gcs, vehicle):
        gcs.step = "arming"
        with pytest.raises(VehicleError, match=r"arming: .*MAV_RESULT_DENIED.*vehicle says: Arming denied: battery"):
            gcs.arm()
        gcs.step = "mode change"
        with pytest.raises(VehicleError, match=r"MAV_RESULT_DENIED.*Offboard denied: no setpoints"):
            gcs.set_mode("offboard")
        with pytest.raises(VehicleError, match=r"MAV_RESULT_DENIED.*Mission denied: no mission"):
            gcs.set_mode("mission")
        with pytest.raises(VehicleError, match=r"MAV_CMD_DO_FLIGHTTERMINATION with MAV_RESULT_UNSUPPORTED"):
            gcs.command(mavlink.MAV_CMD_DO_FLIGHTTERMINATION, [1])
        assert not vehicle.armed and vehicle.mode == "position"


def test_commands_are_acknowledged_once_even_when_repeated():
    with station() as (gcs, vehicle):
        gcs.set_mode("hold")
        assert vehicle.mode == "hold"
        for _ in range(2):  # arming an armed vehicle is accepted and changes nothing
            gcs.arm()
        assert vehicle.armed and [text for _, text in vehicle.events].count("armed") == 1


def test_global_mission_items_land_on_the_local_points_they_were_made_from():
    """mission_frame: global_relative_alt: the device converts with the vehicle's own origin and home."""
    origin = (47.397742, 8.545594, 488.0)
    home = (1.5, -2.0, -0.4)  # the vehicle stands 0.4 m above the EKF origin's height
    with station(origin=origin, home=home) as (gcs, vehicle):
        got = gcs.request_message("GPS_GLOBAL_ORIGIN", mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, 5)
        position = gcs.request_message("HOME_POSITION", mavlink.MAVLINK_MSG_ID_HOME_POSITION, 5)
        geo = (MapProjection(got.latitude * 1e-7, got.longitude * 1e-7), float(position.z))
        frame = LocalFrame((2.0, 6.0, 0.0))
        scene = np.array([[3.5, 4.0, 0.4], [3.5, 4.0, 1.9], [40.0, 30.0, 1.9], [-20.0, 90.0, 2.5], [-20.0, 90.0, 0.4]])
        route = Route(scene, 1, 3, takeoff=True, land=True)
        flight = Flight(gcs, MavlinkVehicleSettings(), frame, route, NullProgress(), geo)
        items, first, last = flight.mission_items()
        assert {i.frame for i in items[1:]} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}
        assert (first, last) == (1, 3)
        gcs.upload(items)
        local = np.array([vehicle._item_position(item) for item in vehicle.mission[1:]])
    expected = frame.to_ned(scene[1:])
    # 1e-7 degrees of latitude are 1.1 cm; altitudes are floats
    assert np.abs(local[:, :2] - expected[:, :2]).max() < 0.012
    assert local[:-1, 2] == pytest.approx(expected[:-1, 2], abs=1e-5)
    # independently: the great-circle distance between two waypoints is their local distance
    lat = np.radians([vehicle.mission[2].x, vehicle.mission[3].x])
    lon = np.radians([vehicle.mission[2].y, vehicle.mission[3].y])
    h = np.sin((lat[1] - lat[0]) / 2) ** 2 + np.cos(lat[0]) * np.cos(lat[1]) * np.sin((lon[1] - lon[0]) / 2) ** 2
    arc = 2 * EARTH_RADIUS * math.asin(math.sqrt(h))
    assert arc == pytest.approx(np.linalg.norm(expected[2, :2] - expected[1, :2]), abs=0.02)


def test_signing_key_reaches_the_simulated_vehicle_from_the_device_settings():
    settings = MavlinkVehicleSettings.model_validate({"signing": {"key": "shared secret"}})
    from surgiplan.plugins.devices.mavlink_vehicle import MavlinkVehicle

    sim = MavlinkVehicle(settings)._sim_settings()
    assert sim.signing_key == "shared secret"
    assert signing_key(sim.signing_key) == hashlib.sha256(b"shared secret").digest()


def test_command_line_reports_bad_settings(capsys):
    assert main(["udpin:127.0.0.1:0", "--settings", '{"speed": -1}']) == 2
    assert "speed" in capsys.readouterr().err
    assert main(["udpin:127.0.0.1:0", "--packet-loss", "1.5"]) == 2
    assert "packet_loss" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(["--help"])
    assert done.value.code == 0 and "PX4-like quadrotor" in capsys.readouterr().out


def test_mission_completes_in_gusts_even_with_a_tight_acceptance_radius():
    """Gusts can keep a hovering vehicle outside a 2 cm radius for ever; it settles and goes on."""
    with station(speed=20.0, wind={"mean": [0.3, 0.6, 0.0], "gust": 1.0}, seed=4) as (gcs, vehicle):
        items = [
            MissionItem(mavlink.MAV_CMD_NAV_TAKEOFF, z=-1.5),
            MissionItem(mavlink.MAV_CMD_NAV_WAYPOINT, x=5.0, y=0.0, z=-1.5, param2=0.02),
            MissionItem(mavlink.MAV_CMD_NAV_LAND, x=5.0, y=0.0),
        ]
        gcs.upload(items)
        gcs.set_mode("hold")
        gcs.arm()
        gcs.set_mode("mission")
        start = gcs.vehicle.vehicle_time
        while vehicle.armed and gcs.vehicle.vehicle_time - start < 120:
            gcs.pump(0.05)
        assert not vehicle.armed  # landed and disarmed by itself
        assert [seq for seq, _ in gcs.vehicle.reached] == [0, 1, 2]
        truth = np.array(vehicle.trajectory)[:, 1:4]
        assert truth[-1][2] == 0.0 and np.linalg.norm(truth[-1][:2] - [5.0, 0.0]) < 0.6  # gusts of 1 m/s
