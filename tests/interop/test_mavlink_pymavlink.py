"""Plain pymavlink scripts against the simulated vehicle: the protocol details, message by message.

What a ground station sees on the wire, checked against the MAVLink common
message set and what PX4 answers: mission items in every frame and message
form (scaled as the spec says), download, set-current, clear, the geofence and
rally lists; the parameter protocol; telemetry rates and SET_MESSAGE_INTERVAL;
the command table; PING and TIMESYNC; AUTOPILOT_VERSION. Each script is what
a user writes with ``mavutil``; every wait is bounded.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np
import pytest
from mavlink_support import ground_distance, offset, simulated
from surgiplan.plugins.devices.mavlink.link import mavlink, mavutil
from surgiplan.plugins.devices.mavlink.sim.params import PARAMETERS
from surgiplan.plugins.devices.mavlink.sim.telemetry import CAPABILITIES, STREAMS

pytestmark = pytest.mark.timeout(90)

LAT, LON, ALT = 47.397742, 8.545594, 488.0
M = mavlink


class Script:
    """A pymavlink ground station (system 255, component 190) talking to the vehicle on ``port``."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, source_component=190, input=False
        )
        self.mav = self.conn.mav
        self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        assert self.expect("HEARTBEAT", timeout=10) is not None, "no HEARTBEAT from the vehicle"

    def expect(self, kind: str, condition=lambda m: True, timeout: float = 3.0):
        """The next message of type ``kind`` that satisfies ``condition``, or None after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while (remaining := deadline - time.monotonic()) > 0:
            message = self.conn.recv_match(type=kind, blocking=True, timeout=min(remaining, 0.2))
            if message is not None and condition(message):
                return message
        return None

    def drain(self) -> None:
        while self.conn.recv_match(blocking=False) is not None:
            pass

    def command(self, command: int, *params: float, timeout: float = 3.0) -> int:
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        ack = self.expect("COMMAND_ACK", lambda m: m.command == command, timeout)
        assert ack is not None, f"no COMMAND_ACK for {command}"
        return int(ack.result)

    def command_with(self, kind: str, command: int, *params: float, timeout: float = 3.0):
        """A command and the message it makes the vehicle send (PX4 sends that first, then the COMMAND_ACK)."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        got = {}
        deadline = time.monotonic() + timeout
        while len(got) < 2 and time.monotonic() < deadline:
            m = self.conn.recv_match(type=[kind, "COMMAND_ACK"], blocking=True, timeout=0.2)
            if m is not None and (m.get_type() == kind or m.command == command):
                got.setdefault(m.get_type(), m)
        return got.get("COMMAND_ACK"), got.get(kind)

    def upload(self, items, mission_type=M.MAV_MISSION_TYPE_MISSION, legacy=False) -> tuple[int, list[str]]:
        """MISSION_COUNT, answer each request (INT or legacy), return the MISSION_ACK result and the request
        kinds the vehicle used."""
        self.drain()
        self.mav.mission_count_send(1, 1, len(items), mission_type)
        kinds = []
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            m = self.conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True,
                                     timeout=0.2)  # fmt: skip
            if m is None:
                continue
            if m.get_type() == "MISSION_ACK":
                return int(m.type), kinds
            kinds.append(m.get_type())
            self.mav.send(items[m.seq](m.seq, legacy))
        return -1, kinds

    def download(self, mission_type=M.MAV_MISSION_TYPE_MISSION, legacy=False) -> list:
        self.drain()
        self.mav.mission_request_list_send(1, 1, mission_type)
        count = self.expect("MISSION_COUNT", lambda m: m.mission_type == mission_type)
        assert count is not None, "no MISSION_COUNT"
        items = []
        for seq in range(count.count):
            send = self.mav.mission_request_send if legacy else self.mav.mission_request_int_send
            kind = "MISSION_ITEM" if legacy else "MISSION_ITEM_INT"
            send(1, 1, seq, mission_type)
            item = self.expect(kind, lambda m, s=seq: m.seq == s)
            assert item is not None, f"no {kind} {seq}"
            items.append(item)
        self.mav.mission_ack_send(1, 1, M.MAV_MISSION_ACCEPTED, mission_type)
        return items

    def close(self) -> None:
        self.conn.close()


