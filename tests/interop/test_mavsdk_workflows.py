"""MAVSDK (the ``mavsdk`` package from the registry) flies the simulated vehicle as its examples do.

Each workflow is MAVSDK's documented one (examples/mission.py, params.py,
takeoff_and_land.py, offboard): connect, wait until the system is healthy and
has a position, then upload/download/fly/clear a mission, read and set
parameters, arm, take off, go to a location, fly offboard, return and land.
What MAVSDK says is checked against the simulator's ground truth and against
independent measures (great-circle distances), and the simulator's own
record of what it received and answered.

MAVSDK 4 runs in this process (a native library, no mavsdk_server): it listens
on ``udpin://127.0.0.1:PORT`` and the test checks, from /proc, that neither it
nor the simulated vehicle binds anything but loopback.
"""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest
from mavlink_support import (
    free_udp_port,
    ground_distance,
    inet_sockets,
    mavsdk_or_skip,
    not_loopback,
    offset,
    simulated,
)
from surgiplan.plugins.devices.mavlink.link import mavlink

pytestmark = pytest.mark.timeout(150)

ORIGIN = (47.397742, 8.545594, 488.0)


async def connect(port: int, timeout: float = 20.0):
    """MAVSDK as its examples connect: a ground station listening on the port; the first autopilot heard."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    drone = await mavsdk.first_autopilot(timeout)
    assert drone is not None, "MAVSDK found no autopilot"
    return mavsdk, drone


async def wait_until(condition, timeout: float, what: str, period: float = 0.1):
    """Poll ``condition`` (an async callable) until it is true; fail after ``timeout`` s naming ``what``."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not await condition():
        if loop.time() > deadline:
            raise AssertionError(f"{what} within {timeout:g} s")
        await asyncio.sleep(period)


async def healthy_with_position(telemetry, timeout: float = 20.0):
    """The loop of every MAVSDK example: wait until gyro, accelerometer, magnetometer, local and global
    position and home are ok, then read the position."""

    async def ok() -> bool:
        h = await telemetry.health()
        return all(
            (
                h.is_gyrometer_calibration_ok,
                h.is_accelerometer_calibration_ok,
                h.is_magnetometer_calibration_ok,
                h.is_local_position_ok,
                h.is_global_position_ok,
                h.is_home_position_ok,
                h.is_armable,
            )
        )

    await wait_until(ok, timeout, "MAVSDK's health never became ok")
    return await telemetry.position()


def mission_item(lat: float, lon: float, altitude: float, speed: float, radius: float):
    from mavsdk.asyncio.plugins.mission import MissionItem

    nan = math.nan
    return MissionItem(
        lat, lon, altitude, speed, True, nan, nan, MissionItem.CameraAction.NONE, nan, nan, radius, nan, nan,
        MissionItem.VehicleAction.NONE,
    )  # fmt: skip


