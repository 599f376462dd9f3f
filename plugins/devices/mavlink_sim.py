"""``surgiplan-sim-vehicle``: a simulated PX4-like quadrotor that speaks MAVLink 2.

It implements, over any pymavlink connection (UDP by default), what the
``mavlink_vehicle`` device needs from a real autopilot, so that the whole
chain can be rehearsed anywhere, faults included:

* HEARTBEAT (1 Hz wall clock), LOCAL_POSITION_NED, EXTENDED_SYS_STATE,
  MISSION_CURRENT, MISSION_ITEM_REACHED, STATUSTEXT, COMMAND_ACK;
* the command protocol: arm/disarm, PX4 mode changes (DO_SET_MODE),
  MISSION_START, LAND, RETURN_TO_LAUNCH, DO_PAUSE_CONTINUE,
  SET_MESSAGE_INTERVAL, REQUEST_MESSAGE (GPS_GLOBAL_ORIGIN, HOME_POSITION);
* the mission protocol, vehicle side (:class:`~.mavlink_mission.MissionReceiver`):
  local-NED and global (relative-altitude) items, optionally requested
  out of order and repeated;
* mission execution (takeoff, waypoints, land, RTL, loiter, change speed)
  and offboard control by SET_POSITION_TARGET_LOCAL_NED, with a point-mass
  multirotor (:mod:`.mavlink_sim_model`) under velocity and acceleration
  limits, in wind;
* faults from its settings (:mod:`.mavlink_sim_settings`): packet loss both
  ways, falling silent at a protocol step, refusing missions or arming,
  losing its heartbeat in flight.

Time: the physics runs at ``speed`` simulated seconds per wall second (so a
test flight can run faster than real time); the link's own timing
(heartbeats, protocol timeouts) stays on the wall clock. In offboard mode
the simulation never runs ahead of the ground station's newest setpoint
(lockstep), so a loaded machine slows the flight down instead of starving it.

Run it on its own (``surgiplan-sim-vehicle --help``); the device starts it as
a subprocess on a free 127.0.0.1 UDP port unless told to connect elsewhere.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time

import numpy as np

from .mavlink_conventions import MapProjection, px4_custom_mode, px4_mode_from_command
from .mavlink_link import Endpoint, mavlink, signing_key
from .mavlink_mission import MissionItem, MissionReceiver, ReceiverFaults
from .mavlink_profile import TimedPath
from .mavlink_sim_model import PointMassMultirotor
from .mavlink_sim_settings import SimSettings

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 magic number

NAV = {
    mavlink.MAV_CMD_NAV_WAYPOINT,
    mavlink.MAV_CMD_NAV_TAKEOFF,
    mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    mavlink.MAV_CMD_NAV_LOITER_TIME,
    mavlink.MAV_CMD_NAV_LOITER_UNLIM,
}
SUPPORTED_ITEMS = NAV | {mavlink.MAV_CMD_DO_CHANGE_SPEED}
POSITION_FRAMES = {
    mavlink.MAV_FRAME_LOCAL_NED,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_INT,
}
#: how far the moving reference may lead the vehicle before it slows down, and stops (m)
LEAD = (0.5, 1.5)
#: seconds a vehicle may hover at a leg's last waypoint, outside its acceptance radius, before it counts
SETTLE = 3.0


class _Follow:
    """Follow a timed polyline; the reference waits for a vehicle that lags (wind, limits)."""

    def __init__(self, profile: TimedPath) -> None:
        self.profile = profile
        self.tau = 0.0
        #: how long (s) the reference has stood at the end
        self.waited = 0.0

    def reference(self, p: np.ndarray, dt: float):
        ref, vel, acc = self.profile.at(self.tau)
        lag = float(np.linalg.norm(ref - p))
        rate = min(max((LEAD[1] - lag) / (LEAD[1] - LEAD[0]), 0.0), 1.0)
        if self.at_end:
            self.waited += dt
        self.tau = min(self.tau + rate * dt, self.profile.duration)
        return ref, vel * rate, acc * rate * rate

    @property
    def at_end(self) -> bool:
        return self.tau >= self.profile.duration


class SimulatedVehicle:
    """The simulated vehicle on ``connection`` (a listening UDP port by default)."""

    def __init__(self, settings: SimSettings | None = None, connection: str = "udpin:127.0.0.1:0") -> None:
        self.settings = s = settings or SimSettings()
        key = signing_key(s.signing_key) if s.signing_key else None
        self.endpoint = Endpoint(
            connection, system_id=s.system_id, component_id=s.component_id, key=key, loss=s.packet_loss, seed=s.seed
        )
        self.model = PointMassMultirotor(s.airframe, s.home, s.wind, seed=s.seed + 1)
        self.projection = MapProjection(s.origin[0], s.origin[1])
        faults = ReceiverFaults(
            reject=s.reject_mission,
            reject_at_item=s.reject_at_item,
            shuffle=s.mission_requests.shuffle,
            repeat=s.mission_requests.repeat,
            seed=s.seed + 2,
        )
        self.receiver = MissionReceiver(
            s.system_id,
            s.component_id,
            capacity=s.mission_capacity,
            timeout=s.mission_timeout,
            retries=s.mission_retries,
            validate=self._validate_item,
            on_accept=self._mission_accepted,
            faults=faults,
        )
        self._noise = np.random.default_rng(s.seed + 3)
        self.t = 0.0
        self._next_heartbeat = -math.inf
        self.armed = False
        self.mode = "position"
        self.mission: list[MissionItem] = []
        self.current = 0
        self.cruise_speed = s.airframe.cruise_speed
        self.guidance = None
        self.hold_point = self.model.p.copy()
        self._leg: list[int] = []
        self._leg_reached = 0
        self._hold_until: float | None = None
        self._landing = False
        self._landed_at: float | None = None
        self.armed_at: float | None = None
        self._armed_wall = math.inf
        self.setpoint = None  # (time s, p, v, a)
        self._setpoint_wall = -math.inf
        self.silent = s.stop_answering is not None and s.stop_answering.step == "connect"
        self._silence_count = 0
        self.heartbeat_lost = False
        self.telemetry_lost = False
        self.position_interval = 1.0 / s.position_rate
        self._next = {"position": 0.0, "state": 0.0, "current": 0.0}
        #: (t, x, y, z, vx, vy, vz) true states at the position rate, for tests and figures
        self.trajectory: list[tuple[float, ...]] = []
        #: what happened, in words, with the vehicle time (for tests and the log)
        self.events: list[tuple[float, str]] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # ------------------------------------------------------------------ state announced at once
    @property
    def mode(self) -> str:
        return self._mode

    @mode.setter
    def mode(self, value: str) -> None:
        if value != getattr(self, "_mode", None):
            self._next_heartbeat = -math.inf  # a mode change is announced by a HEARTBEAT at once
        self._mode = value

    @property
    def armed(self) -> bool:
        return self._armed

    @armed.setter
    def armed(self, value: bool) -> None:
        if value != getattr(self, "_armed", None):
            self._next_heartbeat = -math.inf
        self._armed = value

    # ------------------------------------------------------------------ running
    @property
    def port(self) -> int | None:
        return self.endpoint.port

    def start(self) -> SimulatedVehicle:
        """Run in a daemon thread (tests); :meth:`stop` ends it."""
        self._thread = threading.Thread(target=self.run, name="surgiplan-sim-vehicle", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        self.endpoint.close()

    def __enter__(self) -> SimulatedVehicle:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def run(self) -> None:
        dt = self.settings.step
        last = time.monotonic()
        carry = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            # never more than 0.25 s of simulated time per pass: a stalled machine slows the run down
            due = (now - last) * self.settings.speed
            behind = due > 0.25
            budget = min(due, 0.25) + carry
            last = now
            limit = self._time_limit(now)
            steps = int(budget / dt)
            carry = budget - steps * dt
            for _ in range(steps):
                if self.t + dt > limit + 1e-12:
                    carry = 0.0
                    break
                self._physics(dt)
            for message in self.endpoint.receive():
                self._handle(message, now)
            self._send(self.receiver.on_timer(now))
            self._offboard_watchdog(now)
            if now >= self._next_heartbeat:
                self._heartbeat()
                self._next_heartbeat = now + 1.0 / self.settings.heartbeat_rate
            if not behind:  # running behind the asked speed: no sleeping
                wait = min(0.005, self._next_heartbeat - now, self.receiver.deadline - now)
                self.endpoint.wait(max(wait, 0.0))

    def _time_limit(self, now: float) -> float:
        s = self.settings
        if self.mode == "offboard" and s.lockstep and self.setpoint is not None:
            return self.setpoint[0] + s.lockstep_horizon
        return math.inf

    # ------------------------------------------------------------------ sending
    def _send(self, messages) -> None:
        if self.silent or self.telemetry_lost:
            return
        for message in messages:
            self.endpoint.send(message)

    def _telemetry(self, message) -> None:
        if not (self.silent or self.telemetry_lost):
            self.endpoint.send(message)

    def _say(self, text: str, severity: int = mavlink.MAV_SEVERITY_INFO) -> None:
        self.events.append((self.t, text))
        self._telemetry(mavlink.MAVLink_statustext_message(severity, text[:50].encode(), 0, 0))

    def _heartbeat(self) -> None:
        if self.heartbeat_lost:
            return
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if self.mode in ("mission", "offboard", "land", "return", "hold", "takeoff"):
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        self._telemetry(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, px4_custom_mode(self.mode), status, 3
            )
        )

    def _landed_state(self) -> int:
        if not self.model.airborne:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if self._landing:
            return mavlink.MAV_LANDED_STATE_LANDING
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _periodic(self) -> None:
        t = self.t
        ms = round(t * 1000)
        if t >= self._next["position"] - 1e-9 and self.position_interval > 0:
            self._next["position"] = t + self.position_interval
            p, v = self.model.p, self.model.v
            self.trajectory.append((t, *p, *v))
            noisy = p + self._noise.normal(0.0, self.settings.position_noise, 3) if self.settings.position_noise else p
            self._telemetry(mavlink.MAVLink_local_position_ned_message(ms, *noisy, *v))
        if t >= self._next["state"] - 1e-9:
            self._next["state"] = t + 0.2
            self._telemetry(mavlink.MAVLink_extended_sys_state_message(0, self._landed_state()))
        if t >= self._next["current"] - 1e-9:
            self._next["current"] = t + 1.0
            self._mission_current()

    def _mission_current(self) -> None:
        if not self.mission:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.current >= len(self.mission):
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.mode == "mission" and self.armed:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        self._telemetry(
            mavlink.MAVLink_mission_current_message(self.current, len(self.mission), state, int(self.mode == "mission"))
        )

    # ------------------------------------------------------------------ physics and autopilot
    def _physics(self, dt: float) -> None:
        reference = self._reference(dt)
        self.model.step(dt, reference, self.armed)
        self.t += dt
        self._after_step()
        self._periodic()
        self._faults()

    def _reference(self, dt: float):
        p = self.model.p
        if self.mode == "offboard" and self.setpoint is not None:
            t0, sp, sv, sa = self.setpoint
            h = min(max(self.t - t0, -0.5), 0.5)  # a setpoint stamped for t0 holds near t0, extrapolated
            return sp + sv * h + 0.5 * sa * h * h, sv + sa * h, sa
        if isinstance(self.guidance, _Follow):
            return self.guidance.reference(p, dt)
        if self.mode == "land" or self._landing:
            ground = self.model.ground
            x, y, z = self.hold_point
            z = min(self.hold_point[2] + self.settings.airframe.landing_speed * dt, ground + 0.2)
            self.hold_point = np.array([x, y, z])
            return self.hold_point.copy(), np.array([0.0, 0.0, self.settings.airframe.landing_speed]), np.zeros(3)
        return self.hold_point.copy(), np.zeros(3), np.zeros(3)

    def _after_step(self) -> None:
        model = self.model
        if self.armed and not model.airborne and self._landing:
            if self._landed_at is None:
                self._landed_at = self.t
                self._say("landed")
            elif self.t - self._landed_at >= 1.0:
                self._disarm("auto-disarmed after landing")
        # PX4's COM_DISARM_PRFLT, on the wall clock: it waits for people, not for the physics
        idle = self.guidance is None or (self.mode == "mission" and self.current >= len(self.mission))
        if self.armed and not model.airborne and not self._landing and idle and self.mode != "offboard":
            if time.monotonic() - self._armed_wall > 10.0:
                self._disarm("auto-disarmed: no takeoff within 10 s")
        if self.mode == "mission" and self.armed:
            self._mission_step()
        elif self.mode == "return" and isinstance(self.guidance, _Follow) and self._arrived(self.guidance):
            self._begin_landing()
        elif self.mode == "takeoff" and isinstance(self.guidance, _Follow) and self._arrived(self.guidance):
            self.mode = "hold"
            self._hold_here()

    def _arrived(self, guidance: _Follow, radius: float | None = None) -> bool:
        radius = radius if radius is not None else self.settings.airframe.acceptance_radius
        return guidance.at_end and np.linalg.norm(self.model.p - guidance.profile.end) <= radius

    def _hold_here(self) -> None:
        self.guidance = None
        self._landing = False
        self.hold_point = self.model.stopping_point()

    def _begin_landing(self) -> None:
        self.guidance = None
        self._landing = True
        self._landed_at = None
        self.hold_point = self.model.p.copy()

    def _disarm(self, why: str) -> None:
        self.armed = False
        self.armed_at = None
        self._landing = False
        self.guidance = None
        self.hold_point = self.model.p.copy()
        self._say(why)

    def _faults(self) -> None:
        loss = self.settings.heartbeat_loss
        if loss is not None and self.armed_at is not None and not self.heartbeat_lost:
            if self.t - self.armed_at >= loss.at_s:
                self.heartbeat_lost = True
                self.events.append((self.t, "heartbeat lost (injected)"))
                self.telemetry_lost = loss.all_telemetry

    def _offboard_watchdog(self, now: float) -> None:
        if self.mode != "offboard" or not self.armed:
            return
        s = self.settings
        stale = (
            (now - self._setpoint_wall) if s.lockstep else (self.t - (self.setpoint[0] if self.setpoint else -math.inf))
        )
        if stale > s.offboard_timeout:
            self.mode = "hold"
            self._hold_here()
            self._say("offboard setpoints lost: holding", mavlink.MAV_SEVERITY_WARNING)

    # ------------------------------------------------------------------ missions
    def _item_position(self, item: MissionItem) -> np.ndarray:
        """An item's position in local NED (NaN coordinates: the vehicle's)."""
        p = self.model.p
        if item.frame == mavlink.MAV_FRAME_LOCAL_NED:
            xyz = np.array([item.x, item.y, item.z], float)
        else:
            north, east = self.projection.project(item.x, item.y)
            if item.frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT:
                down = self.settings.home[2] - item.z
            else:
                down = -(item.z - self.settings.origin[2])
            xyz = np.array([north, east, down], float)
        return np.where(np.isnan(xyz), p, xyz)

    def _validate_item(self, item: MissionItem, seq: int) -> int | None:
        if item.command not in SUPPORTED_ITEMS:
            return mavlink.MAV_MISSION_UNSUPPORTED
        if item.command in NAV and item.command != mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            if item.frame not in POSITION_FRAMES:
                return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
            if item.command in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF) and math.isnan(item.z):
                return mavlink.MAV_MISSION_INVALID_PARAM7
        return None

    def _mission_accepted(self, items: list[MissionItem]) -> None:
        self.mission = items
        self.current = 0
        self.guidance = None
        self.events.append((self.t, f"mission accepted ({len(items)} items)"))
        if self.mode == "mission":
            self.mode = "hold"
            self._hold_here()
        self._mission_current()

    def _start_mission(self) -> None:
        self._leg = []
        self._start_item(self.current)

    def _reached(self, seq: int) -> None:
        self.events.append((self.t, f"reached item {seq}"))
        self._telemetry(mavlink.MAVLink_mission_item_reached_message(seq))

    def _start_item(self, index: int) -> None:
        """Begin mission item ``index`` (DO items run at once; a run of waypoints is one leg)."""
        airframe = self.settings.airframe
        while True:
            self.current = index
            self._mission_current()
            if index >= len(self.mission):
                self.events.append((self.t, "mission complete"))
                if self.model.airborne:
                    self.mode = "hold"
                    self._hold_here()
                return
            item = self.mission[index]
            if item.command != mavlink.MAV_CMD_DO_CHANGE_SPEED:
                break
            if item.param2 > 0:
                self.cruise_speed = min(item.param2, airframe.max_speed)
            index += 1
        start = self.guidance.profile.end if isinstance(self.guidance, _Follow) else self.hold_point
        start = np.asarray(start, float)
        self._hold_until = None
        self._leg = [index]
        if item.command == mavlink.MAV_CMD_NAV_WAYPOINT:
            leg = [index]
            while (
                leg[-1] + 1 < len(self.mission)
                and self.mission[leg[-1]].param1 <= 0
                and self.mission[leg[-1] + 1].command == mavlink.MAV_CMD_NAV_WAYPOINT
            ):
                leg.append(leg[-1] + 1)
            self._leg = leg
            self._leg_reached = 0
            points = [start] + [self._item_position(self.mission[i]) for i in leg]
            radius = self.mission[leg[0]].param2 or airframe.acceptance_radius
            self._follow(points, corner=0.5 * radius)
        elif item.command == mavlink.MAV_CMD_NAV_TAKEOFF:
            target = self._item_position(item)
            target[:2] = self.model.p[:2]
            self._follow([self.model.p.copy(), target], corner=0.0)
        elif item.command == mavlink.MAV_CMD_NAV_LAND:
            target = self._item_position(item)
            target[2] = start[2]
            if np.linalg.norm(target[:2] - self.model.p[:2]) > airframe.acceptance_radius:
                self._follow([start, target], corner=0.0)
            else:
                self._begin_landing()
        elif item.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._follow([start, np.array([*self.settings.home[:2], start[2]])], corner=0.0)
        else:  # loiter: hold at the item's position (param1 seconds, or for ever)
            self._follow([start, self._item_position(item)], corner=0.0)
            if item.command == mavlink.MAV_CMD_NAV_LOITER_TIME:
                self._hold_until = math.inf  # set when the position is reached

    def _follow(self, points, corner: float) -> None:
        airframe = self.settings.airframe
        profile = TimedPath.along(
            np.asarray(points, float),
            self.cruise_speed,
            0.5 * airframe.max_acceleration,
            corner,
            vertical_speed=min(airframe.max_climb, airframe.max_descent),
        )
        self._landing = False
        self.guidance = _Follow(profile)

    def _mission_step(self) -> None:
        if self.current >= len(self.mission):
            return
        item = self.mission[self.current]
        guidance = self.guidance
        if item.command == mavlink.MAV_CMD_NAV_WAYPOINT and isinstance(guidance, _Follow):
            # waypoint k of the leg is reached when the reference has passed it and the vehicle is within
            # its acceptance radius (or past the plane through it, across the path)
            profile = guidance.profile
            while self._leg_reached < len(self._leg):
                seq = self._leg[self._leg_reached]
                k = self._leg_reached + 1  # the leg's waypoints follow its start point in the profile
                waypoint = profile.waypoints[k]
                incoming = waypoint - profile.waypoints[k - 1]
                radius = self.mission[seq].param2 or self.settings.airframe.acceptance_radius
                final = k == len(profile.waypoints) - 1
                passed = not final and float((self.model.p - waypoint) @ incoming) > 0
                distance = float(np.linalg.norm(self.model.p - waypoint))
                # gusts can keep a hovering vehicle just outside a tight radius: after SETTLE seconds at
                # the end, within 3 radii counts as there, and after 4 SETTLE as close as it gets
                settled = (
                    final and guidance.waited >= SETTLE and (distance <= 3 * radius or guidance.waited >= 4 * SETTLE)
                )
                if guidance.tau < profile.waypoint_time[k] or not (distance <= radius or passed or settled):
                    break
                self._reached(seq)
                self._leg_reached += 1
                if self._leg_reached < len(self._leg):
                    self.current = self._leg[self._leg_reached]
                    self._mission_current()
            if self._leg_reached >= len(self._leg):
                last = self.mission[self._leg[-1]]
                if last.param1 > 0:
                    self._hold_until = self.t + last.param1
                    self.guidance = None
                    self.hold_point = profile.end.copy()
                else:
                    self._start_item(self._leg[-1] + 1)
            return
        if self._hold_until is not None and guidance is None:
            if self.t >= self._hold_until:
                self._hold_until = None
                self._start_item((self._leg[-1] if self._leg else self.current) + 1)
            return
        if item.command == mavlink.MAV_CMD_NAV_TAKEOFF and isinstance(guidance, _Follow) and self._arrived(guidance):
            self._reached(self.current)
            self._start_item(self.current + 1)
        elif item.command in (mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            if isinstance(guidance, _Follow) and self._arrived(guidance):
                self._begin_landing()
            elif self._landing and not self.model.airborne and self._landed_at is not None:
                self._reached(self.current)
                self.current += 1
                self._mission_current()
        elif item.command in (mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LOITER_UNLIM):
            if isinstance(guidance, _Follow) and self._arrived(guidance):
                self._reached(self.current)
                self.guidance = None
                self.hold_point = guidance.profile.end.copy()
                if item.command == mavlink.MAV_CMD_NAV_LOITER_TIME:
                    self._hold_until = self.t + item.param1
                    self._leg = [self.current]

    # ------------------------------------------------------------------ messages
    def _silence(self, step: str) -> bool:
        rule = self.settings.stop_answering
        if rule is None or rule.step != step or self.silent:
            return self.silent
        self._silence_count += 1
        if self._silence_count > rule.after:
            self.silent = True
            self.events.append((self.t, f"fell silent at {step} (injected)"))
        return self.silent

    def _handle(self, message, now: float) -> None:
        if self.silent:
            return
        kind = message.get_type()
        source = (message.get_srcSystem(), message.get_srcComponent())
        target = getattr(message, "target_system", None)
        if target not in (None, 0, self.settings.system_id):
            return
        if kind in ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM"):
            if self._silence("mission_upload"):
                return
            self._send(self.receiver.on_message(message, source, now))
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(message, source)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._setpoint(message, now)

    def _ack(self, command: int, result: int, source) -> None:
        self._send([mavlink.MAVLink_command_ack_message(command, result, 255, 0, source[0], source[1])])

    def _command(self, message, source) -> None:
        command = int(message.command)
        params = [message.param1, message.param2, message.param3, message.param4]
        steps = {
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: "arming",
            mavlink.MAV_CMD_DO_SET_MODE: "mode_change",
            mavlink.MAV_CMD_MISSION_START: "mission_start",
        }
        step = steps.get(command)
        if command == mavlink.MAV_CMD_DO_SET_MODE and px4_mode_from_command(params[1], params[2]) == "mission":
            step = "mission_start"  # switching to mission mode starts a mission, as MISSION_START does
        if step is not None and self._silence(step):
            return
        handler = {
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm,
            mavlink.MAV_CMD_DO_SET_MODE: self._cmd_mode,
            mavlink.MAV_CMD_MISSION_START: self._cmd_mission_start,
            mavlink.MAV_CMD_NAV_LAND: lambda p: self._set_mode("land"),
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda p: self._set_mode("return"),
            mavlink.MAV_CMD_DO_PAUSE_CONTINUE: self._cmd_pause,
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_interval,
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._cmd_request,
        }.get(command)
        result = handler(params) if handler is not None else UNSUPPORTED
        self._ack(command, result, source)
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE and result == ACCEPTED:
            self._send_requested(int(params[0]))

    def _cmd_arm(self, params) -> int:
        if params[0] >= 0.5:
            if self.armed:
                return ACCEPTED
            if self.settings.refuse_arming:
                self._say(f"Arming denied: {self.settings.refuse_arming}", mavlink.MAV_SEVERITY_CRITICAL)
                return DENIED
            if self.mode == "offboard" and not self._fresh_setpoint():
                self._say("Arming denied: no offboard setpoints", mavlink.MAV_SEVERITY_CRITICAL)
                return DENIED
            self.armed = True
            self.armed_at = self.t
            self._armed_wall = time.monotonic()
            self.hold_point = self.model.p.copy()
            self._say("armed")
            if self.mode == "mission" and self.mission:
                self._start_mission()
            return ACCEPTED
        if self.model.airborne and int(params[1]) != FORCE_DISARM:
            self._say("Disarming denied: in air", mavlink.MAV_SEVERITY_CRITICAL)
            return DENIED
        if self.armed:
            self._disarm("disarmed")
        return ACCEPTED

    def _fresh_setpoint(self) -> bool:
        return self.setpoint is not None and time.monotonic() - self._setpoint_wall < self.settings.offboard_timeout

    def _cmd_mode(self, params) -> int:
        mode = px4_mode_from_command(params[1], params[2])
        if mode is None:
            return UNSUPPORTED
        return self._set_mode(mode)

    def _set_mode(self, mode: str) -> int:
        if mode == self.mode:
            return ACCEPTED
        if mode == "offboard" and not self._fresh_setpoint():
            self._say("Offboard denied: no setpoints", mavlink.MAV_SEVERITY_CRITICAL)
            return DENIED
        if mode == "mission" and not self.mission:
            self._say("Mission denied: no mission", mavlink.MAV_SEVERITY_CRITICAL)
            return DENIED
        self.mode = mode
        self.events.append((self.t, f"mode {mode}"))
        self._landing = False
        if mode == "mission":
            if self.armed:
                self._start_mission()
        elif mode == "land":
            self._begin_landing() if self.model.airborne else self._hold_here()
        elif mode == "return":
            if self.model.airborne:
                start = self.model.stopping_point()
                self.cruise_speed = self.settings.airframe.cruise_speed
                self._follow([self.model.p.copy(), start, np.array([*self.settings.home[:2], start[2]])], 0.0)
        elif mode == "offboard":
            self.guidance = None
        else:
            self._hold_here()
        return ACCEPTED

    def _cmd_mission_start(self, params) -> int:
        if not self.mission:
            self._say("Mission denied: no mission", mavlink.MAV_SEVERITY_CRITICAL)
            return DENIED
        first = int(params[0])
        if self.mode == "mission" and self.armed and self.guidance is not None:
            return ACCEPTED  # already flying it (PX4 starts a mission when armed in mission mode)
        self.current = first if 0 <= first < len(self.mission) else 0
        self.mode = "mission"
        if self.armed:
            self._start_mission()
        return ACCEPTED

    def _cmd_pause(self, params) -> int:
        if params[0] < 0.5:
            self.mode = "hold"
            self._hold_here()
        elif self.mission:
            self.mode = "mission"
            if self.armed:
                self._start_item(self.current)
        return ACCEPTED

    def _cmd_interval(self, params) -> int:
        message_id, interval = int(params[0]), float(params[1])
        if message_id != mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return UNSUPPORTED
        if interval == 0:
            self.position_interval = 1.0 / self.settings.position_rate
        else:
            self.position_interval = -1.0 if interval < 0 else max(interval * 1e-6, self.settings.step)
        return ACCEPTED

    def _cmd_request(self, params) -> int:
        known = (mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN, mavlink.MAVLINK_MSG_ID_HOME_POSITION)
        return ACCEPTED if int(params[0]) in known else UNSUPPORTED

    def _send_requested(self, message_id: int) -> None:
        lat, lon, alt = self.settings.origin
        if message_id == mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN:
            self._send([mavlink.MAVLink_gps_global_origin_message(int(lat * 1e7), int(lon * 1e7), int(alt * 1000), 0)])
        else:
            home = np.asarray(self.settings.home, float)
            hlat, hlon = self.projection.reproject(home[0], home[1])
            self._send(
                [
                    mavlink.MAVLink_home_position_message(
                        int(hlat * 1e7), int(hlon * 1e7), int((alt - home[2]) * 1000), *home, [1, 0, 0, 0], 0, 0, 0, 0
                    )
                ]
            )

    def _setpoint(self, message, now: float) -> None:
        if message.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
            return
        mask = int(message.type_mask)
        p = np.array([message.x, message.y, message.z])
        v = np.zeros(3) if mask & 0b111000 else np.array([message.vx, message.vy, message.vz])
        a = np.zeros(3) if mask & 0b111000000 else np.array([message.afx, message.afy, message.afz])
        stamp = message.time_boot_ms / 1000.0
        if self.setpoint is None or stamp >= self.setpoint[0]:
            self.setpoint = (stamp, p, v, a)
        self._setpoint_wall = now


# ----------------------------------------------------------------------------- command line


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="surgiplan-sim-vehicle",
        description="A simulated PX4-like quadrotor speaking MAVLink 2 (surgiplan's mavlink_vehicle device).",
    )
    parser.add_argument(
        "connection",
        nargs="?",
        default="udpout:127.0.0.1:14550",
        help="pymavlink connection: udpout:HOST:PORT sends to a ground station (default 127.0.0.1:14550, where "
        "QGroundControl listens); udpin:HOST:PORT waits for one (port 0: a free port, printed)",
    )
    parser.add_argument("--settings", help="settings as JSON (see surgiplan's mavlink_sim_settings)")
    parser.add_argument("--speed", type=float, help="simulated seconds per wall second")
    parser.add_argument("--packet-loss", type=float, help="fraction of messages dropped each way")
    parser.add_argument("--signing-key", help="MAVLink 2 signing key: 64 hex digits or a passphrase")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--exit-with-parent", action="store_true", help="exit when the parent process ends")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from pydantic import ValidationError

    try:
        data = json.loads(args.settings) if args.settings else {}
        for key in ("speed", "packet_loss", "signing_key", "seed"):
            value = getattr(args, key)
            if value is not None:
                data[key] = value
        settings = SimSettings.model_validate(data)
        vehicle = SimulatedVehicle(settings, args.connection)
    except (ValueError, ValidationError) as exc:
        print(f"surgiplan-sim-vehicle: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # e.g. the port is taken
        print(f"surgiplan-sim-vehicle: error: {exc}", file=sys.stderr)
        return 2
    port = vehicle.port
    where = args.connection if not args.connection.endswith(":0") or port is None else f"{args.connection[:-2]}:{port}"
    print(f"surgiplan-sim-vehicle: system {settings.system_id} on {where}", flush=True)

    def stop(*_args) -> None:
        vehicle._stop.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    if args.exit_with_parent:
        parent = os.getppid()

        def watch() -> None:
            while not vehicle._stop.wait(0.5):
                if os.getppid() != parent:
                    vehicle._stop.set()

        threading.Thread(target=watch, daemon=True).start()
    try:
        vehicle.run()
    finally:
        vehicle.endpoint.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