def item(command, frame, lat=0.0, lon=0.0, alt=0.0, p1=0.0, p2=0.0, p3=0.0, p4=0.0, mission_type=0):
    """A mission item as a function of (seq, legacy): MISSION_ITEM_INT (global frames: deg * 1e7) or MISSION_ITEM."""

    def make(seq: int, legacy: bool):
        if legacy:
            return M.MAVLink_mission_item_message(
                1, 1, seq, frame, command, 0, 1, p1, p2, p3, p4, lat, lon, alt, mission_type
            )
        scale = 1e7 if frame in (0, 3, 5, 6, 10, 11) else (1e4 if frame in (1, 7, 8, 9) else 1)
        return M.MAVLink_mission_item_int_message(
            1, 1, seq, frame, command, 0, 1, p1, p2, p3, p4, round(lat * scale), round(lon * scale), alt, mission_type
        )

    return make


@pytest.fixture
def script():
    with simulated(origin=(LAT, LON, ALT)) as vehicle:
        client = Script(vehicle.port)
        try:
            yield client, vehicle
        finally:
            client.close()


# ----------------------------------------------------------------------------- missions


@pytest.mark.parametrize(
    ("frame", "legacy", "result"),
    [
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, False, M.MAV_MISSION_ACCEPTED),  # 3, the current frame, in _INT
        (M.MAV_FRAME_GLOBAL, False, M.MAV_MISSION_ACCEPTED),  # 0
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, False, M.MAV_MISSION_ACCEPTED),  # 6 (deprecated)
        (M.MAV_FRAME_GLOBAL_INT, False, M.MAV_MISSION_ACCEPTED),  # 5 (deprecated)
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, True, M.MAV_MISSION_ACCEPTED),  # legacy MISSION_ITEM, floats
        (M.MAV_FRAME_GLOBAL, True, M.MAV_MISSION_ACCEPTED),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, True, M.MAV_MISSION_UNSUPPORTED_FRAME),  # PX4: _INT frames in _INT only
        (M.MAV_FRAME_LOCAL_NED, False, M.MAV_MISSION_UNSUPPORTED_FRAME),  # PX4 flies no local mission
        (M.MAV_FRAME_GLOBAL_TERRAIN_ALT, False, M.MAV_MISSION_UNSUPPORTED_FRAME),
    ],
)
def test_mission_items_in_every_frame_are_scaled_and_placed_as_the_spec_says(script, frame, legacy, result):
    client, vehicle = script
    absolute = frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT)
    up = 3.0 + (ALT if absolute else 0.0)  # 3 m above home, in the frame's altitude reference
    target = offset(LAT, LON, 12.3456, -7.8912)
    items = [
        item(M.MAV_CMD_NAV_TAKEOFF, frame, LAT, LON, up),
        item(M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION, p1=1, p2=2.0, p3=-1),
        item(M.MAV_CMD_NAV_WAYPOINT, frame, *target, up, p2=0.3),
        item(M.MAV_CMD_NAV_LAND, frame, *target, 0.0 + (ALT if absolute else 0.0)),
    ]
    got, kinds = client.upload(items, legacy=legacy)
    assert got == result
    if result != M.MAV_MISSION_ACCEPTED:
        assert vehicle.mission == []
        return
    # PX4 asks with MISSION_REQUEST_INT, and switches to MISSION_REQUEST once it receives a MISSION_ITEM
    assert kinds[0] == "MISSION_REQUEST_INT" and set(kinds[1:]) == {
        "MISSION_REQUEST" if legacy else "MISSION_REQUEST_INT"
    }
    stored = vehicle.mission[2]
    precision = 2e-6 if legacy else 0.6e-7  # a float32 latitude is good to ~4e-6 deg (0.4 m), 1e-7 deg in _INT
    assert abs(stored.x - target[0]) < precision and abs(stored.y - target[1]) < precision
    # where the vehicle will fly: 12.35 m north, 7.89 m west, 3 m up, whatever the frame
    north, east, down = vehicle._item_position(stored)
    assert (north, east) == pytest.approx((12.3456, -7.8912), abs=0.012 if not legacy else 0.5)
    assert down == pytest.approx(-3.0, abs=1e-4)


