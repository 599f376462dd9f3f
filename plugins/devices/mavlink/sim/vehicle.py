"""``surgiplan-sim-vehicle``: a simulated PX4-like quadrotor that speaks MAVLink 2 as PX4 does.

It implements, over any pymavlink connection (UDP by default), what a PX4
vehicle offers a ground station (the README's MAVLink table lists it, and
what is answered MAV_RESULT_UNSUPPORTED), so that MAVSDK, MAVProxy,
QGroundControl and the ``mavlink_vehicle`` device can rehearse against it:

* telemetry (:mod:`.telemetry`): HEARTBEAT at 1 Hz of wall clock, SYS_STATUS,
  EXTENDED_SYS_STATE, ATTITUDE, GLOBAL_POSITION_INT, LOCAL_POSITION_NED,
  GPS_RAW_INT, HOME_POSITION, BATTERY_STATUS, VFR_HUD, GPS_GLOBAL_ORIGIN at
  PX4's default rates for a ground station link, changed by
  SET_MESSAGE_INTERVAL; MISSION_CURRENT, MISSION_ITEM_REACHED, STATUSTEXT;
  AUTOPILOT_VERSION with the capability bits it honours;
* the command protocol (:mod:`.commands`): arming, PX4 modes, take-off,
  land, return, reposition, mission start/pause/current, speed, message
  intervals and requests; everything else MAV_RESULT_UNSUPPORTED;
* the mission protocol for missions, geofences and rally points (upload,
  download, clear, set current; :mod:`.missions` holds PX4's rules);
* the parameter protocol over a subset of PX4's parameters that drive the
  simulation (:mod:`.params`);
* PING and TIMESYNC answered;
* the geofence and rally points, enforced on the vehicle (:mod:`.geofence`):
  missions that leave the fence refused, breaches acted on (GF_ACTION),
  returns to the nearest rally point;
* mission execution, take-off, return, reposition, land, loiter and
  offboard control by SET_POSITION_TARGET_LOCAL_NED (:mod:`.autopilot`), with
  a point-mass multirotor (:mod:`.model`) under velocity and acceleration
  limits, in wind;
* faults from its settings (:mod:`.settings`): packet loss both ways,
  falling silent at a protocol step, refusing missions or arming, losing
  its heartbeat in flight.

Time: the physics runs at ``speed`` simulated seconds per wall second (so a
test flight can run faster than real time); the link's own timing
(heartbeats, protocol timeouts) stays on the wall clock. In offboard mode
each setpoint applies at the vehicle time it is stamped for and the
simulation never runs past the ground station's newest stamp (lockstep,
:mod:`.offboard`), so a loaded machine slows the flight down instead of
changing it. Gusts advance only in the air (:mod:`.model`): with both, a
flight is reproducible from its seed.

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
from surgiplan.plugins.devices.mavlink.conventions import MapProjection, px4_custom_mode
from surgiplan.plugins.devices.mavlink.link import Endpoint, mavlink, signing_key
from surgiplan.plugins.devices.mavlink.mission import ALL_TYPES, FENCE, MISSION, RALLY, MissionItem
from surgiplan.plugins.devices.mavlink.mission_vehicle import MissionReceiver, MissionSender, ReceiverFaults

from .autopilot import Autopilot
from .commands import Commands
from .geofence import Geofence
from .missions import px4_check, px4_stored
from .model import PointMassMultirotor
from .offboard import OffboardSetpoints
from .params import ParameterStore
from .settings import SimSettings
from .telemetry import Telemetry

#: while waiting in lockstep for a setpoint, the position is said again this often (wall s): a lost
#: report must not leave a ground station that stamps its setpoints from the reports waiting for ever
WAITING_REPORT = 0.1


class SimulatedVehicle(Autopilot, Commands, Geofence, Telemetry):
    """The simulated vehicle on ``connection`` (a listening UDP port by default)."""

    def __init__(self, settings: SimSettings | None = None, connection: str = "udpin:127.0.0.1:0") -> None:
        # a private copy: the parameters (PARAM_SET) change it while the simulation runs
        self.settings = s = (settings or SimSettings()).model_copy(deep=True)
        key = signing_key(s.signing_key) if s.signing_key else None
        self.endpoint = Endpoint(
            connection, system_id=s.system_id, component_id=s.component_id, key=key, loss=s.packet_loss, seed=s.seed
        )
        self.params = ParameterStore(s, self._parameter_changed)
        self.model = PointMassMultirotor(s.airframe, s.home, s.wind, seed=s.seed + 1)
        self.projection = MapProjection(s.origin[0], s.origin[1])
        self.home = np.asarray(s.home, float).copy()
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
            capacity={MISSION: s.mission_capacity, FENCE: s.fence_capacity, RALLY: s.rally_capacity},
            timeout=s.mission_timeout,
            retries=s.mission_retries,
            validate=self._validate_item,
            check=self._check_list,
            on_accept=self._mission_accepted,
            faults=faults,
            types=(MISSION, FENCE, RALLY),
            int_requests="MISSION_INT" not in s.capabilities_withheld,
        )
        self.sender = MissionSender(
            lambda mission_type: len(self.receiver.stored.get(mission_type, [])),
            lambda seq, mission_type, int_form: px4_stored(self.receiver.stored[mission_type][seq], int_form),
            current=lambda: self.current,
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
        self._leg_offset = 1
        self._hold_until: float | None = None
        self._landing = False
        self._landed_at: float | None = None
        self.armed_at: float | None = None
        self._armed_wall = math.inf
        self._armed_time = 0.0
        self._consumed_mah = 0.0
        self.takeoff_height = s.takeoff_altitude
        self._takeoff_request: float | None = None
        self.offboard = OffboardSetpoints(s.offboard_timeout, s.lockstep, s.lockstep_horizon)
        self.silent = s.stop_answering is not None and s.stop_answering.step == "connect"
        self._silence_count = 0
        self.heartbeat_lost = False
        self.telemetry_lost = False
        self._next = {"current": 0.0}
        self._init_telemetry()
        self._init_geofence()
        self._reported = -math.inf  # vehicle time of the last LOCAL_POSITION_NED
        self._reported_wall = -math.inf
        #: (t, x, y, z, vx, vy, vz) true states at the position rate, for tests and figures
        self.trajectory: list[tuple[float, ...]] = []
        #: what happened, in words, with the vehicle time (for tests and the log)
        self.events: list[tuple[float, str]] = []
        #: (MAV_CMD, MAV_RESULT) of every command answered, in order (for tests)
        self.commands_answered: list[tuple[int, int]] = []
        #: the message ids MAV_CMD_REQUEST_MESSAGE asked for, in order (for tests)
        self.messages_requested: list[int] = []
        #: every list the vehicle accepted (upload or clear), with its mission type, in order (for tests)
        self.uploads: list[tuple[int, list[MissionItem]]] = []
        #: messages received by type (for tests: what a client sent)
        self.received: dict[str, int] = {}
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        #: set (SIGUSR1 in the program): print link_statistics() as a JSON line on stdout at the next pass
        self.statistics_requested = threading.Event()

    def link_statistics(self) -> dict:
        """What went over the link, as the vehicle counted it (the device reports it for a simulated vehicle)."""
        stats = self.endpoint.stats
        return {
            "messages_sent": int(sum(stats.sent.values())),
            "messages_received": int(sum(stats.received.values())),
            # injected faults: messages dropped before sending, and received but dropped
            "injected_drops_out": stats.dropped_out,
            "injected_drops_in": stats.dropped_in,
            # the ground station's messages that never arrived, by the gaps in their sequence numbers
            "lost_in": self.endpoint.lost_in,
        }

    def _parameter_changed(self, parameter, value) -> None:
        self.events.append((self.t, f"parameter {parameter.name} = {value}"))
        if parameter.name == "COM_OF_LOSS_T":
            self.offboard.timeout = float(value)
        elif parameter.name == "MPC_XY_CRUISE":
            self.cruise_speed = float(value)

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
                    self._waiting_report(now)
                    break
                self._physics(dt)
                self._offboard_watchdog(now)  # offboard loss on the step it falls due (vehicle time)
            if steps == 0 and self.t + dt > limit + 1e-9:
                self._waiting_report(now)
            for message in self.endpoint.receive():
                self._handle(message, now)
            self._send(self.receiver.on_timer(now))
            self.sender.on_timer(now)
            self._offboard_watchdog(now)
            if now >= self._next_heartbeat:
                self._heartbeat()
                self._next_heartbeat = now + 1.0 / self.settings.heartbeat_rate
            if self.statistics_requested.is_set():
                self.statistics_requested.clear()
                print(json.dumps({"link": self.link_statistics()}), flush=True)
            if not behind:  # running behind the asked speed: no sleeping
                wait = min(0.005, self._next_heartbeat - now, self.receiver.deadline - now)
                self.endpoint.wait(max(wait, 0.0))

    def _time_limit(self, now: float) -> float:
        return self.offboard.lockstep_limit() if self.mode == "offboard" else math.inf

    def _waiting_report(self, now: float) -> None:
        """Waiting for a setpoint: say where we wait (once per vehicle time, then every WAITING_REPORT wall s).

        A ground station that stamps its setpoints from our reports (at a slow telemetry rate) would
        otherwise never get past here, nor one that lost the one report sent at this time."""
        if self.position_interval <= 0:
            return
        if self._reported < self.t:
            self._report_position()
        elif now - self._reported_wall >= WAITING_REPORT:
            self._reported_wall = now
            self._telemetry(self._position_message())

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
        if self.mode == "takeoff" and self.guidance is not None:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _position_message(self):
        p, v = self.model.p, self.model.v
        noisy = p + self._noise.normal(0.0, self.settings.position_noise, 3) if self.settings.position_noise else p
        return mavlink.MAVLink_local_position_ned_message(round(self.t * 1000), *noisy, *v)

    def _report_position(self) -> None:
        t = self.t
        self._reported = t
        self._reported_wall = time.monotonic()
        p, v = self.model.p, self.model.v
        self.trajectory.append((t, *p, *v))
        self._telemetry(self._position_message())

    def _mission_current_message(self):
        if not self.mission:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self.current >= len(self.mission):
            state = mavlink.MISSION_STATE_COMPLETE
        elif self.mode == "mission" and self.armed:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED
        total = len(self.mission) if self.mission else 0xFFFF  # the spec's (and PX4's) "no mission"
        return mavlink.MAVLink_mission_current_message(self.current, total, state, int(self.mode == "mission"))

    def _mission_current(self) -> None:
        self._telemetry(self._mission_current_message())

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
        self.received[kind] = self.received.get(kind, 0) + 1
        source = (message.get_srcSystem(), message.get_srcComponent())
        target = getattr(message, "target_system", None)
        if target not in (None, 0, self.settings.system_id):
            return
        if kind in ("MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM"):
            list_type = int(getattr(message, "mission_type", MISSION))
            if self._silence({FENCE: "fence_upload", RALLY: "rally_upload"}.get(list_type, "mission_upload")):
                return
            if self.sender.busy and kind == "MISSION_COUNT":
                if self.sender.partner == source and self.sender.next_seq >= self.sender.total:
                    self.sender.partner = None  # every item went out: the download's final ACK was lost
                else:
                    self._send([mavlink.MAVLink_mission_ack_message(*source, mavlink.MAV_MISSION_ERROR, list_type)])
                    return  # PX4: busy with a download
            self._send(self.receiver.on_message(message, source, now))
        elif kind in ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"):
            self._send(self.sender.on_message(message, source, now))
        elif kind == "MISSION_CLEAR_ALL":
            self._clear(message, source)
        elif kind == "MISSION_SET_CURRENT":
            if not self.set_current(int(message.seq)):
                self._say("WPM: WP CURR CMD: Not in list", mavlink.MAV_SEVERITY_CRITICAL)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            self._command(message, source)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            if "SET_POSITION_TARGET_LOCAL_NED" not in self.settings.capabilities_withheld:
                self._setpoint(message, now)
        elif kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            answers, refusal = self.params.handle(message)
            self._send(answers)  # the value in force first, then why it is not the one asked for
            if refusal:
                self._say(f"param: {refusal}", mavlink.MAV_SEVERITY_WARNING)
        elif kind == "PING":
            self._ping(message, source)
        elif kind == "TIMESYNC":
            if int(message.tc1) == 0:  # a request: our time (ns) and theirs back (PX4's timesync)
                self._send([mavlink.MAVLink_timesync_message(time.monotonic_ns(), int(message.ts1))])

    def _ping(self, message, source) -> None:
        """A PING addressed to all (target 0/0) is a request: sent back, addressed to the sender (PX4)."""
        if int(message.target_system) == 0 and int(message.target_component) == 0:
            self._send([mavlink.MAVLink_ping_message(int(message.time_usec), int(message.seq), *source)])

    def _clear(self, message, source) -> None:
        mission_type = int(getattr(message, "mission_type", MISSION))
        if self.receiver.busy or self.sender.busy:
            self._say("WPM: IGN CLEAR CMD: Busy", mavlink.MAV_SEVERITY_CRITICAL)
            return
        if mission_type not in (MISSION, FENCE, RALLY, ALL_TYPES):
            result = mavlink.MAV_MISSION_ERROR
        else:
            self.receiver.clear(mission_type)
            result = mavlink.MAV_MISSION_ACCEPTED
        self._send([mavlink.MAVLink_mission_ack_message(*source, result, mission_type)])

    def _validate_item(self, item: MissionItem, seq: int, mission_type: int, int_form: bool) -> int | None:
        result, why = px4_check(item, mission_type, int_form)
        if result is not None:
            self._say(f"item {seq}: {why}"[:50], mavlink.MAV_SEVERITY_CRITICAL)
        return result


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
    from surgiplan.processes import exit_with_parent

    exit_with_parent()  # started by a run (mavlink_vehicle): never outlive it, even a kill -9 of it

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
    # SIGUSR1: the link statistics as a JSON line on stdout (the device reads them for its report)
    signal.signal(signal.SIGUSR1, lambda *_args: vehicle.statistics_requested.set())
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
