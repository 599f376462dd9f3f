"""Settings of the simulated MAVLink vehicle (``surgiplan-sim-vehicle``), faults included.

Plain SI numbers in the vehicle's own local NED frame (m, s, m/s): the
simulator is a separate program that knows nothing of scenes. In a pipeline
they sit under the ``mavlink_vehicle`` device's ``sim:`` key, so every fault
can be rehearsed from the pipeline file::

    settings:
      sim: {speed: 4, packet_loss: 0.2}                        # a poor radio link
      sim: {stop_answering: mission_upload}                     # the vehicle goes silent
      sim: {reject_mission: MAV_MISSION_NO_SPACE}               # the vehicle refuses
      sim: {heartbeat_loss: {at_s: 3}}                          # heartbeats stop in flight
      sim: {params: {MPC_XY_VEL_MAX: 1.0}}                       # a vehicle configured slower
      sim: {rates: {ATTITUDE: 0}}                                # telemetry rates (Hz) other than PX4's

Several settings are PX4 parameters as well (the ``params`` table of
:mod:`.params` names which): they are the parameters' values at power-up,
and a ground station that sets the parameter changes the simulation.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, NonNegativeFloat, PositiveFloat, field_validator, model_validator
from surgiplan.models import StrictModel
from surgiplan.plugins.devices.mavlink.link import enum_value, mavlink, signing_key


class StopAnswering(StrictModel):
    """Fall silent (send nothing, ignore everything) when ``step`` begins, after ``after`` of its messages."""

    step: Literal["connect", "fence_upload", "rally_upload", "mission_upload", "arming", "mode_change", "mission_start"]
    after: int = Field(default=0, ge=0)


class HeartbeatLoss(StrictModel):
    """Stop sending HEARTBEAT ``at_s`` seconds (vehicle time) after arming; ``all_telemetry``: stop everything."""

    at_s: NonNegativeFloat = 0.0
    all_telemetry: bool = False


class MissionRequests(StrictModel):
    """How the vehicle requests mission items: in a shuffled order, and/or some twice."""

    shuffle: bool = False
    repeat: float = Field(default=0.0, ge=0.0, le=1.0)


class Wind(StrictModel):
    """Mean wind (NED, m/s) plus gusts: an Ornstein-Uhlenbeck process per axis (std m/s, correlation s)."""

    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust: NonNegativeFloat = 0.0
    gust_time: PositiveFloat = 2.0


class Airframe(StrictModel):
    """The point-mass multirotor and its position controller (PX4-like cascaded P / PI gains)."""

    max_speed: PositiveFloat = 5.0  # m/s horizontal
    max_climb: PositiveFloat = 2.0  # m/s up
    max_descent: PositiveFloat = 1.5  # m/s down
    max_acceleration: PositiveFloat = 4.0  # m/s^2, thrust authority beyond gravity
    position_gain: PositiveFloat = 1.0  # 1/s (PX4 MPC_XY_P ~0.95)
    velocity_gain: PositiveFloat = 2.0  # 1/s (PX4 MPC_XY_VEL_P_ACC 1.8)
    velocity_integral: NonNegativeFloat = 0.4  # 1/s^2 (PX4 MPC_XY_VEL_I_ACC 0.4)
    #: aerodynamic drag (1/s): the wind pushes with drag * (wind - velocity)
    drag: NonNegativeFloat = 0.35
    #: mission and RTL cruise speed unless a DO_CHANGE_SPEED says otherwise (m/s)
    cruise_speed: PositiveFloat = 1.0
    landing_speed: PositiveFloat = 0.5  # m/s
    #: default acceptance radius of waypoints whose param2 is 0 (m)
    acceptance_radius: PositiveFloat = 0.3
    #: acceleration along mission and return legs (m/s^2; PX4 MPC_ACC_HOR)
    auto_acceleration: PositiveFloat = 2.0
    #: climb speed of a take-off (m/s; PX4 MPC_TKO_SPEED)
    takeoff_speed: PositiveFloat = 1.5
    #: vertical gains (PX4 MPC_Z_P, MPC_Z_VEL_P_ACC, MPC_Z_VEL_I_ACC); the horizontal ones above are MPC_XY_*
    position_gain_z: PositiveFloat = 1.0
    velocity_gain_z: PositiveFloat = 2.0
    velocity_integral_z: NonNegativeFloat = 0.4


class SimSettings(StrictModel):
    """The simulated vehicle (a PX4-like quadrotor)."""

    system_id: int = Field(default=1, ge=1, le=255)
    component_id: int = Field(default=1, ge=1, le=255)
    #: simulated seconds per wall-clock second (>1 runs faster than real time)
    speed: PositiveFloat = 1.0
    #: in offboard mode, never run past the newest setpoint's stamp (PX4 SITL's lockstep, here with the
    #: ground station; see mavlink_sim_offboard): a loaded machine slows a flight down, never changes it
    lockstep: bool = True
    #: how far (s) past the newest stamp the lockstepped clock may run; above 0 the flight depends on
    #: scheduling again (the setpoint in force is then extrapolated beyond the newest one)
    lockstep_horizon: NonNegativeFloat = 0.0
    #: physics step (s)
    step: PositiveFloat = 0.01
    #: HEARTBEAT rate (Hz, wall clock: the link's, not the physics')
    heartbeat_rate: PositiveFloat = 1.0
    #: telemetry rates (Hz of vehicle time, 0: off) other than PX4's defaults for a ground station link
    #: (MAVLINK_MODE_NORMAL: LOCAL_POSITION_NED 1, GLOBAL_POSITION_INT 5, ATTITUDE 15, ...; see telemetry.STREAMS)
    rates: dict[str, NonNegativeFloat] = Field(default_factory=dict)
    #: PX4 parameters at power-up (name -> value), over the settings they stand for
    params: dict[str, float] = Field(default_factory=dict)
    #: where the vehicle stands at power-up, local NED (m); the ground is at its z
    home: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: the EKF origin (GPS_GLOBAL_ORIGIN): latitude, longitude (deg), altitude AMSL (m)
    origin: tuple[float, float, float] = (47.397742, 8.545594, 488.0)
    #: standard deviation of the noise on reported positions (m)
    position_noise: NonNegativeFloat = 0.0
    airframe: Airframe = Field(default_factory=Airframe)
    wind: Wind = Field(default_factory=Wind)
    #: mission items the vehicle can store
    mission_capacity: int = Field(default=1000, ge=0)
    #: the vehicle's mission protocol timeout while waiting for an item (s) and its retries: as PX4,
    #: a request every 250 ms, and the transfer given up after 5 s without progress
    mission_timeout: PositiveFloat = 0.25
    mission_retries: int = Field(default=20, ge=0)
    #: offboard setpoints older than this stop offboard control (PX4 COM_OF_LOSS_T); wall s with lockstep
    offboard_timeout: PositiveFloat = 1.0
    #: what offboard loss does (PX4 COM_OBL_RC_ACT: 0, 1, 2, 5 hold, 3 return, 4 land)
    offboard_loss_action: int = Field(default=0, ge=0, le=5)
    #: take-off altitude above home when a NAV_TAKEOFF gives none (m; PX4 MIS_TAKEOFF_ALT)
    takeoff_altitude: PositiveFloat = 2.5
    #: a return first climbs to this height above home, if lower (m; PX4 RTL_RETURN_ALT)
    rtl_return_altitude: NonNegativeFloat = 60.0
    #: auto-disarm after landing (s; PX4 COM_DISARM_LAND) and without take-off (wall s; COM_DISARM_PRFLT)
    disarm_after_landing: PositiveFloat = 1.0
    disarm_before_takeoff: PositiveFloat = 10.0
    #: fence and rally-point items the vehicle can store (PX4 on NuttX: 64 fence points, 8 safe points)
    fence_capacity: int = Field(default=64, ge=0)
    rally_capacity: int = Field(default=8, ge=0)
    #: what a geofence breach does (PX4 GF_ACTION: 0 none, 1 warning, 2 hold, 3 return, 4 terminate, 5 land)
    geofence_action: int = Field(default=2, ge=0, le=5)
    #: act on the breach predicted a braking distance ahead (PX4 GF_PREDICT; PX4's default 0)
    geofence_predict: int = Field(default=0, ge=0, le=1)
    #: fence-wide limits from home (m; PX4 GF_MAX_HOR_DIST, GF_MAX_VER_DIST; 0: none)
    geofence_max_horizontal: NonNegativeFloat = 0.0
    geofence_max_vertical: NonNegativeFloat = 0.0
    #: where a return goes (PX4 RTL_TYPE: 0 the nearest of home and the rally points, 1 the nearest rally
    #: point, home only without one)
    rtl_type: int = Field(default=0, ge=0, le=1)
    #: MAVLink 2 signing key (64 hex digits or a passphrase); unsigned frames are then rejected
    signing_key: str | None = None
    seed: int = 0
    # ---------------------------------------------------------------- faults
    #: fraction of messages dropped in each direction
    packet_loss: float = Field(default=0.0, ge=0.0, lt=1.0)
    stop_answering: StopAnswering | None = None
    #: refuse every mission upload with this MAV_MISSION_RESULT (name or number) ...
    reject_mission: str | int | None = None
    #: ... at this item (default: at MISSION_COUNT)
    reject_at_item: int | None = Field(default=None, ge=0)
    heartbeat_loss: HeartbeatLoss | None = None
    mission_requests: MissionRequests = Field(default_factory=MissionRequests)
    #: refuse arming with this reason (a STATUSTEXT and MAV_RESULT_TEMPORARILY_REJECTED)
    refuse_arming: str | None = None
    #: behave as a vehicle without these MAV_PROTOCOL_CAPABILITY bits (names without the prefix): they are
    #: not announced, and MISSION_INT withheld makes it request items with MISSION_REQUEST (the deprecated
    #: float items), SET_POSITION_TARGET_LOCAL_NED withheld makes it ignore offboard setpoints
    capabilities_withheld: list[str] = Field(default_factory=list)

    @field_validator("stop_answering", mode="before")
    @classmethod
    def _step_shorthand(cls, value: Any) -> Any:
        return {"step": value} if isinstance(value, str) else value

    @field_validator("reject_mission")
    @classmethod
    def _known_result(cls, value):
        if value is None:
            return None
        result = enum_value("MAV_MISSION_RESULT", value)
        if result == 0:
            raise ValueError("MAV_MISSION_ACCEPTED is not a rejection")
        return result

    @field_validator("params")
    @classmethod
    def _known_params(cls, value):
        from .params import validate_overrides  # the table lives with the protocol

        return validate_overrides(value)

    @field_validator("rates")
    @classmethod
    def _known_streams(cls, value):
        from .telemetry import STREAMS

        unknown = sorted(set(value) - set(STREAMS))
        if unknown:
            raise ValueError(f"unknown message {unknown[0]!r} in rates; the streams are: {', '.join(STREAMS)}")
        return value

    @field_validator("capabilities_withheld")
    @classmethod
    def _known_capabilities(cls, value):
        names = {
            e.name.removeprefix("MAV_PROTOCOL_CAPABILITY_") for e in mavlink.enums["MAV_PROTOCOL_CAPABILITY"].values()
        }
        for name in value:
            if name.upper().removeprefix("MAV_PROTOCOL_CAPABILITY_") not in names:
                raise ValueError(f"unknown capability '{name}'; choose among: {', '.join(sorted(names))}")
        return [name.upper().removeprefix("MAV_PROTOCOL_CAPABILITY_") for name in value]

    @field_validator("signing_key")
    @classmethod
    def _key(cls, value):
        if value is not None:
            signing_key(value)
        return value

    @model_validator(mode="after")
    def _consistent(self):
        if self.reject_at_item is not None and self.reject_mission is None:
            raise ValueError("reject_at_item needs reject_mission (the MAV_MISSION_RESULT to refuse with)")
        return self