def test_download_answers_as_px4_in_either_message_and_marks_the_current_item(script):
    client, _vehicle = script
    target = offset(LAT, LON, 5.0, 5.0)
    items = [
        item(M.MAV_CMD_NAV_TAKEOFF, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, LAT, LON, 3.0, p4=math.nan),
        item(M.MAV_CMD_NAV_WAYPOINT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT, *target, 3.0, p1=1.5, p2=0.4, p3=0.7, p4=-90),
        item(M.MAV_CMD_NAV_WAYPOINT, M.MAV_FRAME_GLOBAL, *target, ALT + 4.0, p2=0.4),
        item(M.MAV_CMD_DO_CHANGE_SPEED, M.MAV_FRAME_MISSION, p1=1, p2=2.5, p3=-1),
    ]
    assert client.upload(items)[0] == M.MAV_MISSION_ACCEPTED
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 2, 0) == M.MAV_RESULT_ACCEPTED
    as_int = client.download()
    as_float = client.download(legacy=True)
    # MISSION_ITEM_INT: PX4's _INT frames (6 relative, 5 absolute), degrees * 1e7 exactly as sent
    assert [m.frame for m in as_int] == [6, 6, 5, 2]
    assert (as_int[1].x, as_int[1].y) == (round(target[0] * 1e7), round(target[1] * 1e7))
    # the parameters PX4 keeps: hold 1.5 s, radius 0.4 m, yaw -90 deg as 270 (wrapped), param3 not kept
    assert (as_int[1].param1, as_int[1].param2, as_int[1].param3) == pytest.approx((1.5, 0.4, 0.0))
    assert as_int[1].param4 == pytest.approx(270.0, abs=1e-4) and math.isnan(as_int[0].param4)
    assert as_int[2].z == pytest.approx(ALT + 4.0) and as_int[3].param2 == pytest.approx(2.5)
    assert [m.current for m in as_int] == [0, 0, 1, 0]
    # MISSION_ITEM: the current frames (3, 0) and float degrees
    assert [m.frame for m in as_float] == [3, 3, 0, 2]
    assert as_float[1].x == pytest.approx(target[0], abs=4e-6) and as_float[1].y == pytest.approx(target[1], abs=4e-6)


def test_set_current_and_clear_answer_as_px4(script):
    client, vehicle = script
    items = [item(M.MAV_CMD_NAV_WAYPOINT, 3, *offset(LAT, LON, k, 0), 3.0) for k in range(4)]
    assert client.upload(items)[0] == M.MAV_MISSION_ACCEPTED
    # MISSION_SET_CURRENT (the message): MISSION_CURRENT follows; out of range: refused with a STATUSTEXT
    client.mav.mission_set_current_send(1, 1, 3)
    assert client.expect("MISSION_CURRENT", lambda m: m.seq == 3) is not None
    client.mav.mission_set_current_send(1, 1, 9)
    assert "Not in list" in client.expect("STATUSTEXT", lambda m: b"WPM" in m.text.encode()).text
    # MAV_CMD_DO_SET_MISSION_CURRENT: accepted, FAILED out of range, DENIED for a param2 that is not 0 or 1
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 1, 0) == M.MAV_RESULT_ACCEPTED and vehicle.current == 1
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 7, 0) == M.MAV_RESULT_FAILED
    assert client.command(M.MAV_CMD_DO_SET_MISSION_CURRENT, 1, 0.5) == M.MAV_RESULT_DENIED
    # MISSION_CLEAR_ALL: acknowledged with its mission type; then MISSION_CURRENT says "no mission" (total 65535)
    client.mav.mission_clear_all_send(1, 1, M.MAV_MISSION_TYPE_MISSION)
    ack = client.expect("MISSION_ACK")
    assert (ack.type, ack.mission_type) == (M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION)
    current = client.expect("MISSION_CURRENT", timeout=5)
    assert (current.total, current.mission_state) == (65535, M.MISSION_STATE_NO_MISSION)
    assert vehicle.mission == [] and client.download() == []
    assert client.command(M.MAV_CMD_MISSION_START, 0, 0) == M.MAV_RESULT_DENIED  # no mission to start


