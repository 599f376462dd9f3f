"""MAVSDK's geofence and mission_raw plugins, and an offboard flight aimed through an obstacle, against the
simulated vehicle.

* the geofence plugin uploads an inclusion polygon, an exclusion polygon and an exclusion circle, downloads
  them back and clears them; the vehicle's own zones are compared with the points MAVSDK was given
  (great-circle distances on PX4's sphere);
* mission_raw uploads and downloads fence and rally lists item by item, and has a mission through the fence
  refused (MissionRawResult.DENIED, the vehicle's "Geofence violation for waypoint N");
* offboard: MAVSDK streams a position setpoint on the far side of an exclusion circle; the vehicle
  (GF_ACTION 2, GF_PREDICT 1, set through MAVSDK's param plugin) holds on its own before the circle, as its
  ground truth shows, and MAVSDK sees it in HOLD.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest
from mavlink_support import free_udp_port, ground_distance, mavsdk_or_skip, offset, simulated
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.sim.model import braking_distance
from surgiplan.plugins.devices.mavlink.sim.settings import Airframe
from test_mavsdk_workflows import ORIGIN, connect, healthy_with_position, wait_until

pytestmark = pytest.mark.timeout(150)


def raw_item(seq: int, command: int, lat: float, lon: float, z: float, mission_type: int, **params):
    from mavsdk.asyncio.plugins.mission_raw import MissionItem

    p = [params.get(f"param{k}", 0.0) for k in range(1, 5)]
    current = int(seq == 0 and mission_type == 0)  # MAVSDK: one mission item is the current one
    return MissionItem(seq, 3 if mission_type != 1 else 0, command, current, 1, *p, round(lat * 1e7),
                       round(lon * 1e7), z, mission_type)  # fmt: skip


def test_mavsdk_geofence_and_mission_raw_lists():
    mavsdk_or_skip()
    from mavsdk.asyncio.plugins.geofence import Circle, FenceType, GeofenceAsync, GeofenceData, Point, Polygon
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync, MissionRawError, MissionRawResult
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    port = free_udp_port()
    with simulated(f"udpout:127.0.0.1:{port}", origin=ORIGIN) as vehicle:
        lat0, lon0 = ORIGIN[:2]
        box = [(-5, -5), (25, -5), (25, 15), (-5, 15)]
        block = [(9, 3), (11, 3), (11, 5), (9, 5)]

        async def workflow() -> dict:
            _mavsdk, drone = await connect(port)
            telemetry, geofence, raw = TelemetryAsync(drone), GeofenceAsync(drone), MissionRawAsync(drone)
            await healthy_with_position(telemetry)
            points = lambda corners: [Point(*offset(lat0, lon0, n, e)) for n, e in corners]  # noqa: E731
            data = GeofenceData(
                [Polygon(points(box), FenceType.INCLUSION), Polygon(points(block), FenceType.EXCLUSION)],
                [Circle(Point(*offset(lat0, lon0, 8, 0)), 1.5, FenceType.EXCLUSION)],
            )
            await geofence.upload_geofence(data)
            out = {"zones": list(vehicle.zones), "downloaded": await geofence.download_geofence()}
            # mission_raw: the same fence as items, read back; a mission through the circle, refused
            out["fence_items"] = await raw.download_geofence()
            lat, lon = offset(lat0, lon0, 8.5, 0.2)
            mission = [
                raw_item(0, mavlink.MAV_CMD_NAV_TAKEOFF, lat0, lon0, 2.0, 0),
                raw_item(1, mavlink.MAV_CMD_NAV_WAYPOINT, *offset(lat0, lon0, 4, 0), 2.0, 0),
                raw_item(2, mavlink.MAV_CMD_NAV_WAYPOINT, lat, lon, 2.0, 0),
            ]
            try:
                await raw.upload_mission(mission)
                out["refused"] = None
            except MissionRawError as exc:
                out["refused"] = exc.result
            rally = [
                raw_item(0, mavlink.MAV_CMD_NAV_RALLY_POINT, *offset(lat0, lon0, 14, 3), 0.0, 2),
                raw_item(1, mavlink.MAV_CMD_NAV_RALLY_POINT, *offset(lat0, lon0, -2, 6), 1.5, 2),
            ]
            await raw.upload_rally_points(rally)
            out["rally"] = await raw.download_rallypoints()
            await geofence.clear_geofence()
            out["after_clear"] = list(vehicle.zones)
            return out

        out = asyncio.run(asyncio.wait_for(workflow(), 120))
        said = [text for _, text in vehicle.events]
        rally_held = np.array(vehicle.rally_points)

    # what the vehicle holds is what MAVSDK was given: the circle's centre within 1.1 cm, its radius exact
    inclusion, exclusion, circle = out["zones"]
    assert inclusion.inclusion and not exclusion.inclusion and circle.kind == "circle" and not circle.inclusion
    assert np.abs(inclusion.vertices - np.array(box, float)).max() < 0.011
    assert np.abs(exclusion.vertices - np.array(block, float)).max() < 0.011
    assert np.linalg.norm(circle.centre - [8, 0]) < 0.011 and circle.radius == pytest.approx(1.5)
    # downloaded back by MAVSDK's geofence plugin: the same polygons and circle
    down = out["downloaded"]
    assert [p.fence_type for p in down.polygons] == [FenceType.INCLUSION, FenceType.EXCLUSION]
    for polygon, corners in zip(down.polygons, (box, block), strict=True):
        for point, (n, e) in zip(polygon.points, corners, strict=True):
            assert ground_distance(point.latitude_deg, point.longitude_deg, *offset(lat0, lon0, n, e)) < 0.011
    assert len(down.circles) == 1 and down.circles[0].radius == pytest.approx(1.5)
    # ... and by mission_raw, item by item, in the fence commands (4 + 4 vertices, 1 circle)
    commands = [i.command for i in out["fence_items"]]
    assert commands == [5001] * 4 + [5002] * 4 + [5004] and {i.param1 for i in out["fence_items"][:8]} == {4.0}
    # the mission through the circle: DENIED, with PX4's words (waypoint 3 counted from 1)
    assert out["refused"] == MissionRawResult.DENIED and "Geofence violation for waypoint 3" in said
    assert [(i.command, i.z) for i in out["rally"]] == [(5100, 0.0), (5100, 1.5)]
    np.testing.assert_allclose(rally_held, [[14, 3, 0], [-2, 6, -1.5]], atol=0.011)
    assert out["after_clear"] == []


def test_mavsdk_offboard_aimed_through_an_obstacle_is_stopped_at_the_fence():
    mavsdk_or_skip()
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.geofence import Circle, FenceType, GeofenceAsync, GeofenceData, Point
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    port = free_udp_port()
    truth_rate = {"LOCAL_POSITION_NED": 50.0}  # the ground truth every 20 ms (0.04 m apart at 2 m/s)
    with simulated(f"udpout:127.0.0.1:{port}", origin=ORIGIN, rates=truth_rate) as vehicle:
        lat0, lon0 = ORIGIN[:2]

        async def workflow() -> dict:
            _mavsdk, drone = await connect(port)
            telemetry, action, offboard = TelemetryAsync(drone), ActionAsync(drone), OffboardAsync(drone)
            param, geofence = ParamAsync(drone), GeofenceAsync(drone)
            await healthy_with_position(telemetry)
            await param.set_param_int("GF_PREDICT", 1)
            await param.set_param_float("MPC_XY_VEL_MAX", 2.0)
            await geofence.upload_geofence(
                GeofenceData([], [Circle(Point(*offset(lat0, lon0, 8, 0)), 1.5, FenceType.EXCLUSION)])
            )
            await action.arm()
            await action.takeoff()

            async def up() -> bool:
                return (
                    await telemetry.flight_mode() == FlightMode.HOLD
                    and (await telemetry.position()).relative_altitude_m > 2.4
                )

            await wait_until(up, 30, "the vehicle did not take off")
            await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -2.5, 0.0))
            await offboard.start()
            await offboard.set_position_ned(PositionNedYaw(16.0, 0.0, -2.5, 0.0))  # through the circle's centre

            async def offboard_mode() -> bool:  # (MAVSDK's telemetry may still say HOLD, from the take-off)
                return await telemetry.flight_mode() == FlightMode.OFFBOARD or bool(vehicle.fence_breaches)

            async def held() -> bool:
                return await telemetry.flight_mode() == FlightMode.HOLD and bool(vehicle.fence_breaches)

            await wait_until(offboard_mode, 30, "MAVSDK did not see offboard mode")
            await wait_until(held, 30, "the vehicle did not hold on its own")
            held_at = vehicle.fence_breaches[0]["t"]

            async def settled() -> bool:  # 4 s of vehicle time after the breach (10x; slower when loaded)
                return vehicle.t >= held_at + 4.0

            await wait_until(settled, 30, "the vehicle's clock did not advance 4 s")
            out = {"mode": await telemetry.flight_mode()}
            await offboard.stop()
            return out

        out = asyncio.run(asyncio.wait_for(workflow(), 120))
        truth = np.array(vehicle.trajectory)
        breaches = list(vehicle.fence_breaches)

    assert out["mode"] == FlightMode.HOLD
    assert len(breaches) == 1 and breaches[0]["action"] == "hold" and breaches[0]["mode"] == "offboard"
    # it never entered the circle (the vehicle's own positions, every 20 ms), and stopped within its braking
    # distance plus one check's look-ahead of where the breach was predicted
    distance = np.hypot(truth[:, 1] - 8.0, truth[:, 2])
    assert distance.min() >= 1.5
    speed = float(np.linalg.norm(breaches[0]["velocity"]))
    assert truth[:, 1].max() - breaches[0]["position"][0] <= braking_distance(Airframe(), speed) + 0.05
    assert math.isclose(truth[-1, 1], breaches[0]["position"][0], abs_tol=0.1)
