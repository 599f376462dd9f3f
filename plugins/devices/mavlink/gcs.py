"""The ground-station side of a MAVLink link: heartbeats and liveness, commands, missions, parameters.

mavlink.io services used:

* *Heartbeat*: both ends send HEARTBEAT at 1 Hz; a system is lost when
  ``missed`` heartbeats in a row (5 by default) do not arrive.
* *Command protocol*: :class:`~.transactions.CommandTransaction`,
  COMMAND_LONG re-sent with ``confirmation`` increased when no COMMAND_ACK
  arrives within the timeout (default 1.5 s, 5 retries);
  MAV_RESULT_IN_PROGRESS extends the wait.
* *Mission protocol*: :class:`~.mission_gcs.MissionUpload`; a transfer
  that fails for a lost link is started again from MISSION_COUNT up to
  ``upload_attempts`` times, a refusal (MISSION_ACK with an error) never is;
  :class:`~.mission_gcs.MissionDownload` and :class:`~.mission_gcs.MissionClear`
  likewise (a download is how an upload is verified).
* *Parameter protocol*: :class:`~.transactions.ParamTransaction` reads one parameter by name
  (PARAM_REQUEST_READ) or sets it (PARAM_SET) and waits for the vehicle's
  PARAM_VALUE, re-sent after each timeout; INT32 values are decoded bytewise
  when the vehicle says it encodes them so (PX4), by a C cast otherwise.
* *Capabilities*: AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE), whose
  ``capabilities`` bits say which protocols the vehicle honours.
* *Offboard control* and telemetry rates (MAV_CMD_SET_MESSAGE_INTERVAL,
  MAV_CMD_REQUEST_MESSAGE) are thin helpers over the command protocol.

Everything runs in the caller's thread: :meth:`GroundStation.pump` waits for
traffic, updates :class:`~.vehicle_state.VehicleState`, sends our heartbeat when due, and
raises :class:`LinkLost` when the vehicle's heartbeats stop. Errors are
:class:`~.mavlink_link.VehicleError` naming the step (``arming: ...``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence

import numpy as np

from .conventions import px4_mode_command, px4_mode_name
from .link import Endpoint, VehicleError, is_mavlink2, mavlink
from .mission import MISSION, MissionItem
from .mission_gcs import MissionClear, MissionDownload, MissionUpload, UploadStatistics
from .tlog import RECORDING_STARTED, RECORDING_STOPPED
from .transactions import (
    RESULT_ACCEPTED,
    CommandTransaction,
    ParamDownload,
    ParamTransaction,
    command_name,
    result_name,
)
from .vehicle_state import PositionSample, VehicleState

log = logging.getLogger("surgiplan.devices.mavlink")


class LinkLost(VehicleError):
    """No heartbeat from the vehicle for longer than the liveness timeout."""


class GroundStation:
    """surgiplan as a MAVLink ground station for one vehicle."""

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        heartbeat_period: float = 1.0,
        missed_heartbeats: int = 5,
        command_timeout: float = 1.5,
        command_retries: int = 5,
        mission_timeout: float = 1.5,
        mission_retries: int = 5,
        item_timeout: float = 0.5,
        upload_attempts: int = 3,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.link = endpoint
        self.heartbeat_period = heartbeat_period
        self.missed_heartbeats = missed_heartbeats
        self.command_timeout = command_timeout
        self.command_retries = command_retries
        self.mission_timeout = mission_timeout
        self.mission_retries = mission_retries
        #: how long a download waits for each item, and a parameter read or set for its PARAM_VALUE, before
        #: asking again: the vehicle answers these at once (MAVSDK's default timeout, 0.5 s)
        self.item_timeout = item_timeout
        self.upload_attempts = upload_attempts
        self.clock = clock
        self.vehicle = VehicleState()
        self.samples: list[PositionSample] = []
        self._recording = False
        self.check_liveness = True
        self.step = "connect"
        #: called after every pump with the vehicle's messages and the wall time (offboard streaming)
        self.tickers: list[Callable[[list, float], None]] = []
        self._next_heartbeat = -math.inf
        self._transactions: list = []

    @property
    def recording(self) -> bool:
        """Whether the vehicle's LOCAL_POSITION_NED are the flight's samples; a change is noted in the telemetry
        log (:mod:`.tlog`), so that a replay takes the same samples."""
        return self._recording

    @recording.setter
    def recording(self, value: bool) -> None:
        if bool(value) != self._recording:
            self.link.note(RECORDING_STARTED if value else RECORDING_STOPPED)
        self._recording = bool(value)

    @property
    def target(self) -> tuple[int, int]:
        return self.vehicle.system_id, self.vehicle.component_id

    @property
    def liveness_timeout(self) -> float:
        return self.missed_heartbeats * self.heartbeat_period

    # ------------------------------------------------------------------ the loop
    def send(self, messages) -> None:
        for message in messages:
            self.link.send(message)

    def _heartbeat(self, now: float) -> None:
        if now >= self._next_heartbeat:
            self.link.send(
                mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
                )
            )
            self._next_heartbeat = now + self.heartbeat_period

    def pump(self, timeout: float = 0.0) -> list:
        """Wait up to ``timeout`` s for traffic; process it; return the vehicle's messages.

        Raises :class:`LinkLost` when the vehicle's heartbeat has been missing for too long.
        """
        now = self.clock()
        self._heartbeat(now)
        deadlines = [t.deadline for t in self._transactions] + [self._next_heartbeat, now + timeout]
        self.link.wait(max(0.0, min(deadlines) - now))
        now = self.clock()
        mine = []
        for message in self.link.receive():
            if self.vehicle.system_id and message.get_srcSystem() != self.vehicle.system_id:
                continue
            self._update(message, now)
            for transaction in self._transactions:
                self.send(transaction.on_message(message, now))
            mine.append(message)
        for transaction in self._transactions:
            self.send(transaction.on_timer(now))
        if self.recording and any(m.get_type() == "LOCAL_POSITION_NED" for m in mine):
            self.vehicle.link.append((self.vehicle.vehicle_time, self.link.lost_in, self.link.counted_in))
        for ticker in list(self.tickers):
            ticker(mine, now)
        self._heartbeat(now)
        if self.check_liveness and self.vehicle.system_id:
            silent = now - self.vehicle.last_heartbeat
            if silent > self.liveness_timeout:
                raise LinkLost(
                    f"the vehicle stopped answering: no HEARTBEAT for {silent:.1f} s "
                    f"({self.missed_heartbeats} missed at {1 / self.heartbeat_period:g} Hz)",
                    step=self.step,
                )
        return mine

    def _update(self, message, now: float) -> None:
        v = self.vehicle
        kind = message.get_type()
        if kind == "HEARTBEAT":
            v.last_heartbeat = now
            v.heartbeats += 1
            v.armed = bool(message.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            v.custom_mode = int(message.custom_mode)
            v.mode = px4_mode_name(message.custom_mode) if v.autopilot == mavlink.MAV_AUTOPILOT_PX4 else ""
        elif kind == "LOCAL_POSITION_NED":
            sample = PositionSample(
                message.time_boot_ms / 1000.0, (message.x, message.y, message.z), (message.vx, message.vy, message.vz)
            )
            v.position = sample
            if self.recording:
                self.samples.append(sample)
        elif kind == "EXTENDED_SYS_STATE":
            v.landed_state = int(message.landed_state)
        elif kind == "MISSION_CURRENT":
            if int(message.seq) != v.mission_current:
                v.current_changes.append((int(message.seq), v.vehicle_time))
            v.mission_current = int(message.seq)
            v.mission_state = int(getattr(message, "mission_state", 0))
        elif kind == "MISSION_ITEM_REACHED":
            v.reached.append((int(message.seq), v.vehicle_time))
        elif kind == "STATUSTEXT":
            text = message.text if isinstance(message.text, str) else message.text.decode("utf-8", "replace")
            v.statustext.append(text)
            if "geofence" in text.lower():
                v.fence_events.append((v.vehicle_time, text))
            log.info("vehicle: %s", text)
        elif kind == "SYS_STATUS":
            bit = mavlink.MAV_SYS_STATUS_GEOFENCE
            fence = tuple(bool(int(x) & bit) for x in (message.onboard_control_sensors_present,
                          message.onboard_control_sensors_enabled, message.onboard_control_sensors_health))  # fmt: skip
            if v.fence is not None and fence[0] and fence[1] and v.fence[2] and not fence[2]:
                v.fence_events.append((v.vehicle_time, "SYS_STATUS: geofence not healthy (breached)"))
            v.fence = fence

    def wait_for(self, condition: Callable[[], bool], timeout: float, what: str) -> None:
        """Pump until ``condition()`` holds; :class:`VehicleError` naming ``what`` after ``timeout`` s."""
        deadline = self.clock() + timeout
        while not condition():
            remaining = deadline - self.clock()
            if remaining <= 0:
                raise VehicleError(f"{what} within {timeout:g} s", step=self.step)
            self.pump(min(remaining, 0.1))

    # ------------------------------------------------------------------ connecting
    def connect(self, timeout: float, system_id: int | None = None) -> VehicleState:
        """Wait for the vehicle's first HEARTBEAT (MAVLink 2 only) and adopt it as the target."""
        self.step = "connect"
        deadline = self.clock() + timeout
        heard: set[str] = set()
        while self.clock() < deadline:
            for message in self.pump(min(0.1, max(0.0, deadline - self.clock()))):
                if message.get_type() != "HEARTBEAT":
                    heard.add(message.get_type())
                    continue
                if message.type == mavlink.MAV_TYPE_GCS or message.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                    heard.add("a ground station's HEARTBEAT")
                    continue
                if system_id is not None and message.get_srcSystem() != system_id:
                    heard.add(f"HEARTBEAT of system {message.get_srcSystem()}")
                    continue
                if not is_mavlink2(message):
                    raise VehicleError(
                        f"the vehicle (system {message.get_srcSystem()}) speaks MAVLink 1; MAVLink 2 is required "
                        "(mission types, signing): enable it on the vehicle's link (PX4: MAV_PROTO_VER 2)",
                        step="connect",
                    )
                if message.get_header().incompat_flags & mavlink.MAVLINK_IFLAG_SIGNED and not self.link.signed:
                    # it would reject every unsigned command we send: say so now, not after the timeouts
                    raise VehicleError(
                        f"the vehicle (system {message.get_srcSystem()}) signs its messages (MAVLink 2 signing) "
                        "and will ignore unsigned commands: give the shared key in signing.key",
                        step="connect",
                    )
                v = self.vehicle
                v.system_id, v.component_id = message.get_srcSystem(), message.get_srcComponent()
                v.autopilot, v.vehicle_type = int(message.autopilot), int(message.type)
                self._update(message, self.clock())
                return v
        detail = f"heard only {', '.join(sorted(heard))}" if heard else "no MAVLink traffic at all"
        rejected = self.link.signature_rejections + self.link.stats.rejected
        if rejected:
            detail += f"; {rejected} frames were rejected (unsigned or wrongly signed: check the signing key)"
        raise VehicleError(
            f"no HEARTBEAT from a vehicle on '{self.link.connection}' within {timeout:g} s ({detail})", step="connect"
        )

    # ------------------------------------------------------------------ commands
    def command(
        self,
        command: int,
        params: Sequence[float] = (),
        *,
        accept_unsupported: bool = False,
        effect: Callable[[], bool] | None = None,
    ) -> int:
        """Send a command and wait for its final COMMAND_ACK; raises unless it is accepted.

        ``effect``: when the vehicle's telemetry already shows what the command does (armed, the
        new mode), a lost acknowledgement is not worth a retransmission: a late duplicate could do
        it a second time after the vehicle has moved on (arm it again after it landed).
        """
        transaction = CommandTransaction(
            command, params, self.target, timeout=self.command_timeout, retries=self.command_retries
        )

        def seen_done() -> None:
            if effect is not None and not transaction.finished and effect():
                transaction.result = RESULT_ACCEPTED  # seen done; its ACK was lost

        self._run([transaction], seen_done)
        if transaction.timed_out:
            raise VehicleError(
                f"no COMMAND_ACK for {command_name(command)} after {transaction.retransmissions + 1} attempts "
                f"({self.command_timeout:g} s apart)",
                step=self.step,
            )
        if transaction.result != RESULT_ACCEPTED:
            if accept_unsupported and transaction.result == mavlink.MAV_RESULT_UNSUPPORTED:
                return transaction.result
            reasons = f"; vehicle says: {self.vehicle.statustext[-1]}" if self.vehicle.statustext else ""
            raise VehicleError(
                f"the vehicle answered {command_name(command)} with {result_name(transaction.result)}{reasons}",
                step=self.step,
            )
        return transaction.result

    def set_message_interval(self, message_id: int, rate: float) -> bool:
        """Ask for a message at ``rate`` Hz (0: not at all); False when the vehicle does not support it."""
        interval = 1e6 / rate if rate > 0 else -1
        result = self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, [message_id, interval], accept_unsupported=True)
        return result == RESULT_ACCEPTED

    def stop_message(self, message_id: int) -> bool:
        """Ask the vehicle not to stream a message (any refusal is fine: it is only bandwidth)."""
        try:
            return self.set_message_interval(message_id, 0)
        except VehicleError:
            return False

    def request_message(self, message_type: str, message_id: int, timeout: float):
        """MAV_CMD_REQUEST_MESSAGE, then wait for the message itself.

        On a lossy link the message can be lost after its request was acknowledged: then it is requested
        again (the command protocol's timeout and retries), for at most ``timeout`` s overall."""
        got = []

        def collect(messages, now) -> None:  # it may come in the same datagram burst as the ACK
            got.extend(m for m in messages if m.get_type() == message_type)

        self.tickers.append(collect)
        try:
            deadline = self.clock() + timeout
            while not got:
                self.command(mavlink.MAV_CMD_REQUEST_MESSAGE, [message_id])
                wait = min(self.command_timeout, max(deadline - self.clock(), 0.0))
                until = self.clock() + wait
                while not got and self.clock() < until:
                    self.pump(0.05)
                if not got and self.clock() >= deadline:
                    raise VehicleError(f"the vehicle did not send {message_type} within {timeout:g} s", step=self.step)
        finally:
            self.tickers.remove(collect)
        return got[0]

    def set_mode(self, mode: str, timeout: float = 5.0) -> None:
        """Switch flight mode (PX4 custom modes), wait for the ACK and for the HEARTBEAT to show it."""
        shown = self.vehicle.mode == mode

        def changed() -> bool:
            return self.vehicle.mode == mode and not shown

        self.command(mavlink.MAV_CMD_DO_SET_MODE, px4_mode_command(mode), effect=changed)
        self.wait_for(lambda: self.vehicle.mode == mode, timeout, f"the vehicle's HEARTBEAT did not show mode {mode}")

    def arm(self, timeout: float = 5.0) -> None:
        was_armed = self.vehicle.armed
        self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1], effect=lambda: self.vehicle.armed and not was_armed)
        self.wait_for(lambda: self.vehicle.armed, timeout, "the vehicle's HEARTBEAT did not show it armed")

    # ------------------------------------------------------------------ missions
    def upload(
        self, items: Sequence[MissionItem], progress=None, *, legacy: bool = False, mission_type: int = MISSION
    ) -> tuple[UploadStatistics, int]:
        """Upload a list; returns the statistics of the successful transfer and the number of transfers.

        ``legacy``: as MISSION_ITEM (a vehicle without MAV_PROTOCOL_CAPABILITY_MISSION_INT)."""
        last_error = ""
        for attempt in range(1, self.upload_attempts + 1):
            upload = MissionUpload(
                items, *self.target, timeout=self.mission_timeout, retries=self.mission_retries, legacy=legacy,
                mission_type=mission_type,
            )  # fmt: skip
            done = 0

            def advance(upload: MissionUpload = upload) -> None:  # this attempt's transfer
                nonlocal done
                if progress is not None and len(upload.requested) > done:
                    progress.advance(len(upload.requested) - done)
                    done = len(upload.requested)

            self._run([upload], advance)
            if upload.state == "done":
                return upload.stats, attempt
            if upload.result is not None and upload.result != mavlink.MAV_MISSION_OPERATION_CANCELLED:
                raise VehicleError(upload.error, step=self.step)
            last_error = upload.error or "the vehicle cancelled the transfer (MAV_MISSION_OPERATION_CANCELLED)"
            if progress is not None:
                progress.update(0)
            log.warning("mission upload attempt %d failed: %s", attempt, last_error)
        raise VehicleError(f"{last_error} ({self.upload_attempts} transfers tried)", step=self.step)

    def _run(self, transactions: list, after_pump: Callable[[], None] | None = None) -> None:
        """Start the transactions and pump the link until every one has finished (each ends by its answer
        or after its retries), calling ``after_pump`` after each pump; the link routes them their messages."""
        self._transactions.extend(transactions)
        try:
            for transaction in transactions:
                self.send(transaction.start(self.clock()))
            while not all(transaction.finished for transaction in transactions):
                self.pump(0.1)
                if after_pump is not None:
                    after_pump()
        finally:
            for transaction in transactions:
                self._transactions.remove(transaction)

    def _exchange(self, transaction, what: str):
        """Run a mission exchange (download, clear) to its end; :class:`VehicleError` naming ``what``."""
        self._run([transaction])
        if transaction.state != "done":
            raise VehicleError(f"{what}: {transaction.error}", step=self.step)
        return transaction

    def download(self, mission_type: int = MISSION, *, legacy: bool = False) -> list[MissionItem]:
        """Download a list (mission, fence or rally points) from the vehicle; tried ``upload_attempts`` times."""
        for attempt in range(1, self.upload_attempts + 1):
            download = MissionDownload(
                *self.target, timeout=self.mission_timeout, retries=self.mission_retries, mission_type=mission_type,
                legacy=legacy, item_timeout=self.item_timeout,
            )  # fmt: skip
            try:
                return self._exchange(download, "mission download").items
            except VehicleError:
                if download.result is not None or attempt == self.upload_attempts:
                    raise
                log.warning("mission download attempt %d failed: %s", attempt, download.error)
        raise AssertionError("unreachable")

    def clear(self, mission_type: int = MISSION) -> None:
        """MISSION_CLEAR_ALL for one list (or MAV_MISSION_TYPE_ALL), acknowledged."""
        clear = MissionClear(
            *self.target, timeout=self.mission_timeout, retries=self.mission_retries, mission_type=mission_type
        )
        self._exchange(clear, "mission clear")

    # ------------------------------------------------------------------ parameters
    @property
    def bytewise_params(self) -> bool:
        """Whether INT32 parameters travel bytewise (PX4, or the capability bit) rather than C-cast."""
        caps = self.vehicle.capabilities or 0
        if caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST:
            return False
        return bool(caps & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE) or (
            self.vehicle.autopilot == mavlink.MAV_AUTOPILOT_PX4
        )

    @property
    def item_retries(self) -> int:
        """Retries of the quick exchanges (an item, a parameter): as many as fit a command's patience."""
        return max(
            self.command_retries, math.ceil(self.command_timeout * (self.command_retries + 1) / self.item_timeout) - 1
        )

    def _param(self, transaction: ParamTransaction) -> ParamTransaction:
        self._run([transaction])
        return transaction

    def read_param(self, name: str) -> tuple[float | int, int]:
        """A parameter's value and MAV_PARAM_TYPE; :class:`VehicleError` when the vehicle does not answer."""
        return self.read_params([name])[name]

    def read_params(self, names: Sequence[str]) -> dict[str, tuple[float | int, int]]:
        """Several parameters at once (their requests and retries in parallel): name -> (value, MAV_PARAM_TYPE)."""
        reads = [
            ParamTransaction(
                name, self.target, bytewise=self.bytewise_params, timeout=self.item_timeout,
                retries=self.item_retries,
            )
            for name in names
        ]  # fmt: skip
        self._run(reads)
        for read in reads:
            if read.timed_out:
                raise VehicleError(
                    f"the vehicle did not send parameter {read.name} after {read.retransmissions + 1} requests "
                    f"({self.item_timeout:g} s apart): it has no such parameter",
                    step=self.step,
                )
        return {read.name: (read.result, read.result_kind) for read in reads}

    def download_params(self) -> ParamDownload:
        """Every parameter (PARAM_REQUEST_LIST, then by index what a lossy link lost); :attr:`ParamDownload.values`
        holds them. :class:`VehicleError` when the download is given up (its retries, its time)."""
        download = ParamDownload(
            self.target, bytewise=self.bytewise_params, timeout=self.command_timeout, retries=self.command_retries,
            item_timeout=self.item_timeout, item_retries=self.item_retries,
        )  # fmt: skip
        self._run([download])
        if download.failed:
            raise VehicleError(f"parameter download: {download.error}", step=self.step)
        return download

    def set_param(self, name: str, value: float | int, kind: int = mavlink.MAV_PARAM_TYPE_REAL32) -> float | int:
        """Set a parameter and check the vehicle's PARAM_VALUE says it took the value; returns it."""
        write = self._param(
            ParamTransaction(
                name, self.target, value=value, kind=kind, bytewise=self.bytewise_params,
                timeout=self.item_timeout, retries=self.item_retries,
            )
        )  # fmt: skip
        if write.timed_out:
            raise VehicleError(f"the vehicle did not confirm setting {name} to {value:g}", step=self.step)
        if np.float32(write.result) != np.float32(value):
            reasons = f"; vehicle says: {self.vehicle.statustext[-1]}" if self.vehicle.statustext else ""
            raise VehicleError(
                f"the vehicle kept {name} at {write.result:g} when set to {value:g}{reasons}", step=self.step
            )
        return write.result

    def autopilot_version(self, timeout: float = 5.0):
        """AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE); its capabilities are kept in :attr:`vehicle`."""
        message = self.request_message("AUTOPILOT_VERSION", mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, timeout)
        self.vehicle.capabilities = int(message.capabilities)
        return message

    # ------------------------------------------------------------------ offboard
    def position_target(self, vehicle_time: float, position, velocity, acceleration):
        """A SET_POSITION_TARGET_LOCAL_NED (position, velocity and acceleration; yaw ignored) for ``vehicle_time``."""
        ignore = mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
        p, v, a = (np.asarray(x, float) for x in (position, velocity, acceleration))
        return mavlink.MAVLink_set_position_target_local_ned_message(
            round(vehicle_time * 1000) & 0xFFFFFFFF,
            *self.target,
            mavlink.MAV_FRAME_LOCAL_NED,
            ignore,
            *p,
            *v,
            *a,
            0.0,
            0.0,
        )