def test_geofence_and_rally_lists_are_stored_sent_back_and_cleared(script):
    client, vehicle = script
    F, R = M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY
    corners = [offset(LAT, LON, n, e) for n, e in ((-20, -20), (-20, 20), (20, 20), (20, -20))]
    inclusion = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    fence = [item(inclusion, 3, *c, 0.0, p1=4, mission_type=F) for c in corners]
    assert client.upload(fence, mission_type=F)[0] == M.MAV_MISSION_ACCEPTED
    rally = [item(M.MAV_CMD_NAV_RALLY_POINT, 3, *offset(LAT, LON, 10, 0), 5.0, mission_type=R)]
    assert client.upload(rally, mission_type=R)[0] == M.MAV_MISSION_ACCEPTED
    back = client.download(F)
    assert [m.command for m in back] == [inclusion] * 4 and [m.param1 for m in back] == [4.0] * 4
    assert [(m.x, m.y) for m in back] == [(round(a * 1e7), round(b * 1e7)) for a, b in corners]
    assert [m.command for m in client.download(R)] == [M.MAV_CMD_NAV_RALLY_POINT]
    assert vehicle.mission == []  # the mission list is another list
    # PX4's checks: a polygon of 2 vertices is an error, a waypoint is no fence item, a fence item no mission item
    two = [item(inclusion, 3, *c, 0.0, p1=2, mission_type=F) for c in corners[:2]]
    assert client.upload(two, mission_type=F)[0] == M.MAV_MISSION_ERROR
    assert client.upload([item(M.MAV_CMD_NAV_WAYPOINT, 3, LAT, LON, 3, mission_type=F)], mission_type=F)[0] == (
        M.MAV_MISSION_UNSUPPORTED
    )
    assert client.upload([item(inclusion, 3, LAT, LON, 0, p1=4)])[0] == M.MAV_MISSION_ERROR
    assert len(client.download(F)) == 4  # refused uploads left the stored fence as it was
    # clear every list at once
    client.mav.mission_clear_all_send(1, 1, M.MAV_MISSION_TYPE_ALL)
    assert client.expect("MISSION_ACK", lambda m: m.mission_type == M.MAV_MISSION_TYPE_ALL).type == 0
    assert client.download(F) == [] and client.download(R) == []


# ----------------------------------------------------------------------------- parameters


def _name(message) -> str:
    return message.param_id if isinstance(message.param_id, str) else message.param_id.decode()


def _int(value: float) -> int:
    return struct.unpack("<i", struct.pack("<f", value))[0]


def test_parameter_protocol_lists_reads_sets_and_refuses(script):
    client, vehicle = script
    client.drain()
    client.mav.param_request_list_send(1, 1)
    listed = {}
    deadline = time.monotonic() + 5
    while len(listed) < len(PARAMETERS) and time.monotonic() < deadline:
        m = client.expect("PARAM_VALUE", timeout=0.5)
        if m is not None:
            listed[m.param_index] = m
    count = len(PARAMETERS)  # 26: 21 that drive the airframe and failsafes, 5 of the geofence and return
    assert count == 26 and sorted(listed) == list(range(count)) and {m.param_count for m in listed.values()} == {count}
    assert [_name(listed[i]) for i in range(count)] == sorted(_name(m) for m in listed.values())
    types = {_name(m): m.param_type for m in listed.values()}
    assert types["COM_OBL_RC_ACT"] == M.MAV_PARAM_TYPE_INT32 and types["MPC_XY_VEL_MAX"] == M.MAV_PARAM_TYPE_REAL32
    # read by name and by index
    client.mav.param_request_read_send(1, 1, b"NAV_ACC_RAD", -1)
    assert client.expect("PARAM_VALUE", lambda m: _name(m) == "NAV_ACC_RAD").param_value == pytest.approx(0.3)
    index = [_name(listed[i]) for i in range(count)].index("MPC_Z_VEL_MAX_UP")
    client.mav.param_request_read_send(1, 1, b"", index)
    assert client.expect("PARAM_VALUE", lambda m: m.param_index == index).param_value == pytest.approx(2.0)
    # an unknown name: no answer (a client times out, as with PX4)
    client.mav.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    assert client.expect("PARAM_VALUE", lambda m: _name(m) == "NO_SUCH_PARAM", timeout=1.0) is None
    # set: a REAL32 and an INT32 (bytewise); each answered with the new value and in force in the simulation
    client.mav.param_set_send(1, 1, b"MPC_XY_VEL_MAX", 1.25, M.MAV_PARAM_TYPE_REAL32)
    assert client.expect("PARAM_VALUE", lambda m: _name(m) == "MPC_XY_VEL_MAX").param_value == pytest.approx(1.25)
    wire = struct.unpack("<f", struct.pack("<i", 3))[0]
    client.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", wire, M.MAV_PARAM_TYPE_INT32)
    assert _int(client.expect("PARAM_VALUE", lambda m: _name(m) == "COM_OBL_RC_ACT").param_value) == 3
    assert vehicle.settings.airframe.max_speed == 1.25 and vehicle.settings.offboard_loss_action == 3
    # refused: out of range, and the wrong type; the unchanged value comes back, and a STATUSTEXT says why
    client.mav.param_set_send(1, 1, b"MPC_XY_VEL_MAX", -4.0, M.MAV_PARAM_TYPE_REAL32)
    assert client.expect("PARAM_VALUE", lambda m: _name(m) == "MPC_XY_VEL_MAX").param_value == pytest.approx(1.25)
    assert "outside" in client.expect("STATUSTEXT", lambda m: "MPC_XY_VEL_MAX" in m.text).text
    client.mav.param_set_send(1, 1, b"COM_OBL_RC_ACT", 4.0, M.MAV_PARAM_TYPE_REAL32)
    assert _int(client.expect("PARAM_VALUE", lambda m: _name(m) == "COM_OBL_RC_ACT").param_value) == 3
    assert vehicle.settings.airframe.max_speed == 1.25 and vehicle.settings.offboard_loss_action == 3


