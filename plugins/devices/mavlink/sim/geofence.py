"""The simulated vehicle's geofence and rally points, kept and enforced as PX4's navigator and commander do.

A mix-in of :class:`~.vehicle.SimulatedVehicle` (it uses the vehicle's
state, airframe, parameters and telemetry). Everything the ground station
uploads is judged and enforced *on the vehicle*: a flight's safety does not
depend on the link staying up.

* **The lists** (``src/modules/navigator/geofence.cpp``): the fence items
  accepted (``MAV_MISSION_TYPE_FENCE``) become zones in the local
  north/east plane (:func:`~surgiplan.plugins.devices.mavlink.zones.zones_from_items`,
  PX4's projection about the EKF origin); a zone that would leave home
  outside the fence, or (armed, in the air, GF_ACTION not 0) the vehicle
  itself, is dropped with PX4's message ("Geofence invalid, doesn't contain
  Home position"); a list whose polygons do not add up is refused with
  MAV_MISSION_ERROR. Rally points (``MAV_MISSION_TYPE_RALLY``) are kept as
  return destinations.
* **Feasibility** (PX4's ``MissionFeasibilityChecker``): a mission uploaded
  while a fence is in force (zones, GF_MAX_VER_DIST or GF_MAX_HOR_DIST)
  whose waypoint is outside it, or (as PX4 1.16 checks) whose straight leg
  between two waypoints leaves it, is refused: MISSION_ACK
  ``MAV_MISSION_DENIED`` and the STATUSTEXT "Geofence violation for
  waypoint N" or "Geofence breach on path to waypoint N" (N counted from 1,
  as PX4 does). PX4 itself acknowledges the upload and refuses the mission
  when it is started; the simulator says so at once, and refuses at the start
  too a mission that a fence uploaded later makes infeasible.
* **The breach check** (PX4's ``Navigator::geofence_breach_check``): every
  200 ms of vehicle time, armed and in the air, with GF_ACTION not 0, the
  position is tested; with GF_PREDICT 1 the point the vehicle would reach if
  it braked now is tested instead: ahead along its horizontal velocity by the
  200 ms to the next check plus its braking distance
  (:func:`~.model.braking_distance`, the position loop's overshoot, about
  0.30 s x v, longer by what its velocity integral has learnt), both at the
  speed it may have by the next check if it goes on accelerating as it does
  (PX4 takes the speed of the moment), and above or below by the same for
  its climb rate. At a steady 1.5 m/s that is
  0.30 + 0.45 = 0.75 m ahead. On a breach (once, until it
  clears) the vehicle says so (STATUSTEXT) and does GF_ACTION: 1 nothing
  more, 2 hold (where it is when the breach is predicted: it brakes within
  the braking distance, so before the fence, and settles back), 3 return,
  4 terminate (motors off), 5 land. Without GF_PREDICT the breach is seen
  only once the fence is crossed, and the vehicle holds beyond it, as PX4's.
* **SYS_STATUS**: ``MAV_SYS_STATUS_GEOFENCE`` present while a fence is in
  force, enabled when GF_ACTION is not 0, healthy while it is not breached.
* **Return** (PX4's RTL_TYPE): 0 to the nearest (horizontally) of home and
  the rally points, 1 to the nearest rally point (home without one); the
  return climbs to RTL_RETURN_ALT above that destination first if lower,
  flies there straight, and lands.
"""

from __future__ import annotations

import math

import numpy as np
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.mission import FENCE, MISSION, MissionItem
from surgiplan.plugins.devices.mavlink.zones import FenceFormatError, Zone, inside_fence, path_clear, zones_from_items

from .model import braking_distance

C = mavlink
#: PX4's GEOFENCE_CHECK_INTERVAL_US (s)
CHECK_INTERVAL = 0.2
#: mission items with a position (what the feasibility check tests)
POSITION_ITEMS = {
    C.MAV_CMD_NAV_WAYPOINT,
    C.MAV_CMD_NAV_TAKEOFF,
    C.MAV_CMD_NAV_LAND,
    C.MAV_CMD_NAV_LOITER_TIME,
    C.MAV_CMD_NAV_LOITER_UNLIM,
}
#: GF_ACTION values (PX4's geofence_violation_action) and what the STATUSTEXT says
ACTIONS = {0: "none", 1: "warning", 2: "hold", 3: "return", 4: "terminate", 5: "land"}


