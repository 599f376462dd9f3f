"""``mavlink_vehicle``: fly a planned path on a MAVLink 2 vehicle (a simulated one by default).

Paper 000 (Jain, Hong & Rozenblit 2019) ends (§5) by proposing its safe
planner for "an autonomous quadrotor when it is required to maintain a
certain distance from the obstacle, but due to the presence of some
unavoidable passages, like Critical Regions, it might fail". This device
makes that real: an ``execute`` stage flies the path of a ``safe_prm`` (or
any R3) plan stage on a vehicle reached through pymavlink, and reports what
was flown, re-measured against the scene.

Lifecycle (:class:`surgiplan.Device`, ros2_control's):

* ``configure``: the simulated vehicle is started (``surgiplan-sim-vehicle``
  on a free 127.0.0.1 UDP port, :mod:`.local_simulator`) unless
  ``connection`` names a real one; the link is opened (MAVLink 2, signed
  when a key is given); the first
  HEARTBEAT adopts the vehicle (no heartbeat: a clear error); its
  AUTOPILOT_VERSION says which protocols it honours (a mission needs
  MISSION_ITEM_INT or at least MISSION_ITEM, offboard needs
  SET_POSITION_TARGET_LOCAL_NED: refused otherwise, naming the bit);
  telemetry rates are requested (LOCAL_POSITION_NED at ``telemetry_rate``,
  the high-rate streams it does not read off); the EKF origin and home are read
  (GPS_GLOBAL_ORIGIN, HOME_POSITION) for the global mission frames; the PX4
  parameters the flight relies on are read (:data:`RELIED_ON`);
* ``activate``: the vehicle must report a local position;
* ``execute``: refused before any motion when the planned path's certified
  clearance (the vehicle a sphere of the plan's ``tip_radius``) is negative
  or below ``safety_margin`` anywhere, whatever planner produced it, or when
  the vehicle's limits (its parameters) are tighter than the flight's
  profile (naming the parameter), or when the scene's geofence cannot be
  made for the route (:mod:`.scene_fence`: beyond the vehicle's capacity,
  the route outside the bounds); then the parameters the failsafe relies on
  are set (and read back), the fence and rally points uploaded and verified
  (:mod:`.safety`), :mod:`.flight` (route, mission upload verified by
  download, or offboard stream, arming and modes with their
  acknowledgements, the watch with the failsafe), then :mod:`.report`
  (tracking error, flown clearance, ``<stage>.csv`` and ``<stage>.png``, named after the stage);
* ``cleanup``/``shutdown``: the link is closed, the simulated vehicle
  stopped.

Settings (:mod:`.settings`; lengths in the pipeline's ``length_unit``; speeds m/s, times s)::

    connection: udpin:127.0.0.1:14550   # default: none, i.e. start the simulated vehicle
    mode: mission                        # or offboard (SET_POSITION_TARGET_LOCAL_NED stream)
    frame: {local_origin: [2, 6, 0], heading: 90 deg}   # the vehicle's NED origin in the scene
    mission_frame: global_relative_alt   # or global (AMSL altitudes); frame 3 or 0
    cruise_speed: 1.0
    safety_margin: 0.1                   # the planned path must keep this much (else refused)
    failsafe: land                       # on heartbeat loss: land, return or hold
    fence: {action: hold, predict: false}  # the scene's geofence (default on; enabled: false: none)
    rally_points: [pad_b]                # returns go to the nearest of home and these
    signing: {key: 64 hex digits or a passphrase}
    sim: {speed: 4, packet_loss: 0.2}    # the simulated vehicle, faults included
"""

from __future__ import annotations

import logging
import math

import numpy as np
from surgiplan.clearance import intervals
from surgiplan.devices import Device, ExecutionReport, Trajectory
from surgiplan.errors import ConfigError
from surgiplan.plugins.devices.mavlink.sim.settings import SimSettings
from surgiplan.progress import NullProgress
from surgiplan.status import ExecuteStatus