def test_parameters_drive_the_simulation(script):
    """MPC_XY_VEL_MAX set to 1 m/s caps a mission flown at a requested 3 m/s; NAV_ACC_RAD and MPC_Z_VEL_MAX_UP
    likewise shape the flight (measured on the simulator's ground truth)."""
    client, vehicle = script
    for name, value in (("MPC_XY_VEL_MAX", 1.0), ("MPC_Z_VEL_MAX_UP", 0.8), ("MPC_XY_CRUISE", 3.0)):
        client.mav.param_set_send(1, 1, name.encode(), value, M.MAV_PARAM_TYPE_REAL32)
        assert client.expect("PARAM_VALUE", lambda m, n=name: _name(m) == n).param_value == pytest.approx(value)
    target = offset(LAT, LON, 8.0, 0.0)
    items = [item(M.MAV_CMD_NAV_TAKEOFF, 3, LAT, LON, 2.0), item(M.MAV_CMD_NAV_WAYPOINT, 3, *target, 2.0)]
    assert client.upload(items)[0] == M.MAV_MISSION_ACCEPTED
    assert client.command(M.MAV_CMD_MISSION_START, 0, 0) == M.MAV_RESULT_ACCEPTED  # PX4: switches and arms
    reached = client.expect("MISSION_ITEM_REACHED", lambda m: m.seq == 1, timeout=30)
    assert reached is not None
    truth = np.array(vehicle.trajectory)
    horizontal = np.hypot(truth[:, 4], truth[:, 5])
    assert horizontal.max() <= 1.0 + 1e-6 and horizontal.max() > 0.95  # capped by the parameter, and reaching it
    assert -truth[:, 6].min() <= 0.8 + 1e-6  # climb capped by MPC_Z_VEL_MAX_UP


# ----------------------------------------------------------------------------- telemetry


def test_telemetry_streams_at_px4_rates_and_follows_set_message_interval(script):
    client, vehicle = script
    client.drain()

    def rates(seconds: float) -> dict[str, float]:
        """Messages per second of *vehicle* time, over ``seconds`` of it (at 10x, a tenth of that in wall time)."""
        counts: dict[str, int] = {}
        start = end = None
        deadline = time.monotonic() + 2 * seconds / 10 + 5
        while time.monotonic() < deadline:
            m = client.conn.recv_match(blocking=True, timeout=0.2)
            if m is None:
                continue
            if m.get_type() == "LOCAL_POSITION_NED":  # the vehicle's clock
                start = m.time_boot_ms if start is None else start
                end = m.time_boot_ms
                if (end - start) / 1000 >= seconds:
                    break
            if start is not None:
                counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
        span = (end - start) / 1000
        return {k: v / span for k, v in counts.items()}, span

    measured, span = rates(20.0)
    assert span >= 20.0
    for name, rate in STREAMS.items():
        assert measured.get(name, 0.0) == pytest.approx(rate, abs=1.5 / span), name
    # SET_MESSAGE_INTERVAL: ATTITUDE at 2 Hz, GLOBAL_POSITION_INT off; the interval read back
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 500_000) == 0
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, -1) == 0
    ack, interval = client.command_with("MESSAGE_INTERVAL", M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE)
    assert ack.result == 0 and (interval.message_id, interval.interval_us) == (M.MAVLINK_MSG_ID_ATTITUDE, 500_000)
    client.drain()
    measured, span = rates(10.0)
    assert measured.get("ATTITUDE", 0) == pytest.approx(2.0, abs=1.5 / span)
    assert measured.get("GLOBAL_POSITION_INT", 0) == 0
    # 0 restores PX4's default; HEARTBEAT and messages the vehicle does not stream: MAV_RESULT_FAILED (PX4)
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 0) == 0
    assert vehicle.intervals["ATTITUDE"] == pytest.approx(1 / 15)
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HEARTBEAT, 100_000) == M.MAV_RESULT_FAILED
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ODOMETRY, 100_000) == M.MAV_RESULT_FAILED