class Geofence:
    """The geofence and rally points of the simulated vehicle (a mix-in: see the module's docstring)."""

    def _init_geofence(self) -> None:
        #: the zones in force (local north, east), the rally points (local NED)
        self.zones: list[Zone] = []
        self.rally_points: list[np.ndarray] = []
        #: every breach acted on: vehicle time, kind, GF_ACTION, position and the point tested (NED)
        self.fence_breaches: list[dict] = []
        self._breached = False
        #: the next breach check, counted in CHECK_INTERVALs since arming
        self._next_fence_check = 0

    # ------------------------------------------------------------------ the lists
    @property
    def fence_present(self) -> bool:
        s = self.settings
        return bool(self.zones) or s.geofence_max_vertical > 0 or s.geofence_max_horizontal > 0

    def _check_list(self, items: list[MissionItem], mission_type: int) -> int | None:
        """The whole-list judgement before a list is accepted (MissionReceiver's ``check``)."""
        if mission_type == FENCE:
            try:
                zones_from_items(items, self.projection)
            except FenceFormatError as exc:
                self._say(f"fence: {exc}"[:50], C.MAV_SEVERITY_CRITICAL)
                return C.MAV_MISSION_ERROR
        elif mission_type == MISSION and self.fence_present:
            problem = self._infeasible(items)
            if problem is not None:
                self._say(problem, C.MAV_SEVERITY_CRITICAL)
                return C.MAV_MISSION_DENIED
        return None

    def _fence_accepted(self, items: list[MissionItem]) -> None:
        zones, _ = zones_from_items(items, self.projection)
        kept = []
        for zone in zones:
            if not inside_fence([zone], self.home[:2])[0]:
                self._say("Geofence invalid, doesn't contain Home position", C.MAV_SEVERITY_CRITICAL)
                continue
            flying = self.armed and self.model.airborne and self.settings.geofence_action != 0
            if flying and not inside_fence([zone], self.model.p[:2])[0]:
                self._say("Geofence invalid, doesn't contain current vehicle position", C.MAV_SEVERITY_CRITICAL)
                continue
            kept.append(zone)
        self.zones = kept
        self._breached = False
        self.events.append((self.t, f"geofence: {len(kept)} zones in force"))

    def _rally_accepted(self, items: list[MissionItem]) -> None:
        self.rally_points = [self._item_position(item) for item in items if item.command == C.MAV_CMD_NAV_RALLY_POINT]
        self.events.append((self.t, f"{len(self.rally_points)} rally points"))

    # ------------------------------------------------------------------ feasibility
    def _violation(self, point: np.ndarray) -> str | None:
        """Which limit a local NED point is beyond (PX4's checkPointAgainstAllGeofences), or None."""
        s = self.settings
        if s.geofence_max_vertical > 0 and float(self.home[2] - point[2]) >= s.geofence_max_vertical:
            return "max altitude"
        if s.geofence_max_horizontal > 0 and float(np.hypot(*(point[:2] - self.home[:2]))) >= s.geofence_max_horizontal:
            return "max distance"
        if not inside_fence(self.zones, point[:2])[0]:
            return "fence"
        return None

    def _infeasible(self, mission: list[MissionItem]) -> str | None:
        """PX4's words for the first waypoint outside the fence, or leg leaving it; None when feasible."""
        previous = None
        for seq, item in enumerate(mission):
            if item.command not in POSITION_ITEMS:
                continue
            point = self._item_position(item)
            if self._violation(point) is not None:
                return f"Geofence violation for waypoint {seq + 1}"
            if previous is not None and not path_clear(self.zones, previous[:2], point[:2]):
                return f"Geofence breach on path to waypoint {seq + 1}"
            previous = point
        return None

    # ------------------------------------------------------------------ the breach check
    def _test_point(self) -> np.ndarray:
        """Where the breach check looks: the position, or (GF_PREDICT) where braking now would take it."""
        p, v = self.model.p, self.model.v
        if not self.settings.geofence_predict:
            return p.copy()
        airframe = self.settings.airframe
        thrust = np.asarray(self.model.thrust, float)
        test = p.copy()
        speed = float(np.hypot(v[0], v[1]))
        if speed > 1e-6:
            direction = v[:2] / speed
            # the speed it may have by the next check, accelerating as it does now
            faster = min(speed + max(float(thrust[:2] @ direction), 0.0) * CHECK_INTERVAL, airframe.max_speed)
            learnt = float(np.asarray(self.model.integral[:2], float) @ direction)
            braking = braking_distance(airframe, faster, self.settings.step, integral=learnt)
            ahead = CHECK_INTERVAL * 0.5 * (speed + faster) + braking
            test[:2] += ahead * direction
        climb = -float(v[2])
        if abs(climb) > 1e-6:
            up = braking_distance(airframe, abs(climb), self.settings.step, vertical=True) + CHECK_INTERVAL * abs(climb)
            test[2] -= math.copysign(up, climb)
        return test

    def _geofence_step(self) -> None:
        """PX4's breach check, every CHECK_INTERVAL s of vehicle time since arming (called after each physics
        step; counted from arming, so that a flight is checked at the same instants however long the vehicle
        waited on the ground first)."""
        action = int(self.settings.geofence_action)
        if action == 0 or not self.armed or self.armed_at is None or not self.model.airborne or not self.fence_present:
            self._breached = False
            return
        tick = math.floor((self.t - self.armed_at) / CHECK_INTERVAL + 1e-6)
        if tick < self._next_fence_check:
            return
        self._next_fence_check = tick + 1
        test = self._test_point()
        kind = self._violation(test)
        if kind is None:
            self._breached = False
            return
        if self._breached:
            return
        self._breached = True
        self.fence_breaches.append(
            {
                "t": self.t,
                "kind": kind,
                "action": ACTIONS[action],
                "mode": self.mode,
                "position": self.model.p.tolist(),
                "velocity": self.model.v.tolist(),
                "test_point": test.tolist(),
            }
        )
        self._act_on_breach(action, kind)

    def _act_on_breach(self, action: int, kind: str) -> None:
        words = {1: "warning", 2: "holding", 3: "returning", 4: "terminating", 5: "landing"}[action]
        self._say(f"Geofence breached ({kind}): {words}", C.MAV_SEVERITY_CRITICAL)
        if action == 2:
            self.guidance = None
            self._landing = False
            self.hold_point = self.model.p.copy()  # it brakes within its braking distance, and settles back
            if self.mode != "hold":
                self.mode = "hold"
                self.events.append((self.t, "mode hold (geofence)"))
        elif action == 3:
            self._set_mode("return", force=self.mode != "return")
        elif action == 5:
            self._set_mode("land", force=self.mode != "land")
        elif action == 4:
            self._disarm("Flight termination (geofence)")

    # ------------------------------------------------------------------ telemetry and return
    def _geofence_sensor_bits(self) -> tuple[int, int, int]:
        """SYS_STATUS present, enabled and health bits for the geofence (healthy unless breached, present or
        not: MAVProxy reads a clear health bit as a breach)."""
        bit = C.MAV_SYS_STATUS_GEOFENCE
        health = 0 if self._breached else bit
        if not self.fence_present:
            return 0, 0, health
        return bit, bit if self.settings.geofence_action != 0 else 0, health

    def _return_destination(self) -> tuple[np.ndarray, str]:
        """Where a return goes (local NED) and what it is, by RTL_TYPE."""
        home = np.asarray(self.home, float)
        candidates = [(point, f"rally point {k}") for k, point in enumerate(self.rally_points)]
        if self.settings.rtl_type == 0 or not candidates:
            candidates.append((home, "home"))
        p = self.model.p
        return min(candidates, key=lambda c: float(np.hypot(*(c[0][:2] - p[:2]))))

    def _mission_start_problem(self) -> str | None:
        """A mission a fence uploaded after it makes infeasible is refused at its start (PX4)."""
        if not self.fence_present or not self.mission:
            return None
        return self._infeasible(self.mission)
