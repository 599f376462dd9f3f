"""Settings of the ``mavlink_vehicle`` device (lengths in the pipeline's ``length_unit``; speeds m/s, times s).

See :mod:`.device` for what each does in the device's lifecycle; the simulated
vehicle's own settings (``sim:``) are :class:`~.sim.settings.SimSettings`.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, PositiveFloat, field_validator, model_validator
from surgiplan.models import StrictModel
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.units import Angle, Length, PositiveLength, Vec3

from .link import check_connection_string, signing_key
from .scene_fence import FenceSettings


class FrameSettings(StrictModel):
    """Where the vehicle's local NED frame is in the scene."""

    #: the local origin (where the vehicle's EKF puts 0, 0, 0) in scene coordinates
    local_origin: Vec3 = (0.0, 0.0, 0.0)
    #: direction of the scene's +x axis, clockwise from north (90 deg: x east, y north, z up)
    heading: Angle = math.pi / 2


class HeartbeatSettings(StrictModel):
    #: our HEARTBEAT period (s); the vehicle's is expected at the same rate
    period: PositiveFloat = 1.0
    #: the vehicle is lost after this many missed heartbeats
    missed: int = Field(default=5, ge=2)


class Timeouts(StrictModel):
    """Protocol timeouts (wall-clock s) and retries; the flight's allowance is vehicle time."""

    connect: PositiveFloat = 15.0
    command: PositiveFloat = 1.5
    command_retries: int = Field(default=5, ge=0)
    mission: PositiveFloat = 1.5
    mission_retries: int = Field(default=5, ge=0)
    #: a download's wait for each item, a parameter's for its value, before asking again (the vehicle
    #: answers these at once; MAVSDK's default 0.5 s)
    mission_item: PositiveFloat = 0.5
    #: whole transfers tried when a mission upload is cancelled or times out
    upload_attempts: int = Field(default=3, ge=1)
    #: waiting for a mode or arming to show in the vehicle's HEARTBEAT
    mode: PositiveFloat = 5.0
    #: the flight (vehicle s); default: 3x the route at cruise speed plus 60 s
    flight: PositiveFloat | None = None
    #: watching a commanded failsafe (s)
    failsafe: PositiveFloat = 60.0


class Rehearsal(StrictModel):
    """Faults the ground station itself rehearses, to see what the vehicle does about them."""

    #: offboard: once at the path's start, the setpoints leave the plan and fly straight at this obstacle
    #: (its centre, at the start's altitude) and beyond, as a rogue setpoint source would; the vehicle's
    #: geofence must stop it before the obstacle's zone
    setpoints_through: str | None = None


class SigningSettings(StrictModel):
    """MAVLink 2 signing: the shared secret as 64 hex digits, or a passphrase (hashed with SHA-256)."""

    key: str
    link_id: int = Field(default=0, ge=0, le=255)

    @field_validator("key")
    @classmethod
    def _valid(cls, value: str) -> str:
        signing_key(value)
        return value


class MavlinkVehicleSettings(StrictModel):
    #: pymavlink connection string; none: start the simulated vehicle on 127.0.0.1 (UDP)
    connection: str | None = None
    baud: int = 57600
    #: the vehicle's system id; none: the first vehicle heard
    system_id: int | None = Field(default=None, ge=1, le=255)
    gcs_system_id: int = Field(default=255, ge=1, le=255)
    gcs_component_id: int = Field(default=190, ge=1, le=255)  # MAV_COMP_ID_MISSIONPLANNER
    mode: Literal["mission", "offboard"] = "mission"
    #: mission items in MAV_FRAME_GLOBAL_RELATIVE_ALT (3; altitude above home) or MAV_FRAME_GLOBAL (0; AMSL),
    #: the current frames (their _INT twins 6 and 5 are deprecated); PX4 flies no local-frame mission
    mission_frame: Literal["global_relative_alt", "global"] = "global_relative_alt"
    #: the planned path's certified clearance (the vehicle a sphere of the plan's tip_radius) must be at
    #: least this everywhere, or the flight is refused before any motion (negative: always refused)
    safety_margin: Length = Field(default=0.0, ge=0.0)
    frame: FrameSettings = Field(default_factory=FrameSettings)
    cruise_speed: PositiveFloat = 1.0  # m/s
    acceleration: PositiveFloat = 1.0  # m/s^2, offboard profile
    vertical_speed: PositiveFloat = 0.5  # m/s, offboard profile
    #: offboard: how far the setpoint path rounds a corner of the planned path (its arcs' midpoints)
    corner_deviation: PositiveLength = 0.05
    #: mission waypoints' acceptance radius; also the arrival tolerance at the goal
    acceptance_radius: PositiveLength = 0.1
    #: Douglas-Peucker tolerance for turning the path into waypoints (0 keeps every waypoint)
    waypoint_tolerance: Length = 0.02
    takeoff: bool = True
    land: bool = True
    #: fly straight from where the vehicle is to the path's start (checked clear)
    approach: bool = True
    #: the unplanned legs (take-off, approach, landing) must keep this much clearance
    approach_clearance: Length = 0.1
    #: LOCAL_POSITION_NED rate requested from the vehicle (Hz)
    telemetry_rate: PositiveFloat = 20.0
    failsafe: Literal["land", "return", "hold"] = "land"
    #: the scene's safety as the vehicle's geofence (:mod:`.scene_fence`), uploaded before the mission
    fence: FenceSettings = Field(default_factory=FenceSettings)
    #: rally points (scene point names, or coordinates in the scene): a return goes to the nearest (RTL_TYPE)
    rally_points: list[str | Vec3] = Field(default_factory=list)
    rehearsal: Rehearsal = Field(default_factory=Rehearsal)
    heartbeat: HeartbeatSettings = Field(default_factory=HeartbeatSettings)
    timeouts: Timeouts = Field(default_factory=Timeouts)
    signing: SigningSettings | None = None
    #: the simulated vehicle (only without a connection); its faults rehearse the real ones
    sim: SimSettings | None = None
    #: run the simulated vehicle as a subprocess (the real program) or in a thread
    sim_process: Literal["subprocess", "thread"] = "subprocess"
    figure: bool = True
    #: write <stage>.tlog, the flight's telemetry log as MAVProxy writes it (pymavlink's tools, MAVExplorer, QGC)
    tlog: bool = True

    @field_validator("mission_frame", mode="before")
    @classmethod
    def _no_local_missions(cls, value):
        if value == "local_ned":
            raise ValueError(
                "local_ned is no longer offered: PX4 refuses mission items in local frames "
                "(MAV_MISSION_UNSUPPORTED_FRAME); use global_relative_alt (the default) or global"
            )
        return value

    @field_validator("connection")
    @classmethod
    def _connection(cls, value):
        return None if value is None else check_connection_string(value)

    @model_validator(mode="after")
    def _rehearsal_offboard(self):
        if self.rehearsal.setpoints_through is not None and self.mode != "offboard":
            raise ValueError("rehearsal.setpoints_through rehearses a rogue offboard stream: it needs mode: offboard")
        return self

    @model_validator(mode="after")
    def _sim_or_connection(self):
        if self.connection is not None and self.sim is not None:
            raise ValueError(
                "'sim' configures the simulated vehicle, which is started only without a 'connection'; "
                "remove one of them"
            )
        return self
