"""The simulated vehicle's telemetry: PX4's streams at PX4's default rates, and what a ground station requests.

A mix-in of :class:`~.vehicle.SimulatedVehicle`. PX4 streams to a ground
station link (``MAVLINK_MODE_NORMAL``, the link QGroundControl uses) at the
rates in :data:`STREAMS`; HEARTBEAT goes out at 1 Hz of wall clock (the
link's liveness), everything else on the vehicle's clock (as PX4 SITL in
lockstep with its simulator), on multiples of each interval.
SET_MESSAGE_INTERVAL (the message or MAV_CMD_SET_MESSAGE_INTERVAL) changes
a rate (-1 off, 0 PX4's default), MAV_CMD_GET_MESSAGE_INTERVAL reads it, and
MAV_CMD_REQUEST_MESSAGE sends any of them once, AUTOPILOT_VERSION and
MESSAGE_INTERVAL too.

What the point-mass simulation does not have is derived, and said so:
the attitude is the tilt that points the rotors' thrust along the
acceleration the position controller asks for (yaw is 0: the vehicle faces
north); the battery is a 4S pack drained linearly over
:data:`ENDURANCE` s of armed time; the GPS always has a 3D fix with 12
satellites at the true position; every sensor is present and healthy.
"""

from __future__ import annotations

import math

import numpy as np
from surgiplan.plugins.devices.mavlink.link import mavlink

#: stream -> default rate (Hz) on a ground-station link (PX4 mavlink_main.cpp, MAVLINK_MODE_NORMAL)
STREAMS: dict[str, float] = {
    "SYS_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 1.0,
    "ATTITUDE": 15.0,
    "GLOBAL_POSITION_INT": 5.0,
    "LOCAL_POSITION_NED": 1.0,
    "GPS_RAW_INT": 1.0,
    "HOME_POSITION": 0.5,
    "BATTERY_STATUS": 0.5,
    "VFR_HUD": 4.0,
    "GPS_GLOBAL_ORIGIN": 0.1,
}
STREAM_IDS: dict[int, str] = {getattr(mavlink, f"MAVLINK_MSG_ID_{name}"): name for name in STREAMS}

#: MAV_PROTOCOL_CAPABILITY bits the simulated vehicle honours (AUTOPILOT_VERSION.capabilities)
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT  # the deprecated MISSION_ITEM, both ways
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT  # REAL32 parameters
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT  # MISSION_ITEM_INT, MISSION_REQUEST_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT  # COMMAND_INT (DO_REPOSITION in a global frame)
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE  # INT32 parameters in the float's bytes
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED  # offboard setpoints
    | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE  # fence lists: stored, sent back, enforced
    | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY  # rally points: stored, sent back, returned to
)
#: flight_sw_version: the PX4 release whose conventions the simulator follows (1.15.0, type "dev")
FLIGHT_SW_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | mavlink.FIRMWARE_VERSION_TYPE_DEV
#: seconds of armed time on one battery
ENDURANCE = 1200.0
CELLS = 4
#: sensors a PX4 multirotor reports present, enabled and healthy (MAVSDK's health checks read these)
SENSORS = (
    mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mavlink.MAV_SYS_STATUS_AHRS
    | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
)
GRAVITY = 9.81


def message_name(message_id: int) -> str:
    entry = mavlink.mavlink_map.get(int(message_id))
    return entry.msgname if entry is not None else f"message {int(message_id)}"