from .conventions import LocalFrame, MapProjection
from .flight import Flight, Refusal, build_route, check_path_clearance
from .gcs import GroundStation
from .link import Endpoint, VehicleError, enum_name, mavlink, signing_key
from .local_simulator import LocalSimulator
from .report import describe, fence_breaches, fence_position_metrics, flight_figure, flight_metrics, write_flight_csv
from .safety import upload_safety
from .scene_fence import FenceRefusal, rally_positions, scene_fence
from .settings import MavlinkVehicleSettings
from .tlog import TelemetryLog
from .vehicle_state import capability_names

logger = logging.getLogger(__name__)

#: the PX4 parameters the flight relies on (read at configure; see MavlinkVehicle._limits)
RELIED_ON = (
    "MPC_XY_VEL_MAX",  # top horizontal speed: not below cruise_speed
    "MPC_Z_VEL_MAX_UP",  # top climb speed: not below vertical_speed (offboard)
    "MPC_Z_VEL_MAX_DN",  # top descent speed: likewise
    "MPC_ACC_HOR_MAX",  # thrust authority: not below acceleration (offboard)
    "COM_OF_LOSS_T",  # offboard loss timeout: several keep-alive periods at least
    "COM_OBL_RC_ACT",  # offboard loss action: set to the failsafe (offboard)
    "RTL_RETURN_ALT",  # a return climbs to this first: not above the route (failsafe return)
)
#: ... and with the fence on (GF_PREDICT only when fence.predict: PX4 1.16 has no such parameter)
FENCE_PARAMETERS = ("GF_ACTION", "GF_MAX_VER_DIST")
#: streams PX4 sends a ground station by default that this device does not read: switched off
UNUSED_STREAMS = (
    mavlink.MAVLINK_MSG_ID_ATTITUDE,  # 15 Hz
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,  # 5 Hz (LOCAL_POSITION_NED is what it flies by)
    mavlink.MAVLINK_MSG_ID_VFR_HUD,  # 4 Hz
)
#: COM_OBL_RC_ACT for each failsafe
OFFBOARD_LOSS_ACTION = {"land": 4, "return": 3, "hold": 5}
#: the offboard stream keeps the vehicle fed at 20 Hz of wall clock; a COM_OF_LOSS_T below this is too tight
MIN_OFFBOARD_TIMEOUT = 0.2
#: capability bits each mode needs
NEEDS = {
    "offboard": ("SET_POSITION_TARGET_LOCAL_NED", mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED),
}


