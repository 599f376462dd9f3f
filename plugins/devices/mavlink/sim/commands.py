"""The simulated vehicle's command protocol: what PX4's commander and navigator answer, and how.

A mix-in of :class:`~.vehicle.SimulatedVehicle`. COMMAND_LONG and
COMMAND_INT (for the vehicle's system id or 0, component id or 0), each
answered by one COMMAND_ACK with PX4's result (``Commander.cpp``,
``navigator_main.cpp``, ``mavlink_receiver.cpp``):

* MAV_CMD_COMPONENT_ARM_DISARM: ACCEPTED (also when nothing changes);
  TEMPORARILY_REJECTED when arming is refused (the reason in a STATUSTEXT)
  or disarming in the air without the force magic number 21196;
* MAV_CMD_DO_SET_MODE (PX4 custom modes), MAV_CMD_NAV_TAKEOFF (param7
  altitude AMSL, else MIS_TAKEOFF_ALT above home), MAV_CMD_NAV_LAND,
  MAV_CMD_NAV_RETURN_TO_LAUNCH: ACCEPTED, or TEMPORARILY_REJECTED when the
  mode cannot be entered (offboard without setpoints, mission without a
  mission, the manual modes: no RC in a simulation);
* MAV_CMD_DO_REPOSITION: fly to a latitude/longitude/altitude (NaN: keep
  the current one) and hold there; param2 must set exactly
  MAV_DO_REPOSITION_FLAGS_CHANGE_MODE (else UNSUPPORTED, as PX4);
* MAV_CMD_MISSION_START (switches to mission mode *and arms*, as PX4),
  MAV_CMD_DO_PAUSE_CONTINUE, MAV_CMD_DO_SET_MISSION_CURRENT (DENIED for bad
  parameters, FAILED out of range), MAV_CMD_DO_CHANGE_SPEED;
* MAV_CMD_SET_MESSAGE_INTERVAL (FAILED for a message the vehicle does not
  stream, HEARTBEAT included), MAV_CMD_GET_MESSAGE_INTERVAL,
  MAV_CMD_REQUEST_MESSAGE (the message, then ACCEPTED; DENIED when the
  vehicle has no such message), MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
  (deprecated: AUTOPILOT_VERSION);
* anything else: MAV_RESULT_UNSUPPORTED.

SET_POSITION_TARGET_LOCAL_NED (offboard setpoints) is handled here too.
"""

from __future__ import annotations

import math
import time

import numpy as np
from surgiplan.plugins.devices.mavlink.conventions import PX4_MODES, px4_mode_name
from surgiplan.plugins.devices.mavlink.link import mavlink
from surgiplan.plugins.devices.mavlink.mission import GLOBAL_FRAMES

from .offboard import Setpoint

C = mavlink
ACCEPTED = C.MAV_RESULT_ACCEPTED
REJECTED = C.MAV_RESULT_TEMPORARILY_REJECTED
DENIED = C.MAV_RESULT_DENIED
FAILED = C.MAV_RESULT_FAILED
UNSUPPORTED = C.MAV_RESULT_UNSUPPORTED
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 magic number

#: PX4 modes the simulation cannot enter (they need a pilot's sticks): refused, not unknown
PILOT_MODES = {"manual", "altctl", "stabilized", "acro", "rattitude", "followme", "rtgs"}


def _lround(x: float) -> int:
    """C's lroundf (halves away from zero), as PX4 reads integer parameters of commands."""
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