class Telemetry:
    """PX4's telemetry streams on the simulated vehicle (a mix-in: see the module's docstring)."""

    def _init_telemetry(self) -> None:
        rates = {**STREAMS, **self.settings.rates}
        #: stream -> interval (s of vehicle time); <= 0: off
        self.intervals = {name: (1.0 / rate if rate > 0 else -1.0) for name, rate in rates.items()}
        self._due = dict.fromkeys(STREAMS, 0.0)
        self._next["current"] = 0.0

    # ------------------------------------------------------------------ rates
    @property
    def position_interval(self) -> float:
        return self.intervals["LOCAL_POSITION_NED"]

    def set_interval(self, message_id: int, interval_us: float) -> int:
        """SET_MESSAGE_INTERVAL: -1 off, 0 PX4's default, else that interval (µs); MAV_RESULT as PX4 answers."""
        name = STREAM_IDS.get(int(message_id))
        if name is None:
            return mavlink.MAV_RESULT_FAILED  # PX4: no stream of that id (HEARTBEAT included)
        if interval_us < -1e-5:
            self.intervals[name] = -1.0
        elif interval_us > 1e-5:
            self.intervals[name] = max(interval_us * 1e-6, self.settings.step)
        else:
            rate = self.settings.rates.get(name, STREAMS[name])
            self.intervals[name] = 1.0 / rate if rate > 0 else -1.0
        self._due[name] = self.t  # the new rate from now on
        return mavlink.MAV_RESULT_ACCEPTED

    def interval_message(self, message_id: int):
        """MESSAGE_INTERVAL: the interval (µs), -1 when off, 0 when the vehicle has no such message (PX4)."""
        name = STREAM_IDS.get(int(message_id))
        if name is None:
            interval = 0
        else:
            interval = -1 if self.intervals[name] <= 0 else round(self.intervals[name] * 1e6)
        return mavlink.MAVLink_message_interval_message(int(message_id), interval)

    # ------------------------------------------------------------------ streaming
    def _periodic(self) -> None:
        t = self.t
        for name, interval in self.intervals.items():
            if interval <= 0 or t < self._due[name] - 1e-9:
                continue
            # on multiples of the interval: reports fall on the ground station's setpoint grid (50 ms)
            self._due[name] = (round(t / interval) + 1) * interval
            if name == "LOCAL_POSITION_NED":
                self._report_position()
            else:
                self._telemetry(self.build(name))
        if t >= self._next["current"] - 1e-9:
            self._next["current"] = t + 1.0
            self._mission_current()

    def build(self, name: str):
        """The current value of stream ``name`` as a message."""
        return getattr(self, f"_msg_{name.lower()}")()

    def _time_ms(self) -> int:
        return round(self.t * 1000) & 0xFFFFFFFF

    def _geodetic(self):
        """Latitude, longitude (deg * 1e7), altitude AMSL and above home (mm) of the vehicle now."""
        north, east, down = (float(x) for x in self.model.p)
        lat, lon = self.projection.reproject(north, east)
        amsl = self.settings.origin[2] - down
        return round(float(lat) * 1e7), round(float(lon) * 1e7), round(amsl * 1000), round(self._height() * 1000)

    def _height(self) -> float:
        return float(self.home[2] - self.model.p[2])

    def _msg_sys_status(self):
        health = SENSORS
        if not self.settings.refuse_arming:
            health |= mavlink.MAV_SYS_STATUS_PREARM_CHECK  # PX4: set while arming is possible
        fence_present, fence_enabled, fence_health = self._geofence_sensor_bits()
        present = SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK | fence_present
        volts, amps, remaining = self._battery()
        return mavlink.MAVLink_sys_status_message(
            present, SENSORS | mavlink.MAV_SYS_STATUS_PREARM_CHECK | fence_enabled, health | fence_health,
            250, round(volts * 1000), round(amps * 100), remaining, 0, 0, 0, 0, 0, 0,
        )  # fmt: skip

    def _battery(self) -> tuple[float, float, int]:
        """Voltage (V), current (A), remaining (%) of the simulated pack."""
        used = min(self._armed_time / ENDURANCE, 1.0)
        remaining = round(100 * (1 - used))
        volts = CELLS * (4.2 - 0.7 * used)
        amps = (12.0 if self.model.airborne else 1.5) if self.armed else 0.3
        return volts, amps, remaining

    def _msg_battery_status(self):
        volts, amps, remaining = self._battery()
        cell = round(volts / CELLS * 1000)
        return mavlink.MAVLink_battery_status_message(
            0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO, 0x7FFF,
            [cell] * CELLS + [0xFFFF] * (10 - CELLS), round(amps * 100), round(self._consumed_mah), -1, remaining,
        )  # fmt: skip

    def _attitude(self) -> tuple[float, float]:
        """Roll and pitch (rad) that point the thrust along the controller's acceleration (yaw 0)."""
        ax, ay, az = self.model.thrust
        body_z = np.array([-ax, -ay, GRAVITY - az])
        norm = float(np.linalg.norm(body_z))
        if norm < 1e-6 or not self.armed:
            return 0.0, 0.0
        bx, by, bz = body_z / norm
        return math.asin(max(-1.0, min(1.0, -by))), math.atan2(bx, bz)

    def _msg_attitude(self):
        roll, pitch = self._attitude()
        return mavlink.MAVLink_attitude_message(self._time_ms(), roll, pitch, 0.0, 0.0, 0.0, 0.0)

    def _msg_global_position_int(self):
        lat, lon, amsl, height = self._geodetic()
        vx, vy, vz = (round(float(v) * 100) for v in self.model.v)
        return mavlink.MAVLink_global_position_int_message(self._time_ms(), lat, lon, amsl, height, vx, vy, vz, 0)

    def _msg_gps_raw_int(self):
        lat, lon, amsl, _ = self._geodetic()
        v = self.model.v
        speed = float(np.hypot(v[0], v[1]))
        course = math.degrees(math.atan2(v[1], v[0])) % 360 if speed > 0.05 else 0.0
        return mavlink.MAVLink_gps_raw_int_message(
            round(self.t * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, amsl, 70, 100, round(speed * 100),
            round(course * 100) % 36000, 12, amsl, 300, 500, 100, 0, 0,
        )  # fmt: skip

    def _msg_home_position(self):
        lat, lon, alt = self._home_geodetic()
        x, y, z = (float(c) for c in self.home)
        return mavlink.MAVLink_home_position_message(
            lat, lon, alt, x, y, z, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, round(self.t * 1e6)
        )

    def _home_geodetic(self) -> tuple[int, int, int]:
        north, east, down = (float(c) for c in self.home)
        lat, lon = self.projection.reproject(north, east)
        return round(float(lat) * 1e7), round(float(lon) * 1e7), round((self.settings.origin[2] - down) * 1000)

    def _msg_gps_global_origin(self):
        lat, lon, alt = self.settings.origin
        return mavlink.MAVLink_gps_global_origin_message(
            round(lat * 1e7), round(lon * 1e7), round(alt * 1000), round(self.t * 1e6)
        )

    def _msg_extended_sys_state(self):
        return mavlink.MAVLink_extended_sys_state_message(mavlink.MAV_VTOL_STATE_UNDEFINED, self._landed_state())

    def _msg_vfr_hud(self):
        v = self.model.v
        speed = float(np.hypot(v[0], v[1]))
        throttle = 50 if self.armed and self.model.airborne else 0
        amsl = self.settings.origin[2] - float(self.model.p[2])
        return mavlink.MAVLink_vfr_hud_message(speed, speed, 0, throttle, amsl, -float(v[2]))

    @property
    def capabilities(self) -> int:
        """The capability bits announced: :data:`CAPABILITIES` but those withheld (a rehearsal setting)."""
        bits = CAPABILITIES
        for name in self.settings.capabilities_withheld:
            bits &= ~getattr(mavlink, f"MAV_PROTOCOL_CAPABILITY_{name}")
        return bits

    def _msg_autopilot_version(self):
        return mavlink.MAVLink_autopilot_version_message(
            self.capabilities, FLIGHT_SW_VERSION, 0, 0, 0, list(b"surgipln"), [0] * 8, [0] * 8, 0, 0,
            0x53555247_49504C4E, [0] * 18,
        )  # fmt: skip

    def requestable(self, message_id: int):
        """The message MAV_CMD_REQUEST_MESSAGE asks for, or None when the vehicle has none of that id."""
        message_id = int(message_id)
        if message_id in STREAM_IDS:
            name = STREAM_IDS[message_id]
            return self._position_message() if name == "LOCAL_POSITION_NED" else self.build(name)
        if message_id == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return self._msg_autopilot_version()
        if message_id == mavlink.MAVLINK_MSG_ID_MESSAGE_INTERVAL:
            return None  # answered separately (it takes the id asked about in param2)
        if message_id == mavlink.MAVLINK_MSG_ID_MISSION_CURRENT:
            return self._mission_current_message()
        return None