def test_telemetry_says_where_the_vehicle_is_consistently(script):
    """GLOBAL_POSITION_INT, GPS_RAW_INT, LOCAL_POSITION_NED and HOME_POSITION agree (great-circle distances),
    SYS_STATUS reports its sensors healthy and arming possible, EXTENDED_SYS_STATE the landed state."""
    client, _vehicle = script
    target = offset(LAT, LON, -6.0, 9.0)
    items = [item(M.MAV_CMD_NAV_TAKEOFF, 3, LAT, LON, 4.0), item(M.MAV_CMD_NAV_WAYPOINT, 3, *target, 4.0)]
    assert client.upload(items)[0] == M.MAV_MISSION_ACCEPTED
    assert client.command(M.MAV_CMD_MISSION_START, 0, 0) == M.MAV_RESULT_ACCEPTED
    assert client.expect("MISSION_ITEM_REACHED", lambda m: m.seq == 1, timeout=30) is not None
    time.sleep(0.5)
    client.drain()
    local = client.expect("LOCAL_POSITION_NED")
    glob = client.expect("GLOBAL_POSITION_INT")
    gps = client.expect("GPS_RAW_INT", timeout=5)
    home = client.expect("HOME_POSITION", timeout=5)
    status = client.expect("SYS_STATUS", timeout=5)
    state = client.expect("EXTENDED_SYS_STATE", timeout=5)
    lat, lon = glob.lat * 1e-7, glob.lon * 1e-7
    assert ground_distance(lat, lon, *target) < 0.35  # holding at the waypoint (radius 0.3 m by default)
    assert ground_distance(lat, lon, gps.lat * 1e-7, gps.lon * 1e-7) < 0.35 and gps.fix_type == 3
    assert math.hypot(local.x, local.y) == pytest.approx(ground_distance(lat, lon, LAT, LON), abs=0.4)
    assert glob.relative_alt / 1000 == pytest.approx(4.0, abs=0.1) and glob.alt / 1000 == pytest.approx(
        ALT + 4, abs=0.1
    )
    assert (home.latitude, home.longitude, home.altitude) == (round(LAT * 1e7), round(LON * 1e7), round(ALT * 1000))
    required = M.MAV_SYS_STATUS_SENSOR_GPS | M.MAV_SYS_STATUS_SENSOR_3D_GYRO | M.MAV_SYS_STATUS_PREARM_CHECK
    assert status.onboard_control_sensors_health & required == required
    assert state.landed_state == M.MAV_LANDED_STATE_IN_AIR


# ----------------------------------------------------------------------------- commands, PING, TIMESYNC, version