class Commands:
    """The command protocol of the simulated vehicle (a mix-in: see the module's docstring)."""

    def _ack(self, command: int, result: int, source) -> None:
        self._send([C.MAVLink_command_ack_message(command, result, 255, 0, source[0], source[1])])

    def _params7(self, message) -> list[float]:
        """param1..7 of a COMMAND_LONG or COMMAND_INT (COMMAND_INT: x, y in degrees for global frames)."""
        p = [float(message.param1), float(message.param2), float(message.param3), float(message.param4)]
        if message.get_type() == "COMMAND_INT":
            k = 1e-7 if int(message.frame) in GLOBAL_FRAMES else 1.0
            return [*p, message.x * k, message.y * k, float(message.z)]
        return [*p, float(message.param5), float(message.param6), float(message.param7)]

    def _command(self, message, source) -> None:
        command = int(message.command)
        if getattr(message, "target_component", 0) not in (0, self.settings.component_id):
            return
        params = self._params7(message)
        steps = {
            C.MAV_CMD_COMPONENT_ARM_DISARM: "arming",
            C.MAV_CMD_DO_SET_MODE: "mode_change",
            C.MAV_CMD_MISSION_START: "mission_start",
        }
        step = steps.get(command)
        if command == C.MAV_CMD_DO_SET_MODE and self._mode_asked(params) == "mission":
            step = "mission_start"  # switching to mission mode starts a mission, as MISSION_START does
        if step is not None and self._silence(step):
            return
        if command == C.MAV_CMD_DO_REPOSITION and message.get_type() == "COMMAND_INT":
            relative = int(message.frame) in (C.MAV_FRAME_GLOBAL_RELATIVE_ALT, C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
            if relative and math.isfinite(params[6]):
                params[6] += self.settings.origin[2] - float(self.home[2])  # relative to home -> AMSL
        handler = {
            C.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm,
            C.MAV_CMD_DO_SET_MODE: self._cmd_mode,
            C.MAV_CMD_NAV_TAKEOFF: self._cmd_takeoff,
            C.MAV_CMD_NAV_LAND: lambda p: self._request_mode("land"),
            C.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda p: self._request_mode("return"),
            C.MAV_CMD_DO_REPOSITION: self._cmd_reposition,
            C.MAV_CMD_MISSION_START: self._cmd_mission_start,
            C.MAV_CMD_DO_PAUSE_CONTINUE: self._cmd_pause,
            C.MAV_CMD_DO_SET_MISSION_CURRENT: self._cmd_set_mission_current,
            C.MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
            C.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_interval,
            C.MAV_CMD_GET_MESSAGE_INTERVAL: lambda p: self._cmd_get_interval(p, source),
            C.MAV_CMD_REQUEST_MESSAGE: lambda p: self._cmd_request(p, source),
            C.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda p: self._cmd_request(
                [C.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0], source
            ),
        }.get(command)
        result = handler(params) if handler is not None else UNSUPPORTED
        self.commands_answered.append((command, result))
        self._ack(command, result, source)

    # ------------------------------------------------------------------ arming and modes
    def _cmd_arm(self, params) -> int:
        action = _lround(params[0]) if math.isfinite(params[0]) else -1
        forced = math.isfinite(params[1]) and _lround(params[1]) == FORCE_DISARM
        if action == 1:
            return self._arm("external command")
        if action != 0:
            self._say(f"Unsupported ARM_DISARM param: {params[0]:.3f}", C.MAV_SEVERITY_CRITICAL)
            return UNSUPPORTED
        if self.model.airborne and not forced:
            self._say("Disarming denied: not landed", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        if self.armed:
            self._disarm("Disarmed by external command")
        return ACCEPTED

    def _arm(self, why: str) -> int:
        if self.armed:
            return ACCEPTED
        if self.settings.refuse_arming:
            self._say(f"Arming denied: {self.settings.refuse_arming}", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        if self.mode == "offboard" and not self._fresh_setpoint():
            self._say("Arming denied: no offboard setpoints", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        if self.mode == "mission" and not self.mission:
            self._say("Arming denied: no valid mission", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        if self.mode == "mission" and (problem := self._mission_start_problem()) is not None:
            self._say(problem, C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        self.armed = True
        self.armed_at = self.t
        self._next_fence_check = 0
        self._armed_wall = time.monotonic()
        self.hold_point = self.model.p.copy()
        self.home = self.model.p.copy()  # PX4 (COM_HOME_EN): home is where the vehicle arms
        self._say(f"Armed by {why}")
        if self.mode == "mission" and self.mission:
            self._start_mission()
        elif self.mode == "takeoff":
            self._begin_takeoff()
        return ACCEPTED

    def _fresh_setpoint(self) -> bool:
        return self.offboard.fresh(time.monotonic())

    def _mode_asked(self, params) -> str | None:
        base = int(params[0]) if math.isfinite(params[0]) else 0
        if not base & C.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return None
        main, sub = int(params[1]), int(params[2])
        return px4_mode_name((main << 16) | (sub << 24))

    def _cmd_mode(self, params) -> int:
        mode = self._mode_asked(params)
        if mode is None:  # base mode flags without MAV_MODE_FLAG_CUSTOM_MODE_ENABLED: not simulated
            self._say("Only PX4 custom modes are supported", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        if mode in PILOT_MODES:
            self._say(f"Switching to {mode} is not possible: no RC", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        return self._request_mode(mode)

    def _request_mode(self, mode: str) -> int:
        if mode not in PX4_MODES:
            self._say(f"Unsupported mode {mode}", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        return ACCEPTED if self._set_mode(mode) else REJECTED

    def _cmd_takeoff(self, params) -> int:
        altitude = params[6]
        height = (
            altitude - (self.settings.origin[2] - float(self.home[2]))
            if math.isfinite(altitude)
            else self.settings.takeoff_altitude
        )
        if height <= 0:
            self._say("Takeoff denied: altitude below home", C.MAV_SEVERITY_CRITICAL)
            return DENIED
        self._takeoff_request = height
        return ACCEPTED if self._set_mode("takeoff", force=True) else REJECTED

    def _cmd_reposition(self, params) -> int:
        flags = int(params[1]) if math.isfinite(params[1]) else 0
        if flags != C.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE:
            return UNSUPPORTED  # PX4: the mode change bit must be set, and nothing else
        if not self.armed or not self.model.airborne:
            self._say("Reposition denied: not flying", C.MAV_SEVERITY_CRITICAL)
            return REJECTED
        target = self.model.p.copy()
        lat, lon, alt = params[4], params[5], params[6]
        if math.isfinite(lat) and math.isfinite(lon):
            target[0], target[1] = (float(v) for v in self.projection.project(lat, lon))
        if math.isfinite(alt):
            target[2] = self.settings.origin[2] - alt
        speed = params[0]
        self.mode = "hold"
        self.events.append((self.t, f"reposition to {np.round(target, 3).tolist()}"))
        self._fly_to(target, speed if math.isfinite(speed) and speed > 0 else None)
        return ACCEPTED

    # ------------------------------------------------------------------ missions
    def _cmd_mission_start(self, params) -> int:
        if not self.mission:
            self._say("Mission start denied! No valid mission", C.MAV_SEVERITY_CRITICAL)
            return DENIED
        if (problem := self._mission_start_problem()) is not None:
            self._say(problem, C.MAV_SEVERITY_CRITICAL)
            return DENIED
        first = params[0]
        if not (math.isfinite(first) and -1 <= first < len(self.mission)):
            return DENIED
        if self.mode == "mission" and self.armed and self.guidance is not None:
            return ACCEPTED  # already flying it
        if first >= 0:
            self.current = int(first)
        self.mode = "mission"
        self.events.append((self.t, "mode mission"))
        if self.armed:
            self._start_mission()
            return ACCEPTED
        return ACCEPTED if self._arm("mission start") == ACCEPTED else REJECTED  # PX4 arms on MISSION_START

    def _cmd_pause(self, params) -> int:
        if params[0] < 0.5:
            self.mode = "hold"
            self._hold_here()
        elif self.mission:
            self.mode = "mission"
            if self.armed:
                self._start_item(self.current)
        return ACCEPTED

    def _cmd_set_mission_current(self, params) -> int:
        seq, reset = params[0], params[1]
        if not (math.isfinite(seq) and seq >= -1 and math.isfinite(reset) and reset in (0.0, 1.0)):
            return DENIED
        if seq == -1:
            return ACCEPTED if self.mission else FAILED
        return ACCEPTED if self.set_current(int(seq)) else FAILED

    def _cmd_change_speed(self, params) -> int:
        speed = params[1]
        if not math.isfinite(speed) or speed <= 0:
            return ACCEPTED  # PX4: -1 and 0 mean "no change"
        self.cruise_speed = min(speed, self.settings.airframe.max_speed)
        return ACCEPTED

    # ------------------------------------------------------------------ messages on request
    def _cmd_interval(self, params) -> int:
        if any(math.isfinite(p) and round(p) != 0 for p in (params[2], params[3], params[6])):
            return FAILED  # PX4: param3, param4 and the response target are not supported
        return self.set_interval(int(params[0]), params[1])

    def _cmd_get_interval(self, params, source) -> int:
        self._send([self.interval_message(int(params[0]))])
        return ACCEPTED

    def _cmd_request(self, params, source) -> int:
        message_id = int(params[0]) if math.isfinite(params[0]) else -1
        self.messages_requested.append(message_id)
        if message_id == C.MAVLINK_MSG_ID_MESSAGE_INTERVAL:
            self._send([self.interval_message(int(params[1]))])
            return ACCEPTED
        message = self.requestable(message_id)
        if message is None:
            return DENIED  # PX4: no stream of that id
        self._send([message])  # PX4 sends the message first, then the acknowledgement
        return ACCEPTED

    # ------------------------------------------------------------------ offboard
    def _setpoint(self, message, now: float) -> None:
        if message.coordinate_frame != C.MAV_FRAME_LOCAL_NED:
            return
        mask = int(message.type_mask)
        p = np.array([message.x, message.y, message.z])
        v = np.zeros(3) if mask & 0b111000 else np.array([message.vx, message.vy, message.vz])
        a = np.zeros(3) if mask & 0b111000000 else np.array([message.afx, message.afy, message.afz])
        self.offboard.receive(Setpoint(message.time_boot_ms / 1000.0, p, v, a), self.t, now)
