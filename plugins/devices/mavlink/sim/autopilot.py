"""The simulated vehicle's autopilot: its flight modes, mission execution and failsafes.

A mix-in of :class:`~.vehicle.SimulatedVehicle` (it uses the vehicle's
state, airframe and telemetry), kept apart because it is the part that
*decides* where to fly, as PX4's navigator and commander do:

* the reference for the position controller in each mode: offboard (the
  setpoint in force, see :mod:`.offboard`, extrapolated from its time stamp
  with its velocity and acceleration), mission, take-off, return and
  reposition legs (:class:`Follow` along a
  :class:`~surgiplan.plugins.devices.mavlink.profile.TimedPath` at
  MPC_ACC_HOR), landing (descend at MPC_LAND_SPEED), hold (the stopping
  point);
* mission execution: DO items at once (DO_CHANGE_SPEED sets the speed,
  payload items are skipped); a run of NAV_WAYPOINTs flown as one leg,
  corners rounded within half the acceptance radius, each
  MISSION_ITEM_REACHED when the reference has passed it and the vehicle is
  within its acceptance radius (NAV_ACC_RAD when param2 is 0) or past it
  across the path; NAV_TAKEOFF, NAV_LAND, NAV_LOITER_TIME and
  NAV_LOITER_UNLIM; NAV_RETURN_TO_LAUNCH switches to return mode, as PX4's
  navigator does; global frames, absolute (AMSL) or relative to home;
* return mode: to home or the nearest rally point (RTL_TYPE), climbing to
  RTL_RETURN_ALT above it if lower, at MPC_XY_CRUISE, then land (PX4 also
  descends to RTL_DESCEND_ALT first and shortens the climb near home,
  RTL_CONE_ANG: not simulated);
* automatic disarming after landing (COM_DISARM_LAND) and before take-off
  (COM_DISARM_PRFLT, on the wall clock: it waits for people); home set where
  the vehicle arms; the injected heartbeat loss; the loss of offboard
  setpoints (COM_OF_LOSS_T, then COM_OBL_RC_ACT: hold, return or land).
"""

from __future__ import annotations

import math
import time

import numpy as np
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.mission import MissionItem
from surgiplan.plugins.devices.mavlink.profile import TimedPath

from .params import OFFBOARD_LOSS_ACTIONS

NAV = {
    mavlink.MAV_CMD_NAV_WAYPOINT,
    mavlink.MAV_CMD_NAV_TAKEOFF,
    mavlink.MAV_CMD_NAV_LAND,
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    mavlink.MAV_CMD_NAV_LOITER_TIME,
    mavlink.MAV_CMD_NAV_LOITER_UNLIM,
}
AMSL_FRAMES = {mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT}
#: PX4's MPC_LAND_ALT2 default (m above the ground): a landing slows to MPC_LAND_SPEED below it
LAND_SLOW_HEIGHT = 5.0
#: how far the moving reference may lead the vehicle before it slows down, and stops (m)
LEAD = (0.5, 1.5)
#: seconds a vehicle may hover at a leg's last waypoint, outside its acceptance radius, before it counts
SETTLE = 3.0


class Follow:
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


