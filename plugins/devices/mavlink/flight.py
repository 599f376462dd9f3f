"""Flying a planned path on a MAVLink vehicle: the route, the mission or setpoint stream, the watch.

The route is the planned path as the vehicle flies it: a vertical take-off
from where the vehicle stands to the path's altitude, a straight approach to
the path's start (when it does not stand right below it), the path's
waypoints (Douglas-Peucker thinned, every kept chord certified against the
scene, as safe_prm does), and a vertical landing below the goal. The legs
the planner did not plan (take-off, approach, landing) are checked against
the scene before anything moves; a leg closer than ``approach_clearance`` to
an obstacle refuses the flight.

Two ways to fly it (the ``mode`` setting):

* ``mission``: a mission (DO_CHANGE_SPEED, NAV_TAKEOFF, NAV_WAYPOINT...,
  NAV_LAND) in MAV_FRAME_GLOBAL_RELATIVE_ALT (or MAV_FRAME_GLOBAL),
  uploaded with the mission protocol and downloaded back to check that the
  vehicle holds what was sent (else the flight does not start), then hold
  mode, arming and mission mode (which starts it, exactly once), each
  acknowledged; progress from MISSION_CURRENT and MISSION_ITEM_REACHED;
* ``offboard``: the route time-parameterised (:mod:`.mavlink_profile`) and
  streamed as SET_POSITION_TARGET_LOCAL_NED (position, velocity and
  acceleration) up to the path's end, then NAV_LAND, on the *vehicle's* clock (:mod:`.mavlink_stream`): one
  setpoint for every 50 ms of vehicle time, kept 0.1 s ahead of the newest
  LOCAL_POSITION_NED, plus a 20 Hz wall-clock keep-alive, so the stream
  follows the vehicle at any simulation speed; PX4's rule is kept: setpoints
  flow before the switch to offboard mode and arming.

During the flight the vehicle's heartbeats are watched; when they stop the
configured failsafe (land, return, hold) is commanded and the flight ends
``stopped`` with the fault in the report. A Ctrl-C commands the failsafe too.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from surgiplan.errors import SurgiplanError

from .conventions import LocalFrame, px4_mode_command
from .gcs import GroundStation, LinkLost
from .link import VehicleError, enum_name, mavlink
from .mission import MissionItem, compare_missions
from .profile import TimedPath
from .stream import SetpointStream

#: how long (s of vehicle time) the setpoints flow before the switch to offboard mode: 10 grid setpoints,
#: so that a lossy link (20 % lost) still delivers some before the vehicle judges the stream
SETPOINTS_BEFORE_SWITCH = 0.5
#: how long a landing failsafe waits, once the vehicle says it landed, for the position report after it: this many
#: report periods (``telemetry_rate``), at least :data:`TOUCHDOWN_REPORT_S` s
TOUCHDOWN_REPORTS = 3
TOUCHDOWN_REPORT_S = 1.0


class Refusal(SurgiplanError):
    """The flight will not start; the message says why.

    A user error (exit status 2, :class:`~surgiplan.errors.SurgiplanError`'s): the plan or the settings ask
    for a flight this vehicle must not fly (too little clearance, a profile beyond its limits). The device
    reports it as a refused execution before any motion.
    """


def check_path_clearance(trajectory, margin: float) -> None:
    """Refuse a planned path whose certified clearance is negative or below ``margin`` anywhere.

    Each straight segment of the path is measured exactly (the vehicle a sphere of the space's
    ``tip_radius`` swept along it: a capsule against every obstacle), whatever planner produced it; the
    first offending segment is named with its clearance and the obstacle.
    """
    space = trajectory.space
    path = space.tip(np.atleast_2d(trajectory.path))
    if len(path) < 2:
        return
    clearance = space.segment_clearance(path[:-1], path[1:])
    bad = np.flatnonzero((clearance < margin) | (clearance < 0) | ~np.isfinite(clearance))
    if not len(bad):
        return
    i = int(bad[0])
    nearest = int(space.scene.segment_distance(path[i][None], path[i + 1][None])[1][0])
    what = f"'{space.scene.obstacles[nearest].name}'" if nearest >= 0 else "an obstacle"
    how = "collides with" if clearance[i] < 0 else "passes"
    radius = getattr(space, "tip_radius", 0.0)
    limit = f"below safety_margin {margin:g} m" if clearance[i] >= 0 else "a collision"
    raise Refusal(
        f"segment {i} of the planned path (waypoints {i} to {i + 1}: {np.round(path[i], 3).tolist()} to "
        f"{np.round(path[i + 1], 3).tolist()} m) {how} {what}: certified clearance {clearance[i]:.3f} m for the "
        f"vehicle's {radius:g} m radius, {limit} ({len(bad)} of {len(clearance)} segments below it; "
        f"plan stage '{trajectory.source}')"
    )


@dataclass
class Route:
    """The flight as a polyline in scene coordinates, and where the planned path lies in it."""

    points: np.ndarray  # (n, 3) m, scene frame
    path_first: int  # index of the planned path's first waypoint
    path_last: int
    takeoff: bool
    land: bool
    metrics: dict[str, Any] = field(default_factory=dict)

    @property
    def path(self) -> np.ndarray:
        return self.points[self.path_first : self.path_last + 1]


def build_route(trajectory, vehicle: np.ndarray, on_ground: bool, ground_z: float, settings, threshold) -> Route:
    """The route from the vehicle's position through the planned path; :class:`Refusal` if a leg is not clear."""
    from surgiplan.paths import thin

    space = trajectory.space
    path = space.tip(np.atleast_2d(trajectory.path))
    metrics: dict[str, Any] = {"planned_waypoints": len(path)}
    if len(path) >= 2:
        planned = space.segment_clearance(path[:-1], path[1:])
        if settings.waypoint_tolerance > 0 and len(path) >= 3:
            limit = planned if threshold is None else np.minimum(planned, threshold)
            margins = np.clip(limit - settings.waypoint_tolerance, 0.0, None)
            path, _ = thin(space, path, margins, settings.waypoint_tolerance)
        metrics["route_path_min_clearance_m"] = float(np.min(space.segment_clearance(path[:-1], path[1:])))
    metrics["waypoints"] = len(path)
    start, goal = path[0], path[-1]
    points = [vehicle]
    if on_ground:
        if not settings.takeoff:
            raise Refusal("the vehicle is on the ground and takeoff is false")
        points.append(np.array([vehicle[0], vehicle[1], start[2]]))
    gap = float(np.linalg.norm(points[-1] - start))
    if gap > 1e-3 and not settings.approach:
        raise Refusal(f"the vehicle is {gap:.2f} m from the path's start and approach is false")
    if gap <= 1e-3 and on_ground:
        points.pop()  # the take-off ends at the path's start
    first = len(points)
    points.extend(path)
    last = len(points) - 1
    if settings.land:
        points.append(np.array([goal[0], goal[1], ground_z]))
    points = np.asarray(points, float)
    legs = [(i, "takeoff" if i == 0 and on_ground else "approach") for i in range(first)]
    if settings.land:
        legs.append((last, "landing"))
    for i, name in legs:
        clearance = float(space.segment_clearance(points[i][None], points[i + 1][None])[0])
        metrics[f"{name}_clearance_m"] = clearance
        if clearance < settings.approach_clearance:
            nearest = int(space.scene.segment_distance(points[i][None], points[i + 1][None])[1][0])
            what = space.scene.obstacles[nearest].name if nearest >= 0 else "an obstacle"
            raise Refusal(
                f"the {name} leg from {np.round(points[i], 3).tolist()} to {np.round(points[i + 1], 3).tolist()} m "
                f"passes {clearance:.3f} m from '{what}', less than approach_clearance "
                f"{settings.approach_clearance:g} m"
            )
    return Route(points, first, last, on_ground, settings.land, metrics)


@dataclass
class FlightLog:
    """What happened: samples (vehicle time s, NED m, NED m/s), events, faults, the outcome."""

    status: str = "completed"
    message: str = ""
    samples: list = field(default_factory=list)
    faults: list[dict[str, Any]] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)
    #: vehicle times (s) when the path's first and last waypoints were reached (the tracked stretch)
    path_window: tuple[float, float] = (0.0, math.inf)
    metrics: dict[str, Any] = field(default_factory=dict)
    #: offboard: the timed route and the vehicle time it started at
    profile: TimedPath | None = None
    profile_start: float = 0.0
    #: vehicle time (s) the vehicle's geofence took over (inf: it did not)
    stopped_at: float = math.inf


