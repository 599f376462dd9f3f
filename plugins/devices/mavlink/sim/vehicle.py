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
each setpoint applies at the vehicle time it is stamped for and the
simulation never runs past the ground station's newest stamp (lockstep,
:mod:`.mavlink_sim_offboard`), so a loaded machine slows the flight down
instead of changing it. Gusts advance only in the air
(:mod:`.mavlink_sim_model`): with both, a flight is reproducible from its seed.

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
from surgiplan.plugins.devices.mavlink.conventions import MapProjection, px4_custom_mode, px4_mode_from_command
from surgiplan.plugins.devices.mavlink.link import Endpoint, mavlink, signing_key
from surgiplan.plugins.devices.mavlink.mission import MissionItem, MissionReceiver, ReceiverFaults

from .autopilot import Autopilot
from .model import PointMassMultirotor
from .offboard import OffboardSetpoints, Setpoint
from .settings import SimSettings

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
UNSUPPORTED = mavlink.MAV_RESULT_UNSUPPORTED
FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2 magic number


class SimulatedVehicle(Autopilot):
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
        self.t = 0.0  # vehicle time (s): steps * step
        self.steps = 0
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
        self.offboard = OffboardSetpoints(s.offboard_timeout, s.lockstep, s.lockstep_horizon)
        self.silent = s.stop_answering is not None and s.stop_answering.step == "connect"
        self._silence_count = 0
        self.heartbeat_lost = False
        self.telemetry_lost = False
        self.position_interval = 1.0 / s.position_rate
        self._next = {"position": 0.0, "state": 0.0, "current": 0.0}
        self._reported = -math.inf  # vehicle time of the last LOCAL_POSITION_NED
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
                if (self.steps + 1) * dt > limit + 1e-9:
                    carry = 0.0
                    if self._reported < self.t and self.position_interval > 0:
                        # waiting for a setpoint: say where we wait, or a ground station that stamps its
                        # setpoints from our reports (at a slow telemetry rate) would never get past here
                        self._report_position()
                    break
                self._physics(dt)
                self._offboard_watchdog(now)  # offboard loss on the step it falls due (vehicle time)
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
        return self.offboard.lockstep_limit() if self.mode == "offboard" else math.inf

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
        if t >= self._next["position"] - 1e-9 and self.position_interval > 0:
            # on multiples of the interval: reports fall on the ground station's setpoint grid (50 ms)
            self._next["position"] = (round(t / self.position_interval) + 1) * self.position_interval
            self._report_position()
        if t >= self._next["state"] - 1e-9:
            self._next["state"] = t + 0.2
            self._telemetry(mavlink.MAVLink_extended_sys_state_message(0, self._landed_state()))
        if t >= self._next["current"] - 1e-9:
            self._next["current"] = t + 1.0
            self._mission_current()

    def _report_position(self) -> None:
        t = self.t
        self._reported = t
        p, v = self.model.p, self.model.v
        self.trajectory.append((t, *p, *v))
        noisy = p + self._noise.normal(0.0, self.settings.position_noise, 3) if self.settings.position_noise else p
        self._telemetry(mavlink.MAVLink_local_position_ned_message(round(t * 1000), *noisy, *v))

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
        return self.offboard.fresh(time.monotonic())

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
        self.offboard.receive(Setpoint(message.time_boot_ms / 1000.0, p, v, a), self.t, now)


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