class Autopilot:
    """Modes, missions and failsafes of the simulated vehicle (a mix-in: see the module's docstring)."""

    # ------------------------------------------------------------------ physics and autopilot
    def _physics(self, dt: float) -> None:
        reference = self._reference(dt)
        self.model.step(dt, reference, self.armed)
        if self.armed:
            self._armed_time += dt
            self._consumed_mah += self._battery()[1] * dt / 3.6
        # the clock counts steps: no rounding drift, so that times on a grid (telemetry, setpoints) stay on it
        self.steps += 1
        self.t = self.steps * dt
        self._after_step()
        self._periodic()
        self._faults()
        self._geofence_step()

    def _reference(self, dt: float):
        p = self.model.p
        if self.mode == "offboard" and self.offboard.in_force(self.t) is not None:
            return self.offboard.reference(self.t)
        if isinstance(self.guidance, Follow):
            return self.guidance.reference(p, dt)
        if self.mode == "land" or self._landing:
            ground = self.model.ground
            x, y, z = self.hold_point
            airframe = self.settings.airframe
            # PX4: the descent speed down to MPC_LAND_ALT2 above the ground, MPC_LAND_SPEED below it
            speed = airframe.max_descent if ground - z > LAND_SLOW_HEIGHT else airframe.landing_speed
            z = min(self.hold_point[2] + speed * dt, ground + 0.2)
            self.hold_point = np.array([x, y, z])
            return self.hold_point.copy(), np.array([0.0, 0.0, speed]), np.zeros(3)
        return self.hold_point.copy(), np.zeros(3), np.zeros(3)

    def _after_step(self) -> None:
        model = self.model
        if self.armed and not model.airborne and self._landing:
            if self._landed_at is None:
                self._landed_at = self.t
                self._say("landed")
            elif self.t - self._landed_at >= self.settings.disarm_after_landing:
                self._disarm("auto-disarmed after landing")
        # PX4's COM_DISARM_PRFLT, on the wall clock: it waits for people, not for the physics
        idle = self.guidance is None or (self.mode == "mission" and self.current >= len(self.mission))
        if self.armed and not model.airborne and not self._landing and idle and self.mode != "offboard":
            if time.monotonic() - self._armed_wall > self.settings.disarm_before_takeoff:
                self._disarm(f"auto-disarmed: no takeoff within {self.settings.disarm_before_takeoff:g} s")
        if self.mode == "mission" and self.armed:
            self._mission_step()
        elif self.mode == "return" and isinstance(self.guidance, Follow) and self._arrived(self.guidance):
            self._begin_landing()
        elif self.mode in ("takeoff", "hold") and isinstance(self.guidance, Follow) and self._arrived(self.guidance):
            self.mode = "hold"  # a take-off or a reposition arrived: PX4 loiters there
            self._hold_here()

    def _set_mode(self, mode: str, force: bool = False) -> bool:
        """Enter ``mode`` as PX4's commander allows; False (and a STATUSTEXT saying why) when it cannot."""
        if mode == self.mode and not force:
            return True
        if mode == "offboard" and not self._fresh_setpoint():
            self._say("Offboard denied: no setpoints", mavlink.MAV_SEVERITY_CRITICAL)
            return False
        if mode == "mission" and not self.mission:
            self._say("Mission denied: no mission", mavlink.MAV_SEVERITY_CRITICAL)
            return False
        if mode == "mission" and (problem := self._mission_start_problem()) is not None:
            self._say(problem, mavlink.MAV_SEVERITY_CRITICAL)
            return False
        self.mode = mode
        self.events.append((self.t, f"mode {mode}"))
        self._landing = False
        if mode == "mission":
            if self.armed:
                self._start_mission()
        elif mode == "land":
            self._begin_landing() if self.model.airborne else self._hold_here()
        elif mode == "return":
            self._begin_return() if self.model.airborne else self._hold_here()
        elif mode == "takeoff":
            request = self._takeoff_request
            self._takeoff_request = None
            self.takeoff_height = request if request is not None else self.settings.takeoff_altitude
            self._begin_takeoff() if self.armed else self._hold_here()
        elif mode == "offboard":
            self.guidance = None
        else:
            self._hold_here()
        return True

    def _arrived(self, guidance: Follow, radius: float | None = None) -> bool:
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
        if self.offboard.stale(self.t, now):
            action = OFFBOARD_LOSS_ACTIONS[int(self.settings.offboard_loss_action)]
            if action in ("return", "land"):
                self._set_mode(action, force=True)
                self._say(f"offboard setpoints lost: {action}", mavlink.MAV_SEVERITY_WARNING)
            else:
                self.mode = "hold"
                self._hold_here()
                self._say("offboard setpoints lost: holding", mavlink.MAV_SEVERITY_WARNING)

    # ------------------------------------------------------------------ missions
    def _item_position(self, item: MissionItem) -> np.ndarray:
        """An item's position in local NED (NaN latitude/longitude or altitude: the vehicle's)."""
        p = self.model.p
        north, east = self.projection.project(item.x, item.y)
        if item.frame in AMSL_FRAMES:
            down = self.settings.origin[2] - item.z
        else:  # relative to home (PX4 stores these with altitude_is_relative)
            down = float(self.home[2]) - item.z
        xyz = np.array([north, east, down], float)
        return np.where(np.isnan(xyz), p, xyz)

    def _mission_accepted(self, items: list[MissionItem], mission_type: int = 0) -> None:
        self.uploads.append((mission_type, list(items)))
        if mission_type != mavlink.MAV_MISSION_TYPE_MISSION:
            self.events.append((self.t, f"{len(items)} items stored (mission type {mission_type})"))
            if mission_type == mavlink.MAV_MISSION_TYPE_FENCE:
                self._fence_accepted(items)
            elif mission_type == mavlink.MAV_MISSION_TYPE_RALLY:
                self._rally_accepted(items)
            return
        self.mission = items
        self.current = 0
        self.events.append((self.t, f"mission accepted ({len(items)} items)"))
        if self.mode == "mission":
            self.guidance = None
            self.mode = "hold"
            self._hold_here()
        self._mission_current()

    def set_current(self, seq: int) -> bool:
        """MISSION_SET_CURRENT / DO_SET_MISSION_CURRENT: the mission goes on from item ``seq``."""
        if not 0 <= seq < len(self.mission):
            return False
        self.current = seq
        self.events.append((self.t, f"current item {seq}"))
        if self.mode == "mission" and self.armed:
            self.guidance = None
            self._start_mission()
        self._mission_current()
        return True

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
            if item.command in NAV:
                break
            if item.command == mavlink.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0:
                self.cruise_speed = min(item.param2, airframe.max_speed)
            index += 1  # other DO items (camera, gimbal, ROI): no such payload, skipped
        start = self.guidance.profile.end if isinstance(self.guidance, Follow) else self.hold_point
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
            points = [start]
            if not self.model.airborne:
                # PX4 begins a mission on the ground with a vertical climb: to the first waypoint's
                # altitude, or MIS_TAKEOFF_ALT if that is higher
                first = self._item_position(self.mission[leg[0]])
                height = max(float(self.home[2] - first[2]), self.settings.takeoff_altitude)
                points.append(np.array([start[0], start[1], float(self.home[2]) - height]))
            self._leg_offset = len(points)  # the profile's index of the leg's first waypoint
            points += [self._item_position(self.mission[i]) for i in leg]
            radius = self.mission[leg[0]].param2 or airframe.acceptance_radius
            self._follow(points, corner=0.5 * radius)
        elif item.command == mavlink.MAV_CMD_NAV_TAKEOFF:
            target = self._item_position(item)
            target[:2] = self.model.p[:2]
            self._follow([self.model.p.copy(), target], corner=0.0, vertical=airframe.takeoff_speed)
        elif item.command == mavlink.MAV_CMD_NAV_LAND:
            target = self._item_position(item)
            target[2] = start[2]
            if np.linalg.norm(target[:2] - self.model.p[:2]) > airframe.acceptance_radius:
                self._follow([start, target], corner=0.0)
            else:
                self._begin_landing()
        elif item.command == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            self._reached(index)
            self._set_mode("return", force=True)  # PX4's navigator hands over to return mode
        else:  # loiter: hold at the item's position (param1 seconds, or for ever)
            self._follow([start, self._item_position(item)], corner=0.0)
            if item.command == mavlink.MAV_CMD_NAV_LOITER_TIME:
                self._hold_until = math.inf  # set when the position is reached

    def _follow(self, points, corner: float, vertical: float | None = None, speed: float | None = None) -> None:
        airframe = self.settings.airframe
        profile = TimedPath.along(
            np.asarray(points, float),
            speed if speed is not None else self.cruise_speed,
            airframe.auto_acceleration,
            corner,
            vertical_speed=vertical if vertical is not None else min(airframe.max_climb, airframe.max_descent),
        )
        self._landing = False
        self.guidance = Follow(profile)

    def _fly_to(self, target, speed: float | None = None) -> None:
        """Fly straight to ``target`` (NED) from where the vehicle would stop, then hold there (reposition)."""
        self._follow([self.model.p.copy(), self.model.stopping_point(), np.asarray(target, float)], 0.0, speed=speed)

    def _begin_takeoff(self) -> None:
        """Take-off mode, armed: climb straight up to the take-off height above home, then hold (PX4)."""
        target = self.model.p.copy()
        target[2] = float(self.home[2]) - self.takeoff_height
        if target[2] >= self.model.p[2] - 1e-3:
            self.mode = "hold"
            self._hold_here()
            return
        self._follow([self.model.p.copy(), target], 0.0, vertical=self.settings.airframe.takeoff_speed)

    def _begin_return(self) -> None:
        """Return mode: to home or a rally point (RTL_TYPE, :mod:`.geofence`), climbing to RTL_RETURN_ALT above
        it first if lower; then land."""
        start = self.model.stopping_point()
        destination, what = self._return_destination()
        self.events.append((self.t, f"return to {what}"))
        altitude = min(start[2], float(destination[2]) - self.settings.rtl_return_altitude)
        points = [self.model.p.copy(), start, np.array([start[0], start[1], altitude])]
        points.append(np.array([destination[0], destination[1], altitude]))
        self.cruise_speed = self.settings.airframe.cruise_speed
        self._follow(points, 0.0)

    def _mission_step(self) -> None:
        if self.current >= len(self.mission):
            return
        item = self.mission[self.current]
        guidance = self.guidance
        if item.command == mavlink.MAV_CMD_NAV_WAYPOINT and isinstance(guidance, Follow):
            # waypoint k of the leg is reached when the reference has passed it and the vehicle is within
            # its acceptance radius (or past the plane through it, across the path)
            profile = guidance.profile
            while self._leg_reached < len(self._leg):
                seq = self._leg[self._leg_reached]
                k = self._leg_reached + self._leg_offset  # the leg's waypoints follow its start (and climb)
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
        if item.command == mavlink.MAV_CMD_NAV_TAKEOFF and isinstance(guidance, Follow) and self._arrived(guidance):
            self._reached(self.current)
            self._start_item(self.current + 1)
        elif item.command == mavlink.MAV_CMD_NAV_LAND:
            if isinstance(guidance, Follow) and self._arrived(guidance):
                self._begin_landing()
            elif self._landing and not self.model.airborne and self._landed_at is not None:
                self._reached(self.current)
                self.current += 1
                self._mission_current()
        elif item.command in (mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LOITER_UNLIM):
            if isinstance(guidance, Follow) and self._arrived(guidance):
                self._reached(self.current)
                self.guidance = None
                self.hold_point = guidance.profile.end.copy()
                if item.command == mavlink.MAV_CMD_NAV_LOITER_TIME:
                    self._hold_until = self.t + item.param1
                    self._leg = [self.current]