class Flight:
    """One flight of a :class:`Route` on the vehicle behind a :class:`GroundStation`."""

    def __init__(self, gcs: GroundStation, settings, frame: LocalFrame, route: Route, progress, geo=None) -> None:
        self.gcs = gcs
        self.settings = settings
        self.frame = frame
        self.route = route
        self.progress = progress
        #: (MapProjection, home's local down, the EKF origin's altitude AMSL) for global mission items
        self.geo = geo
        self.log = FlightLog()
        #: upload as the deprecated MISSION_ITEM (a vehicle without MAV_PROTOCOL_CAPABILITY_MISSION_INT)
        self.legacy_missions = False
        self.route_ned = frame.to_ned(route.points)
        #: the rehearsal's rogue offboard setpoints aim through this point (local NED), None in a normal flight
        self.rogue: np.ndarray | None = None
        #: the vehicle's geofence events already in the log
        self._fence_seen = len(gcs.vehicle.fence_events)

    # ------------------------------------------------------------------ missions
    def mission_items(self) -> tuple[list[MissionItem], int, int]:
        """The mission for the route; also the seqs of the path's first and last waypoints."""
        s = self.settings
        ned = self.route_ned
        items = [
            MissionItem(
                mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_FRAME_MISSION, param1=1, param2=s.cruise_speed, param3=-1
            )
        ]
        first = -1
        # route point 0 is where the vehicle is; with a take-off, point 1 is its top (maybe the path's start)
        for i in range(1, self.route.path_last + 1):
            if i == self.route.path_first:
                first = len(items)
            if i == 1 and self.route.takeoff:
                items.append(self._nav(mavlink.MAV_CMD_NAV_TAKEOFF, ned[i], param4=math.nan))
            else:
                items.append(
                    self._nav(mavlink.MAV_CMD_NAV_WAYPOINT, ned[i], param2=s.acceptance_radius, param4=math.nan)
                )
        last = len(items) - 1
        if self.route.land:
            items.append(self._nav(mavlink.MAV_CMD_NAV_LAND, ned[-1], param4=math.nan))
        return items, first, last

    def _nav(self, command: int, ned: np.ndarray, **params) -> MissionItem:
        """A position item at local NED ``ned``: latitude/longitude about the EKF origin, altitude above home
        (MAV_FRAME_GLOBAL_RELATIVE_ALT) or AMSL (MAV_FRAME_GLOBAL)."""
        if self.geo is None:
            raise VehicleError("the vehicle's EKF origin is unknown: no global mission items", step="mission")
        projection, home_down, origin_alt = self.geo
        lat, lon = projection.reproject(ned[0], ned[1])
        if self.settings.mission_frame == "global":
            return MissionItem(
                command, mavlink.MAV_FRAME_GLOBAL, float(lat), float(lon), float(origin_alt - ned[2]), **params
            )
        return MissionItem(
            command, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, float(lat), float(lon), float(home_down - ned[2]), **params
        )

    def fly_mission(self) -> FlightLog:
        gcs = self.gcs
        items, first, last = self.mission_items()
        log = self.log
        gcs.step = "mission upload"
        started = time.monotonic()
        with self.progress.task("uploading mission", total=len(items)) as task:
            stats, transfers = gcs.upload(items, progress=task, legacy=self.legacy_missions)
        uploaded = time.monotonic() - started
        gcs.step = "mission verify"
        held = gcs.download(legacy=self.legacy_missions)
        difference = compare_missions(items, held, self.legacy_missions)
        if difference is not None:
            raise VehicleError(
                f"the mission downloaded back differs from the one uploaded: {difference}", step=gcs.step
            )
        log.metrics.update(
            mission_verified=True,
            mission_message="MISSION_ITEM" if self.legacy_missions else "MISSION_ITEM_INT",
            mission_frame=enum_name("MAV_FRAME", items[-1].frame),
            download_s=time.monotonic() - started - uploaded,
            mission_items=len(items),
            upload_s=uploaded,
            upload_transfers=transfers,
            upload_retransmissions=stats.retransmissions,
            upload_requests=stats.requests,
            upload_repeated_requests=stats.repeated_requests,
            upload_out_of_order_requests=stats.out_of_order_requests,
        )
        # progress of this mission only (a vehicle may have flown another before)
        vehicle = gcs.vehicle
        vehicle.reached.clear()
        vehicle.current_changes.clear()
        vehicle.mission_state = 0
        vehicle.mission_current = -1
        # as MAVSDK does: arm holding, then the switch to mission mode starts the mission, exactly once
        # (a MISSION_START repeated late, its ACK lost, would start it again from wherever the vehicle is)
        timeout = self.settings.timeouts.mode
        gcs.step = "mode change"
        gcs.set_mode("hold", timeout)
        gcs.step = "arming"
        gcs.recording = True
        gcs.arm(timeout)
        gcs.step = "mission start"
        gcs.set_mode("mission", timeout)
        gcs.step = "flight"
        done_seq = len(items) - 1

        def over() -> bool:
            # MISSION_ITEM_REACHED comes once and may be lost: MISSION_CURRENT (streamed) backs it up
            return vehicle.passed(done_seq) < math.inf or vehicle.mission_state == mavlink.MISSION_STATE_COMPLETE

        def finished() -> bool:
            if not over():
                return False
            return (not vehicle.armed) if self.route.land else True

        def window() -> tuple[float, float]:
            return vehicle.passed(first), vehicle.passed(last)

        def advance() -> None:
            task.update(max((seq for seq, _ in vehicle.reached), default=-1) + 1)

        with self.progress.task("flying mission", total=len(items)) as task:
            self._watch(finished, window, advance, allowed=("mission",), over=over)
            if log.status != "completed":
                task.abandon()
        return log

    # ------------------------------------------------------------------ offboard
    def fly_offboard(self) -> FlightLog:
        s = self.settings
        gcs = self.gcs
        log = self.log
        # the setpoints end at the path's end, in the air; the landing is PX4's land mode, vertical from
        # wherever the vehicle arrived (as the mission's NAV_LAND): flown as setpoints, a touchdown a gust
        # put beside the goal could never arrive (the vehicle cannot move on the ground)
        airborne = self.route_ned[: self.route.path_last + 1]
        if self.rogue is not None:  # the rehearsal: from the path's start straight through the obstacle
            start = self.route_ned[self.route.path_first]
            aim = np.asarray(self.rogue, float) - start
            aim[2] = 0.0
            reach = float(np.linalg.norm(aim))
            airborne = np.vstack([self.route_ned[: self.route.path_first + 1], start + aim / reach * (reach + 3.0)])
        profile = TimedPath.along(
            airborne, s.cruise_speed, s.acceleration, s.corner_deviation, vertical_speed=s.vertical_speed
        )
        log.profile = profile
        stream = SetpointStream(gcs, profile, self.route_ned[0])
        gcs.tickers.append(stream)
        try:
            gcs.step = "offboard setpoints"
            gcs.wait_for(lambda: stream.flowing() >= SETPOINTS_BEFORE_SWITCH, s.timeouts.mode, "no LOCAL_POSITION_NED")
            gcs.step = "mode change"
            gcs.set_mode("offboard", s.timeouts.mode)
            gcs.step = "arming"
            gcs.recording = True
            gcs.arm(s.timeouts.mode)
            start = log.profile_start = stream.begin()
            gcs.step = "flight"
            passing = profile.waypoint_time
            path_window = (
                start + passing[self.route.path_first],
                start + passing[min(self.route.path_last, len(passing) - 1)],
            )
            goal = airborne[-1]
            end = start + profile.duration

            def arrived() -> bool:
                position = gcs.vehicle.position
                return (
                    position is not None
                    and position.time >= end
                    and np.linalg.norm(np.asarray(position.position) - goal) <= s.acceptance_radius
                )

            total = profile.total_length

            def advance() -> None:
                task.update(float(profile.arc_length(gcs.vehicle.vehicle_time - start)[0]))

            with self.progress.task("flying offboard", total=total) as task:
                self._watch(arrived, lambda: path_window, advance, allowed=("offboard",))
                if log.status != "completed":
                    task.abandon()
                    return log
                gcs.step = "landing" if self.route.land else "hold"
                if self.route.land:
                    gcs.command(mavlink.MAV_CMD_NAV_LAND, [0, 0, 0, math.nan, math.nan, math.nan, math.nan])
                else:
                    gcs.set_mode("hold", s.timeouts.mode)  # its HEARTBEAT showing hold stands for a lost ACK
                gcs.tickers.remove(stream)
                if self.route.land:
                    self._watch(
                        lambda: not gcs.vehicle.armed, lambda: path_window, advance, allowed=("land", "offboard")
                    )
        finally:
            if stream in gcs.tickers:
                gcs.tickers.remove(stream)
        return log

    # ------------------------------------------------------------------ watching
    def _watch(self, finished, window, advance, allowed: tuple[str, ...], over=lambda: False) -> None:
        """Pump until ``finished()``; heartbeat loss -> failsafe; a mode the vehicle chose itself -> stopped.

        Once ``over()`` (the last item reached) the vehicle may change mode by itself (PX4 holds
        after a mission): only the landing is still awaited.
        """
        gcs = self.gcs
        s = self.settings
        log = self.log
        allowance = self.flight_allowance()
        limit = gcs.vehicle.vehicle_time + allowance
        try:
            while not finished():
                gcs.pump(0.05)
                advance()
                log.path_window = window()
                self._fence_news()
                if finished():
                    break
                mode = gcs.vehicle.mode
                if mode and mode not in allowed and not over() and self._fence_stop(mode):
                    return
                if mode and mode not in allowed and not over():
                    log.status = "stopped"
                    log.message = f"the vehicle left {allowed[0]} mode by itself (now {mode})"
                    log.faults.append({"kind": "mode_change", "mode": mode, "vehicle_time_s": gcs.vehicle.vehicle_time})
                    return
                if gcs.vehicle.vehicle_time > limit:
                    log.status = "stopped"
                    log.message = f"the flight did not finish within {allowance:.0f} s (vehicle time)"
                    log.faults.append({"kind": "timeout", "vehicle_time_s": gcs.vehicle.vehicle_time})
                    self._failsafe("timeout")
                    return
            log.path_window = window()
        except LinkLost as exc:
            log.status = "stopped"
            log.faults.append(
                {
                    "kind": "heartbeat_lost",
                    "step": gcs.step,
                    "vehicle_time_s": gcs.vehicle.vehicle_time,
                    "missed_heartbeats": s.heartbeat.missed,
                }
            )
            log.message = f"{exc}; {self._failsafe('heartbeat lost')}"
        except KeyboardInterrupt:
            self._failsafe("interrupted")
            raise

    def _fence_news(self) -> list[tuple[float, str]]:
        """The vehicle's new word on its geofence (STATUSTEXT, SYS_STATUS health), logged as faults."""
        events = self.gcs.vehicle.fence_events[self._fence_seen :]
        self._fence_seen += len(events)
        for when, text in events:
            self.log.faults.append({"kind": "geofence", "vehicle_time_s": when, "message": text})
        return events

    def _fence_stop(self, mode: str) -> bool:
        """The vehicle left the flight's mode by itself: when its geofence says why (a breach and GF_ACTION),
        the flight ends ``stopped`` and the vehicle is watched until it is at rest (hold) or down (land,
        return); False when the geofence has nothing to do with it."""
        gcs = self.gcs
        vehicle = gcs.vehicle
        s = self.settings
        flight_events = [e for e in self.log.faults if e["kind"] == "geofence"]
        deadline = time.monotonic() + 1.2  # the STATUSTEXT may trail the HEARTBEAT (or be lost: SYS_STATUS)
        while not (flight_events or vehicle.fence_breached) and time.monotonic() < deadline:
            gcs.pump(0.05)
            self._fence_news()
            flight_events = [e for e in self.log.faults if e["kind"] == "geofence"]
        if not (flight_events or vehicle.fence_breached):
            return False
        # what the vehicle said (its STATUSTEXT), else what its SYS_STATUS showed (the STATUSTEXT lost)
        words = [e["message"] for e in flight_events if not e["message"].startswith("SYS_STATUS")]
        said = words[0] if words else "SYS_STATUS: geofence not healthy"
        log = self.log
        log.status = "stopped"
        log.stopped_at = vehicle.vehicle_time
        log.faults.append({"kind": "geofence_breach", "mode": mode, "vehicle_time_s": vehicle.vehicle_time})
        for ticker in list(gcs.tickers):
            gcs.tickers.remove(ticker)  # the vehicle ignores setpoints now; no more of them
        gcs.step = f"geofence ({mode})"
        try:
            if mode in ("land", "return"):
                gcs.wait_for(lambda: not vehicle.armed, s.timeouts.failsafe, "the vehicle did not land")
                outcome = "landed"
            else:
                still = {"since": None}

                def at_rest() -> bool:
                    sample = vehicle.position
                    if sample is None or float(np.linalg.norm(sample.velocity)) > 0.05:
                        still["since"] = None
                        return False
                    still["since"] = sample.time if still["since"] is None else still["since"]
                    return sample.time - still["since"] >= 1.0

                gcs.wait_for(at_rest, s.timeouts.failsafe, "the vehicle did not come to rest")
                outcome = "at rest"
        except VehicleError as exc:
            outcome = exc.detail
        self._fence_news()
        log.message = f"the vehicle's geofence stopped the flight: {mode} by itself ({said}); {outcome}"
        return True

    def flight_allowance(self) -> float:
        """Vehicle seconds the flight may take: the setting, or 3x the route at cruise speed plus a minute."""
        if self.settings.timeouts.flight is not None:
            return self.settings.timeouts.flight
        length = float(np.sum(np.linalg.norm(np.diff(self.route.points, axis=0), axis=1)))
        return 3.0 * length / self.settings.cruise_speed + 60.0

    def _touchdown_report(self) -> None:
        """Pump until a position report sent after the landed state was heard, so that the flight's log ends on the
        floor: the vehicle reports its landed state and its position in two streams, and "landed" can arrive
        before the report of the touchdown's last centimetres. Bounded (:data:`TOUCHDOWN_REPORTS`): the report may
        be lost, and the log then ends with the last one heard."""
        gcs = self.gcs
        vehicle = gcs.vehicle
        heard = vehicle.position
        wait = max(TOUCHDOWN_REPORTS / self.settings.telemetry_rate, TOUCHDOWN_REPORT_S)
        try:
            gcs.wait_for(lambda: vehicle.position is not heard, wait, "a position report after landing")
        except VehicleError:
            pass

    def _failsafe(self, why: str) -> str:
        """Command the configured failsafe; watch what the vehicle does; say what happened."""
        gcs = self.gcs
        s = self.settings
        log = self.log
        gcs.check_liveness = False
        gcs.step = f"failsafe ({s.failsafe})"
        command = {
            "land": (mavlink.MAV_CMD_NAV_LAND, [0, 0, 0, math.nan, math.nan, math.nan, math.nan]),
            "return": (mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, []),
            "hold": (mavlink.MAV_CMD_DO_SET_MODE, list(px4_mode_command("hold"))),
        }[s.failsafe]
        entry: dict[str, Any] = {"kind": "failsafe", "action": s.failsafe, "reason": why}
        for ticker in list(gcs.tickers):
            gcs.tickers.remove(ticker)  # no more setpoints: the vehicle must act on the failsafe
        try:
            gcs.command(*command)
            entry["acknowledged"] = True
        except VehicleError as exc:
            entry["acknowledged"] = False
            entry["error"] = str(exc)
        log.faults.append(entry)
        outcome = "acknowledged" if entry["acknowledged"] else "not acknowledged"
        if s.failsafe == "land" and entry["acknowledged"]:
            # EXTENDED_SYS_STATE says when it is down (heartbeats, and so the armed flag, may be gone)
            vehicle = gcs.vehicle
            vehicle.landed_state = mavlink.MAV_LANDED_STATE_UNDEFINED
            try:
                gcs.wait_for(lambda: vehicle.on_ground or not vehicle.armed, s.timeouts.failsafe, "landed")
                entry["landed"] = True
                outcome += ", the vehicle landed"
                self._touchdown_report()
            except VehicleError:
                entry["landed"] = False
                outcome += f", no landing seen within {s.timeouts.failsafe:g} s"
        return f"commanded the failsafe: {s.failsafe} ({outcome})"