def test_mavsdk_mission_parameters_offboard_and_return():
    mavsdk_or_skip()
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.mission import MissionAsync, MissionPlan
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    port = free_udp_port()
    # the ground truth is recorded at the LOCAL_POSITION_NED rate: 10 Hz (0.2 m apart at 2 m/s), not PX4's 1 Hz
    truth_rate = {"LOCAL_POSITION_NED": 10.0}
    with simulated(
        f"udpout:127.0.0.1:{port}", origin=ORIGIN, params={"COM_OBL_RC_ACT": 4}, rates=truth_rate
    ) as vehicle:

        async def workflow() -> dict:
            _mavsdk, drone = await connect(port)
            telemetry, mission, param = TelemetryAsync(drone), MissionAsync(drone), ParamAsync(drone)
            action, offboard = ActionAsync(drone), OffboardAsync(drone)
            out = {"sockets": inet_sockets()}
            position = await healthy_with_position(telemetry)
            out["position"] = (position.latitude_deg, position.longitude_deg, position.relative_altitude_m)

            # parameters: a float and an int (PX4's bytewise encoding), read, set, read back
            out["cruise"] = await param.get_param_float("MPC_XY_CRUISE")
            out["loss_action"] = await param.get_param_int("COM_OBL_RC_ACT")
            await param.set_param_float("RTL_RETURN_ALT", 6.0)
            await param.set_param_int("COM_OBL_RC_ACT", 5)
            out["rtl_alt"] = await param.get_param_float("RTL_RETURN_ALT")
            out["loss_action_after"] = await param.get_param_int("COM_OBL_RC_ACT")
            everything = await param.get_all_params()
            out["all"] = {p.name: p.value for p in everything.float_params} | {
                p.name: p.value for p in everything.int_params
            }

            # ten waypoints on a ring of 8 m around home, 3 to 3.9 m up, at 2 m/s
            lat0, lon0 = position.latitude_deg, position.longitude_deg
            ring = [(8 * math.cos(2 * math.pi * k / 10), 8 * math.sin(2 * math.pi * k / 10)) for k in range(10)]
            points = [(*offset(lat0, lon0, n, e), 3.0 + 0.1 * k) for k, (n, e) in enumerate(ring)]
            items = [mission_item(lat, lon, alt, 2.0, 0.5) for lat, lon, alt in points]
            await mission.upload_mission(MissionPlan(items))
            out["downloaded"] = (await mission.download_mission()).mission_items
            out["points"] = points

            await action.arm()
            await mission.start_mission()
            await wait_until(mission.is_mission_finished, 60, "the mission did not finish", 0.2)
            out["progress"] = await mission.mission_progress()
            end = await telemetry.position()
            out["end"] = (end.latitude_deg, end.longitude_deg, end.relative_altitude_m)
            await mission.clear_mission()
            out["after_clear"] = (await mission.download_mission()).mission_items

            # offboard: 5 m north of where the mission ended, 4 m up
            here = await telemetry.position_velocity_ned()
            target = (here.position.north_m + 5.0, here.position.east_m, -4.0)
            await offboard.set_position_ned(PositionNedYaw(here.position.north_m, here.position.east_m, -4.0, 0.0))
            await offboard.start()
            await offboard.set_position_ned(PositionNedYaw(*target, 0.0))

            async def arrived() -> bool:
                p = (await telemetry.position_velocity_ned()).position
                return math.dist((p.north_m, p.east_m, p.down_m), target) < 0.2

            await wait_until(arrived, 30, "the offboard setpoint was not reached")
            out["offboard_mode"] = await telemetry.flight_mode()
            await offboard.stop()

            # return: climb to RTL_RETURN_ALT (6 m above home), fly home, land, disarm
            await action.return_to_launch()

            async def disarmed() -> bool:
                return not await telemetry.armed()

            await wait_until(disarmed, 60, "the vehicle did not land and disarm after RTL", 0.2)
            home = await telemetry.position()
            out["home"] = (home.latitude_deg, home.longitude_deg, home.relative_altitude_m)
            out["sockets_after"] = inet_sockets()
            return out

        out = asyncio.run(asyncio.wait_for(workflow(), 120))
        truth = np.array(vehicle.trajectory)
        stored = next(items for kind, items in vehicle.uploads if kind == 0 and items)
        events = [text for _, text in vehicle.events]
        received = dict(vehicle.received)
        requested = list(vehicle.messages_requested)

    # loopback only: MAVSDK listened on 127.0.0.1, the simulated vehicle's socket is bound to 127.0.0.1
    assert not not_loopback(out["sockets"]) and not not_loopback(out["sockets_after"]), out["sockets_after"]
    assert ("udp", "127.0.0.1", port) in out["sockets"]
    # AUTOPILOT_VERSION answered: MAVSDK asked for it once (it re-requested it every second, for ever, from a
    # vehicle that never sent it)
    assert 1 <= requested.count(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) <= 2
    # healthy, and the position is the vehicle's home (the EKF origin), on the ground
    lat, lon, rel = out["position"]
    assert ground_distance(lat, lon, *ORIGIN[:2]) < 0.02 and abs(rel) < 0.01
    # parameters as the simulation has them; the int decoded bytewise; the new values drive the simulation
    assert out["cruise"] == pytest.approx(1.0) and out["loss_action"] == 4
    assert out["rtl_alt"] == pytest.approx(6.0) and out["loss_action_after"] == 5
    assert len(out["all"]) == 26 and out["all"]["COM_OBL_RC_ACT"] == 5 and out["all"]["MPC_XY_VEL_MAX"] == 5.0
    assert out["all"]["GF_ACTION"] == 2 and out["all"]["RTL_TYPE"] == 0  # PX4's defaults, as ints
    assert "parameter RTL_RETURN_ALT = 6.0" in events and "parameter COM_OBL_RC_ACT = 5" in events

    # MAVSDK 4 sent the waypoints in the current frame 3 as MISSION_ITEM_INT (degrees * 1e7), with its speed items
    positions = [i for i in stored if i.command == mavlink.MAV_CMD_NAV_WAYPOINT]
    assert len(positions) == 10 and {i.frame for i in positions} == {mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT}
    assert received.get("MISSION_ITEM_INT", 0) >= len(stored) and "MISSION_ITEM" not in received
    for item, (plat, plon, palt) in zip(positions, out["points"], strict=True):
        assert abs(item.x - plat) <= 1e-7 and abs(item.y - plon) <= 1e-7 and item.z == pytest.approx(palt, abs=1e-5)
    # downloaded back, it is the mission uploaded (to 1e-7 deg, as MAVSDK decodes PX4's frame 6 answer)
    down = out["downloaded"]
    assert len(down) == 10
    for item, (plat, plon, palt) in zip(down, out["points"], strict=True):
        assert ground_distance(item.latitude_deg, item.longitude_deg, plat, plon) < 0.02
        assert item.relative_altitude_m == pytest.approx(palt, abs=1e-4)
        assert item.speed_m_s == pytest.approx(2.0) and item.acceptance_radius_m == pytest.approx(0.5)

    # flown to the end: every waypoint reached (ground truth within its 0.5 m radius), progress 10 of 10
    assert (out["progress"].current, out["progress"].total) == (10, 10)
    for plat, plon, palt in out["points"]:
        north = math.radians(plat - ORIGIN[0]) * 6371000.0
        east = math.radians(plon - ORIGIN[1]) * 6371000.0 * math.cos(math.radians(ORIGIN[0]))
        miss = np.min(np.linalg.norm(truth[:, 1:4] - [north, east, -palt], axis=1))
        assert miss < 0.5 + 0.1  # the acceptance radius, and samples 0.2 m apart
    elat, elon, ealt = out["end"]
    assert ground_distance(elat, elon, *out["points"][-1][:2]) < 1.0 and ealt == pytest.approx(3.9, abs=0.3)
    assert out["after_clear"] == [] and "mission accepted (0 items)" in events

    # offboard flown (MAVSDK stamps setpoints with its own clock: applied on receipt, as PX4 does)
    assert out["offboard_mode"] == FlightMode.OFFBOARD
    assert vehicle.offboard.unstamped > 0
    # return: climbed to RTL_RETURN_ALT = 6 m above home (the parameter set above), landed at home, disarmed
    during = truth[truth[:, 0] >= next(t for t, text in vehicle.events if text == "mode return")]
    assert -during[:, 3].min() == pytest.approx(6.0, abs=0.15)
    hlat, hlon, halt = out["home"]
    assert ground_distance(hlat, hlon, *ORIGIN[:2]) < 0.3 and abs(halt) < 0.05
    assert not vehicle.armed and truth[-1, 3] == 0.0