class MavlinkVehicle(Device):
    """A MAVLink 2 vehicle (PX4 conventions) flying R3 paths; simulated unless a connection is given."""

    Settings = MavlinkVehicleSettings

    def __init__(self, settings: MavlinkVehicleSettings) -> None:
        super().__init__(settings)
        self.frame = LocalFrame(tuple(settings.frame.local_origin), settings.frame.heading)
        self.endpoint: Endpoint | None = None
        self.gcs: GroundStation | None = None
        self.simulator: LocalSimulator | None = None
        self.geo: tuple[MapProjection, float] | None = None
        self.connection = settings.connection
        #: the vehicle's AUTOPILOT_VERSION capability names, its parameters read, those set
        self.capabilities: list[str] = []
        self.vehicle_params: dict[str, float | int] = {}
        self.params_set: dict[str, float | int] = {}
        #: upload as the deprecated MISSION_ITEM (a vehicle without MISSION_INT)
        self.legacy_missions = False

    # ------------------------------------------------------------------ the simulated vehicle
    def _sim_settings(self) -> SimSettings:
        s = self.settings
        sim = s.sim or SimSettings()
        if s.signing is not None and sim.signing_key is None:
            sim = sim.model_copy(update={"signing_key": s.signing.key})
        return sim

    def _start_simulator(self) -> str:
        s = self.settings
        self.simulator = LocalSimulator(self._sim_settings(), s.sim_process, s.timeouts.connect)
        return self.simulator.start()

    def _stop_simulator(self) -> None:
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, context) -> None:
        s = self.settings
        try:
            connection = s.connection if s.connection is not None else self._start_simulator()
            self.connection = connection
            key = signing_key(s.signing.key) if s.signing is not None else None
            self.endpoint = Endpoint(
                connection,
                system_id=s.gcs_system_id,
                component_id=s.gcs_component_id,
                baud=s.baud,
                key=key,
                link_id=s.signing.link_id if s.signing else 0,
            )
            if s.tlog and context is not None:
                self.endpoint.tlog = TelemetryLog(context.output_dir / f"{context.name}.tlog")
            t = s.timeouts
            self.gcs = GroundStation(
                self.endpoint,
                heartbeat_period=s.heartbeat.period,
                missed_heartbeats=s.heartbeat.missed,
                command_timeout=t.command,
                command_retries=t.command_retries,
                mission_timeout=t.mission,
                mission_retries=t.mission_retries,
                item_timeout=t.mission_item,
                upload_attempts=t.upload_attempts,
            )
            vehicle = self.gcs.connect(t.connect, s.system_id)
            if vehicle.autopilot != mavlink.MAV_AUTOPILOT_PX4:
                raise VehicleError(
                    f"the vehicle's autopilot is {_autopilot(vehicle.autopilot)}; this device speaks PX4's "
                    "conventions (custom modes, mission item 0 is a mission item): use PX4 or the simulated vehicle",
                    step="connect",
                )
            self._check_capabilities()
            self.gcs.step = "telemetry setup"
            self.gcs.set_message_interval(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, s.telemetry_rate)
            for message_id in UNUSED_STREAMS:  # bandwidth a radio link needs for the rest
                self.gcs.stop_message(message_id)
            self.gcs.step = "reading the EKF origin"
            origin = self.gcs.request_message("GPS_GLOBAL_ORIGIN", mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, t.mode)
            home = self.gcs.request_message("HOME_POSITION", mavlink.MAVLINK_MSG_ID_HOME_POSITION, t.mode)
            #: projection about the EKF origin, home's local down (m), the origin's altitude AMSL (m)
            self.geo = (
                MapProjection(origin.latitude * 1e-7, origin.longitude * 1e-7),
                float(home.z),
                origin.altitude * 1e-3,
            )
            self.gcs.step = "reading parameters"
            names = RELIED_ON
            if s.fence.enabled:
                names += FENCE_PARAMETERS + (("GF_PREDICT",) if s.fence.predict else ())
            self.vehicle_params = {name: value for name, (value, _) in self.gcs.read_params(names).items()}
        except BaseException:
            self._release()
            raise

    def _check_capabilities(self) -> None:
        """AUTOPILOT_VERSION's capability bits: the protocols this flight needs, or a refusal naming the bit."""
        gcs, s = self.gcs, self.settings
        gcs.step = "capabilities"
        try:
            gcs.autopilot_version(s.timeouts.mode)
        except VehicleError as exc:
            raise VehicleError(
                f"{exc.detail}; without AUTOPILOT_VERSION its capabilities (mission protocol, offboard) are unknown",
                step="capabilities",
            ) from None
        bits = gcs.vehicle.capabilities
        self.capabilities = capability_names(bits)
        missing = []
        if not bits & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2:
            missing.append("MAVLINK2")
        if s.fence.enabled and not bits & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE:
            missing.append("MISSION_FENCE (for the geofence; fence.enabled: false flies without)")
        if s.rally_points and not bits & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY:
            missing.append("MISSION_RALLY (for rally_points)")
        if s.mode == "mission":
            if not bits & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT:
                if bits & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT:
                    self.legacy_missions = True  # the deprecated MISSION_ITEM it is (float latitudes: ~0.5 m)
                else:
                    missing.append("MISSION_INT (or MISSION_FLOAT)")
        elif s.mode in NEEDS and not bits & NEEDS[s.mode][1]:
            missing.append(NEEDS[s.mode][0])
        if missing:
            raise VehicleError(
                f"the vehicle's AUTOPILOT_VERSION lacks MAV_PROTOCOL_CAPABILITY_{', '.join(missing)}, which "
                f"mode {s.mode} needs (it has: {', '.join(self.capabilities) or 'none'})",
                step="capabilities",
            )

    def on_activate(self) -> None:
        gcs = self.gcs
        gcs.step = "activate"
        gcs.wait_for(
            lambda: gcs.vehicle.position is not None,
            self.settings.timeouts.mode,
            "the vehicle reported no LOCAL_POSITION_NED (no local position estimate?)",
        )

    def on_cleanup(self) -> None:
        self._release()

    def on_shutdown(self) -> None:
        self._release()

    def _release(self) -> None:
        if self.endpoint is not None:
            self.endpoint.close()
            tlog, self.endpoint.tlog = self.endpoint.tlog, None
            self.endpoint = None
            if tlog is not None:
                try:
                    self.recordings.append(tlog.close().name)
                except OSError as exc:  # a full disk must not hide what the flight did
                    tlog.abandon()
                    logger.warning("could not write the telemetry log %s: %s", tlog.path, exc)
        self._stop_simulator()

    # ------------------------------------------------------------------ execution
    def run(self, trajectory: Trajectory) -> ExecutionReport:
        s = self.settings
        gcs = self.gcs
        if trajectory.space.kind != "r3":
            raise ConfigError(
                f"mavlink_vehicle flies paths of the r3 space (the vehicle a sphere of tip_radius); plan stage "
                f"'{trajectory.source}' planned in '{trajectory.space.kind}'"
            )
        context = self.context
        # the plan's clearance threshold and critical regions, as the plan stage measured them
        threshold = float(trajectory.clearance_threshold) if trajectory.clearance_threshold is not None else None
        critical = intervals(trajectory.critical_regions)
        vehicle = gcs.vehicle
        position = self.frame.from_ned(np.asarray(vehicle.position.position))
        on_ground = vehicle.on_ground or (
            not vehicle.armed and vehicle.landed_state == mavlink.MAV_LANDED_STATE_UNDEFINED
        )
        try:
            check_path_clearance(trajectory, s.safety_margin)
            self._limits()
            # the ground: where the vehicle stands, or (airborne) the local origin's height, its EKF's ground
            ground = float(position[2]) if on_ground else float(self.frame.origin[2])
            route = build_route(trajectory, position, on_ground, ground, s, threshold)
            # the scene as the pipeline has it (the plan's space is bounded to its own layer)
            scene = getattr(context, "scene", None) or trajectory.space.scene
            radius = float(getattr(trajectory.space, "tip_radius", 0.0))
            fence = scene_fence(scene, route.points, radius, threshold, s.fence) if s.fence.enabled else None
            rally = rally_positions(scene, s.rally_points)
            rogue = self._rogue_target(scene, route)
        except (Refusal, FenceRefusal) as exc:
            return ExecutionReport(
                ExecuteStatus.REFUSED,
                {"refused": True, "vehicle_parameters": self.vehicle_params},
                message=f"refused before any motion: {exc}",
            )
        self._set_failsafe_parameters(route)
        projection, home_down, _ = self.geo
        home_z = float(self.frame.from_ned(np.array([0.0, 0.0, home_down]))[2])
        safety = upload_safety(
            gcs, self.frame, projection, home_z, fence, s.fence, rally, self.params_set, self.legacy_missions
        )
        flight = Flight(gcs, s, self.frame, route, context.progress if context else NullProgress(), self.geo)
        flight.legacy_missions = self.legacy_missions
        flight.rogue = rogue
        flight.log.metrics.update(safety)
        log = flight.fly_offboard() if s.mode == "offboard" else flight.fly_mission()
        gcs.recording = False
        return self._report(trajectory, route, flight, log, threshold, critical, fence)

    def _rogue_target(self, scene, route) -> np.ndarray | None:
        """The rehearsal's rogue setpoints aim at this point (local NED): an obstacle's centre at the path's
        start altitude; None without the rehearsal."""
        name = self.settings.rehearsal.setpoints_through
        if name is None:
            return None
        if name not in scene.obstacle_names:
            known = ", ".join(scene.obstacle_names)
            raise FenceRefusal(f"rehearsal.setpoints_through: the scene has no obstacle '{name}' (it has: {known})")
        low, high = scene.obstacle(name).aabb()
        target = 0.5 * (low + high)
        target[2] = route.points[route.path_first][2]
        return self.frame.to_ned(target)

    def _link_metrics(self) -> dict:
        """Messages each way and how many were lost: the vehicle's by the gaps in its sequence numbers (any
        vehicle), ours as the simulated vehicle counted them (None for a real one)."""
        link = self.endpoint.stats.to_json()
        lost_in = self.endpoint.lost_in
        link["messages_dropped_in"] = lost_in
        link["link_loss_in"] = lost_in / max(lost_in + self.endpoint.counted_in, 1)
        sim = self.simulator.link_statistics() if self.simulator is not None else None
        if sim is not None:
            link["messages_dropped_out"] = sim["injected_drops_in"] + sim["lost_in"]
            link["link_loss_out"] = link["messages_dropped_out"] / max(link["messages_sent"], 1)
            link["vehicle_link"] = sim
        else:
            link["messages_dropped_out"] = None
        return link

    def _limits(self) -> None:
        """Refuse (naming the parameter) when the vehicle's limits are tighter than the flight's profile."""
        s, params = self.settings, self.vehicle_params
        checks = [("MPC_XY_VEL_MAX", s.cruise_speed, "cruise_speed", "m/s")]
        if s.mode == "offboard":
            checks += [
                ("MPC_Z_VEL_MAX_UP", s.vertical_speed, "vertical_speed", "m/s"),
                ("MPC_Z_VEL_MAX_DN", s.vertical_speed, "vertical_speed", "m/s"),
                ("MPC_ACC_HOR_MAX", s.acceleration, "acceleration", "m/s^2"),
            ]
        for name, wanted, setting, unit in checks:
            if name in params and params[name] < wanted - 1e-6:
                raise Refusal(
                    f"the vehicle's {name} is {params[name]:g} {unit}, below the flight's {setting} {wanted:g} "
                    f"{unit}: it cannot fly the profile as planned (lower {setting}, or raise {name})"
                )
        if s.mode == "offboard" and params.get("COM_OF_LOSS_T", math.inf) < MIN_OFFBOARD_TIMEOUT:
            raise Refusal(
                f"the vehicle's COM_OF_LOSS_T is {params['COM_OF_LOSS_T']:g} s: offboard control would be lost "
                f"between setpoints (at least {MIN_OFFBOARD_TIMEOUT:g} s: the stream keeps a 50 ms period)"
            )

    def _set_failsafe_parameters(self, route) -> None:
        """Set what the failsafe relies on: a return no higher than the route, offboard loss = the failsafe."""
        s, gcs = self.settings, self.gcs
        gcs.step = "setting parameters"
        wanted: dict[str, tuple[float | int, int]] = {}
        if s.failsafe == "return" and "RTL_RETURN_ALT" in self.vehicle_params:
            # a return climbs to RTL_RETURN_ALT above home first: not above the highest point of the route
            home_down = self.geo[1]
            top = math.floor((home_down - float(np.min(self.frame.to_ned(route.points)[:, 2]))) * 100) / 100
            if self.vehicle_params["RTL_RETURN_ALT"] > top:
                wanted["RTL_RETURN_ALT"] = (max(top, 0.0), mavlink.MAV_PARAM_TYPE_REAL32)
        if s.mode == "offboard" and "COM_OBL_RC_ACT" in self.vehicle_params:
            action = OFFBOARD_LOSS_ACTION[s.failsafe]
            if self.vehicle_params["COM_OBL_RC_ACT"] != action:
                wanted["COM_OBL_RC_ACT"] = (action, mavlink.MAV_PARAM_TYPE_INT32)
        for name, (value, kind) in wanted.items():
            self.params_set[name] = self.vehicle_params[name] = gcs.set_param(name, value, kind)

    def _report(self, trajectory, route, flight, log, threshold, critical, fence=None) -> ExecutionReport:
        s = self.settings
        samples = self.gcs.samples
        t = np.array([x.time for x in samples])
        ned = np.array([x.position for x in samples]).reshape(-1, 3)
        flown = self.frame.from_ned(ned)
        velocity = self.frame.vector_from_ned(np.array([x.velocity for x in samples]).reshape(-1, 3))
        planned = trajectory.space.tip(np.atleast_2d(trajectory.path))
        setpoints = None
        if log.profile is not None and len(t):
            setpoints = self.frame.from_ned(log.profile.sample(t - log.profile_start)[0])
            # only while the stream flies the profile: before it the vehicle takes off from its pad, after it
            # it lands (NAV_LAND), and "the setpoint" is then the profile's end, which it leaves on purpose
            since = t - log.profile_start
            setpoints[(since < 0) | (since > log.profile.duration) | (t > log.stopped_at)] = np.nan
        metrics, arrays = flight_metrics(
            t, flown, velocity, trajectory.space, planned, log.path_window, threshold, critical, setpoints
        )
        metrics = {
            "mode": s.mode,
            "connection": self.connection,
            "simulated": s.connection is None,
            **route.metrics,
            **log.metrics,
            **metrics,
            **self._link_metrics(),
            "heartbeats_received": self.gcs.vehicle.heartbeats,
            "autopilot_capabilities": self.capabilities,
            "vehicle_parameters": self.vehicle_params,
            "parameters_set": self.params_set,
            "setpoints_sent": self.endpoint.stats.sent["SET_POSITION_TARGET_LOCAL_NED"],
            "signed": self.endpoint.signed,
        }
        if len(flown):
            metrics["final_position_error_m"] = float(np.linalg.norm(flown[-1] - route.points[-1]))
        breaches = fence_breaches(self.gcs.vehicle.fence_events, t, flown)
        if fence is not None:
            metrics["fence_events"] = breaches
            if len(flown):
                metrics.update(fence_position_metrics(fence, trajectory.space, flown[-1]))
        files: list[str] = []
        context = self.context
        if context is not None and len(t):
            name = context.name
            write_flight_csv(context.output_dir / f"{name}.csv", t, flown, velocity, arrays)
            files.append(f"{name}.csv")
            if s.figure:
                title = f"{name} (mavlink_vehicle, {s.mode}): {log.status}; {describe(metrics)}"
                flight_figure(
                    context.output_dir / f"{name}.png",
                    trajectory.space.scene,
                    planned,
                    route.points,
                    t,
                    flown,
                    arrays,
                    metrics,
                    threshold,
                    critical,
                    title,
                    link=np.array(self.gcs.vehicle.link) if self.gcs.vehicle.link else None,
                    link_text=_link_text(metrics),
                    zones=fence.zones if fence is not None else None,
                    breaches=breaches,
                    setpoints=setpoints,
                )
                files.append(f"{name}.png")
        annotations: dict = {"zones": fence.annotation()} if fence is not None else {}
        if len(t):  # report.html's time bar: the flight on the vehicle's clock
            annotations["timeline"] = {
                "t": t.tolist(),
                "tip": flown.tolist(),
                "clearance": arrays["clearance"].tolist(),
            }  # its events are the faults (metrics), which the report marks on this time axis
        flown_path = flown if len(flown) else None
        return ExecutionReport(log.status, metrics, flown_path, log.faults, log.message, files, annotations)


def _link_text(metrics: dict) -> str:
    """The link's totals for the figure: losses each way and what the mission upload had to repeat."""
    text = f"lost: {metrics['messages_dropped_in']} of the vehicle's messages ({100 * metrics['link_loss_in']:.1f} %)"
    if metrics.get("messages_dropped_out") is not None:
        text += f", {metrics['messages_dropped_out']} of ours ({100 * metrics['link_loss_out']:.1f} %)"
    if "upload_requests" in metrics:
        text += (
            f"\nupload: {metrics['upload_requests']} requests for {metrics['mission_items']} items, "
            f"{metrics['upload_repeated_requests']} repeated, {metrics['upload_retransmissions']} re-sent"
        )
    return text


def _autopilot(value: int) -> str:
    return enum_name("MAV_AUTOPILOT", value)