def test_commands_are_answered_as_px4_and_the_rest_unsupported(script):
    client, _vehicle = script
    R = M
    # refused before it can be done: PX4's TEMPORARILY_REJECTED / DENIED
    assert client.command(R.MAV_CMD_DO_SET_MODE, 1, 6, 0) == R.MAV_RESULT_TEMPORARILY_REJECTED  # offboard, no setpoints
    assert client.command(R.MAV_CMD_DO_SET_MODE, 1, 1, 0) == R.MAV_RESULT_TEMPORARILY_REJECTED  # manual: no RC
    assert client.command(R.MAV_CMD_COMPONENT_ARM_DISARM, 2) == R.MAV_RESULT_UNSUPPORTED  # neither arm nor disarm
    assert client.command(R.MAV_CMD_DO_REPOSITION, -1, 1, 0, math.nan, LAT, LON, ALT + 2) == (
        R.MAV_RESULT_TEMPORARILY_REJECTED  # not flying
    )
    # take-off as a command, then DO_REPOSITION in COMMAND_INT (frame 3: altitude above home), land
    assert client.command(R.MAV_CMD_COMPONENT_ARM_DISARM, 1) == R.MAV_RESULT_ACCEPTED
    assert client.command(R.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, ALT + 3.0) == 0
    assert client.expect("EXTENDED_SYS_STATE", lambda m: m.landed_state == R.MAV_LANDED_STATE_IN_AIR, 20) is not None
    assert client.expect("HEARTBEAT", lambda m: (m.custom_mode >> 24) == 3, 20) is not None  # then it holds (loiter)
    target = offset(LAT, LON, 4.0, -3.0)
    flags = R.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
    client.mav.command_int_send(
        1, 1, R.MAV_FRAME_GLOBAL_RELATIVE_ALT, R.MAV_CMD_DO_REPOSITION, 0, 0, -1, flags, 0, math.nan,
        round(target[0] * 1e7), round(target[1] * 1e7), 5.0,
    )  # fmt: skip
    assert client.expect("COMMAND_ACK", lambda m: m.command == R.MAV_CMD_DO_REPOSITION).result == 0
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        glob = client.expect("GLOBAL_POSITION_INT")
        if ground_distance(glob.lat * 1e-7, glob.lon * 1e-7, *target) < 0.05 and abs(glob.relative_alt - 5000) < 50:
            break
    else:
        raise AssertionError("DO_REPOSITION did not get there")
    assert client.command(R.MAV_CMD_COMPONENT_ARM_DISARM, 0) == R.MAV_RESULT_TEMPORARILY_REJECTED  # in the air
    assert client.command(R.MAV_CMD_DO_REPOSITION, -1, 0, 0, math.nan, *target, ALT + 2) == R.MAV_RESULT_UNSUPPORTED
    assert client.command(R.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
    assert client.expect("HEARTBEAT", lambda m: not m.base_mode & R.MAV_MODE_FLAG_SAFETY_ARMED, 30) is not None
    # the rest: MAV_RESULT_UNSUPPORTED
    for command in (R.MAV_CMD_DO_SET_SERVO, R.MAV_CMD_DO_FLIGHTTERMINATION, R.MAV_CMD_PREFLIGHT_CALIBRATION):
        assert client.command(command, 1) == R.MAV_RESULT_UNSUPPORTED
    assert client.command(R.MAV_CMD_REQUEST_MESSAGE, R.MAVLINK_MSG_ID_ODOMETRY) == R.MAV_RESULT_DENIED  # none


def test_ping_timesync_and_autopilot_version(script):
    client, _vehicle = script
    client.mav.ping_send(123456789, 42, 0, 0)  # a request: addressed to all
    pong = client.expect("PING", lambda m: m.seq == 42)
    assert (pong.time_usec, pong.target_system, pong.target_component) == (123456789, 255, 190)
    before = time.monotonic_ns()
    client.mav.timesync_send(0, 987654321)
    sync = client.expect("TIMESYNC", lambda m: m.ts1 == 987654321)
    assert before <= sync.tc1 <= time.monotonic_ns()  # the vehicle's clock (ns)
    ack, version = client.command_with(
        "AUTOPILOT_VERSION", M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
    )
    assert ack.result == M.MAV_RESULT_ACCEPTED
    assert version.capabilities == CAPABILITIES
    for bit in ("MISSION_INT", "MISSION_FLOAT", "COMMAND_INT", "PARAM_ENCODE_BYTEWISE", "MAVLINK2",
                "SET_POSITION_TARGET_LOCAL_NED", "MISSION_FENCE", "MISSION_RALLY"):  # fmt: skip
        assert version.capabilities & getattr(M, f"MAV_PROTOCOL_CAPABILITY_{bit}")
    for bit in ("FTP", "SET_ATTITUDE_TARGET", "TERRAIN", "FLIGHT_TERMINATION", "PARAM_ENCODE_C_CAST"):
        assert not version.capabilities & getattr(M, f"MAV_PROTOCOL_CAPABILITY_{bit}")
    assert (version.flight_sw_version >> 24, (version.flight_sw_version >> 16) & 0xFF) == (1, 15)