def test_mavsdk_takeoff_goto_and_land():
    """action.set_takeoff_altitude (MIS_TAKEOFF_ALT), arm, takeoff (NAV_TAKEOFF), goto_location (DO_REPOSITION),
    land (NAV_LAND): each acknowledged and each done, measured on the simulator's ground truth."""
    mavsdk_or_skip()
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    port = free_udp_port()
    with simulated(f"udpout:127.0.0.1:{port}", origin=ORIGIN) as vehicle:

        async def workflow() -> dict:
            _mavsdk, drone = await connect(port)
            telemetry, action = TelemetryAsync(drone), ActionAsync(drone)
            position = await healthy_with_position(telemetry)
            await action.set_takeoff_altitude(3.5)
            out = {"takeoff_alt": await action.get_takeoff_altitude()}
            await action.arm()
            await action.takeoff()

            async def up() -> bool:
                high = (await telemetry.position()).relative_altitude_m > 3.4
                return high and await telemetry.flight_mode() == FlightMode.HOLD

            await wait_until(up, 30, "the vehicle did not take off to 3.5 m and hold")
            out["after_takeoff"] = (await telemetry.position()).relative_altitude_m
            target = offset(position.latitude_deg, position.longitude_deg, -6.0, 4.0)
            await action.goto_location(*target, ORIGIN[2] + 5.0, math.nan)

            async def there() -> bool:
                p = await telemetry.position()
                return ground_distance(p.latitude_deg, p.longitude_deg, *target) < 0.1 and (
                    abs(p.absolute_altitude_m - ORIGIN[2] - 5.0) < 0.1
                )

            await wait_until(there, 30, "goto_location was not reached")
            await action.land()

            async def down() -> bool:
                return not await telemetry.armed()

            await wait_until(down, 40, "the vehicle did not land and disarm")
            end = await telemetry.position()
            out["end"] = (end.latitude_deg, end.longitude_deg, end.relative_altitude_m)
            out["target"] = target
            return out

        out = asyncio.run(asyncio.wait_for(workflow(), 120))
        answered = list(vehicle.commands_answered)
        truth = np.array(vehicle.trajectory)

    assert out["takeoff_alt"] == pytest.approx(3.5) and out["after_takeoff"] == pytest.approx(3.5, abs=0.15)
    # every command MAVSDK sent for these was accepted, and none was left unanswered or unsupported
    sent = {command for command, _ in answered}
    for command in (
        mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
        mavlink.MAV_CMD_NAV_TAKEOFF,
        mavlink.MAV_CMD_DO_REPOSITION,
        mavlink.MAV_CMD_NAV_LAND,
    ):
        assert command in sent
        assert {result for c, result in answered if c == command} == {mavlink.MAV_RESULT_ACCEPTED}
    # landed where it went: the goto target, at 5 m above home before the landing
    lat, lon, alt = out["end"]
    assert ground_distance(lat, lon, *out["target"]) < 0.2 and abs(alt) < 0.05
    assert -truth[:, 3].min() == pytest.approx(5.0, abs=0.15)
